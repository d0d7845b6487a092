"""Controller variants, their validation, the scaling of initial errors, the derived bound and
the semi-implicit step, checked without running a swarm (fast)."""

from __future__ import annotations

import copy
import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fxswarm.core import control, paper_law
from fxswarm.core.bounds import estimator_bound_derived, estimator_bound_printed, settling_time_limit
from fxswarm.core.control import BehaviourGains, EstimatorGains
from fxswarm.core.scenario import ScenarioError, load, parse
from fxswarm.study.sweep import formation_exact_time
from fxswarm.study.variants import case_toml, scaled_toml, slots, variant_gains, variant_toml

PAPER = "configs/paper.toml"


@pytest.fixture(scope="module")
def paper():
    return load(PAPER)


def test_variant_gains_change_only_exponents(paper):
    g = paper.raw["gains"]
    asym = variant_gains(g, "asymptotic")
    assert (asym["r0"], asym["r1"], asym["r2"]) == (1.0, 1.0, 1.0)
    assert asym["r3"] == asym["r4"] and asym["r5"] == asym["r6"]
    fin = variant_gains(g, "finite-time")
    assert fin["r1"] * fin["r0"] == pytest.approx(0.9) and fin["r3"] / fin["r4"] == pytest.approx(0.9)
    assert (fin["r2"], fin["r5"], fin["r6"]) == (g["r2"], g["r5"], g["r6"])
    for v in (asym, fin):
        assert {k: v[k] for k in ("b1", "b2", "lam_f", "K1", "K2", "K3")} == \
               {k: g[k] for k in ("b1", "b2", "lam_f", "K1", "K2", "K3")}
    assert variant_gains(g, "fixed-time") == g
    with pytest.raises(ValueError, match="unknown controller variant"):
        variant_gains(g, "sliding")


@pytest.mark.parametrize("variant", ["fixed-time", "asymptotic", "finite-time"])
def test_each_variant_parses_and_is_recorded(paper, variant):
    sc = parse(variant_toml(paper.raw, variant), "v.toml")
    assert sc.variant == sc.estimator_variant == variant
    assert sc.discretisation == "euler"


@pytest.mark.parametrize("declared, gains_of, field", [
    ("asymptotic", "fixed-time", "gains.r1"),
    ("finite-time", "fixed-time", "gains.r1"),
    ("fixed-time", "finite-time", "gains.r1"),
    ("fixed-time", "asymptotic", "gains.r1"),
])
def test_validation_knows_each_variants_conditions(paper, declared, gains_of, field):
    raw = copy.deepcopy(paper.raw)
    raw["gains"] = variant_gains(paper.raw["gains"], gains_of)
    raw["controller"] = {"variant": declared}
    with pytest.raises(ScenarioError, match=rf"v\.toml: {field}: expected .*{declared}"):
        parse(raw, "v.toml")


def test_estimator_variant_is_checked_on_its_own(paper):
    raw = copy.deepcopy(paper.raw)
    raw["gains"] = dict(paper.raw["gains"], r3=4.0)  # r3/r4 = 0.8: not fixed-time
    with pytest.raises(ScenarioError, match=r"gains\.r3: expected r3/r4 > 1 for the fixed-time estimator"):
        parse(raw, "v.toml")
    raw["controller"] = {"estimator_variant": "finite-time"}  # behaviours stay fixed-time
    sc = parse(raw, "v.toml")
    assert (sc.variant, sc.estimator_variant) == ("fixed-time", "finite-time")


def test_controller_table_rejects_unknown_values(paper):
    for table, pattern in [({"discretisation": "rk4"}, r"controller\.discretisation: expected one of"),
                           ({"variant": "slow"}, r"controller\.variant: expected one of"),
                           ({"gain": 1}, r"controller\.gain: expected no such field")]:
        raw = copy.deepcopy(paper.raw)
        raw["controller"] = table
        with pytest.raises(ScenarioError, match=pattern):
            parse(raw, "v.toml")


@pytest.mark.parametrize("scale", [1.0, 37.0, 1e5])
def test_scaling_multiplies_displacement_and_estimate_error(paper, scale):
    sc = parse(scaled_toml(paper, paper.raw, scale), "s.toml")
    p0 = paper.leader.position(0.0)
    for before, after, slot in zip(paper.robots, sc.robots, slots(paper)):
        np.testing.assert_allclose(np.array(after.position) - slot, scale * (np.array(before.position) - slot),
                                   rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(np.array(after.estimate) - p0, scale * (np.array(before.estimate) - p0),
                                   rtol=1e-12, atol=1e-9)


def test_case_switches_avoidance_off_unless_asked(paper):
    off = parse(case_toml(paper, "fixed-time", 10.0, 30.0), "c.toml")
    assert off.obstacles == () and off.d < 1e-3 and off.duration == 30.0
    on = parse(case_toml(paper, "fixed-time", 10.0, 30.0, avoidance=True), "c.toml")
    assert len(on.obstacles) == 4 and on.d == paper.d


# --- theory: the settling-time shapes the sweep should reproduce ---------------------------


def test_formation_theory_bounded_logarithmic_power(paper):
    """The continuous-time settle time from |e0| to the tolerance, per variant (SPEC section 6)."""
    tol = paper.settle_tolerance
    gains = {v: parse(variant_toml(paper.raw, v), "v").formation for v in ("fixed-time", "asymptotic", "finite-time")}
    e0s = [10.0**k for k in range(0, 9)]
    T = {v: [formation_exact_time(e0, tol, g) for e0 in e0s] for v, g in gains.items()}
    # fixed time: bounded by the limit, itself below the paper's closed-form bound
    assert max(T["fixed-time"]) < settling_time_limit(gains["fixed-time"]) < 23.3
    # asymptotic: the same increment per decade, ln(100)/(lam (b1+b2)) (rho ~ e^2)
    steps = np.diff(T["asymptotic"])
    np.testing.assert_allclose(steps, math.log(100.0) / 1.2, rtol=1e-9)
    # finite time: log T against log e0 tends to a straight line of slope 2*(1 - r1*r0) = 0.2
    slope = np.diff(np.log(T["finite-time"][-3:])) / math.log(10.0)
    np.testing.assert_allclose(slope, 0.2, atol=0.02)


def test_derived_estimator_bound(paper):
    H, g = paper.H, paper.estimator
    uniform = estimator_bound_derived(H, g)
    assert 70.0 < uniform < 76.0  # paper scenario: 73.1 s
    assert estimator_bound_printed(H, g) < 0.3  # the printed T_E, two orders of magnitude lower
    delta = np.tile([-2.0, 0.0, 0.0], (paper.n, 1))
    from_initial = [estimator_bound_derived(H, g, s * delta, 0.2) for s in (1.0, 1e2, 1e4, 1e5, 1e8)]
    assert all(a < b for a, b in zip(from_initial, from_initial[1:]))  # more error, more time...
    assert from_initial[-1] < uniform  # ...but never beyond the uniform bound
    asym = parse(variant_toml(paper.raw, "asymptotic"), "a").estimator
    assert estimator_bound_derived(H, asym) == math.inf
    grow = [estimator_bound_derived(H, asym, s * delta, 0.2) for s in (1e2, 1e3, 1e4)]
    assert grow[2] - grow[1] == pytest.approx(grow[1] - grow[0], rel=1e-3)  # logarithmic


# --- the semi-implicit step --------------------------------------------------------------


GAINS = EstimatorGains(K1=0.4, K2=0.6, K3=1.0, r3=6.0, r4=5.0, r5=3.0, r6=5.0)
FORMATION = BehaviourGains(lam=1.0, b1=0.6, b2=0.6, r0=0.9, r1=1.2, r2=0.6)


@settings(max_examples=150, deadline=None)
@given(
    m=st.integers(1, 3),
    log_scale=st.floats(-5.0, 5.0),
    log_dt=st.floats(-3.5, -1.3),
    power=st.sampled_from(["pairwise", "aggregate"]),
    seed=st.integers(0, 2**32 - 1),
)
def test_estimator_step_solves_the_implicit_equation(m, log_scale, log_dt, power, seed):
    rng = np.random.default_rng(seed)
    scale, dt = 10.0**log_scale, 10.0**log_dt
    ph, held, w = rng.normal(size=3) * scale, rng.normal(size=(m, 3)) * scale, rng.uniform(0.5, 2.0, m)
    g = replace(GAINS, power=power)
    nxt = control.estimator_step_semi_implicit(ph, held, w, g, dt)
    consensus = w @ held / w.sum()
    for c in range(3):
        x = float(nxt[c])
        column = np.repeat(held[:, c:c + 1], 3, axis=1)
        if math.isclose(x, consensus[c], rel_tol=1e-12, abs_tol=1e-15):
            # snapped: the sign term's set-valued range [-K3, K3] contains what the step needs
            powers = control.estimator_rate(np.full(3, x), column, w, replace(g, K3=0.0))[0]
            assert abs(x - ph[c] - dt * powers) <= dt * g.K3 * (1 + 1e-9) + 1e-12 * max(1.0, abs(x))
        else:
            rate = control.estimator_rate(np.full(3, x), column, w, g)[0]
            assert abs(x - ph[c] - dt * rate) <= 1e-9 * max(1.0, abs(x), abs(ph[c]))


def test_estimator_step_snaps_to_consensus_within_one_step():
    held = np.array([[1.0, 2.0, 3.0], [1.002, 2.0, 3.0]])
    ph = np.array([1.005, 2.003, 2.996])  # within K3*dt = 0.01 of consensus on every axis
    nxt = control.estimator_step_semi_implicit(ph, held, np.ones(2), GAINS, 0.01)
    np.testing.assert_allclose(nxt, [1.001, 2.0, 3.0], rtol=0, atol=1e-15)
    assert np.array_equal(control.estimator_step_semi_implicit(ph, np.zeros((0, 3)), np.zeros(0), GAINS, 0.01), ph)


@pytest.mark.parametrize("rho", [1e-15, 1e-6, 0.02, 1.0, 1e4, 1e11])
@pytest.mark.parametrize("dt", [0.0005, 0.01, 0.05])
def test_implicit_task_value(rho, dt):
    nxt = control.implicit_task_value(rho, FORMATION, dt)
    assert 0.0 <= nxt < rho
    assert nxt + dt * control.task_rate(nxt, FORMATION) == pytest.approx(rho, rel=1e-12, abs=1e-300)


def test_formation_step_lands_on_the_implicit_error():
    e = np.array([3.0, -4.0, 1.0])
    dph, dp_i0, dt = np.array([0.3, 0.1, 1.0]), np.array([0.01, 0.0, 0.0]), 0.01
    v = control.formation_velocity_semi_implicit(e, dph, dp_i0, FORMATION, dt)
    e_next = e + dt * (v - dph - dp_i0)  # the world's step, the estimate's step, the offset's step
    rho_next = control.implicit_task_value(0.5 * float(e @ e), FORMATION, dt)
    assert 0.5 * float(e_next @ e_next) == pytest.approx(rho_next, rel=1e-12)
    np.testing.assert_allclose(np.cross(e_next, e), 0.0, atol=1e-12)  # direction kept
    # the part of v along e tends to eq. (v2)'s as dt -> 0
    v2 = control.formation_velocity(e, dph, dp_i0, FORMATION)
    vs = control.formation_velocity_semi_implicit(e, dph, dp_i0, FORMATION, 1e-7)
    assert float(vs @ e) == pytest.approx(float(v2 @ e), rel=1e-5)


def test_robot_control_default_is_explicit_euler():
    law = control.ControlParameters(FORMATION, FORMATION, GAINS, d=2.0)
    args = ([1.0, 2.0, 0.5], [0.0, 0.0, 0.0], [[0.1, 0.2, 0.0], [0.0, 0.0, 0.3]], [1.0, 1.0],
            [1.0, 0.0, 0.0], [0.0, 0.0, 0.0], None, None)
    out = paper_law.robot_control(*args, law, 0.01)
    dph = control.estimator_rate(args[1], args[2], args[3], GAINS)
    assert out.dph == dph
    assert out.v == control.formation_velocity(out.e, dph, args[5], FORMATION)
    semi = paper_law.robot_control(*args, replace(law, semi_implicit=True), 0.01)
    nxt = control.estimator_step_semi_implicit(args[1], args[2], args[3], GAINS, 0.01)
    np.testing.assert_allclose(np.array(args[1]) + 0.01 * np.array(semi.dph), nxt, rtol=0, atol=1e-15)
