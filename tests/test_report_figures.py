"""``fxswarm report``: every figure written, each a real image; index.md; sweep plot; headless snapshot."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from fxswarm.cli import main as cli
from fxswarm.core.scenario import load
from fxswarm.report import FIGURES, SETTLING, sweep_rows
from fxswarm.runtime.output import write_run
from fxswarm.runtime.sim import Simulation

ROOT = Path(__file__).resolve().parents[1]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A 12 s paper-fast run (long enough to reach the first obstacle), written like `fxswarm sim`."""
    sc = dataclasses.replace(load(ROOT / "configs/paper-fast.toml"), duration=12.0)
    sc = dataclasses.replace(sc, source=str(ROOT / "configs/paper-fast.toml"))
    sim = Simulation(sc)
    folder = tmp_path_factory.mktemp("run")
    write_run(folder, sim.run(), sim.trajectory())
    return folder


def image_stats(path: Path) -> tuple[tuple[int, int], float, int]:
    """(size (h, w), fraction of non-background pixels, number of distinct colours)."""
    import matplotlib.image as mpimg

    assert path.read_bytes()[:8] == PNG_MAGIC, f"{path} is not a PNG"
    img = mpimg.imread(path)[..., :3]
    background = np.median(img.reshape(-1, 3), axis=0)
    ink = np.any(np.abs(img - background) > 0.1, axis=2).mean()
    rgb = (img * 255).astype(np.uint32)
    colours = len(np.unique((rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]))
    return img.shape[:2], float(ink), colours


def has_colour(path: Path, rgb: int, tol: int = 25, min_pixels: int = 30) -> bool:
    import matplotlib.image as mpimg

    img = (mpimg.imread(path)[..., :3] * 255).astype(int)
    target = np.array([(rgb >> 16) & 255, (rgb >> 8) & 255, rgb & 255])
    return int((np.abs(img - target).max(axis=2) <= tol).sum()) >= min_pixels


def test_report_writes_every_figure_and_index(run_dir):
    assert cli(["report", str(run_dir), "--recording"]) == 0
    from fxswarm.logger.style import FORMATION_ERROR, robot_rgb
    from rerun.chunk import RrdReader

    assert any(c.entity_path == "/" + FORMATION_ERROR for c in RrdReader(run_dir / "recording.rrd").stream())

    for name in FIGURES:
        size, ink, colours = image_stats(run_dir / name)
        assert size[0] >= 300 and size[1] >= 500, name
        assert 0.02 < ink < 0.9, f"{name}: {ink:.3f} of the pixels drawn"
        assert colours > 50, name
        for i in range(6):  # every robot's curve is drawn, in its viewer colour
            assert has_colour(run_dir / name, robot_rgb(i)), f"{name}: robot {i + 1} missing"
    assert not (run_dir / SETTLING).exists()  # no sweep.json, no settling figure
    index = (run_dir / "index.md").read_text()
    for name in FIGURES:
        assert f"]({name})" in index
    summary = json.loads((run_dir / "summary.json").read_text())
    assert f"{summary['formation_error_final_m']:.4f} m" in index
    assert "No `sweep.json`" in index


def test_report_plots_a_sweep_when_there_is_one(run_dir, tmp_path):
    for name in ("trajectory.npz", "summary.json"):
        (tmp_path / name).write_bytes((run_dir / name).read_bytes())
    rows = [{"variant": v, "scale": s, "initial_error_m": 5.0 * s,
             "formation_settle_s": (10.0 if v == "fixed-time" else 5.0 + 3 * np.log10(s)),
             "estimate_settle_s": 2.0 + (0.1 if v == "fixed-time" else 1.0) * np.log10(s)}
            for v in ("fixed-time", "asymptotic") for s in (1, 10, 100, 1000)]
    (tmp_path / "sweep.json").write_text(json.dumps({"rows": rows}))
    assert cli(["report", str(tmp_path)]) == 0
    _, ink, colours = image_stats(tmp_path / SETTLING)
    assert ink > 0.02 and colours > 50
    assert f"]({SETTLING})" in (tmp_path / "index.md").read_text()


def test_sweep_rows_accepts_both_layouts_and_skips_junk():
    rows = [{"variant": "fixed-time", "initial_error": 3.0, "formation_settle_s": 4.0, "estimator_settle_s": None},
            {"variant": "x"}, "junk"]
    assert sweep_rows(rows) == sweep_rows({"rows": rows})
    (only,) = sweep_rows(rows)
    assert only == {"variant": "fixed-time", "scale": None, "initial_error": 3.0, "formation": 4.0,
                    "estimator": None}


def test_report_names_what_is_missing(tmp_path, capsys):
    assert cli(["report", str(tmp_path)]) == 2
    assert "trajectory.npz: no such file" in capsys.readouterr().err


@pytest.mark.slow
def test_snapshot_renders_the_default_blueprint_headless(run_dir):
    from fxswarm.report.snapshot import can_render

    why = can_render()
    if why:
        pytest.skip(f"no headless rendering here: {why}")
    assert cli(["report", str(run_dir), "--snapshot", "--times", "9"]) == 0
    shot = run_dir / "snapshots" / "view_9s.png"
    size, ink, colours = image_stats(shot)
    assert size == (1080, 1920)
    assert colours > 500
    from fxswarm.logger.style import robot_rgb

    # The robots and their curves are drawn, not just the empty layout (chunks fetched late).
    assert sum(has_colour(shot, robot_rgb(i), min_pixels=200) for i in range(6)) >= 4
    assert "snapshots/view_9s.png" in (run_dir / "index.md").read_text()
