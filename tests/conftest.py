"""Fixtures the test layers share (helpers are in ``support.py``; the project's own harness,
``fxswarm.testing``, is a pytest plugin giving ``launch_swarm``)."""

from __future__ import annotations

import dataclasses
import signal

import pytest

from fxswarm.launch.launcher import free_port
from fxswarm.runtime.zenoh_bus import ZenohBus, ZenohOptions
from support import PAPER_FAST, RECORDED_S, once_per_session, record_in_process

# On CI (CI=true) a skip, at collection too, fails unless .ci/run declared its prerequisite missing (docs/testing.md).
from prerequisites import pytest_make_collect_report, pytest_runtest_makereport  # noqa: F401  (pytest hooks)


#: The integration modules that took longest (wall, --durations, docs/testing.md): started first
#: on their workers, so the run does not end on one of them alone. A stale list costs only time.
LONGEST_FIRST = ("test_runtime_lockstep", "test_runtime_realtime", "test_router_restart", "test_runtime_shutdown",
                 "test_secure_swarm", "test_campaign_cli")


def pytest_collection_modifyitems(items):
    """A test that asks for the ROS 2 modules (fixtures ``ros2``, ``ros2_msgs``, which need
    prerequisite ros2) carries its marker, as prerequisites.py lists tests by marker.

    Then the order in which ``--dist loadscope`` hands the groups out (pytest_xdist_make_scheduler):
    the docker layer, LONGEST_FIRST, the other integration modules, and the unit modules last:
    seconds each, they fill the workers' ends."""
    for item in items:
        if {"ros2", "ros2_msgs"} & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.ros2)

    def rank(item) -> int:
        if item.get_closest_marker("docker"):
            return -1
        if item.path.parent.name == "unit":
            return len(LONGEST_FIRST) + 1
        stem = item.path.stem
        return LONGEST_FIRST.index(stem) if stem in LONGEST_FIRST else len(LONGEST_FIRST)
    items.sort(key=rank)  # stable: in their order within each rank


def scope(nodeid: str) -> str:
    """The group a test runs in under `make test`: the docker layer is one (its compose projects
    and stacks one at a time, as their bounds were measured, and one swarm-mode engine for the
    session; two at once, beside the integration layer, kept the machine at load 45 and failed),
    and any other test goes with its module, whose fixtures are then made once."""
    module = nodeid.split("::")[0]
    return "tests/docker" if module.startswith("tests/docker/") else module


def pytest_xdist_make_scheduler(config, log):
    """``--dist loadscope`` with :func:`scope`'s groups. (pytest-xdist's own ``xdist_group`` marks do
    nothing under pytest 9: they rename a node id that pytest no longer reads.)"""
    if config.getvalue("dist") != "loadscope":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class Groups(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return scope(nodeid)

    return Groups(config, log)


@pytest.fixture
def fxswarm_here(capsys):
    """``fxswarm_here(*ARGS)``: `fxswarm ARGS` run in this process, as the console script runs it;
    its exit code, stdout and stderr. For commands that refuse or compute and exit: a subprocess
    costs a new interpreter and its imports (about 0.35 s of CPU) for the same code path."""
    def run(*args) -> tuple[int, str, str]:
        from fxswarm.cli import main

        capsys.readouterr()
        # A command that gets as far as running installs its own: this process keeps its handlers.
        handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            code = main([str(a) for a in args])
        except SystemExit as exc:  # argparse's refusals
            code = exc.code
        finally:
            for sig, handler in handlers.items():
                signal.signal(sig, handler)
        out = capsys.readouterr()
        return code, out.out, out.err
    return run


@pytest.fixture
def router():
    """A Zenoh router (a session in this process) on a free port; its endpoint."""
    port = free_port()
    bus = ZenohBus("unused", ZenohOptions("router", listen=(f"tcp/127.0.0.1:{port}",), multicast=False))
    yield f"tcp/127.0.0.1:{port}"
    bus.close()


@pytest.fixture
def zenoh_client(router):
    """``zenoh_client(swarm)``: a client session of :func:`router`'s, closed at teardown."""
    opened: list[ZenohBus] = []

    def open_client(swarm: str) -> ZenohBus:
        bus = ZenohBus(swarm, ZenohOptions("client", connect=(router,), multicast=False))
        opened.append(bus)
        return bus

    yield open_client
    for bus in opened:
        bus.close()


@pytest.fixture(scope="module")
def scenario():
    """paper-fast cut to :data:`RECORDED_S` seconds (a ``Scenario``)."""
    from fxswarm.core.scenario import load

    return dataclasses.replace(load(PAPER_FAST), duration=RECORDED_S)


@pytest.fixture(scope="module")
def live_run(scenario, tmp_path_factory):
    """A lock-step simulation with the recorder on its bus; returns (rrd path, trajectory, recorder)."""
    from fxswarm.logger.recorder import RecorderOptions
    from fxswarm.runtime.output import write_run

    folder = tmp_path_factory.mktemp("live")
    rrd = folder / "recording.rrd"
    sim, summary, recorder = record_in_process(scenario, rrd, "test-live",
                                               RecorderOptions(rate_hz=20.0, velocities=True))
    write_run(folder, summary, sim.trajectory())
    return rrd, sim.trajectory(), recorder


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A 12 s paper-fast run (long enough to reach the first obstacle), written like `fxswarm sim`."""
    from fxswarm.core.scenario import load
    from fxswarm.launch.sim import Simulation
    from fxswarm.runtime.output import write_run

    sc = dataclasses.replace(load(PAPER_FAST), duration=12.0, source=str(PAPER_FAST))
    sim = Simulation(sc)
    folder = tmp_path_factory.mktemp("run")
    write_run(folder, sim.run(), sim.trajectory())
    return folder


@pytest.fixture(scope="session")
def paper_run(tmp_path_factory, worker_id):
    """configs/paper.toml as shipped, its 300 s simulated once per test session (about 7 s of CPU)
    for the tests that only read it: (scenario, summary, trajectory). The pytest-xdist workers
    share one run folder: the first to ask simulates, the others read its files."""
    import json

    import numpy as np

    from fxswarm.core.scenario import load
    from fxswarm.launch.sim import Simulation
    from fxswarm.runtime.output import write_run

    sc = load(PAPER_FAST.parent / "paper.toml")
    with once_per_session(tmp_path_factory, worker_id, "paper-run") as folder:
        if not (folder / "summary.json").is_file():  # written last
            sim = Simulation(sc)
            write_run(folder, sim.run(), sim.trajectory())
    with np.load(folder / "trajectory.npz") as saved:
        trajectory = dict(saved)
    return sc, json.loads((folder / "summary.json").read_text()), trajectory
