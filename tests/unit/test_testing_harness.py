"""The test harness (fxswarm.testing) before any process starts."""

import pytest

from fxswarm.testing import SwarmUnderTest
from support import PAPER_FAST


def test_waiting_on_the_silence_of_a_robot_the_world_cannot_see_is_an_error_not_a_timeout(tmp_path):
    swarm = SwarmUnderTest(PAPER_FAST, tmp_path)  # built, never started
    with pytest.raises(ValueError, match="robot 99: no links into it"):
        swarm.wait_for_silence(99, ticks=3, timeout=0.1)


def test_a_run_that_differs_from_the_simulator_says_where_and_whether_a_tick_timed_out(tmp_path):
    """assert_matches_sim names the first differing index (its tick first) and, when the run closed
    ticks on its --tick-timeout (load, not the law), says so: what tells a defect from a slow machine."""
    import json

    import numpy as np

    from fxswarm.core.scenario import load
    from fxswarm.launch.sim import Simulation
    from fxswarm.testing import scenario_with

    config = scenario_with(PAPER_FAST, tmp_path, duration=0.05)
    sim = Simulation(load(config))
    sim.run()
    traj = sim.trajectory()
    swarm = SwarmUnderTest(config, tmp_path / "run")  # built, never started: its folder made by hand
    swarm.out.mkdir(parents=True, exist_ok=True)
    np.savez(swarm.out / "trajectory.npz", **traj)
    (swarm.out / "summary.json").write_text(json.dumps({"missed_ticks": 0}))
    swarm.assert_matches_sim()  # the same run: nothing to say
    traj["p"][3, 1, 2] += 1e-12
    np.savez(swarm.out / "trajectory.npz", **traj)
    with pytest.raises(AssertionError, match=r"p differs from fxswarm sim's: first at index \(3, 1, 2\)") as err:
        swarm.assert_matches_sim()
    assert "tick-timeout" not in str(err.value)
    (swarm.out / "summary.json").write_text(json.dumps({"missed_ticks": 2}))
    with pytest.raises(AssertionError, match="closed 2 tick\\(s\\) on its --tick-timeout"):
        swarm.assert_matches_sim()
