"""The in-process simulator: determinism, locality, metrics helpers, the 300 s paper scenario
(``fxswarm sim`` as a command is in tests/integration/test_sim_cli.py)."""

import numpy as np
import pytest

from fxswarm.core.metrics import avoidance_episodes, settle_time
from fxswarm.core.scenario import load
from fxswarm.launch.sim import Simulation


def test_simulation_is_deterministic():
    sc = load("configs/paper-fast.toml")
    import dataclasses
    sc = dataclasses.replace(sc, duration=2.0)
    a, b = Simulation(sc), Simulation(sc)
    a.run(), b.run()
    ta, tb = a.trajectory(), b.trajectory()
    assert all(np.array_equal(ta[k], tb[k]) for k in ta)


def test_agents_only_hear_their_neighbours_the_leader_if_pinned_and_their_own_sensing():
    sc = load("configs/paper-fast.toml")
    sim = Simulation(sc)
    heard: dict[int, set[str]] = {a.id: set() for a in sim.agents}
    for agent in sim.agents:
        original = agent.handle

        def spy(topic, msg, agent=agent, original=original):
            heard[agent.id].add(topic)
            return original(topic, msg)

        agent.handle = spy
    sim.bus._exact.clear()
    from fxswarm.launch.sim import attach
    for node in (sim.world, sim.leader, *sim.agents):
        attach(sim.bus, node)
    import dataclasses
    sim.scenario = dataclasses.replace(sc, duration=0.5)
    sim.world.sc = sim.scenario
    sim.run()
    # A neighbour's estimate rides on its command: robot 1 hears agent/2/cmd, not agent/3/cmd.
    assert heard[1] == {"world/sense/1", "agent/2/cmd", "agent/6/cmd", "leader/state"}
    assert heard[3] == {"world/sense/3", "agent/2/cmd", "agent/4/cmd"}


def test_settle_time_and_episode_helpers():
    t = np.arange(10) * 0.5
    err = np.array([3, 2, 1, 0.1, 0.3, 0.1, 0.1, 0.05, 0.0, 0.0])
    assert settle_time(t, err, 0.2) == 2.5
    assert settle_time(t, np.full(10, 1.0), 0.2) is None
    active = np.zeros((10, 2), dtype=bool)
    active[2:4, 1] = True
    active[5:7, 1] = True  # a gap of one sample (0.5 s): a separate episode at merge_gap 0.1 s
    assert avoidance_episodes(t, active) == [{"robot": 2, "start_s": 1.0, "end_s": 2.0},
                                              {"robot": 2, "start_s": 2.5, "end_s": 3.5}]
    assert avoidance_episodes(t, active, merge_gap=1.0) == [{"robot": 2, "start_s": 1.0, "end_s": 3.5}]


@pytest.mark.slow
def test_paper_scenario_300_s_passes_every_obstacle(paper_run):
    sc, s, traj = paper_run
    assert s["min_object_distance_m"] >= 1.8
    assert s["formation_error_final_m"] <= 0.15 and s["estimate_error_final_m"] <= 0.15
    top = max(o.position(0.0)[2] for o in sc.obstacles)
    assert traj["p"][-1, :, 2].min() > top + 1.5  # every robot ended well above the highest obstacle
