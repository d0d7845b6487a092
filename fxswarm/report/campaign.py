"""A campaign folder's figures and ``index.md``, from ``campaign.json`` and ``runs.jsonl``.

- ``success_map.png``: the success rate over the first two grid axes with more than one
  value, one panel per law (cells pooled over any further axis), each square labelled
  ``successes/runs``;
- ``distributions.png``: settling time and closest approach of every run, per law, against
  the first grid axis.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fxswarm.report.figures import _save, plt
from fxswarm.logger.style import robot_hex
from fxswarm.runtime.campaign_folder import read_result, read_runs

MAP = "success_map.png"
DISTRIBUTIONS = "distributions.png"


def map_axes(doc: dict) -> list[str]:
    """The grid axes the map spans: the first two with more than one value."""
    return [name for name, values in doc["axes"].items() if len(values) > 1][:2]


def _label(value) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def success_map(doc: dict, out: Path) -> Path:
    """Success rate per cell, one panel per law (see the module docstring)."""
    axes = map_axes(doc)
    xs = doc["axes"][axes[0]] if axes else [None]
    ys = doc["axes"][axes[1]] if len(axes) > 1 else [None]
    laws = doc["laws"]
    fig, panels = plt.subplots(1, len(laws), figsize=(1.2 + 0.9 * len(xs) * len(laws) + 1.2 * len(laws),
                                                      1.6 + 0.7 * len(ys)), squeeze=False)
    image = None
    for ax, law in zip(panels[0], laws):
        wins = np.zeros((len(ys), len(xs)))
        runs = np.zeros((len(ys), len(xs)))
        for c in doc["cells"]:
            if c["law"] != law:
                continue
            i = ys.index(c["cell"][axes[1]]) if len(axes) > 1 else 0
            j = xs.index(c["cell"][axes[0]]) if axes else 0
            wins[i, j] += c["successes"]
            runs[i, j] += c["runs"]
        rate = np.where(runs > 0, wins / np.maximum(runs, 1), np.nan)
        image = ax.imshow(rate, origin="lower", cmap="RdYlGn", vmin=0.0, vmax=1.0, aspect="auto")
        for i in range(len(ys)):
            for j in range(len(xs)):
                ax.text(j, i, f"{int(wins[i, j])}/{int(runs[i, j])}", ha="center", va="center", fontsize=9)
        ax.set_xticks(range(len(xs)), [_label(x) for x in xs])
        ax.set_yticks(range(len(ys)), [_label(y) for y in ys])
        ax.set_xlabel(axes[0] if axes else "")
        ax.set_ylabel(axes[1] if len(axes) > 1 else "")
        ax.set_title(f"law: {law}")
    fig.colorbar(image, ax=panels[0].tolist(), label="success rate", shrink=0.9)
    fig.suptitle("success rate per cell (successes/runs)", fontsize=11)
    fig.savefig(out, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return out


def distributions(doc: dict, runs: list[dict], out: Path) -> Path:
    """Formation settling time and closest approach of every finished run, per law, against
    the first grid axis (the others pooled); unsettled runs drawn at the top as crosses."""
    axes = map_axes(doc)
    axis = axes[0] if axes else None
    xs = doc["axes"][axis] if axis else [None]
    laws = doc["laws"]
    fig, (ax_t, ax_d) = plt.subplots(1, 2, figsize=(11, 4))
    width = 0.8 / max(len(laws), 1)
    top = max([r["metrics"]["duration_s"] for r in runs if r.get("metrics")] or [1.0])
    for k, law in enumerate(laws):
        colour = robot_hex(k)
        for j, x in enumerate(xs):
            mine = [r for r in runs if r["law"] == law and r["status"] == "done" and (axis is None or r["cell"][axis] == x)]
            pos = j + (k - (len(laws) - 1) / 2) * width
            jitter = np.linspace(-0.3, 0.3, len(mine)) * width if mine else []
            settle = [r["metrics"]["formation_settle_s"] for r in mine]
            ax_t.scatter([pos + dj for dj, s in zip(jitter, settle) if s is not None],
                         [s for s in settle if s is not None], s=14, color=colour,
                         label=law if j == 0 else None)
            never = [pos + dj for dj, s in zip(jitter, settle) if s is None]
            ax_t.scatter(never, [top] * len(never), marker="x", s=18, color=colour)
            dist = [r["metrics"]["min_distance_m"] for r in mine if r["metrics"]["min_distance_m"] is not None]
            ax_d.scatter([pos + dj for dj in jitter[:len(dist)]], dist, s=14, color=colour,
                         label=law if j == 0 else None)
    limit = doc["criteria"]["min_distance_m"]
    ax_d.axhline(limit, color="#e15759", ls="--", lw=1, label=f"collision below {limit:g} m")
    ax_t.axhline(top, color="0.5", ls=":", lw=1, label="x: never settled")
    for ax, title in ((ax_t, "formation settling time (s)"), (ax_d, "closest approach to any object (m)")):
        ax.set_xticks(range(len(xs)), [_label(x) for x in xs])
        ax.set_xlabel(axis or "")
        ax.set_title(title)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return _save(fig, out)


def _fmt(x, form: str = "{:.2f}") -> str:
    return "-" if x is None else form.format(x)


def write_campaign_report(folder: Path) -> list[Path]:
    """Figures and ``index.md`` of a campaign folder; returns the paths written."""
    doc = read_result(folder)
    runs = list(read_runs(folder).values())
    figures = [success_map(doc, folder / MAP), distributions(doc, runs, folder / DISTRIBUTIONS)]
    t = doc["totals"]
    c = doc["criteria"]
    spec = doc["spec"]
    settle = "within the run" if c["settle_within_s"] is None else f"by {c['settle_within_s']:g} s"
    lines = [
        f"# Campaign of `{spec['config']}`", "",
        f"{t['runs']} of {t['planned']} runs, {t['successes']} succeeded, {t['errors']} errors"
        + ("" if doc["complete"] else " (not complete: run the same command again to finish it)") + ".", "",
        f"Faults: {', '.join(f'`{f}`' for f in spec['faults']) or 'none'}; grid: "
        + ", ".join(f"`{k}` = {', '.join(v)}" for k, v in spec["grid"].items())
        + f"; laws: {', '.join(doc['laws'])}; {spec['seeds']} seeds per cell (campaign seed {spec['seed']}).", "",
        f"A run succeeds when its closest approach to any object stays above {c['min_distance_m']:g} m, the "
        f"formation settles {settle}, its final formation error is under {c['final_error_m']:g} m, and its "
        "law never failed.", "",
        "| law | cell | runs | successes | success rate (95 % Wilson) | settling median / p95 (s) | unsettled "
        "| min distance p05 (m) | errors |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for cell in doc["cells"]:
        ci = cell["success_rate_ci95"]
        rate = "-" if cell["success_rate"] is None else f"{cell['success_rate']:.2f} [{ci[0]:.2f}, {ci[1]:.2f}]"
        st = cell["formation_settle_s"]
        md = cell["min_distance_m"] or {}
        where = " ".join(f"{k}={_label(v)}" for k, v in cell["cell"].items())
        lines.append(f"| {cell['law']} | {where} | {cell['runs']} | {cell['successes']} | {rate} | "
                     f"{_fmt(st['median'])} / {_fmt(st['p95'])} | {st['unsettled']} | {_fmt(md.get('p05'), '{:.3f}')} "
                     f"| {cell['errors']} |")
    lines += ["", "## Figures", ""]
    captions = {MAP: "Success rate over the grid, one panel per law.",
                DISTRIBUTIONS: "Every run's settling time and closest approach, per law."}
    for path in figures:
        lines += [f"![{path.stem}]({path.name})", "", captions[path.name], ""]
    lines += ["Each line of `runs.jsonl` holds a run and the `fxswarm sim` command line that replays it alone.", ""]
    index = folder / "index.md"
    index.write_text("\n".join(lines))
    return [*figures, index]
