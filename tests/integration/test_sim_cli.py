"""``fxswarm sim`` as a user runs it, a separate process: the paper-fast outcomes, the files it
writes, its progress line, bad input, and a trajectory independent of the BLAS kernel."""

import json
import os
import platform
import subprocess
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fxswarm.core.scenario import load
from fxswarm.runtime.output import load_trajectory
from fxswarm.testing import dump_toml

from support import PAPER_FAST, fxswarm_command


SUMMARY_FIELDS = {
    "robots", "ticks", "dt", "duration_s", "wall_s", "min_object_distance_m", "min_obstacle_distance_m",
    "formation_error_final_m", "estimate_error_final_m", "formation_settle_s", "estimate_settle_s",
    "avoidance_episodes", "fixed_time_bounds_s",
}


@pytest.fixture(scope="module")
def paper_fast_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper-fast")
    result = subprocess.run(fxswarm_command("sim", "configs/paper-fast.toml", "--out", out),
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return json.loads((out / "summary.json").read_text()), load_trajectory(out), result


def test_paper_fast_meets_the_core_outcomes(paper_fast_run):
    s, _, _ = paper_fast_run
    assert SUMMARY_FIELDS <= s.keys()
    assert s["robots"] == 6 and s["ticks"] == 4000 and s["dt"] == 0.01
    assert s["min_object_distance_m"] >= 1.8
    assert s["formation_error_final_m"] <= 0.15
    assert s["estimate_error_final_m"] <= 0.15
    assert s["estimate_settle_s"] is not None and s["estimate_settle_s"] <= 5
    assert len(s["avoidance_episodes"]) >= 1
    assert set(s["fixed_time_bounds_s"]) == {"formation", "avoidance", "estimator"}


def test_trajectory_file_has_the_documented_shapes(paper_fast_run):
    s, traj, _ = paper_fast_run
    k, n = s["ticks"], s["robots"]
    shapes = {"t": (k,), "p": (k, n, 3), "ph": (k, n, 3), "p0": (k, 3), "v": (k, n, 3),
              "nearest_distance": (k, n), "avoid_active": (k, n)}
    for name, shape in shapes.items():
        assert traj[name].shape == shape, name
        assert np.all(np.isfinite(traj[name])), name
    assert traj["avoid_active"].dtype == bool
    assert np.allclose(traj["p"][0], [r.position for r in load("configs/paper-fast.toml").robots])
    assert np.allclose(traj["p"][1:], traj["p"][:-1] + 0.01 * traj["v"][:-1])  # explicit Euler, SPEC section 7
    assert np.allclose(traj["p0"][-1], [2 * np.cos(0.05 * 39.99), 2 * np.sin(0.05 * 39.99), 39.99])


def test_summary_agrees_with_the_trajectory(paper_fast_run):
    s, traj, _ = paper_fast_run
    assert s["min_object_distance_m"] == pytest.approx(traj["nearest_distance"].min())
    ep = s["avoidance_episodes"][0]
    i, t = ep["robot"] - 1, traj["t"]
    inside = (t >= ep["start_s"]) & (t < ep["end_s"])
    assert traj["avoid_active"][inside, i].mean() > 0.5
    assert np.all(traj["nearest_distance"][traj["avoid_active"]] < 2.0)  # active only inside the zone


def test_progress_line_is_shown_and_quiet_hides_it(paper_fast_run, tmp_path):
    _, _, result = paper_fast_run
    assert "ticks/s" in result.stderr and "max formation error" in result.stderr
    sc = tmp_path / "short.toml"
    sc.write_text(open("configs/paper-fast.toml").read().replace("duration = 40.0", "duration = 1.0"))
    quiet = subprocess.run(fxswarm_command("sim", sc, "--out", tmp_path / "o", "--quiet"),
                           capture_output=True, text=True, timeout=120)
    assert quiet.returncode == 0 and quiet.stderr == "" and quiet.stdout == ""
    # A run shorter than one report period (0.5 s) still ends on its progress line.
    short = subprocess.run(fxswarm_command("sim", sc, "--out", tmp_path / "s"),
                           capture_output=True, text=True, timeout=120)
    assert short.returncode == 0 and "t =    0.99 / 1 s" in short.stderr and "ticks/s" in short.stderr, short.stderr


def test_cli_exits_non_zero_naming_the_file_and_field(tmp_path):
    data = tomllib.loads(PAPER_FAST.read_text())
    data["robots"][3]["position"] = [1.0, 2.0]
    path = str(tmp_path / "x.toml")
    Path(path).write_text(dump_toml(data))
    result = subprocess.run(fxswarm_command("sim", path, "--out", tmp_path / "o"),
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert f"{path}: robots[3].position: expected 3 numbers, got 2" in result.stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.skipif(platform.machine() != "x86_64", reason="OpenBLAS core types named here are x86's")
def test_a_trajectory_does_not_depend_on_which_blas_kernel_the_machine_picks(tmp_path):
    """OpenBLAS picks its kernels per CPU, or as OPENBLAS_CORETYPE says (this machine's
    environment sets it; a container does not inherit it), and they round differently: the law
    must not go through BLAS, or a compose run parts from `fxswarm sim` on the host."""
    sc = tmp_path / "to-the-first-avoidance.toml"  # the first avoidance begins at 5.5 s
    sc.write_text(open("configs/paper-fast.toml").read().replace("duration = 40.0", "duration = 8.0"))
    runs = {}
    for core in ("Prescott", None):  # the oldest x86-64 kernel, and what the machine picks
        env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
        if core:
            env["OPENBLAS_CORETYPE"] = core
        out = tmp_path / (core or "auto")
        done = subprocess.run(fxswarm_command("sim", sc, "--out", out, "--quiet"),
                              capture_output=True, text=True, timeout=120, env=env)
        assert done.returncode == 0, done.stderr
        runs[core] = load_trajectory(out)
    assert runs[None]["avoid_active"].any(), "no avoidance in the segment: nothing compared"
    for key, value in runs[None].items():
        assert np.array_equal(value, runs["Prescott"][key]), key
