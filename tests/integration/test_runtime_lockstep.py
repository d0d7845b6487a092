"""Lock-step over real processes and real Zenoh sessions: exactness and locality."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from fxswarm.core.scenario import load
from fxswarm.launch.launcher import ZENOH_RUNTIME

from support import CONFIGS, PAPER_FAST, SHIPPED_CONFIGS


@pytest.mark.zenoh
@pytest.mark.parametrize("topology", ["mesh", "routed"])
def test_lockstep_run_is_bit_identical_to_the_in_memory_sim_and_agents_hear_only_neighbours(launch_swarm, topology):
    swarm = launch_swarm(PAPER_FAST, duration=1.5, topology=topology)
    assert swarm.swarm.options.mode == ("peer" if topology == "mesh" else "client")
    summary = swarm.wait_done(timeout=120)
    swarm.assert_matches_sim()
    sc = load(swarm.swarm.config)
    assert summary["complete"] and summary["missed_ticks"] == 0 and summary["ticks"] == sc.ticks

    # Locality, counted: each tick an agent hears its sensing, each neighbour's command (with the
    # estimate riding on it) and, if pinned, the leader, and nothing else (a non-neighbour's
    # would show here). A robot says one message per tick, plus its first estimate on its own:
    # from each neighbour that first estimate and ticks commands. The last command carries no
    # estimate and may still be on its way when the run ends and the robot leaves.
    procs = summary["processes"]
    assert set(procs) == {"world-0", "leader-0"} | {f"agent-{r.id}" for r in sc.robots}
    for r in sc.robots:
        c = procs[f"agent-{r.id}"]
        neighbours, pinned = len(sc.neighbours(r.id)), int(sc.is_pinned(r.id))
        needed = sc.ticks * (1 + neighbours + pinned)  # every sensing, estimate and leader state
        assert needed <= c["received"] <= needed + neighbours, (r.id, c)
        assert c["sent"] == sc.ticks + 1 and c["invalid"] == 0 and c["stale"] == 0
    # The world hears each robot's first estimate too (on its command key), and sends no clock:
    # the leader takes the tick from robot 1's sensing.
    assert procs["world-0"]["received"] == sc.ticks * sc.n + sc.n
    assert procs["world-0"]["sent"] == sc.ticks * (sc.n + 1)
    assert procs["leader-0"]["received"] == sc.ticks


@pytest.mark.zenoh
def test_a_mesh_swarm_runs_on_its_direct_links_when_the_router_dies(launch_swarm):
    """In a mesh the router is only where the peers met: killed once the links are up (and the
    world has ticked), the run still completes, bit for bit the in-memory sim; routed, every
    message would have gone through it.

    The mesh takes wall time to form (seconds on a loaded machine) and a lock-step world ticks as
    fast as the robots answer, so the wait for it would race the run's end. The world's clock is
    held instead (``--wait-for gate/0``, a token this test declares) until the mesh has formed:
    what is left between the clock's start and the kill is one signal, against 330 ticks."""
    swarm = launch_swarm(PAPER_FAST, duration=4.0, world_args=("--wait-for", f"{GATE}/0"))
    assert swarm.swarm.topology == "mesh"  # auto, 6 robots
    environ = Path(f"/proc/{swarm.pid('agent-1')}/environ").read_bytes().split(b"\0")
    runtime = os.environ.get("ZENOH_RUNTIME", ZENOH_RUNTIME)  # the launcher's, unless the user set one
    assert f"ZENOH_RUNTIME={runtime}".encode() in environ
    # Wait until the launcher's own peer session links to every process (world, leader, 6
    # agents) directly, a sign that gossip has done its work; the world waits for the gate.
    session, end = swarm.swarm.bus.session, time.monotonic() + 60
    while len(session.info.peers_zid()) < 8 and time.monotonic() < end:
        swarm.pump(0.05)
    assert len(session.info.peers_zid()) == 8, "the mesh did not form"
    assert swarm.sim_time() < 0, "the world ticked before the gate opened"
    swarm.swarm.bus.declare_alive(GATE, 0)
    swarm.wait_for_sim_time(0.2)
    swarm.kill("router")
    assert swarm.sim_time() < 3.5, "the run was nearly over before the router died: nothing tested"
    summary = swarm.wait_done(timeout=120)
    swarm.assert_matches_sim()
    assert summary["complete"] and summary["missed_ticks"] == 0


#: The token the mesh test's world waits for before its clock starts (``fxswarm world --wait-for``).
GATE = "test-gate"


# --- every shipped scenario ------------------------------------------------------------------

#: How each shipped config is cut short for the lock-step comparison ([scenario] duration, s, and
#: the fault events moved inside it, same kinds and lengths relative to the limits they exercise),
#: and what the short run must show to have exercised the config's features.
SHORTENED = {
    # The first avoidance episode begins at 5.5 s.
    "paper-fast": ({"duration": 6.5}, lambda s: len(s["avoidance_episodes"]) >= 1),
    # The 0.1 m/s climb reaches the obstacles only after 70 s: the leader, graph and law are its features.
    "paper": ({"duration": 1.5}, lambda s: s["ticks"] == 150),
    # 24 robots through the router, explicit edges, moving obstacles: avoidance from the start.
    "large": ({"duration": 0.5}, lambda s: s["robots"] == 24 and len(s["avoidance_episodes"]) >= 1),
    # The ROS 2 world's example (4 robots at 50 Hz, a speed limit); simulated here, its [ros2] ignored.
    "ros2-square": ({"duration": 1.0}, lambda s: s["robots"] == 4 and s["ticks"] == 50),
    # 16 robots on a line, one pinned, a constant-velocity leader: every hop's lag is its feature.
    "line-16": ({"duration": 1.0}, lambda s: s["robots"] == 16 and s["ticks"] == 100),
    # 100 robots (101 processes and a router), a 50 Hz grid: its scale is its feature. The run
    # (scale_100_run) is also compared with the batch path, over 50 ticks (10 000 messages).
    "scale-100": ({"duration": 1.0}, lambda s: s["robots"] == 100 and s["ticks"] == 50),
    # 8 robots of degree 6 (the W-MSR condition for one liar): flown here with W-MSR on and robot 3
    # lying from 0.2 s, so that its trimming discards values in the processes as in the simulator.
    "liar-8": ({"duration": 1.0, "estimator.resilience": "w-msr", "estimator.tolerate": 1,
                "faults.lies": [{"target": "agent:3", "at": 0.2, "drift": [0.5, 0.0, 0.0]}]},
               lambda s: s["robots"] == 8 and sum(s["resilience"]["discarded"].values()) > 0),
    # The helix leader followed on the oriented estimator graph with the velocity feedforward.
    "line-16-helix": ({"duration": 1.0},
                      lambda s: s["robots"] == 16 and s["ticks"] == 100 and s["law"]["name"].endswith("+feedforward")),
    "faults-lossy": ({"duration": 1.0}, lambda s: link_total(s, "dropped") > 0 and link_total(s, "delayed") > 0),
    "faults-slow": ({"duration": 1.0},
                    lambda s: link_total(s, "delayed") > 0 and link_total(s, "duplicated") > 0
                    and s["faults"]["degraded_ticks"]["no_leader"]),
    # The 2 s leader outage at 20 s: 1 s at 0.3 s, still twice the 0.5 s staleness limit.
    "faults-bursty": ({"duration": 1.6, "faults.leader_outages": [{"start": 0.3, "end": 1.3}]},
                      lambda s: link_total(s, "dropped") > 0 and s["faults"]["degraded_ticks"]["no_leader"]),
    # Killed at 10 s, back at 12 s: here at 0.4 s and 1.4 s, silent twice the 0.5 s silent_hold;
    # then 1.6 s more, so that a launcher slowed by a loaded machine still restarts it in the run.
    "faults-crash": ({"duration": 3.0, "faults.processes": [{"target": "agent:2", "kill": 0.4, "restart": 1.4}]},
                     lambda s: s["faults"]["restarts"] == {"agent:2": 1}
                     and s["faults"]["degraded_ticks"]["world_held_at_zero"].get("2", 0) > 0),
    # Robot 3 isolated 12-17 s: here 0.3-1.3 s, twice the 0.5 s staleness limit.
    "faults-partition": ({"duration": 1.8, "faults.partitions": [{"start": 0.3, "end": 1.3, "isolate": [3]}]},
                         lambda s: s["faults"]["degraded_ticks"]["extrapolating"].get("3", 0) > 0),
}


def link_total(summary: dict, what: str) -> int:
    """``what`` (dropped, delayed, duplicated, delivered) summed over every faulty link."""
    return sum(c[what] for c in summary.get("faults", {}).get("links", {}).values())


def test_every_shipped_config_has_a_shortened_lockstep_comparison():
    """A new config under configs/ needs its entry in SHORTENED (how to cut it, what it shows)."""
    assert sorted(SHORTENED) == sorted(c.stem for c in SHIPPED_CONFIGS)


def planned_process_faults(sc) -> list[tuple[float, str, str]]:
    """(time s, action, target) of each scheduled kill, restart, freeze or thaw, in time order."""
    return sorted((float(t), action, event["target"]) for event in sc.raw.get("faults", {}).get("processes", [])
                  for action, t in event.items() if action != "target")


#: Configs whose processes alone take minutes to start on a 2-core machine.
HEAVY = {"scale-100"}

#: The world's tick timeout where a run is compared with the simulator: a tick closed at its
#: deadline without every command parts the run from the sim. 101 processes on 2 cores at load
#: 19 once took longer than the default 1 s over one tick; a hang still ends at the test's timeout.
COMPARED_TICK_TIMEOUT_S = 60.0


@pytest.fixture(scope="module")
def scale_100_run(tmp_path_factory):
    """configs/scale-100.toml as 100 robot processes in lock-step, SHORTENED, run once for the tests
    that read it (its start alone takes 20 s to a minute): (the swarm, its summary, its deaths)."""
    from fxswarm.testing import SwarmUnderTest, scenario_with

    folder = tmp_path_factory.mktemp("scale-100")
    swarm = SwarmUnderTest(scenario_with(CONFIGS / "scale-100.toml", folder, **SHORTENED["scale-100"][0]),
                           folder / "run", tick_timeout=COMPARED_TICK_TIMEOUT_S)
    try:
        swarm.start()
        summary = swarm.wait_done(timeout=600)
        yield swarm, summary
    finally:
        swarm.stop()


@pytest.mark.zenoh
@pytest.mark.slow
def test_a_generated_100_robot_swarm_in_lockstep_equals_the_batch_sim(scale_100_run):
    """configs/scale-100.toml (a [swarm] table, 100 robots) as 100 robot processes equals
    ``fxswarm sim``'s batch path bit for bit (the shipped-config test compares the per-robot one)."""
    from fxswarm.launch.sim import Simulation
    from fxswarm.runtime.output import load_trajectory

    swarm, summary = scale_100_run
    assert summary["complete"] and (summary["robots"], summary["ticks"]) == (100, 50)
    assert summary["missed_ticks"] == 0
    sim = Simulation(load(swarm.swarm.config), path="batch")
    assert sim.run()["path"] == "batch"
    expected, got = sim.trajectory(), load_trajectory(swarm.out)
    assert sorted(got) == sorted(expected)
    for key in expected:
        assert got[key].dtype == expected[key].dtype and np.array_equal(got[key], expected[key]), key


@pytest.mark.zenoh
@pytest.mark.parametrize("config", [pytest.param(c, marks=pytest.mark.slow) if c.stem in HEAVY else c
                                    for c in SHIPPED_CONFIGS], ids=lambda c: c.stem)
def test_lockstep_run_is_bit_identical_to_the_sim_on_every_shipped_config(launch_swarm, request, config):
    """`fxswarm run` (lock-step) equals `fxswarm sim` bit for bit on each shipped scenario, cut short
    (SHORTENED) so that its own features (faults, crash, partition, avoidance, 24 robots) act.

    Process faults (faults-crash) included: a process with a planned kill falls silent at its
    tick by itself (fxswarm.faults.process.PlannedKill), the launcher's SIGKILL landing a few
    ticks later on a silent process; its restart is sent a tick ahead and the world and the
    neighbours hold the restart's tick until the new process is up (RestartHold)."""
    overrides, exercised = SHORTENED[config.stem]
    if config.stem == "scale-100":  # the one run the batch-path test reads too
        swarm, summary = request.getfixturevalue("scale_100_run")
    else:
        swarm = launch_swarm(config, tick_timeout=COMPARED_TICK_TIMEOUT_S, **overrides)
        summary = None
    sc = swarm.scenario
    faults = sc.raw.get("faults", {})
    for event in (*faults.get("partitions", []), *faults.get("leader_outages", [])):
        assert event["end"] < sc.duration, f"{config.name}: {event} is not inside the shortened run"
    planned = planned_process_faults(sc)
    assert all(t < sc.duration for t, _, _ in planned), planned
    summary = summary or swarm.wait_done(timeout=600)
    assert summary["complete"] and summary["ticks"] == sc.ticks
    assert not swarm.deaths  # a planned kill is not a death; nothing else died
    assert summary["missed_ticks"] == 0  # before the comparison: a missed tick parts the two anyway
    expected = swarm.assert_matches_sim()
    # The faults acted the same in the processes as in the simulator.
    assert summary.get("faults", {}).get("degraded_ticks") == expected.get("faults", {}).get("degraded_ticks")
    if not planned:  # per-link counts: a SIGKILLed process's die with it, and a restart's asked-again repeats count twice
        assert summary.get("faults", {}).get("links") == expected.get("faults", {}).get("links")
    else:
        # Sent in the planned order, each once the launcher heard the world pass its time (a restart
        # one tick ahead, for the world to hold that tick), later on a loaded machine.
        sent = summary["faults"]["process_events"]
        assert [(e["action"], e["target"]) for e in sent] == [(a, t) for _, a, t in planned], sent
        assert all(e["t_s"] + (sc.dt if e["action"] == "restart" else 0.0) >= t - 1e-9
                   for e, (t, _, _) in zip(sent, planned)), (sent, planned)
        assert summary["faults"]["restarts"] == expected["faults"]["restarts"]
    assert exercised(expected), (config.stem, expected.get("faults"), expected["avoidance_episodes"])


