"""A user's law beside the scenario, flown as one process per robot over real Zenoh sessions
(issue 27): lock-step equals `fxswarm sim` bit for bit, with and without a fault plan, and a
law that fails is counted the same way in both."""

from __future__ import annotations

import os
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fxswarm.core.metrics import formation_errors
from fxswarm.runtime.output import load_trajectory
from fxswarm.testing import dump_toml
from support import SHORT_RUN_FAULTS as FAULTS, finish_faulted_lockstep_run, measured

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "configs" / "examples" / "tether"
FLAKY = (ROOT / "tests" / "unit" / "data" / "flaky_law.py").read_text()  # see tests/unit/test_laws.py


def tether_scenario(folder: Path, duration: float, **tables) -> Path:
    """The shipped example (tether.toml and tether.py) copied into ``folder``, shortened."""
    shutil.copy(EXAMPLE / "tether.py", folder / "tether.py")
    data = tomllib.loads((EXAMPLE / "tether.toml").read_text())
    data["scenario"]["duration"] = duration
    data.update(tables)
    path = folder / "tether.toml"
    path.write_text(dump_toml(data))
    return path


@pytest.mark.zenoh
def test_lockstep_user_law_is_bit_identical_to_the_sim(launch_swarm, tmp_path):
    swarm = launch_swarm(tether_scenario(tmp_path, 1.5))
    summary = swarm.wait_done(timeout=180)
    expected = swarm.assert_matches_sim()
    assert summary["complete"] and summary["missed_ticks"] == 0
    assert summary["law"] == expected["law"] == {"name": "tether:Tether", "errors": {}}


@pytest.mark.zenoh
def test_lockstep_user_law_under_a_fault_plan_matches_the_sim(launch_swarm, tmp_path):
    swarm = launch_swarm(tether_scenario(tmp_path, 1.5, faults=FAULTS))
    summary = finish_faulted_lockstep_run(swarm)
    assert summary["faults"]["links"]["agent:1->agent:2/estimate"]["dropped"] > 0


@pytest.mark.zenoh
def test_a_failing_law_is_counted_alike_over_zenoh_and_the_run_goes_on(launch_swarm, tmp_path):
    (tmp_path / "flakylaw_z.py").write_text(FLAKY)
    data = tomllib.loads((ROOT / "configs" / "paper-fast.toml").read_text())
    data["scenario"]["duration"] = 1.5
    data["controller"] = {"law": "flakylaw_z:Flaky"}
    config = tmp_path / "flaky.toml"
    config.write_text(dump_toml(data))
    swarm = launch_swarm(config)
    summary = swarm.wait_done(timeout=180)
    expected = swarm.assert_matches_sim()
    assert summary["complete"] and summary["missed_ticks"] == 0
    assert summary["law"] == expected["law"]
    assert summary["law"]["errors"]["2"] == {"ticks": 30, "first": "velocity: RuntimeError: robot 2 gave up at t = 0.50"}
    assert set(summary["law"]["errors"]) == {"2", "3", "5"}
    assert all(c["invalid"] == 0 for c in summary["processes"].values())


@pytest.mark.zenoh
def test_realtime_user_law_flies_and_pulls_its_estimates_onto_the_leader(launch_swarm, tmp_path):
    """Real time, each robot its own process acting on its own clock: Tether starts its
    estimates 2 m off the leader and pulls them in (the sim: under 0.6 m by 3 s, its
    steady lag behind the climbing leader)."""
    swarm = launch_swarm(tether_scenario(tmp_path, 3.0), clock="realtime", speed=1.0)
    summary = swarm.wait_done(timeout=120)
    assert summary["complete"] and summary["law"] == {"name": "tether:Tether", "errors": {}}
    assert all(c["invalid"] == 0 for c in summary["processes"].values())
    traj = load_trajectory(swarm.out)
    err = np.linalg.norm(traj["ph"] - traj["p0"][:, None, :], axis=2).max(axis=1)
    formation = formation_errors(traj).max(axis=1)
    measured("tether_realtime", load1=os.getloadavg()[0], estimate_first_m=err[0], estimate_last_m=err[-1],
             formation_first_m=formation[0], formation_last_m=formation[-1])
    # Measured (23 runs of issue 40 at load average 12-30, the machine shared with other test
    # runs; MEASURED lines): 2.0 m at the start, 0.417-0.486 m at the last tick (the sim: under
    # 0.6 m, its steady lag behind the climbing leader); 0.8 m is 1.6x the worst.
    assert err[0] > 1.5 and err[-1] < 0.8, (err[0], err[-1])


@pytest.mark.zenoh
def test_user_law_survives_its_process_being_killed_and_restarted(launch_swarm, tmp_path):
    """A process fault: agent 2 is SIGKILLed at 1 s and started afresh at 2 s; the new process
    builds the law again from the scenario (the module beside it) and robot 2 flies on."""
    swarm = launch_swarm(tether_scenario(tmp_path, 10.0, faults={"processes": [
        {"target": "agent:2", "kill": 1.0, "restart": 2.0}]}))
    summary = swarm.wait_done(timeout=300)
    assert summary["complete"] and not swarm.deaths
    assert summary["faults"]["restarts"] == {"agent:2": 1}, summary["faults"]
    assert summary["law"]["errors"] == {}
    restart = summary["faults"]["process_events"][-1]
    # Back well before the end, by ticks: the lock-step world holds the restart's tick until the new
    # process is up (--hold-restarts). It used to tick on meanwhile: at load 20 the new process
    # was up at 9.99 s of this 10 s run.
    assert restart["action"] == "restart" and restart["done_t_s"] < 9.0, restart
    traj = load_trajectory(swarm.out)
    back = traj["t"] > restart["done_t_s"] + 0.5
    assert summary["faults"]["degraded_ticks"]["world_held_at_zero"]["2"] > 0  # it was gone a while
    assert np.any(traj["v"][back, 1] != 0.0)  # and flies again under its new process's law
