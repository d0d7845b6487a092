"""The control law's identities (SPEC sections 2-5), guards and projector properties."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fxswarm.core.control import (
    EPS,
    BehaviourGains,
    ControlParameters,
    EstimatorGains,
    avoidance_velocity,
    estimator_rate,
    formation_velocity,
    merged_velocity,
    task_rate,
)
from fxswarm.core.paper_law import robot_control
from oracle import sig

PAPER = BehaviourGains(lam=1.0, b1=0.6, b2=0.6, r0=0.9, r1=1.2, r2=0.6)
ESTIMATOR = EstimatorGains(K1=0.4, K2=0.6, K3=1.0, r3=6, r4=5, r5=3, r6=5)
LAW = ControlParameters(PAPER, PAPER, ESTIMATOR, d=2.0)



def avoidance_task(u, d: float) -> float:
    """``rt = d^2/2 - |u|^2/2``, the avoidance task error (eq. (2)); active iff positive."""
    return 0.5 * d * d - 0.5 * float(u @ u)


def null_space_projector(u) -> np.ndarray:
    """``I - u u^T / |u|^2``, the projector eq. (v) applies to ``v_if``."""
    return np.eye(3) - np.outer(u, u) / (u @ u)


coord = st.floats(-50, 50, allow_nan=False)
vec = st.tuples(coord, coord, coord).map(np.array)


def test_sig_is_odd_and_keeps_magnitude_power():
    x = np.array([-8.0, 0.0, 2.0])
    assert np.allclose(sig(x, 1 / 3), [-2.0, 0.0, 2 ** (1 / 3)])
    assert np.allclose(sig(-x, 1.7), -sig(x, 1.7))


@settings(max_examples=200, deadline=None)
@given(e=vec, dph=vec, dp0=vec)
def test_formation_velocity_makes_rho_decay_at_the_task_rate(e, dph, dp0):
    """d rho/dt = e.(v - dph - dp_i0) = -task_rate(rho) (SPEC section 3), checked by a tiny step."""
    if np.linalg.norm(e) < 1e-3:
        return
    p, ph, p0 = e.copy(), np.zeros(3), np.zeros(3)  # e = p - ph - p0
    v = np.array(formation_velocity(e, dph, dp0, PAPER))
    h = 1e-7
    rho = lambda p_, ph_, p0_: 0.5 * np.sum((p_ - ph_ - p0_) ** 2)
    drho = (rho(p + h * v, ph + h * dph, p0 + h * dp0) - rho(p - h * v, ph - h * dph, p0 - h * dp0)) / (2 * h)
    expected = -task_rate(0.5 * e @ e, PAPER)
    assert drho == pytest.approx(expected, rel=1e-6, abs=1e-6 * (1 + abs(expected)))


@settings(max_examples=200, deadline=None)
@given(u=vec, vo=vec)
def test_avoidance_velocity_makes_rt_decay_at_the_task_rate(u, vo):
    """d rt/dt = -u.(v - vo) = -task_rate(rt) inside the zone (SPEC section 4)."""
    d = 60.0
    if np.linalg.norm(u) < 1e-3 or avoidance_task(u, d) <= 0:
        return
    v = np.array(avoidance_velocity(u, vo, d, PAPER))
    # rt = d^2/2 - |u|^2/2 with du/dt = v - vo, so d rt/dt = -u.(v - vo) exactly (a finite
    # difference here loses ~1e-5 to cancellation once |u| is tens of metres).
    drt = -u @ (v - vo)
    expected = -task_rate(avoidance_task(u, d), PAPER)
    assert drt == pytest.approx(expected, rel=1e-6, abs=1e-6 * (1 + abs(expected)))


@settings(max_examples=100, deadline=None)
@given(u=vec, v_if=vec)
def test_merge_projects_the_formation_velocity_off_u(u, v_if):
    """With no avoidance velocity, eq. (v) is a projection: orthogonal to u and idempotent."""
    if np.linalg.norm(u) < 1e-3:
        return
    zero = np.zeros(3)
    w = np.array(merged_velocity(zero, u, v_if))
    assert u @ w == pytest.approx(0.0, abs=1e-9 * np.linalg.norm(u) * (1 + np.linalg.norm(v_if)))
    assert np.allclose(merged_velocity(zero, u, w), w, atol=1e-12 * (1 + np.linalg.norm(v_if)))
    assert np.linalg.norm(w) <= np.linalg.norm(v_if) * (1 + 1e-12) + 1e-12


@settings(max_examples=100, deadline=None)
@given(u=vec, v_if=vec, v_io=vec)
def test_merge_keeps_the_avoidance_component_along_u(u, v_if, v_io):
    """The merged velocity's component along u is the avoidance task's alone (eq. (v))."""
    if np.linalg.norm(u) < 1e-3:
        return
    v = np.array(merged_velocity(v_io, u, v_if))
    assert u @ v == pytest.approx(u @ v_io, rel=1e-9, abs=1e-9 * (1 + np.linalg.norm(u) * np.linalg.norm(v_if)))
    assert np.allclose(v, v_io + null_space_projector(u) @ v_if)


def test_guards_at_zero_give_finite_documented_values():
    dph, dp0 = np.array([0.1, 0.2, 0.3]), np.array([1.0, 0.0, 0.0])
    for e in (np.zeros(3), np.full(3, EPS / 10)):
        assert np.array_equal(formation_velocity(e, dph, dp0, PAPER), dph + dp0)
    v = avoidance_velocity(np.zeros(3), np.zeros(3), 2.0, PAPER)
    assert np.all(np.isfinite(v)) and v[2] > 0 and v[0] == v[1] == 0  # pushed straight up
    assert np.all(np.isfinite(merged_velocity(v, np.zeros(3), dph)))
    assert np.all(np.isfinite(estimator_rate(np.zeros(3), np.zeros((2, 3)), np.ones(2), ESTIMATOR)))
    assert np.array_equal(estimator_rate(np.ones(3), np.zeros((0, 3)), np.zeros(0), ESTIMATOR), np.zeros(3))
    zero = [0.0, 0.0, 0.0]
    out = robot_control(zero, zero, [zero], [1.0], zero, zero, zero, zero, LAW, 0.01)
    assert out.avoid_active and np.all(np.isfinite(out.v))


def test_estimator_pairwise_and_aggregate_follow_eq_11():
    ph = np.array([1.0, -2.0, 0.5])
    nb = np.array([[0.0, 0.0, 0.0], [3.0, -1.0, 2.0]])
    w = np.array([1.0, 2.0])
    diff = ph - nb
    pairwise = (-0.4 * (w @ sig(diff, 6 / 5)) - 0.6 * (w @ sig(diff, 3 / 5)) - np.sign(w @ diff))
    assert np.allclose(estimator_rate(ph, nb, w, ESTIMATOR), pairwise)
    agg = dataclasses.replace(ESTIMATOR, power="aggregate")
    s = w @ diff
    assert np.allclose(estimator_rate(ph, nb, w, agg), -0.4 * sig(s, 1.2) - 0.6 * sig(s, 0.6) - np.sign(s))
    # With one neighbour the two forms coincide.
    assert np.allclose(estimator_rate(ph, nb[:1], w[:1], ESTIMATOR), estimator_rate(ph, nb[:1], w[:1], agg))


def test_robot_control_switches_avoidance_only_inside_the_zone():
    zero = [0.0, 0.0, 0.0]
    common = dict(ph=zero, rows=[zero], ws=[1.0], p0=zero, dp0=zero, vo=zero, law=LAW, dt=0.01)
    outside = robot_control(p=[3.0, 0.0, 0.0], po=zero, **common)
    inside = robot_control(p=[1.0, 0.0, 0.0], po=zero, **common)
    assert not outside.avoid_active and inside.avoid_active
    assert inside.v[0] > 0  # pushed away from the object despite the formation pulling back to 0
    alone = robot_control(p=[1.0, 0.0, 0.0], po=None, **common)
    assert not alone.avoid_active


def test_speed_limit_clips_and_reports():
    """``v_max`` scales a faster command down to the limit, direction kept; slower ones pass."""
    zero = [0.0, 0.0, 0.0]
    common = dict(ph=zero, rows=[], ws=[], p0=zero, po=None, vo=None, dt=0.01)
    fast = dict(p=zero, dp0=[3.0, 4.0, 0.0], **common)  # e = 0: the command is the reference's rate
    free = robot_control(law=LAW, **fast)
    assert free.v == [3.0, 4.0, 0.0] and not free.speed_limited
    limited = robot_control(law=dataclasses.replace(LAW, v_max=1.0), **fast)
    assert limited.speed_limited and np.linalg.norm(limited.v) == pytest.approx(1.0)
    assert limited.v[1] / limited.v[0] == pytest.approx(4 / 3)
    slow = robot_control(law=dataclasses.replace(LAW, v_max=1.0), **dict(fast, dp0=[0.3, 0.4, 0.0]))
    assert not slow.speed_limited and slow.v == [0.3, 0.4, 0.0]
