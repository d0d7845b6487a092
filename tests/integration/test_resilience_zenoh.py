"""A lying robot over real Zenoh sessions, one process per robot (issue 39): the liar's own node
tells the lie, so a lock-step run equals `fxswarm sim` bit for bit, W-MSR's discarded counts
included; in secure mode too, the liar holding its own valid key (docs/resilience.md)."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fxswarm.core.scenario import load
from fxswarm.launch.sim import Simulation
from fxswarm.runtime.output import load_trajectory
from fxswarm.security.keys import write_keys
from fxswarm.testing import dump_toml
from support import CONFIGS

pytestmark = [pytest.mark.zenoh]

# From 0.3 s robot 3 says it is 3 m/s further along x than it is, with seeded noise on top.
LIE = {"seed": 5, "lies": [{"target": "agent:3", "at": 0.3, "drift": [3.0, 0.0, 0.0], "noise": 0.05}]}


def liar_file(folder: Path, duration: float = 1.0) -> Path:
    data = tomllib.loads((CONFIGS / "liar-8.toml").read_text())
    data["scenario"]["duration"] = duration
    data["estimator"] |= {"resilience": "w-msr", "tolerate": 1}
    data["faults"] = LIE
    path = folder / "liar.toml"
    path.write_text(dump_toml(data))
    return path


def check_run(swarm) -> None:
    summary = swarm.wait_done(timeout=240)
    expected = swarm.assert_matches_sim()  # every array of trajectory.npz, bit for bit
    assert summary["complete"] and summary["missed_ticks"] == 0
    got, want = summary["resilience"], expected["resilience"]
    assert got["lies"] == want["lies"] == ["lie agent:3 at=0.3 drift=3,0,0 noise=0.05"]
    # Each agent process counted what its trimming discarded: the simulator's counts, robot by robot.
    assert got["discarded"] == want["discarded"] and len(got["discarded"]) == 8
    assert all(n > 0 for n in got["discarded"].values())
    assert got == want
    # The lie reached the neighbours: without it, the same run's estimates differ.
    honest = load(swarm.swarm.config)
    honest = dataclasses.replace(honest, raw={k: v for k, v in honest.raw.items() if k != "faults"})
    truthful = Simulation(honest)
    truthful.run()
    assert not np.array_equal(truthful.trajectory()["ph"], load_trajectory(swarm.out)["ph"])


def test_lockstep_liar_with_w_msr_equals_the_simulator_bit_for_bit(launch_swarm, tmp_path):
    check_run(launch_swarm(liar_file(tmp_path)))


def test_secure_lockstep_liar_holds_its_valid_key_and_still_equals_the_simulator(launch_swarm, tmp_path):
    """Secure mode refuses strangers, not insiders: robot 3's lies are signed with its own key and
    arrive; W-MSR is what stops them."""
    config = liar_file(tmp_path)
    keys = tmp_path / "keys"
    write_keys(keys, load(config))
    check_run(launch_swarm(config, secure=keys))
