"""``fxswarm sweep`` and the discretisation study with the feedforward estimator (issue 20)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from fxswarm.core.scenario import load, parse
from fxswarm.study.discretisation import case_toml as floor_case_toml
from fxswarm.study.sweep import claims, plan, run_sweep
from fxswarm.study.variants import SWEEP_VARIANTS, split_variant, variant_toml

PAPER = "configs/paper.toml"


def test_every_controller_variant_also_comes_with_feedforward_tracking():
    base = load(PAPER)
    assert SWEEP_VARIANTS[3:] == ("fixed-time+feedforward", "asymptotic+feedforward", "finite-time+feedforward")
    for name in SWEEP_VARIANTS:
        variant, tracking = split_variant(name)
        sc = parse(variant_toml(base.raw, name), name)
        assert (sc.variant, sc.estimator_variant, sc.tracking) == (variant, variant, tracking)
    assert parse(floor_case_toml(base.raw, "euler", tracking="feedforward"), "x").tracking == "feedforward"
    assert parse(floor_case_toml(base.raw, "euler"), "x").tracking == "paper"


@pytest.mark.slow  # 35 s simulations on a process pool: minutes under load (make test-unit skips)
def test_fixed_time_feedforward_sweep_stays_bounded():
    """The fixed-time claim holds with the feedforward, as a cascade: eq. (v2ff) feeds the
    formation ``vh``, not the estimate's rate, so the formation task (against the robot's own
    estimate) obeys eq. (v2)'s law only once the estimate has settled and settles within SPEC
    section 6's bound after that (docs/estimator.md; measured: 30.0 and 32.6 s, estimator 25.5
    and 28.1 s, bound 23.2 s). The estimator's and the formation's settle times grow < 25 % from
    1e4 to 1e5 (as issue 7 asks of the paper's estimator; measured: 10 % and 9 %), and the
    observer's own bound is reported (1.5 s on the paper's ring)."""
    base = load(PAPER)
    rows = run_sweep(plan(base, [1e4, 1e5], ["fixed-time+feedforward"], duration=35.0), workers=2)
    assert [r["scale"] for r in rows] == [1e4, 1e5]
    for r in rows:
        assert r["settled"] and r["tracking"] == "feedforward" and r["variant"] == "fixed-time+feedforward"
        assert r["formation_settle_s"] < r["estimate_settle_s"] + r["bounds"]["formation_bound_s"]
        assert r["bounds"]["observer_bound_s"] == pytest.approx(1.5)
    assert rows[1]["estimate_settle_s"] < 1.25 * rows[0]["estimate_settle_s"]
    assert rows[1]["formation_settle_s"] < 1.25 * rows[0]["formation_settle_s"]
    assert claims(rows)["fixed_time_feedforward_estimator_growth_1_to_1e5"] is None  # no scale-1 row


def test_sweep_refuses_an_unknown_tracking_suffix(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "fxswarm.cli", "sweep", PAPER, "--variants", "fixed-time+lookahead",
                           "--out", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "fixed-time+feedforward" in proc.stderr
