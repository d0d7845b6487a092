"""``fxswarm report``: every figure written, each a real image; index.md; sweep plot (the headless
snapshot, which starts a viewer, is in tests/integration/test_rerun_viewer.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fxswarm.cli import main as cli
from fxswarm.report import FIGURES, SETTLING, sweep_rows

from support import has_colour, image_stats


@pytest.mark.slow  # a 12 s simulation and every figure drawn: tens of seconds under load
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


@pytest.mark.slow  # a 12 s simulation and every figure drawn: tens of seconds under load
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


@pytest.mark.parametrize("bad", ["abc", ",", "1,-2", "1,nan"])
def test_report_refuses_bad_snapshot_times_before_it_writes_anything(run_dir, capsys, bad):
    before = sorted(p.name for p in run_dir.iterdir())
    with pytest.raises(SystemExit) as exc:
        cli(["report", str(run_dir), "--snapshot", "--times", bad])
    assert exc.value.code == 2
    assert f"--times: expected comma-separated seconds >= 0, got {bad!r}" in capsys.readouterr().err
    assert sorted(p.name for p in run_dir.iterdir()) == before
