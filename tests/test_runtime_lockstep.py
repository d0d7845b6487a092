"""Lock-step over real processes and real Zenoh sessions: exactness and locality."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from fxswarm.core.scenario import load
from fxswarm.runtime.launcher import ZENOH_RUNTIME

PAPER_FAST = Path(__file__).resolve().parents[1] / "configs" / "paper-fast.toml"


@pytest.mark.zenoh
@pytest.mark.parametrize("topology", ["mesh", "routed"])
def test_lockstep_run_is_bit_identical_to_the_in_memory_sim_and_agents_hear_only_neighbours(launch_swarm, topology):
    swarm = launch_swarm(PAPER_FAST, duration=1.5, topology=topology)
    assert swarm.swarm.options.mode == ("peer" if topology == "mesh" else "client")
    summary = swarm.wait_done(timeout=120)
    swarm.assert_matches_sim()
    sc = load(swarm.swarm.config)
    assert summary["complete"] and summary["missed_ticks"] == 0 and summary["ticks"] == sc.ticks

    # Locality, counted: each tick an agent hears its sensing, each neighbour's estimate and,
    # if pinned, the leader, and nothing else (a non-neighbour's estimate would show here).
    procs = summary["processes"]
    assert set(procs) == {"world-0", "leader-0"} | {f"agent-{r.id}" for r in sc.robots}
    for r in sc.robots:
        c = procs[f"agent-{r.id}"]
        heard = 1 + len(sc.neighbours(r.id)) + int(sc.is_pinned(r.id))
        assert c["received"] == sc.ticks * heard, (r.id, c)
        assert c["sent"] == 2 * sc.ticks and c["invalid"] == 0 and c["stale"] == 0
    assert procs["world-0"]["received"] == sc.ticks * sc.n
    assert procs["leader-0"]["received"] == sc.ticks


@pytest.mark.zenoh
def test_a_mesh_swarm_runs_on_its_direct_links_when_the_router_dies(launch_swarm):
    """In a mesh the router is only where the peers met: killed once the links are up (and the
    world has ticked), the run still completes, bit for bit the in-memory sim; routed, every
    message would have gone through it."""
    swarm = launch_swarm(PAPER_FAST, duration=4.0)
    assert swarm.swarm.topology == "mesh"  # auto, 6 robots
    environ = Path(f"/proc/{swarm.pid('agent-1')}/environ").read_bytes().split(b"\0")
    runtime = os.environ.get("ZENOH_RUNTIME", ZENOH_RUNTIME)  # the launcher's, unless the user set one
    assert f"ZENOH_RUNTIME={runtime}".encode() in environ
    swarm.wait_for_sim_time(0.2)
    # The world came last: wait until the launcher's own peer session links to every process
    # (world, leader, 6 agents) directly, a sign that gossip has done its work.
    session, end = swarm.swarm.bus.session, time.monotonic() + 30
    while len(session.info.peers_zid()) < 8 and time.monotonic() < end:
        swarm.pump(0.05)
    assert len(session.info.peers_zid()) == 8, "the mesh did not form"
    swarm.kill("router")
    assert swarm.sim_time() < 3.5, "the run was nearly over before the router died: nothing tested"
    summary = swarm.wait_done(timeout=120)
    swarm.assert_matches_sim()
    assert summary["complete"] and summary["missed_ticks"] == 0
