"""A Docker Swarm stack outlives its router: the router task killed (``docker kill``) mid-run,
Swarm starts a new one (``restart_policy: any``), every process reconnects and the lock-step run
completes with the figures of ``fxswarm sim`` (no tick closed by the timeout). Real engine, a
single-node Swarm initialised for the test if needed and left as found (tests/docker/conftest.py).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import uuid
from pathlib import Path

import pytest

from docker_support import TAG, leftovers, remove_stack, sh
from fxswarm.launch.launcher import free_port
from support import PAPER_FAST

pytestmark = [pytest.mark.docker, pytest.mark.stack, pytest.mark.timeout(1800)]


def router_container(stack: str) -> str | None:
    ids = sh("docker", "ps", "--filter", f"label=com.docker.swarm.service.name={stack}_router",
             "--format", "{{.ID}}").split()
    return ids[0] if ids else None


def test_stack_router_killed_mid_run_is_restarted_by_swarm_and_the_run_completes(stack_images):
    from fxswarm.core.scenario import load
    from fxswarm.launch.sim import Simulation
    from fxswarm.runtime.zenoh_bus import ZenohBus, ZenohOptions, wait_until

    stack = f"fxrt{uuid.uuid4().hex[:8]}"
    folder = Path(tempfile.mkdtemp(prefix="fxswarm-stack-router-"))
    port = free_port()
    text = Path(PAPER_FAST).read_text()
    assert "duration = 40.0" in text
    scenario = folder / "paper-fast-20.toml"
    scenario.write_text(text.replace("duration = 40.0", "duration = 20.0"))
    sh(sys.executable, "-m", "fxswarm.cli", "stack", str(scenario), "--out", str(folder / "deploy"),
       "--swarm", stack, "--wait-for", "logger/0", "--wait-for", "observer/0")
    env = {**os.environ, "FXSWARM_TAG": TAG, "FXSWARM_ROUTER_PORT": str(port), "FXSWARM_CLOCK": "lockstep",
           "FXSWARM_RUN": "run"}
    bus = None
    routers: set[str] = set()
    world_t = [-1.0]
    try:
        sh("docker", "stack", "deploy", "-c", str(folder / "deploy" / "stack.yml"), stack, env=env, timeout=300)
        # An observer through the router's published port: the world waits for it (observer/0).
        bus = ZenohBus(stack, ZenohOptions("client", (f"tcp/127.0.0.1:{port}",), (), False,
                                           connect_timeout_ms=600_000))
        bus.watch_alive("router/*", lambda name, up: (routers.add if up else routers.discard)(name))
        bus.subscribe("world/state", lambda _t, msg: world_t.__setitem__(0, max(world_t[0], msg.t)))
        bus.declare_alive("observer", 0)
        assert wait_until(bus, lambda: world_t[0] >= 2.0, 900), "the run did not reach t = 2 s"
        victim = router_container(stack)
        assert victim, "no running router task"
        killed_t = world_t[0]
        sh("docker", "kill", victim)
        assert wait_until(bus, lambda: "router/0" not in routers, 60), "the router's token did not go"
        # Swarm starts a new router task; the observer (and every process) reconnects by itself.
        assert wait_until(bus, lambda: "router/0" in routers, 300), "no new router task came up"
        replacement = router_container(stack)
        assert replacement and replacement != victim
        assert wait_until(bus, lambda: world_t[0] > killed_t + 1.0, 300), "the run did not go on"
        # The world's own summary, in the stack's runs volume, once it has written it.
        def summary_written() -> bool:
            out = sh("docker", "run", "--rm", "--user", "0", "-v", f"{stack}_runs:/r", "--entrypoint", "cat",
                     f"fxswarm-world:{TAG}", "/r/run/summary.json", check=False)
            if out.strip().startswith("{"):
                summary_written.value = json.loads(out)
                return True
            return False

        assert wait_until(bus, summary_written, 900), "the world wrote no summary"
        own = summary_written.value
    finally:
        if bus is not None:
            bus.close()
        remove_stack(stack)
    left = leftovers(stack)
    sim = Simulation(load(str(scenario))).run()
    shutil.rmtree(folder, ignore_errors=True)
    assert left == [], left
    print(f"router killed at t = {killed_t:.2f} s; world: complete {own['complete']}, "
          f"missed ticks {own['missed_ticks']}, asked again {own['processes']['world-0']['asked_again']}")
    assert own["complete"] is True and own["ticks"] == 2000, own
    assert own["missed_ticks"] == 0, own  # held through the outage, never closed a tick without a robot
    assert own["processes"]["world-0"]["asked_again"] >= 1
    for key in ("min_object_distance_m", "formation_error_final_m", "estimate_error_final_m"):
        assert own[key] == sim[key], key
