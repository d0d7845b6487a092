"""Writing a run's folder: ``summary.json`` and ``trajectory.npz``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def write_run(out_dir: str | Path, summary: dict, trajectory: dict[str, np.ndarray]) -> Path:
    """Write ``summary.json`` and ``trajectory.npz`` into ``out_dir`` (created); return the folder."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    np.savez(out / "trajectory.npz", **trajectory)
    write_summary(out, summary)
    return out


def write_summary(out_dir: str | Path, summary: dict) -> None:
    path = Path(out_dir) / "summary.json"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(summary, indent=2) + "\n")
    tmp.replace(path)  # readers never see half a summary


def load_trajectory(out_dir: str | Path) -> dict[str, np.ndarray]:
    with np.load(Path(out_dir) / "trajectory.npz") as data:
        return {k: data[k] for k in data.files}
