"""``fxswarm attach``: an observer that joins through the router rebuilds the world's own run folder.

Real processes (router, leader, six agents, world; lock-step paper-fast) on this machine, each a
Zenoh client of the router; the world waits for the observer's liveliness (``--wait-for
observer/0``), and the observer takes the scenario from the router (``--scenario``), as it does
from a stack's router on another host.
"""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from fxswarm.launch.launcher import free_port

from support import port_nobody_listens_on, stop_processes, wait_for_line

pytestmark = [pytest.mark.zenoh, pytest.mark.timeout(600)]

REPO = Path(__file__).resolve().parents[2]
SCENARIO = REPO / "configs" / "paper-fast.toml"


def fxswarm(*args: str, log: Path, **popen) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "fxswarm.cli", *args], stdout=log.open("w"),
                            stderr=subprocess.STDOUT, **popen)


def sigint_ignored() -> None:
    """What a non-interactive shell does to a job it starts with ``&``, before its exec."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def roles_waiting_for_an_observer(tmp_path: Path, common: list[str]) -> list[subprocess.Popen]:
    """Leader, six agents and the world (last; it starts its clock once observer/0 is up), by hand."""
    procs = [fxswarm("leader", str(SCENARIO), *common, log=tmp_path / "leader.log")]
    for i in range(1, 7):
        procs.append(fxswarm("agent", str(SCENARIO), *common, "--id", str(i), log=tmp_path / f"agent{i}.log"))
    return procs + [fxswarm("world", str(SCENARIO), *common, "--wait-for", "observer/0", "--tick-timeout", "5",
                            log=tmp_path / "world.log")]


@pytest.mark.slow
def test_attach_writes_the_same_trajectory_and_figures_as_the_world(tmp_path):
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    swarm = f"attach-{uuid.uuid4().hex[:8]}"
    run = tmp_path / "run"
    common = ["--mode", "client", "--connect", endpoint, "--no-multicast", "--swarm", swarm,
              "--clock", "lockstep", "--out", str(run)]
    procs = [fxswarm("router", "--listen", endpoint, "--swarm", swarm, "--scenario", str(SCENARIO),
                     log=tmp_path / "router.log")]
    try:
        attach = fxswarm("attach", endpoint, "--swarm", swarm, "--out", str(tmp_path / "seen"), "--timeout", "300",
                         log=tmp_path / "attach.log")
        procs.append(attach)
        procs += roles_waiting_for_an_observer(tmp_path, common)
        world = procs[-1]
        assert world.wait(420) == 0, (tmp_path / "world.log").read_text()
        code = attach.wait(120)
        said = (tmp_path / "attach.log").read_text()
        assert code == 0, said
    finally:
        stop_processes(procs)
    print(said.strip().splitlines()[-1])
    seen, own = tmp_path / "seen", run
    assert (seen / "scenario.toml").read_text() == SCENARIO.read_text(), "the scenario came from the router"
    with np.load(own / "trajectory.npz") as a, np.load(seen / "trajectory.npz") as b:
        assert sorted(a.files) == sorted(b.files)
        for key in a.files:
            assert np.array_equal(a[key], b[key]), key
    mine, theirs = json.loads((seen / "summary.json").read_text()), json.loads((own / "summary.json").read_text())
    for key in ("ticks", "min_object_distance_m", "min_obstacle_distance_m", "formation_error_final_m",
                "estimate_error_final_m", "formation_settle_s", "estimate_settle_s", "avoidance_episodes"):
        assert mine[key] == theirs[key], key
    assert mine["complete"] and mine["states_missed"] == 0 and mine["restarts"] == {}
    assert mine["record"]["from"] == "world"
    assert mine["logger"] == {"seen": False, "died": False, "alive_at_end": False}
    assert (seen / "recording.rrd").stat().st_size > 100_000


def test_attach_writes_what_it_saw_when_the_world_dies_mid_run(launch_swarm, tmp_path):
    """The world is the simulation: once it is killed the run cannot end, and attach used to wait
    for run/over until its --timeout (600 s by default) and then return with nothing written.
    Now, once the world's token is gone, it writes the ticks it saw and says the run is incomplete."""
    swarm = launch_swarm(SCENARIO, clock="realtime", speed=1.0, topology="routed")
    log = tmp_path / "attach.log"
    attach = fxswarm("attach", swarm.swarm.endpoint, "--swarm", swarm.swarm.swarm, "--out", str(tmp_path / "seen"),
                     "--config", str(SCENARIO), "--rerun", "none", log=log)
    try:
        def attach_saw_states() -> bool:  # its progress lines: "t =   2.26 / 40 s, ..."
            return any(float(t) > 0 for t in re.findall(r"t = +([\d.]+) /", log.read_text()))

        seen = swarm.wait_for(attach_saw_states, "attach to report the run under way", timeout=60)
        swarm.kill("world")
        code = attach.wait(60)
    finally:
        if attach.poll() is None:
            attach.kill()
            attach.wait()
    said = log.read_text()
    assert code == 1, said
    assert "the world left at t = " in said and "without ending the run" in said, said
    summary = json.loads((tmp_path / "seen" / "summary.json").read_text())
    assert not summary["complete"] and 0 < summary["ticks"] < 4000, summary
    print(f"world killed at t = {seen:.2f} s; attach wrote {summary['ticks']} ticks")


@pytest.mark.parametrize("sig, code, background", [(signal.SIGTERM, 128 + 15, False), (signal.SIGINT, 130, False),
                                                   (signal.SIGINT, 130, True)])
def test_attach_waiting_for_a_router_stops_at_once_on_a_signal(tmp_path, sig, code, background):
    """Its handlers only set a flag for the watch loop, and they used to be in place while it
    waited for the router: a SIGTERM or Ctrl-C then went unheeded until --timeout (600 s).
    ``background``: started as ``cmd &`` in a script (SIGINT ignored), where Python installs no
    KeyboardInterrupt, a SIGINT went unheeded too (as the suite itself, run that way, showed)."""
    log = tmp_path / "attach.log"
    with port_nobody_listens_on() as port:
        attach = fxswarm("attach", f"tcp/127.0.0.1:{port}", "--swarm", "nobody", "--out", str(tmp_path / "seen"),
                         log=log, preexec_fn=sigint_ignored if background else None)
        try:
            deadline = time.monotonic() + 60
            while "waiting for the router" not in log.read_text():  # its own line: it is in the wait
                assert attach.poll() is None and time.monotonic() < deadline, log.read_text()
                time.sleep(0.05)
            attach.send_signal(sig)
            assert attach.wait(10) == code, log.read_text()
        finally:
            if attach.poll() is None:
                attach.kill()
                attach.wait()


@pytest.mark.slow
def test_attach_writes_the_worlds_own_record_whole_when_its_live_stream_loses_ticks(tmp_path):
    """The live stream to attach breaks mid-run (attach's own router, meshed with the swarm's, is
    SIGKILLed and started again): it misses ticks, yet at the run's end it fetches the world's own
    record (world/record) and writes it whole: every tick, equal to the world's, exit 0."""
    from fxswarm.runtime.zenoh_bus import ZenohBus, ZenohOptions

    swarm_ep, attach_ep = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    swarm = f"lossy-{uuid.uuid4().hex[:8]}"
    run, seen = tmp_path / "run", tmp_path / "seen"
    common = ["--mode", "client", "--connect", swarm_ep, "--no-multicast", "--swarm", swarm,
              "--clock", "lockstep", "--out", str(run)]
    attach_router = ("router", "--listen", attach_ep, "--connect", swarm_ep, "--swarm", swarm)
    procs = [fxswarm("router", "--listen", swarm_ep, "--swarm", swarm, log=tmp_path / "router.log"),
             fxswarm(*attach_router, log=tmp_path / "router-attach.log")]
    log = tmp_path / "attach.log"
    watch = None
    try:
        attach = fxswarm("attach", attach_ep, "--swarm", swarm, "--out", str(seen), "--config", str(SCENARIO),
                         "--rerun", "none", "--timeout", "300", log=log)
        procs.append(attach)
        procs += roles_waiting_for_an_observer(tmp_path, common)
        world = procs[-1]
        watch = ZenohBus(swarm, ZenohOptions("client", (swarm_ep,), (), False, connect_timeout_ms=60_000))
        world_t = [-1.0]
        watch.subscribe("world/state", lambda _topic, msg: world_t.__setitem__(0, max(world_t[0], msg.t)))
        deadline = time.monotonic() + 300
        while world_t[0] < 1.0:  # the run is under way, seen through the swarm's router
            assert time.monotonic() < deadline and world.poll() is None, (tmp_path / "world.log").read_text()
            watch.poll(0.1)
        procs[1].kill()  # attach's path to the swarm breaks: what the world sends now never reaches it
        procs[1].wait()
        wait_for_line(log, "lost every router", [world, attach])
        lost_at = world_t[0]
        procs[1] = fxswarm(*attach_router, log=tmp_path / "router-attach-again.log")
        wait_for_line(log, "reached the swarm again", [world, attach])
        assert world.wait(420) == 0, (tmp_path / "world.log").read_text()
        code = attach.wait(120)
        said = log.read_text()
        assert code == 0, said
    finally:
        if watch is not None:
            watch.close()
        stop_processes(procs)
    print(f"attach's router killed at t = {lost_at:.2f} s; {said.strip().splitlines()[-1]}")
    mine, theirs = json.loads((seen / "summary.json").read_text()), json.loads((run / "summary.json").read_text())
    assert mine["states_missed"] > 0, "the live stream lost nothing: the test did not test"
    assert mine["record"]["from"] == "world" and mine["record"]["ticks"] == 4000, mine["record"]
    with np.load(run / "trajectory.npz") as a, np.load(seen / "trajectory.npz") as b:
        assert sorted(a.files) == sorted(b.files)
        assert len(b["t"]) == 4000
        for key in a.files:
            assert np.array_equal(a[key], b[key]), key
    assert (seen / "trajectory.npz").read_bytes() == (run / "trajectory.npz").read_bytes()
    for key, value in theirs.items():
        assert mine[key] == value, key
    assert mine["complete"] and mine["restarts"] == {}, mine["restarts"]  # our own blink is nobody's death
