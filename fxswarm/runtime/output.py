"""A run's folder (``fxswarm sim``, ``fxswarm run``, ``fxswarm attach``): its writer and its one
reader. ``summary.json`` (the numbers, and ``source``: the scenario file), ``trajectory.npz``
(every tick), ``processes/<role>-<id>.json`` (each role process's counters).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from fxswarm.core.scenario import Scenario, load
from fxswarm.faults.summary import add_processes
from fxswarm.runtime.files import write_atomic


def prepare_run_folder(out_dir: str | Path, who: str) -> Path:
    """Make ``out_dir`` (and its parents) and check it takes a file, before any work: a folder
    that cannot be written ends the command at once, in one line with exit status 2, instead of
    a traceback after the run (whose results would be lost)."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        # A probe of its own (mkstemp: O_EXCL, a random name): the processes of one run check the
        # same folder at once, and in containers each is pid 1, so a name by pid was shared.
        fd, probe = tempfile.mkstemp(prefix=".fxswarm-probe-", dir=out)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        print(f"{who}: cannot write the run folder {out}: {exc.strerror or exc}", file=sys.stderr)
        raise SystemExit(2) from None
    return out


def write_run(out_dir: str | Path, summary: dict, trajectory: dict[str, np.ndarray]) -> Path:
    """Write ``summary.json`` and ``trajectory.npz`` into ``out_dir`` (created); return the folder."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    np.savez(out / "trajectory.npz", **trajectory)
    write_summary(out, summary)
    return out


def write_summary(out_dir: str | Path, summary: dict) -> None:
    write_atomic(Path(out_dir) / "summary.json", json.dumps(summary, indent=2) + "\n")


def read_summary(out_dir: str | Path) -> dict | None:
    """The run's ``summary.json`` (None: there is none yet)."""
    path = Path(out_dir) / "summary.json"
    return json.loads(path.read_text()) if path.is_file() else None


def merge_summary(out_dir: str | Path, process_events: list[dict] | None = None,
                  extra: dict | None = None) -> dict | None:
    """The world's ``summary.json`` with every role process's counters (once all have stopped),
    the process faults a launcher sent (:func:`~fxswarm.faults.summary.add_processes`) and
    ``extra`` (the launcher's own facts); written back and returned (None: no summary)."""
    summary = read_summary(out_dir)
    if summary is None:
        return None
    add_processes(summary, read_process_counters(out_dir), process_events)
    summary.update(extra or {})
    write_summary(out_dir, summary)
    return summary


def read_process_counters(out_dir: str | Path, since: float | None = None) -> dict[str, dict]:
    """The role processes' counters files, ``OUT/processes/<role>-<id>.json``, by file stem;
    ``since``: only those written at or after that time (s since the epoch; a reused run
    folder keeps an earlier run's). Unreadable files are skipped."""
    out = {}
    for path in sorted((Path(out_dir) / "processes").glob("*.json")):
        try:
            if since is not None and path.stat().st_mtime < since:
                continue
            out[path.stem] = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
    return out


def load_trajectory(out_dir: str | Path) -> dict[str, np.ndarray]:
    with np.load(Path(out_dir) / "trajectory.npz") as data:
        return {k: data[k] for k in data.files}


def scenario_of_run(run_dir: str | Path) -> Scenario:
    """The scenario named by ``summary.json``'s ``source`` (tried as given, then beside the run's parents)."""
    run = Path(run_dir)
    summary_path = run / "summary.json"
    try:
        source = json.loads(summary_path.read_text())["source"]
    except (OSError, ValueError, KeyError) as exc:
        raise FileNotFoundError(f"{summary_path}: expected a run summary with a 'source' field ({exc})") from None
    candidates = [Path(source)] + [parent / source for parent in run.resolve().parents]
    for path in candidates:
        if path.is_file():
            return load(path)
    raise FileNotFoundError(f"{summary_path}: scenario {source!r} not found (looked in the working directory "
                            "and the run folder's parents)")
