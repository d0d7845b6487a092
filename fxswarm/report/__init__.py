"""``fxswarm report DIR [--snapshot]``: PNG figures and ``index.md`` from a run folder, or
from a campaign's folder (``campaign.json``: :mod:`.campaign`).

Reads ``DIR/trajectory.npz`` and ``DIR/summary.json`` (the scenario is found
from the summary's ``source``), and ``DIR/sweep.json`` when a fixed-time
sweep wrote one. ``--snapshot`` also renders the live view's default
blueprint at chosen simulation times with the Rerun viewer itself
(:mod:`.snapshot`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from fxswarm.runtime.numbers import times

FIGURES = ("formation_error.png", "obstacle_distances.png", "trajectories_3d.png", "estimate_error.png")
SETTLING = "settling_vs_initial_error.png"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dir", help="run folder (trajectory.npz, summary.json; sweep.json if any), or a campaign "
                   "folder (campaign.json)")
    p.add_argument("--snapshot", action="store_true",
                   help="also render the Rerun viewer's default blueprint to PNG, headless")
    p.add_argument("--recording", action="store_true",
                   help="also write DIR/recording.rrd from the trajectory when the run has none (fxswarm sim)")
    p.add_argument("--times", type=times, default=None, metavar="T1,T2,...",
                   help="simulation times of the snapshots, s (default: three across the run)")


def sweep_rows(data) -> list[dict]:
    """Normalise a ``sweep.json`` into rows ``{variant, initial_error, formation, estimator}``.

    Accepts a list of rows or ``{"rows": [...]}``, with the field names the
    sweep may use (``initial_error_m`` / ``initial_error``, ``formation_settle_s``,
    ``estimate_settle_s`` / ``estimator_settle_s``); rows without a variant or an
    initial error are skipped.
    """
    rows = data.get("rows", data.get("runs", [])) if isinstance(data, dict) else data
    out = []
    for r in rows if isinstance(rows, list) else []:
        if not isinstance(r, dict):
            continue
        variant = r.get("variant") or r.get("controller")
        init = _first(r, "initial_error_m", "initial_error", "initial_formation_error_m", "e0")
        if variant is None or not isinstance(init, (int, float)):
            continue
        out.append({
            "variant": str(variant), "scale": r.get("scale"), "initial_error": float(init),
            "formation": _first(r, "formation_settle_s", "formation_settle", "formation"),
            "estimator": _first(r, "estimate_settle_s", "estimator_settle_s", "estimator_settle", "estimator"),
        })
    return out


def _first(row: dict, *keys):
    for k in keys:
        if k in row:
            return row[k]
    return None


def write_figures(run: Path, summary: dict, d: float) -> list[Path]:
    """Every figure this run's data allows; returns their paths."""
    from fxswarm.report import figures
    from fxswarm.runtime.output import load_trajectory

    traj = load_trajectory(run)
    tol = summary.get("settle_tolerance_m")
    law = (summary.get("law") or {}).get("name")  # absent from runs made before the law API
    paths = [
        figures.formation_error(traj, run / FIGURES[0], tol, summary.get("formation_settle_s"), law),
        figures.obstacle_distances(traj, run / FIGURES[1], d, law),
        figures.trajectories_3d(traj, run / FIGURES[2], d, law),
        figures.estimate_error(traj, run / FIGURES[3], summary.get("estimate_settle_s"), law),
    ]
    sweep = run / "sweep.json"
    if sweep.is_file():
        rows = sweep_rows(json.loads(sweep.read_text()))
        if rows:
            paths.append(figures.settling_vs_initial_error(rows, run / SETTLING))
    return paths


def main(args: argparse.Namespace) -> int:
    from fxswarm.core.scenario import ScenarioError
    from fxswarm.report.index import write_index
    from fxswarm.runtime.campaign_folder import FolderError, is_campaign
    from fxswarm.runtime.output import read_summary, scenario_of_run

    run = Path(args.dir)
    if is_campaign(run):  # a campaign's folder (`fxswarm campaign`)
        from fxswarm.report.campaign import write_campaign_report

        try:
            written = write_campaign_report(run)
        except FolderError as exc:
            print(f"fxswarm report: {exc}", file=sys.stderr)
            return 2
        for path in written:
            print(f"wrote {path}")
        return 0
    for name in ("trajectory.npz", "summary.json"):
        if not (run / name).is_file():
            print(f"fxswarm report: {run / name}: no such file (expected a run folder from "
                  "`fxswarm sim` or `fxswarm run`)", file=sys.stderr)
            return 2
    summary = read_summary(run)
    try:
        sc = scenario_of_run(run)
    except (FileNotFoundError, ScenarioError) as exc:
        print(f"fxswarm report: {exc}", file=sys.stderr)
        return 2
    written = write_figures(run, summary, sc.d)
    if args.recording and not (run / "recording.rrd").is_file():
        from fxswarm.logger.replay import record_run

        written.append(record_run(run, scenario=sc))
    shots: list[Path] = []
    if args.snapshot:
        from fxswarm.report.snapshot import SnapshotError, snapshots

        try:
            shots = snapshots(run, sc, times=_times(args.times, summary))
        except SnapshotError as exc:
            print(f"fxswarm report: --snapshot: {exc}", file=sys.stderr)
            write_index(run, summary, written, [])
            return 3
    index = write_index(run, summary, written, shots)
    for path in [*written, *shots, index]:
        print(f"wrote {path}")
    return 0


def _times(given: list[float] | None, summary: dict) -> list[float]:
    if given:
        return given
    duration = float(summary.get("duration_s", 10.0))
    return [round(duration * f, 2) for f in (0.25, 0.5, 0.98)]
