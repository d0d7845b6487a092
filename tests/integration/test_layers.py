"""The import layers (pyproject.toml [tool.importlinter]) as `make lint` checks them: they pass on
the package as it is, and one upward import makes `lint-imports` fail naming the contract."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from support import REPO, copy_source

LINT_IMPORTS = Path(sys.executable).with_name("lint-imports")


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """The package installed with --target (its role folders mapped into fxswarm/, as in a wheel:
    import-linter reads folders, not setuptools' package-dir), from a copy of the tree."""
    src = copy_source(tmp_path_factory.mktemp("src") / "fxswarm")
    target = tmp_path_factory.mktemp("lint")
    done = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
                           "--target", str(target), str(src)], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return target


def lint_imports(folder: Path) -> subprocess.CompletedProcess:
    """`lint-imports` with the project's contracts, on the package under ``folder``."""
    return subprocess.run([str(LINT_IMPORTS), "--no-cache", str(REPO / "pyproject.toml")], cwd=folder,
                          capture_output=True, text=True, timeout=600)


def contract_names() -> list[str]:
    return [c["name"] for c in tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]]


def test_the_layers_hold_on_the_package_as_it_is(installed):
    done = lint_imports(installed)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert all(f"{name} KEPT" in done.stdout for name in contract_names()), done.stdout


def test_one_upward_import_breaks_the_layers_contract_naming_it(installed, tmp_path):
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(installed / "fxswarm", broken / "fxswarm")
    health = broken / "fxswarm" / "runtime" / "health.py"
    health.write_text(health.read_text() + "\nimport fxswarm.launch.launcher  # upward, on purpose\n")
    done = lint_imports(broken)
    assert done.returncode != 0, done.stdout
    (layers,) = [name for name in contract_names() if name.startswith("Layers")]
    assert f"{layers} BROKEN" in done.stdout, done.stdout
    assert "fxswarm.runtime.health -> fxswarm.launch.launcher" in done.stdout, done.stdout
