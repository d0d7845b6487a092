"""Drive models and sensing noise over real processes: the world node is the one place they
live, so `fxswarm run --clock lockstep` equals `fxswarm sim` bit for bit with them on."""

from __future__ import annotations

import numpy as np
import pytest

from support import CONFIGS


@pytest.mark.zenoh
def test_lockstep_with_unicycles_pose_noise_and_link_loss_is_bit_identical_to_the_sim(launch_swarm):
    # faults-lossy: 20 % of the estimates between robots dropped, the rest delayed 50 ms.
    swarm = launch_swarm(CONFIGS / "faults-lossy.toml", duration=1.0,
                         **{"world.model": "unicycle", "world.pose_noise": 0.02, "world.omega_max": 2.0,
                            "world.sensing_range": 8.0})
    summary = swarm.wait_done(timeout=300)
    assert summary["complete"] and summary["missed_ticks"] == 0
    expected = swarm.assert_matches_sim()  # every trajectory array, headings included, bit for bit
    links = summary["faults"]["links"]
    assert sum(c["dropped"] for c in links.values()) > 0 and links == expected["faults"]["links"]
    assert summary["world"] == expected["world"]
    assert set(summary["world"]["models"].values()) == {"unicycle"}
    assert summary["world"]["pose_noise_m"] == 0.02
    from fxswarm.runtime.output import load_trajectory
    heading = load_trajectory(swarm.out)["heading"]
    assert np.abs(heading[-1]).max() > 0  # the robots turned: the unicycle model acted


@pytest.mark.zenoh
def test_lockstep_with_double_integrators_obstacle_noise_and_sensing_delay_is_bit_identical_to_the_sim(launch_swarm):
    swarm = launch_swarm(CONFIGS / "faults-lossy.toml", duration=1.0,
                         **{"world.model": "double-integrator", "world.a_max": 1.0, "world.tau": 0.1,
                            "world.obstacle_noise": 0.05, "world.sensing_delay": 2})
    summary = swarm.wait_done(timeout=300)
    assert summary["complete"] and summary["missed_ticks"] == 0
    expected = swarm.assert_matches_sim()
    assert summary["world"] == expected["world"] and summary["world"]["saturated_ticks"]["acceleration"]
