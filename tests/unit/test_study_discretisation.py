"""Explicit Euler against the semi-implicit step: floors, settle times, fixed-time kept.

The floor is the worst robot's error over the second half of a run; runs here
drop the obstacles (an avoidance episode is not a discretisation floor) and
are short, since every transient is over by about 5 s.
"""

from __future__ import annotations

import pytest

from fxswarm.core.scenario import load
from fxswarm.study.discretisation import case_toml, graph_hops, run_floor_case
from fxswarm.study.parallel import parallel_map
from fxswarm.study.sweep import plan, run_sweep


@pytest.fixture(scope="module")
def floors():
    paper, fast = load("configs/paper.toml"), load("configs/paper-fast.toml")
    cases = [(case_toml(sc.raw, disc, duration=16.0), sc.name, sc.name)
             for sc in (paper, fast) for disc in ("euler", "semi-implicit")]
    rows = parallel_map(run_floor_case, cases, workers=2)
    return {(r["series"], r["discretisation"]): r for r in rows}


def test_hops_of_the_paper_ring():
    assert graph_hops(load("configs/paper.toml")) == 2  # ring of 6 pinned at 1 and 4: one hop, plus the leader link


@pytest.mark.slow  # 16-32 s simulations on a process pool: minutes under load
def test_semi_implicit_cuts_the_paper_floor(floors):
    euler, semi = floors[("paper", "euler")], floors[("paper", "semi-implicit")]
    assert euler["floors_m"]["estimate_m"] >= 5 * semi["floors_m"]["estimate_m"]
    # never below what one hop per tick allows
    assert semi["floors_m"]["estimate_m"] >= semi["floor_limit_m"]
    assert semi["settle_s"]["estimator_s"] == pytest.approx(euler["settle_s"]["estimator_s"], rel=0.10)
    # the implicit formation step: the task's own error is gone, not just smaller
    assert semi["floors_m"]["formation_task_m"] < 1e-5 < 0.01 < euler["floors_m"]["formation_task_m"]


@pytest.mark.slow  # 16-32 s simulations on a process pool: minutes under load
def test_paper_fast_floor_is_set_by_the_leader(floors):
    """Leader at K3 = 1 m/s: lag, not chatter, sets the floor, so the semi-implicit step gains little."""
    euler, semi = floors[("paper-fast", "euler")], floors[("paper-fast", "semi-implicit")]
    ratio = euler["floors_m"]["estimate_m"] / semi["floors_m"]["estimate_m"]
    assert 0.5 < ratio < 2.0
    lag_ticks = semi["floors_m"]["estimate_m"] / (semi["dt"] * semi["leader_speed_mps"])
    assert semi["hops"] <= lag_ticks < 15  # a handful of ticks of leader motion


@pytest.mark.slow  # 16-32 s simulations on a process pool: minutes under load
def test_semi_implicit_keeps_fixed_time():
    base = load("configs/paper.toml")
    euler = plan(base, [1e5], ["fixed-time"], duration=32.0)
    semi = plan(base, [1e5], ["fixed-time"], duration=32.0, discretisation="semi-implicit")
    rows = {r["discretisation"]: r for r in run_sweep(euler + semi, workers=2)}
    s, e = rows["semi-implicit"], rows["euler"]
    assert s["formation_settle_s"] < s["bounds"]["formation_bound_s"]
    assert abs(s["formation_settle_s"] - s["bounds"]["formation_exact_s"]) < 0.05 * s["bounds"]["formation_exact_s"]
    assert s["estimate_settle_s"] == pytest.approx(e["estimate_settle_s"], rel=0.10)
