"""What every benchmark script shares: the machine it ran on, and writing its JSON.

The scripts run as ``python benchmarks/NAME.py``, so this sibling imports as ``bench_io``.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from pathlib import Path


def machine() -> dict:
    """The figures a result needs beside it on a shared machine: cores, Python, load."""
    return {"cpus": os.cpu_count(), "python": platform.python_version(),
            "load_avg_at_start": round(os.getloadavg()[0], 2)}


def write_json(path: str | Path, data: dict) -> None:
    """Write a benchmark's result (its folder made if missing)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=2) + "\n")


def start_router(endpoint: str, *extra: str, env: dict | None = None) -> subprocess.Popen:
    """A Zenoh router (``fxswarm router``) listening on ``endpoint``, output discarded. It leaves
    when this process does (FXSWARM_PARENT_PID), so a benchmark killed mid-run leaves no router."""
    from fxswarm.runtime.process import PARENT_ENV

    return subprocess.Popen([sys.executable, "-m", "fxswarm.cli", "router", "--listen", endpoint, *extra],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env={**(env if env is not None else os.environ), PARENT_ENV: str(os.getpid())})
