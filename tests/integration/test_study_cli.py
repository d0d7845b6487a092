"""``fxswarm sweep`` as a user runs it, a separate process: the JSON and figure it writes, bad input."""

from __future__ import annotations

import json
import subprocess

from support import PAPER, fxswarm_command


def test_sweep_command_writes_json_and_figure(tmp_path):
    out = tmp_path / "sweep"
    proc = subprocess.run(
        fxswarm_command("sweep", PAPER, "--scales", "1,10", "--variants", "fixed-time",
                        "--duration", "12", "--workers", "2", "--out", out, "--quiet"),
        capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((out / "sweep.json").read_text())
    assert [(r["variant"], r["scale"]) for r in doc["rows"]] == [("fixed-time", 1.0), ("fixed-time", 10.0)]
    assert doc["settings"]["avoidance"] is False and doc["settings"]["dt"] == 0.01
    assert doc["bounds"]["estimator_printed_s"] < 0.3 < 70 < doc["bounds"]["estimator_derived_s"]
    for key in ("initial_error_m", "formation_settle_s", "estimate_settle_s", "bounds", "initial_errors_m"):
        assert key in doc["rows"][0]
    figure = out / "settling_vs_initial_error.png"
    assert figure.is_file() and figure.stat().st_size > 10_000


def test_sweep_command_refuses_bad_input(tmp_path):
    proc = subprocess.run(fxswarm_command("sweep", PAPER, "--variants", "sliding", "--out", tmp_path),
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "fixed-time, asymptotic, finite-time" in proc.stderr
