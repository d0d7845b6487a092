"""A generated swarm at its size: configs/scale-100.toml (a [swarm] table, 100 robots) as 100
robot processes in lock-step over Zenoh equals ``fxswarm sim``'s batch path bit for bit.

Slow: 101 processes and a router start on the machine (20 s to a minute on 2 shared cores), and
50 ticks of a 100-robot lock-step run cross about 10 000 messages."""

import numpy as np
import pytest

from fxswarm.core.scenario import load
from fxswarm.launch.sim import Simulation
from fxswarm.runtime.output import load_trajectory


@pytest.mark.zenoh
@pytest.mark.slow
def test_a_generated_100_robot_swarm_in_lockstep_equals_the_batch_sim(launch_swarm):
    swarm = launch_swarm("configs/scale-100.toml", duration=1.0)  # 50 ticks at 50 Hz
    summary = swarm.wait_done(timeout=600)
    assert summary["complete"] and (summary["robots"], summary["ticks"]) == (100, 50)
    sim = Simulation(load(swarm.swarm.config), path="batch")
    assert sim.run()["path"] == "batch"
    expected, got = sim.trajectory(), load_trajectory(swarm.out)
    assert sorted(got) == sorted(expected)
    for key in expected:
        assert got[key].dtype == expected[key].dtype and np.array_equal(got[key], expected[key]), key
