"""``index.md``: the run's numbers from ``summary.json`` beside its figures."""

from __future__ import annotations

from pathlib import Path

_NUMBERS = [
    ("robots", "robots", "{}"),
    ("duration_s", "simulated time", "{:g} s"),
    ("ticks", "ticks", "{}"),
    ("wall_s", "wall time", "{:.2f} s"),
    ("formation_settle_s", "formation settled (all robots within tolerance)", "{:.2f} s"),
    ("estimate_settle_s", "estimator settled", "{:.2f} s"),
    ("settle_tolerance_m", "settling tolerance", "{:g} m"),
    ("formation_error_final_m", "final max formation error", "{:.4f} m"),
    ("estimate_error_final_m", "final max estimate error", "{:.4f} m"),
    ("min_obstacle_distance_m", "closest approach to an obstacle", "{:.3f} m"),
    ("min_object_distance_m", "closest approach to any object", "{:.3f} m"),
    ("missed_ticks", "lock-step ticks closed by timeout", "{}"),
]

_CAPTIONS = {
    "formation_error.png": "Formation error of each robot against the true leader (the paper's Fig. 6).",
    "obstacle_distances.png": "Distance to the nearest obstacle / object, with the repulsive radius d "
                              "(the paper's Fig. 8).",
    "trajectories_3d.png": "Trajectories of the robots and the virtual leader among the obstacles "
                           "(the paper's Fig. 9).",
    "estimate_error.png": "Each robot's error in estimating the leader (log scale).",
    "settling_vs_initial_error.png": "Settling time against initial error, per controller variant "
                                     "(from sweep.json).",
}


def _fmt(value, form: str) -> str:
    if value is None:
        return "never (within the run)"
    try:
        return form.format(value)
    except (ValueError, TypeError):
        return str(value)


def _world_rows(world: dict | None) -> list[str]:
    """The robots as the world flew them (summary.json's ``world``: [world], docs/robots.md)."""
    if not world:
        return []
    models = {}
    for robot, model in world["models"].items():
        models.setdefault(model, []).append(robot)
    rows = ["| drive model (robots) | " + "; ".join(f"{m} ({', '.join(r)})" for m, r in models.items()) + " |",
            f"| sensing: pose noise, obstacle noise, delay, range | {world['pose_noise_m']:g} m, "
            f"{world['obstacle_noise_m']:g} m, {world['sensing_delay_ticks']} ticks, "
            + ("unlimited" if world["sensing_range_m"] is None else f"{world['sensing_range_m']:g} m") + " |"]
    for limit, ticks in world["saturated_ticks"].items():
        rows.append(f"| ticks at the {limit.replace('_', ' ')} limit (robot: ticks) | "
                    + (", ".join(f"{r}: {n}" for r, n in ticks.items()) or "none") + " |")
    return rows


def write_index(run: Path, summary: dict, figures: list[Path], snapshots: list[Path]) -> Path:
    """Write ``run/index.md``; figure links are relative so the folder can move."""
    title = summary.get("scenario", run.name)
    law = summary.get("law") or {}
    lines = [f"# Run `{title}`", "", f"Scenario: `{summary.get('source', '?')}`."
             + (f" Law: `{law['name']}`." if "name" in law else ""), "",
             "| quantity | value |", "| --- | --- |"]
    for robot, error in sorted((law.get("errors") or {}).items(), key=lambda kv: int(kv[0])):
        lines.append(f"| law_error, robot {robot}: ticks (first) | {error['ticks']} ({error['first']}) |")
    lines += _world_rows(summary.get("world"))
    for key, label, form in _NUMBERS:
        if key in summary:
            lines.append(f"| {label} | {_fmt(summary[key], form)} |")
    bounds = summary.get("fixed_time_bounds_s") or {}
    for name, value in bounds.items():
        note = " (as printed in the paper; suspect: docs/design.md, 'The estimator bound')" if name == "estimator" else ""
        lines.append(f"| fixed-time bound, {name} | {_fmt(value, '{:.2f} s')}{note} |")
    logger = (summary.get("processes") or {}).get("logger-0", {}).get("logger")
    if logger:
        lines.append(f"| logger: frames recorded, messages dropped | {logger.get('frames')}, "
                     f"{logger.get('dropped')} |")
    episodes = summary.get("avoidance_episodes") or []
    lines.append(f"| avoidance episodes | {len(episodes)} |")
    lines.append("")
    if episodes:
        lines += ["## Avoidance episodes", "", "| robot | start (s) | end (s) |", "| --- | --- | --- |"]
        lines += [f"| {e['robot']} | {e['start_s']:.2f} | {e['end_s']:.2f} |" for e in episodes[:40]]
        if len(episodes) > 40:
            lines.append(f"| ... | {len(episodes) - 40} more | |")
        lines.append("")
    lines += ["## Figures", ""]
    for path in (f for f in figures if f.suffix == ".png"):
        lines += [f"![{path.stem}]({path.name})", "", _CAPTIONS.get(path.name, ""), ""]
    if not (run / "sweep.json").is_file():
        lines += ["_No `sweep.json` in this folder: run `fxswarm sweep` for settling time against "
                  "initial error._", ""]
    if snapshots:
        lines += ["## The live view (Rerun viewer, rendered headless)", ""]
        for path in snapshots:
            lines += [f"![{path.stem}]({path.relative_to(run).as_posix()})", ""]
    if (run / "recording.rrd").is_file():
        lines += ["Open the recording: `rerun recording.rrd` (rerun-sdk 0.41).", ""]
    out = run / "index.md"
    out.write_text("\n".join(lines))
    return out
