"""The agent, world and leader images carry no Rerun, no matplotlib and no Cyclone DDS: their roles
never import them (the ROS 2 world loads Cyclone DDS only with ``--ros2``).

Each check runs in a fresh interpreter where importing ``rerun``, ``matplotlib``, ``pyarrow`` or
``cyclonedds`` fails, as it does in those images (``fxswarm[logger]``, ``fxswarm[report]`` and
``fxswarm[ros2]`` are extras).
"""

from __future__ import annotations

import subprocess
import sys

import pytest

BLOCK = """
import importlib.abc, sys
class Absent(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("rerun", "rerun_bindings", "matplotlib", "pyarrow", "cyclonedds"):
            raise ModuleNotFoundError(f"No module named {name!r} (blocked: not in this image)")
sys.meta_path.insert(0, Absent())
"""


def run_blocked(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", BLOCK + code], capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("command", ["agent", "world", "leader", "router", "health"])
def test_role_commands_start_without_rerun_or_matplotlib(command):
    r = run_blocked(f"""
from fxswarm.cli import main
try:
    main([{command!r}, "--help"])
except SystemExit as exc:
    assert exc.code == 0, exc.code
loaded = sorted(m for m in sys.modules if m.split(".")[0] in ("rerun", "matplotlib", "pyarrow", "cyclonedds"))
assert not loaded, loaded
""")
    assert r.returncode == 0, r.stderr
    assert "usage: fxswarm " + command in r.stdout


def test_the_block_is_real_the_logger_needs_rerun():
    """The same check fails for the logger, which does need Rerun (so the block works)."""
    r = run_blocked("import fxswarm.logger.process")
    assert r.returncode != 0 and "blocked: not in this image" in r.stderr
