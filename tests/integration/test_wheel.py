"""The built wheel, installed in a fresh venv and run from outside the source tree.

The roles live at the repository root (agents/, leader/, world/, logger/) and are mapped
into the package by setuptools' package-dir: an editable install can hide a mapping that a
wheel gets wrong, so this builds the wheel and runs `fxswarm sim` from it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

from support import PAPER_FAST, copy_source

@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The project's wheel, built from a copy of the tree (``support.copy_source``)."""
    src = copy_source(tmp_path_factory.mktemp("src") / "fxswarm")
    out = tmp_path_factory.mktemp("wheel")
    # --no-build-isolation: this venv's setuptools, nothing downloaded.
    done = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--quiet",
                           "--wheel-dir", str(out), str(src)], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    (whl,) = out.glob("fxswarm-*.whl")
    return whl


def test_the_wheel_holds_every_role_inside_the_package_and_no_bare_role_package(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    for role in ("fxswarm/agents/node.py", "fxswarm/world/node.py", "fxswarm/leader/node.py"):
        assert role in names, role
    assert any(n.startswith("fxswarm/logger/") and n.endswith(".py") for n in names)
    top = {n.split("/", 1)[0] for n in names}
    assert not top & {"agents", "world", "leader", "logger"}, sorted(top)


def test_the_installed_wheel_runs_fxswarm_sim_from_outside_the_tree(wheel, tmp_path):
    """A fresh venv with only the wheel in it; its dependencies come from this venv's
    site-packages through a path line (not a site dir: the editable install's finder there,
    which maps fxswarm onto the source tree, is never run), so nothing is downloaded."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=300)
    py = venv / "bin" / "python"
    site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    done = subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "--no-deps", "--no-index",
                           "--quiet", str(wheel)], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    # Only now: pip, seeing this venv's editable fxswarm on the path, could take it for installed.
    (site / "deps-from-the-test-venv.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")

    away = tmp_path / "elsewhere"  # not the source tree: nothing there to import by accident
    away.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    where = subprocess.run([str(py), "-c", "import fxswarm.agents.node as a, fxswarm.world.node as w; "
                            "print(a.__file__); print(w.__file__)"],
                           capture_output=True, text=True, cwd=away, env=env, timeout=120)
    assert where.returncode == 0, where.stderr
    for path in where.stdout.split():
        assert Path(path).is_relative_to(site), f"{path}: not the installed wheel's"

    out = away / "run"
    done = subprocess.run([str(venv / "bin" / "fxswarm"), "sim", str(PAPER_FAST), "--out", str(out), "--quiet"],
                          capture_output=True, text=True, cwd=away, env=env, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    s = json.loads((out / "summary.json").read_text())
    assert s["robots"] == 6 and s["ticks"] == 4000 and s["dt"] == 0.01
    assert s["min_object_distance_m"] >= 1.8
    assert s["formation_error_final_m"] <= 0.15 and s["estimate_error_final_m"] <= 0.15
    assert len(s["avoidance_episodes"]) >= 1
    assert (out / "trajectory.npz").stat().st_size > 0
