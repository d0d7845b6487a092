"""`fxswarm run --fault ...`: the launcher resolves the plan once and every process receives it,
so a lock-step run with command-line faults is `fxswarm sim` with the same flags, bit for bit."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from fxswarm.core.scenario import load
from fxswarm.faults.plan import loads, resolve
from fxswarm.runtime.output import load_trajectory
from fxswarm.testing import scenario_with

ROOT = Path(__file__).resolve().parents[2]
# Lossy, late links, robot 3 cut off, and a staleness limit that only the plan carries (the
# scenario file says nothing of it): the processes must take it from the plan they receive.
FLAGS = ["agent:*->agent:* drop=0.3 delay=0.05", "partition 1-2.5 isolate=3", "staleness=0.1", "seed=11"]


def fxswarm(*argv: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fxswarm.cli", *argv], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT)


def with_flags(*argv: str) -> list[str]:
    return [*argv, *(a for f in FLAGS for a in ("--fault", f))]


def test_a_lockstep_run_with_fault_flags_is_the_simulator_with_the_same_flags(tmp_path):
    config = scenario_with(ROOT / "configs" / "paper-fast.toml", tmp_path, duration=3.5)
    sim = fxswarm(*with_flags("sim", str(config), "--out", str(tmp_path / "sim"), "--quiet"))
    assert sim.returncode == 0, sim.stderr
    run = fxswarm(*with_flags("run", str(config), "--out", str(tmp_path / "run"), "--quiet", "--no-logger"))
    assert run.returncode == 0, run.stderr + "\n".join(
        p.read_text()[-2000:] for p in (tmp_path / "run" / "logs").glob("*.log"))
    expected, got = load_trajectory(tmp_path / "sim"), load_trajectory(tmp_path / "run")
    assert sorted(got) == sorted(expected)
    for key in expected:
        assert got[key].dtype == expected[key].dtype and np.array_equal(got[key], expected[key]), key
    s_sim = json.loads((tmp_path / "sim" / "summary.json").read_text())
    s_run = json.loads((tmp_path / "run" / "summary.json").read_text())
    for key in ("links", "degraded_ticks", "recoveries", "seed", "restarts"):
        assert s_run["faults"][key] == s_sim["faults"][key], key
    assert s_run["faults"]["seed"] == 11 and s_run["faults"]["degraded_ticks"]["stale_neighbour"]
    # The plan the processes received is on record in the run folder, and is the resolved one.
    sc = load(config)
    plan = loads((tmp_path / "run" / "fault-plan.json").read_text(), sc, "fault-plan.json")
    assert plan == resolve(sc, FLAGS) and plan.limits.staleness == 0.1
    # The staleness flag changes the run: processes that ignored it could not have matched.
    other = fxswarm("sim", str(config), "--out", str(tmp_path / "sim-0.5"), "--quiet",
                    *(a for f in FLAGS if not f.startswith("staleness") for a in ("--fault", f)))
    assert other.returncode == 0, other.stderr
    assert not np.array_equal(load_trajectory(tmp_path / "sim-0.5")["p"], expected["p"])


def test_a_bad_fault_flag_ends_the_run_before_any_process_starts(tmp_path):
    r = fxswarm("run", str(ROOT / "configs" / "paper-fast.toml"), "--out", str(tmp_path / "run"), "--no-logger",
                "--fault", "agent:*->agent:4 drop=2", timeout=60)
    assert r.returncode == 2
    assert "--fault 'agent:*->agent:4 drop=2': faults.links[0].drop: expected a probability in [0, 1]" in r.stderr
    assert not (tmp_path / "run" / "logs").exists()


def test_a_role_process_refuses_a_plan_and_fault_flags_together_before_joining(tmp_path):
    config = str(ROOT / "configs" / "paper-fast.toml")
    r = fxswarm("agent", config, "--id", "2", "--fault-plan", str(tmp_path / "none.json"), "--fault", "seed=3",
                "--connect", "tcp/127.0.0.1:9", "--mode", "client", timeout=60)
    assert r.returncode == 2 and "expected either a resolved plan (--fault-plan) or --fault flags, got both" in r.stderr
