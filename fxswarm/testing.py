"""Test a swarm as real processes: a pytest plugin (fixture ``launch_swarm``) and its handle.

Registered as the pytest plugin ``fxswarm`` (entry point ``pytest11``), so a
project that installs fxswarm can write::

    def test_robot_3_rejoins(launch_swarm):
        swarm = launch_swarm("configs/paper-fast.toml", duration=8.0, clock="realtime", speed=2.0)
        swarm.wait_for_sim_time(2.0)
        swarm.kill("agent-3")
        swarm.wait_for_sim_time(3.0)
        swarm.restart("agent-3")
        summary = swarm.wait_done()
        assert summary["complete"] and summary["min_object_distance_m"] > 1.0

Every swarm runs on its own free port under a unique swarm name, and is
always torn down (no process left behind), pass or fail.
"""

from __future__ import annotations

import itertools
import os
import time
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from fxswarm.core.tomltext import dump_toml

_counter = itertools.count(1)


# --- scenario files with overrides ------------------------------------------------------------


def scenario_with(base: str | Path, folder: str | Path, **overrides: Any) -> Path:
    """Write a copy of scenario ``base`` into ``folder`` with ``[scenario]`` keys overridden.

    A key with a dot names another table: ``**{"faults.seed": 3}``.
    """
    data = tomllib.loads(Path(base).read_text())
    for key, value in overrides.items():
        table, _, name = key.rpartition(".")
        data.setdefault(table or "scenario", {})[name] = value
    out = Path(folder) / f"{Path(base).stem}-{next(_counter)}.toml"
    out.write_text(dump_toml(data))
    return out


# --- the handle -----------------------------------------------------------------------------------


class SwarmUnderTest:
    """A running swarm as a test sees it; wraps :class:`fxswarm.launch.swarm.Swarm`.

    Process names: ``world``, ``leader``, ``router``, ``logger``, ``agent-<id>``.
    """

    def __init__(self, config: str | Path, out: str | Path, *, clock: str = "lockstep", speed: float = 1.0,
                 logger: bool = False, tick_timeout: float = 1.0, lease_ms: int | None = None,
                 topology: str | None = None, secure: str | Path | None = None, audit: bool = False,
                 world_args: tuple[str, ...] = (), routers: int = 1) -> None:
        from fxswarm.launch.swarm import Swarm

        swarm_name = f"test-{os.getpid()}-{next(_counter)}"
        self.swarm = Swarm(str(config), Path(out), clock=clock, speed=speed, swarm=swarm_name, logger=logger,
                           tick_timeout=tick_timeout, lease_ms=lease_ms, topology=topology,
                           secure=str(secure) if secure else None, audit=audit, world_args=tuple(world_args),
                           routers=routers)
        self.deaths: list = []  # unplanned deaths seen so far (processes.Death)

    @property
    def scenario(self):
        return self.swarm.scenario

    @property
    def out(self) -> Path:
        return self.swarm.out

    def start(self, timeout: float = 60.0) -> "SwarmUnderTest":
        self.swarm.start(timeout=timeout)
        return self

    def pump(self, timeout: float = 0.05) -> None:
        deaths, _ = self.swarm.tend(timeout)  # a dead router started again, the scenario's process faults sent
        self.deaths += deaths

    def sim_time(self) -> float:
        return self.swarm.sim_time()

    def wait_for(self, condition: Callable[[], bool], what: str, timeout: float = 60.0) -> float:
        """Block until ``condition()`` holds (checked as the world's reports arrive); return the
        simulation time heard. ``what`` names the wait in the error if it times out or the world
        ends first."""
        end = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > end:
                raise TimeoutError(f"simulation time {self.swarm.sim_time():.2f} s after {timeout:g} s, "
                                   f"waiting for {what}; deaths: {[d.describe() for d in self.deaths]}")
            if not self.swarm.children["world"].running():
                raise RuntimeError(f"the world ended at t = {self.swarm.sim_time():.2f} s before {what}")
            self.pump()
        return self.swarm.sim_time()

    def wait_for_sim_time(self, t: float, timeout: float = 60.0) -> float:
        """Block until the world has reported simulation time ``t`` (s); return the time heard."""
        return self.wait_for(lambda: self.swarm.sim_time() >= t - 1e-9, f"{t:g} s", timeout)

    def wait_for_silence(self, robot: int, ticks: int, timeout: float = 60.0) -> float:
        """Block until the world has gone ``ticks`` ticks without ``robot``'s command, as its state
        shows it: the links into the robot, as the robot last reported them, have aged that much
        (``WorldState.link_age``). A frozen or cut-off robot's silence, seen by the world itself."""
        from fxswarm.core.scenario import directed_links

        into = [k for k, (_, i) in enumerate(directed_links(self.scenario)) if i == robot]
        if not into:
            raise ValueError(f"robot {robot}: no links into it in scenario {self.scenario.name!r}, so the "
                             f"world's state cannot show its silence")

        def silent() -> bool:
            s = self.swarm.state
            return s is not None and len(s.link_age) > 0 and min(int(s.link_age[k]) for k in into) >= ticks

        return self.wait_for(silent, f"robot {robot} silent for {ticks} ticks", timeout)

    def step(self, ticks: int = 1, timeout: float = 30.0) -> float:
        """Wait until ``ticks`` more ticks have been reported (the run is not paused)."""
        return self.wait_for_sim_time(self.sim_time() + ticks * self.scenario.dt, timeout)

    def state(self):
        """The latest :class:`~fxswarm.core.messages.WorldState` heard (None before the first)."""
        return self.swarm.state

    def position(self, robot: int):
        """Robot ``robot``'s latest true position (3,), m."""
        s = self.swarm.state
        assert s is not None, "no world state heard yet"
        return s.p[robot - 1].copy()

    def kill(self, name: str) -> None:
        self.swarm.kill(name)

    def terminate(self, name: str) -> None:
        import signal

        self.swarm.kill(name, signal.SIGTERM)

    def freeze(self, name: str) -> None:
        self.swarm.freeze(name)

    def thaw(self, name: str) -> None:
        self.swarm.thaw(name)

    def wait_alive(self, name: str, timeout: float = 30.0) -> None:
        """Block until ``name``'s liveliness token is up (e.g. again, after a freeze past the lease)."""
        self.swarm.wait_alive(name, timeout)

    def wait_gone(self, name: str, timeout: float = 10.0) -> None:
        """Block until ``name``'s liveliness token is gone (it died, or, frozen or cut off, its
        Zenoh lease ran out)."""
        self.swarm.wait_gone(name, timeout)

    def restart(self, name: str, timeout: float = 30.0) -> None:
        self.swarm.restart(name, timeout)

    def pid(self, name: str) -> int | None:
        return self.swarm.children[name].pid

    def pids(self) -> dict[str, int]:
        return {n: c.pid for n, c in self.swarm.children.items() if c.pid is not None}

    def wait_done(self, timeout: float = 120.0, expect_exit: int = 0) -> dict:
        """Wait for the world to finish, stop the rest, merge counters; return ``summary.json``.
        ``expect_exit``: the world's exit status the run should end with (1: it flew alone to the
        end, e.g. every agent gone; anything else raises)."""
        world = self.swarm.children["world"]
        end = time.monotonic() + timeout
        while world.running():
            if time.monotonic() > end:
                raise TimeoutError(f"the run did not finish within {timeout:g} s (t = {self.sim_time():.2f} s)")
            self.pump(0.1)
        if world.popen.returncode != expect_exit:
            from fxswarm.launch.processes import Death

            raise RuntimeError(Death(world, world.popen.returncode).describe())
        self.swarm.stop(grace=3.0)
        summary = self.swarm.merge_summary()
        assert summary is not None, f"no summary.json in {self.out}"
        return summary

    def summary(self) -> dict | None:
        return self.swarm.summary()

    def assert_matches_sim(self, keys: tuple[str, ...] | None = None) -> dict:
        """Assert the finished run's ``trajectory.npz`` is ``fxswarm sim``'s on the same scenario,
        bit for bit: every array (same names, dtypes and values), or only ``keys``. Returns the
        simulator's summary (lock-step runs only: real time is not meant to match)."""
        import numpy as np

        from fxswarm.core.scenario import load
        from fxswarm.runtime.output import load_trajectory
        from fxswarm.launch.sim import Simulation

        sim = Simulation(load(self.swarm.config))
        summary = sim.run()
        expected, got = sim.trajectory(), load_trajectory(self.out)
        if keys is None:
            assert sorted(got) == sorted(expected), (sorted(got), sorted(expected))
        for key in keys or expected:
            a, b = got[key], expected[key]
            if a.dtype == b.dtype and np.array_equal(a, b):
                continue
            where = f" (dtype {a.dtype}, the simulator's {b.dtype})" if a.dtype != b.dtype else ""
            if a.shape != b.shape:
                where += f" (shape {a.shape}, the simulator's {b.shape})"
            elif not where:
                where = f": first at index {tuple(int(i) for i in np.argwhere(a != b)[0])} (the tick first)"
            missed = (self.summary() or {}).get("missed_ticks")
            if missed:  # a tick closed by the world's --tick-timeout: wall time decided, not the law
                where += f"; the run closed {missed} tick(s) on its --tick-timeout, which the simulator never does"
            raise AssertionError(f"{key} differs from fxswarm sim's{where}")
        return summary

    def stop(self) -> dict[str, str]:
        return self.swarm.stop()


@pytest.fixture
def launch_swarm(tmp_path):
    """``launch_swarm(config, clock=..., speed=..., logger=False, topology=None, secure=None, **scenario_overrides)``
    -> a started swarm.

    Overrides are ``[scenario]`` keys (``duration=5.0``) or ``"table.key"``.
    Every swarm started is torn down at the end of the test.
    """
    made: list[SwarmUnderTest] = []

    def launch(config: str | Path = "configs/paper-fast.toml", *, clock: str = "lockstep", speed: float = 1.0,
               logger: bool = False, tick_timeout: float = 1.0, lease_ms: int | None = None, start: bool = True,
               topology: str | None = None, secure: str | Path | None = None, audit: bool = False,
               world_args: tuple[str, ...] = (), routers: int = 1, **overrides: Any) -> SwarmUnderTest:
        k = len(made) + 1
        path = scenario_with(config, tmp_path, **overrides) if overrides else Path(config)
        s = SwarmUnderTest(path, tmp_path / f"run-{k}", clock=clock, speed=speed, logger=logger,
                           tick_timeout=tick_timeout, lease_ms=lease_ms, topology=topology, secure=secure,
                           audit=audit, world_args=world_args, routers=routers)
        made.append(s)
        if start:
            s.start()
        return s

    yield launch
    for s in made:
        s.stop()
