"""What every benchmark script shares: the machine it ran on, and writing its JSON.

The scripts run as ``python benchmarks/NAME.py``, so this sibling imports as ``bench_io``.
"""

from __future__ import annotations

import json
import os
import platform
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
