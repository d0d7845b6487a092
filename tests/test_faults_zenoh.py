"""Faults over real processes and real Zenoh: same trajectories as the simulator, crashes, garbage."""

from __future__ import annotations

import os
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fxswarm.core.scenario import load
from fxswarm.runtime.output import load_trajectory
from fxswarm.runtime.sim import Simulation
from fxswarm.testing import dump_toml

PAPER_FAST = Path(__file__).resolve().parents[1] / "configs" / "paper-fast.toml"

# Every kind of link fault at once, strong enough to act within a short run.
MIXED_FAULTS = {
    "seed": 11,
    "links": [
        {"link": "agent:*->agent:*", "kinds": ["estimate"], "drop": 0.2, "delay": 0.03, "jitter": 0.02,
         "duplicate": 0.1, "reorder": 0.1},
        {"link": "agent:2->agent:3", "burst": {"p_good_bad": 0.05, "p_bad_good": 0.3}},
        {"link": "leader->agent:1", "drop": 0.3, "delay": 0.01},
        {"link": "world->agent:5", "kinds": ["sense"], "drop": 0.2},
        {"link": "agent:6->world", "kinds": ["command"], "drop": 0.1},
    ],
    "partitions": [{"start": 0.6, "end": 0.9, "isolate": [3]}],
    "leader_outages": [{"start": 1.0, "end": 1.2}],
}


def scenario_file(folder: Path, duration: float, faults: dict) -> Path:
    data = tomllib.loads(PAPER_FAST.read_text())
    data["scenario"]["duration"] = duration
    data["faults"] = faults
    path = folder / f"faulty-{os.getpid()}.toml"
    path.write_text(dump_toml(data))
    return path


@pytest.mark.zenoh
def test_lockstep_processes_with_faults_match_the_simulator_bit_for_bit(launch_swarm, tmp_path):
    config = scenario_file(tmp_path, 1.5, MIXED_FAULTS)
    swarm = launch_swarm(config)
    summary = swarm.wait_done(timeout=180)
    sc = load(config)
    sim = Simulation(sc)
    expected_summary = sim.run()
    expected, got = sim.trajectory(), load_trajectory(swarm.out)
    for key in expected:
        assert np.array_equal(got[key], expected[key]), key
    assert summary["complete"] and summary["missed_ticks"] == 0
    # Each receiver counted its own inbound links; together they are the simulator's counts.
    assert summary["faults"]["links"] == expected_summary["faults"]["links"]
    links = summary["faults"]["links"]
    assert links["agent:2->agent:3/estimate"]["dropped"] > 0
    assert links["agent:1->agent:2/estimate"]["delayed"] > 0
    assert links["agent:1->agent:2/estimate"]["duplicated"] > 0
    assert links["world->agent:5/sense"]["dropped"] > 0
    assert summary["faults"]["degraded_ticks"] == expected_summary["faults"]["degraded_ticks"]
