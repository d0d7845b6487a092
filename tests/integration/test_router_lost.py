"""A process that has lost every router says so at once, and again when one is back; a world
that flew on alone says so, marks its summary degraded and exits non-zero.

Real processes, real sessions: a swarm started by hand (router, leader, six agents, world, each
a Zenoh client of the router, lock-step), whose router is SIGKILLed mid-run and never comes back
(the world of issue 29 held every robot at zero to the end, wrote ``complete: true`` and exited
0 in silence); and one agent whose router is killed and started again.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from fxswarm.launch.launcher import free_port
from fxswarm.runtime.zenoh_bus import ZenohBus, ZenohOptions

from support import PAPER_FAST, stop_processes, wait_for_line

pytestmark = [pytest.mark.zenoh, pytest.mark.timeout(600)]

# The hand-run world's run (200 ticks): the router is killed once it has passed 0.2 s, so the kill
# has 1.8 s to land before the end, the watcher's delay under load included.
DURATION_S = 2.0
TICKS = round(DURATION_S / 0.01)


def fxswarm(*args, log: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "fxswarm.cli", *map(str, args)], stdout=log.open("w"),
                            stderr=subprocess.STDOUT)


def test_a_hand_run_world_whose_router_is_gone_says_so_marks_the_run_degraded_and_exits_1(tmp_path):
    scenario = tmp_path / "short.toml"  # 2 s: after the router's death, the world closes a tick per 0.1 s
    text = PAPER_FAST.read_text()
    assert "duration = 40.0" in text
    scenario.write_text(text.replace("duration = 40.0", f"duration = {DURATION_S}"))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    swarm = f"lost-{uuid.uuid4().hex[:8]}"
    run = tmp_path / "run"
    common = ["--mode", "client", "--connect", endpoint, "--no-multicast", "--swarm", swarm, "--clock", "lockstep",
              "--out", run]
    router = fxswarm("router", "--listen", endpoint, "--swarm", swarm, log=tmp_path / "router.log")
    procs = [router, fxswarm("leader", scenario, *common, log=tmp_path / "leader.log")]
    procs += [fxswarm("agent", scenario, *common, "--id", i, log=tmp_path / f"agent{i}.log") for i in range(1, 7)]
    # Its robots went with the router: held for --rejoin-timeout (60 s by default), then counted gone.
    world = fxswarm("world", scenario, *common, "--rejoin-timeout", "2", log=tmp_path / "world.log")
    procs.append(world)
    watch = ZenohBus(swarm, ZenohOptions("client", (endpoint,), (), False, connect_timeout_ms=60_000))
    try:
        seen = [-1.0]
        watch.subscribe("world/state", lambda _topic, msg: seen.__setitem__(0, max(seen[0], msg.t)))
        deadline = time.monotonic() + 300
        while seen[0] < 0.2:
            assert time.monotonic() < deadline and world.poll() is None, (tmp_path / "world.log").read_text()
            watch.poll(0.1)
        router.kill()
        router.wait()
        killed_t = seen[0]
        said = wait_for_line(tmp_path / "world.log", "lost every router", [world])  # at once, mid-run
        code = world.wait(300)
        for name in ["leader", *(f"agent{i}" for i in range(1, 7))]:
            wait_for_line(tmp_path / f"{name}.log", "lost every router")
    finally:
        watch.close()
        stop_processes(procs)
    log = (tmp_path / "world.log").read_text()
    print(said, log.strip().splitlines()[-1], sep="\n")
    assert code == 1, log
    assert "heard none of its 6 robots" in log and "the run is not a success" in log, log
    summary = json.loads((run / "summary.json").read_text())
    # complete: every tick ran; degraded: not a healthy run, and which robots it could not hear.
    assert summary["complete"] and summary["ticks"] == TICKS
    assert summary["degraded"]["robots"] == [1, 2, 3, 4, 5, 6]
    assert 0 < summary["degraded"]["ticks"] < TICKS
    (outage,) = summary["router_outages"]
    assert outage["end"] is None and outage["ticks"] > 0, outage
    assert killed_t <= outage["start"] <= killed_t + 0.2, (killed_t, outage)  # said when it happened
    assert outage["ticks"] == round((DURATION_S - outage["start"]) / 0.01), outage


def test_an_agent_says_it_lost_every_router_and_that_it_is_back(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    swarm = f"back-{uuid.uuid4().hex[:8]}"
    router_args = ("router", "--listen", endpoint, "--swarm", swarm)
    router = fxswarm(*router_args, log=tmp_path / "router.log")
    log = tmp_path / "agent.log"
    agent = fxswarm("agent", PAPER_FAST, "--id", "1", "--mode", "client", "--connect", endpoint, "--no-multicast",
                    "--swarm", swarm, "--out", tmp_path / "run", log=log)
    procs = [router, agent]
    try:
        watch = ZenohBus(swarm, ZenohOptions("client", (endpoint,), (), False, connect_timeout_ms=60_000))
        up: list[str] = []
        watch.watch_alive("agent/1", lambda name, is_up: up.append(name) if is_up else None)
        deadline = time.monotonic() + 60
        while not up:  # its session is open, its token declared
            assert time.monotonic() < deadline, log.read_text()
            watch.poll(0.1)
        watch.close()
        assert "lost every router" not in log.read_text()
        router.kill()
        router.wait()
        wait_for_line(log, "lost every router", [agent])
        procs[0] = fxswarm(*router_args, log=tmp_path / "router-again.log")
        back = wait_for_line(log, "reached the swarm again", [agent])
        agent.terminate()
        assert agent.wait(30) == 0, log.read_text()
    finally:
        stop_processes(procs)
    print(back)
    counters = json.loads((tmp_path / "run" / "processes" / "agent-1.json").read_text())
    (outage,) = counters["router_outages"]
    assert outage["end"] is not None and outage["end"] >= outage["start"], outage
