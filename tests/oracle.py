"""The test oracle of the control law: the paper's equations transcribed into numpy, slowly.

``fxswarm.core.control`` holds the law once, on Python floats, tuned for the agent's hot
path. This is the same law written the obvious way, as a check on it: the Jacobians and
their pseudo-inverses as matrices (``np.linalg.pinv``), the null-space projector as a 3x3
matrix, ``sig`` as ``sign * |x|^a``, the implicit Euler equations solved by plain bisection.
It shares no code with the package but the gain dataclasses. It rounds differently, so
the two agree to rounding, and on the same side of every switch (the avoidance zone, the
sign term, the speed limit, the consensus snap) unless the input sits within rounding of
that switch: :func:`robot_control` reports its distance to the nearest one (``margin``).

Equation labels as in the package: (11) estimator, (v1) avoidance, (v2) formation,
(v) null-space merge; SPEC sections 2-4 and 7.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fxswarm.core.control import EPS, BehaviourGains, ControlParameters, EstimatorGains


def sig(x, a: float):
    """``|x|^a * sign(x)`` element by element (the paper's ``x^[a]``)."""
    return np.sign(x) * np.abs(x) ** a


def task_rate(x: float, g: BehaviourGains) -> float:
    """``lam (b1 x^r1 + b2 x^r2)^r0`` for ``x > 0``, else 0."""
    return g.lam * (g.b1 * x**g.r1 + g.b2 * x**g.r2) ** g.r0 if x > 0 else 0.0


def estimator_rate(ph: np.ndarray, rows: np.ndarray, ws: np.ndarray, g: EstimatorGains) -> np.ndarray:
    """Eq. (11): ``-K1 sum a sig(d, r3/r4) - K2 sum a sig(d, r5/r6) - K3 sign(eta3)``, pairwise or
    aggregate (``sig`` of the weighted sum ``eta3``), shape (3,)."""
    if len(ws) == 0:
        return np.zeros(3)
    diff = ph[None, :] - rows  # (m, 3)
    eta3 = ws @ diff
    a1, a2 = g.r3 / g.r4, g.r5 / g.r6
    if g.power == "aggregate":
        powers = g.K1 * sig(eta3, a1) + g.K2 * sig(eta3, a2)
    else:
        powers = g.K1 * (ws @ sig(diff, a1)) + g.K2 * (ws @ sig(diff, a2))
    return -powers - g.K3 * np.sign(eta3)


def _bisect(f, lo: float, hi: float) -> float:
    """A root of the increasing ``f`` in ``[lo, hi]`` by bisection, to the last bit."""
    for _ in range(2000):
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            break
        if f(mid) > 0.0:
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


def estimator_step_semi_implicit(ph, rows, ws, g: EstimatorGains, dt: float) -> tuple[np.ndarray, float]:
    """The implicit Euler step of eq. (11) with the neighbours held: per axis the ``x`` with
    ``0 in x - x_k - dt*dph(x)`` (``sign(0) = [-1, 1]``, Filippov), shape (3,); and the distance
    of ``|G(x*)|`` from ``dt K3`` (where the step switches between snapping to consensus and not)."""
    if len(ws) == 0:
        return ph.copy(), math.inf
    consensus = ws @ rows / ws.sum()
    no_sign = EstimatorGains(g.K1, g.K2, 0.0, g.r3, g.r4, g.r5, g.r6, g.power)
    out = np.empty(3)
    margin = math.inf
    for c in range(3):
        def G(x: float, c=c) -> float:  # x - x_k + dt P(x): increasing in x
            at = ph.copy()
            at[c] = x
            return x - ph[c] - dt * estimator_rate(at, rows, ws, no_sign)[c]

        xs = consensus[c]
        jump = dt * g.K3
        g_star = G(xs)
        margin = min(margin, abs(abs(g_star) - jump) / max(jump, 1e-300))
        if abs(g_star) <= jump:
            out[c] = xs
            continue
        target = jump if g_star > 0 else -jump
        width = abs(ph[c] - xs) + jump + 1.0
        while (G(xs - width if g_star > 0 else xs + width) - target) * (g_star - target) > 0:
            width *= 2.0
        lo, hi = (xs - width, xs) if g_star > 0 else (xs, xs + width)
        out[c] = _bisect(lambda x: G(x) - target, lo, hi)
    return out, margin


def implicit_task_value(rho: float, g: BehaviourGains, dt: float) -> float:
    """``rho_next`` in ``[0, rho]`` with ``rho_next + dt task_rate(rho_next) = rho``."""
    if rho <= 0.0:
        return 0.0
    return _bisect(lambda x: x + dt * task_rate(x, g) - rho, 0.0, rho)


@dataclass
class Step:
    v: np.ndarray
    dph: np.ndarray
    e: np.ndarray
    avoid_active: bool
    speed_limited: bool
    margin: float  # relative distance of the input from the law's nearest switch


def robot_control(p, ph, rows, ws, p0, dp0, po, vo, law: ControlParameters, dt: float, dph=None,
                  feedforward=None) -> Step:
    """The law of ``fxswarm.core.control.robot_control`` (same arguments), in matrix form."""
    p, ph, p0, dp0 = (np.asarray(x, dtype=float) for x in (p, ph, p0, dp0))
    rows, ws = np.asarray(rows, dtype=float).reshape(-1, 3), np.asarray(ws, dtype=float)
    margin = math.inf
    reference = None  # what eq. (v2) is fed for the estimate's rate, when not dph: eq. (v2ff)
    if dph is not None:
        dph = np.asarray(dph, dtype=float)
    elif law.semi_implicit:
        shift = np.zeros(3) if feedforward is None else dt * np.asarray(feedforward, dtype=float)
        ph_next, margin = estimator_step_semi_implicit(ph + shift, rows + shift, ws, law.estimator, dt)  # (11ff)
        dph = (ph_next - ph) / dt
    else:
        dph = estimator_rate(ph, rows, ws, law.estimator)
        if feedforward is not None:  # eq. (11ff)
            dph = dph + np.asarray(feedforward, dtype=float)
            reference = np.asarray(feedforward, dtype=float)  # eq. (v2ff): vh, not eq. (11)'s chatter
        if len(ws):
            eta3 = ws @ (ph[None, :] - rows)
            scale = np.abs(ws) @ np.abs(ph[None, :] - rows) + 1e-300
            margin = min(margin, *(abs(x) / s if x != 0 else math.inf for x, s in zip(eta3, scale)))
    e = p - ph - p0  # eq. (ctbf)
    ref = dph if reference is None else reference
    rho = 0.5 * e @ e
    margin = min(margin, abs(math.sqrt(e @ e) - EPS) / EPS)
    if np.sqrt(e @ e) < EPS:
        v = ref + dp0
    else:
        J_if, J_hat = e[None, :], -e[None, :]  # (1, 3): d rho/dt = J_if v + J_hat (dph + dp0)
        if law.semi_implicit:  # e shrinks along itself to the implicit Euler value of rho
            shrink = math.sqrt(implicit_task_value(rho, law.formation, dt) / rho)
            v = (shrink - 1.0) / dt * e + dph + dp0
        else:
            v = np.linalg.pinv(J_if) @ (np.array([-task_rate(rho, law.formation)]) - J_hat @ (ref + dp0))  # (v2)
    active = False
    if po is not None:
        u = p - np.asarray(po, dtype=float)
        vo = np.zeros(3) if vo is None else np.asarray(vo, dtype=float)
        rt = 0.5 * law.d**2 - 0.5 * u @ u  # eq. (2)
        margin = min(margin, abs(rt) / (0.5 * law.d**2))
        if rt > 0:
            active = True
            if np.sqrt(u @ u) < EPS:  # SPEC section 4 guard: push straight up
                n = np.array([0.0, 0.0, 1.0])
                v_io = n * task_rate(rt, law.avoidance) / law.d
            else:
                n = u
                J_io = -u[None, :]  # d rt/dt = J_io (v - vo)
                v_io = np.linalg.pinv(J_io) @ (np.array([-task_rate(rt, law.avoidance)]) + J_io @ vo)  # (v1)
            projector = np.eye(3) - np.outer(n, n) / (n @ n)
            v = v_io + projector @ v  # eq. (v)
    limited = False
    if law.v_max is not None:
        speed = np.linalg.norm(v)
        margin = min(margin, abs(speed - law.v_max) / law.v_max)
        if speed > law.v_max:
            v, limited = v * (law.v_max / speed), True
    return Step(v, dph, e, active, limited, margin)
