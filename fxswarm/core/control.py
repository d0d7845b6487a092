"""The fixed-time behavioural control law: one robot's step, as pure functions on Python floats.

Equation references are to the LaTeX labels of
``shared/paper/fixed-time-behavioral-formation.tex`` (the paper numbers its
equations by those labels' order): (11) the estimator, (v1) the avoidance
behaviour, (v2) the formation behaviour, (v) the null-space merge.
Where SPEC.md settles a point the paper leaves open, the docstring says so.

3-vectors are sequences of three floats ``[x, y, z]`` (lists or tuples; m,
m/s); the functions return lists. Plain floats, not numpy: on 3-vectors each
numpy call costs ~1 us, more than the arithmetic itself, and this is the
agent's per-tick hot path. Sums run left to right in a fixed order, so a
trajectory does not depend on the machine's BLAS (docs/design.md
"Bit for bit: the law stays out of BLAS").
No I/O, no clocks, no globals. These are the law's parts; the law the robots fly is
``fxswarm.core.paper_law`` (:class:`~fxswarm.core.paper_law.BehaviouralLaw`, and
:func:`~fxswarm.core.paper_law.robot_control`, one robot's step through it).
``tests/oracle.py`` holds a plain numpy transcription of the same equations that the tests
check that one against.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

Vec = Sequence[float]

#: Below this norm a behaviour's Jacobian pseudo-inverse is undefined and the
#: guards of SPEC sections 3-4 take over.
EPS = 1e-9

#: The fixed direction the avoidance behaviour pushes along when a robot sits
#: exactly on the object it avoids (SPEC section 4 guard): straight up, since
#: the paper's swarm climbs and up is away from the ground plane.
COINCIDENT_PUSH_DIRECTION = (0.0, 0.0, 1.0)


@dataclass(frozen=True)
class BehaviourGains:
    """Gains shared by the two behaviours (paper section 3; SPEC section 8).

    ``lam`` is the task gain (``lam_f`` or ``lam_o``); the exponents satisfy
    ``r1*r0 > 1`` and ``r2*r0 < 1`` for a fixed-time law.
    """

    lam: float
    b1: float
    b2: float
    r0: float
    r1: float
    r2: float


@dataclass(frozen=True)
class EstimatorGains:
    """Gains of the distributed estimator, paper eq. (11)."""

    K1: float
    K2: float
    K3: float
    r3: float
    r4: float
    r5: float
    r6: float
    power: str = "pairwise"  # "pairwise" (eq. (11) as printed) or "aggregate" (its proof)


@dataclass(frozen=True)
class ControlParameters:
    """Everything the law needs besides the robot's local data: one per scenario.

    ``d``: radius of the repulsive zone, m; ``v_max``: optional speed limit, m/s
    (not in the paper; None: off); ``semi_implicit``: the scenario's
    ``[controller] discretisation = "semi-implicit"`` (False: explicit Euler, SPEC section 7).
    """

    formation: BehaviourGains
    avoidance: BehaviourGains
    estimator: EstimatorGains
    d: float
    v_max: float | None = None
    semi_implicit: bool = False


class ControlOutput(NamedTuple):
    """One robot's control step: the command and what it is made of (vectors as lists)."""

    v: list[float]  # merged (and possibly limited) velocity command, m/s
    dph: list[float]  # the estimate's rate over the step, m/s: ph(k+1) = ph(k) + dt * dph
    e: list[float]  # formation error against the robot's own estimate, m
    avoid_active: bool
    speed_limited: bool


def powers(x, a: float):
    """``x ** a`` for each float of the array ``x`` (>= 0), as a float64 array: the C library's
    ``pow`` element by element, as Python's float ``**`` calls it. The batch form of the law
    (fxswarm.core.paper_law.BehaviouralBatch) raises with this, the per-robot form with ``**``:
    the same function on the same numbers. ``np.float_power``'s float64 loop calls ``pow`` per
    element (about 10 ns); not ``np.power``, which numpy may dispatch to a vectorised pow that
    differs in the last bit (docs/design.md "Bit for bit: batch and per robot";
    tests/unit/test_batch.py checks the two agree). Where ``**`` would raise OverflowError this
    gives inf (numpy's overflow flag: an error under ``np.errstate(over="raise")``)."""
    import numpy as np  # the per-robot hot path above stays numpy-free

    return np.float_power(x, a)


def dot3(a: Vec, b: Vec) -> float:
    """``a . b`` of two 3-vectors, summed left to right."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def task_rate(x: float, g: BehaviourGains) -> float:
    """``lam*(b1*x^r1 + b2*x^r2)^r0`` for ``x >= 0``: the decay rate of a task function.

    Both behaviours make their task function obey ``dx/dt = -task_rate(x)``.
    """
    if x <= 0.0:
        return 0.0
    return g.lam * (g.b1 * x**g.r1 + g.b2 * x**g.r2) ** g.r0


def estimator_rate_step(ph: Vec, rows: Sequence[Vec], ws: Sequence[float], law: ControlParameters, dt: float,
                        feedforward: Vec | None = None) -> list[float]:
    """The estimate's rate over one step, m/s: eq. (11) (with ``feedforward``, eq. (11ff)), or
    under ``law.semi_implicit`` the semi-implicit step's mean rate. Arguments as
    :func:`fxswarm.core.paper_law.robot_control`."""
    if law.semi_implicit:
        start, held = ph, rows
        if feedforward is not None:  # eq. (11ff): eq. (11)'s implicit step in the frame moving at vh,
            # neighbours held in that frame (else the step snaps to their tick-k consensus: a tick of lag a hop)
            shift = [dt * feedforward[0], dt * feedforward[1], dt * feedforward[2]]
            start = [ph[0] + shift[0], ph[1] + shift[1], ph[2] + shift[2]]
            held = [[r[0] + shift[0], r[1] + shift[1], r[2] + shift[2]] for r in rows]
        ph_next = estimator_step_semi_implicit(start, held, ws, law.estimator, dt)
        return [(ph_next[0] - ph[0]) / dt, (ph_next[1] - ph[1]) / dt, (ph_next[2] - ph[2]) / dt]
    dph = estimator_rate(ph, rows, ws, law.estimator)  # eq. (11)
    if feedforward is not None:  # eq. (11ff)
        dph = [dph[0] + feedforward[0], dph[1] + feedforward[1], dph[2] + feedforward[2]]
    return dph


def behaviour_velocity(p: Vec, ph: Vec, dph: Vec, reference: Vec | None, p0: Vec, dp0: Vec, po: Vec | None,
                       vo: Vec | None, law: ControlParameters, dt: float) -> tuple[list[float], list[float], bool]:
    """``(v, e, avoid_active)``: the formation behaviour, eq. (v2) (following ``reference``
    instead of ``dph`` when given: eq. (v2ff)), merged with the avoidance behaviour inside the
    repulsive zone, eqs. (v1), (v). No speed limit. Arguments as
    :func:`fxswarm.core.paper_law.robot_control`."""
    e = [p[0] - ph[0] - p0[0], p[1] - ph[1] - p0[1], p[2] - ph[2] - p0[2]]  # eq. (ctbf)
    if law.semi_implicit:
        v = formation_velocity_semi_implicit(e, dph, dp0, law.formation, dt)
    else:
        v = formation_velocity(e, dph if reference is None else reference, dp0, law.formation)  # eq. (v2), (v2ff)
    active = False
    if po is not None and in_repulsive_zone(p, po, law.d):
        active = True
        u = [p[0] - po[0], p[1] - po[1], p[2] - po[2]]
        v_io = avoidance_velocity(u, vo if vo is not None else (0.0, 0.0, 0.0), law.d, law.avoidance)
        v = merged_velocity(v_io, u, v)  # eq. (v)
    return v, e, active


def in_repulsive_zone(p: Vec, po: Vec, d: float) -> bool:
    """Whether ``p`` is inside the repulsive zone of radius ``d`` around ``po``, eq. (2)."""
    u0, u1, u2 = p[0] - po[0], p[1] - po[1], p[2] - po[2]
    return 0.5 * d * d - 0.5 * (u0 * u0 + u1 * u1 + u2 * u2) > 0.0


def speed_limited(v: list[float], v_max: float | None) -> tuple[list[float], bool]:
    """``v`` scaled down to ``v_max`` (m/s; None: no limit) if faster, and whether it was.
    Not in the paper: the scenario's ``[scenario] v_max``."""
    if v_max is not None:
        speed = math.sqrt(dot3(v, v))
        if speed > v_max:
            return [v[0] * (v_max / speed), v[1] * (v_max / speed), v[2] * (v_max / speed)], True
    return v, False


def estimator_rate(ph: Vec, rows: Sequence[Vec], ws: Sequence[float], gains: EstimatorGains) -> list[float]:
    """``dph_i/dt`` of the fixed-time estimator, paper eq. (11), m/s.

    ph: this robot's estimate of the leader. rows: the estimates it holds of its
    neighbours, shape (m, 3); the leader, when heard, is one more row with
    ``ph_0 := p0``. ws: ``a_ij`` (or ``b_i`` for the leader row), shape (m,).
    With no neighbour at all (m = 0) the rate is zero.

    ``power="pairwise"`` applies ``sig(., r3/r4)`` and ``sig(., r5/r6)`` to each
    difference before summing (eq. (11) as printed); ``"aggregate"`` applies
    them to the weighted sum (the form its proof uses; SPEC section 2).
    """
    if not len(ws):
        return [0.0, 0.0, 0.0]
    # The three axes unrolled: the same sums in the same order as a loop over axes.
    a1, a2 = gains.r3 / gains.r4, gains.r5 / gains.r6
    K1, K2, K3 = gains.K1, gains.K2, gains.K3
    copysign = math.copysign
    pairwise = gains.power != "aggregate"
    x0, x1, x2 = ph
    p0 = p1 = p2 = q0 = q1 = q2 = e0 = e1 = e2 = 0.0  # per axis: the r3/r4 sum, the r5/r6 sum, eta3
    for w, (y0, y1, y2) in zip(ws, rows):
        d0, d1, d2 = x0 - y0, x1 - y1, x2 - y2
        e0 += w * d0
        e1 += w * d1
        e2 += w * d2
        if pairwise:  # w * sig(d, r3/r4), w * sig(d, r5/r6)
            if d0:
                ad = abs(d0)
                p0 += copysign(w * ad**a1, d0)
                q0 += copysign(w * ad**a2, d0)
            if d1:
                ad = abs(d1)
                p1 += copysign(w * ad**a1, d1)
                q1 += copysign(w * ad**a2, d1)
            if d2:
                ad = abs(d2)
                p2 += copysign(w * ad**a1, d2)
                q2 += copysign(w * ad**a2, d2)
    out = []
    for s1, s2, s3 in ((p0, q0, e0), (p1, q1, e1), (p2, q2, e2)):
        if not pairwise and s3:
            ad = abs(s3)
            s1, s2 = copysign(ad**a1, s3), copysign(ad**a2, s3)
        out.append(-K1 * s1 - K2 * s2 - (K3 if s3 > 0.0 else -K3 if s3 < 0.0 else 0.0))  # eq. (11)
    return out


def formation_velocity(e: Vec, dph: Vec, dp0: Vec, g: BehaviourGains) -> list[float]:
    """The formation behaviour's velocity ``v_if``, paper eq. (v2), m/s.

    e: the formation error ``p_i - ph_i - p_i0``, m; dph, dp0: the estimate's and
    the offset's rates, m/s. With ``J_if = e^T``, ``J_ihat = J_i0 = -e^T`` and
    ``rho_tilde = -rho`` substituted (SPEC section 3), so that
    ``d rho/dt = -task_rate(rho)``. Guard: for ``|e| < EPS`` the pseudo-inverse is
    undefined and the robot just follows its reference, ``dph + dp0``.
    """
    ff = [dph[0] + dp0[0], dph[1] + dp0[1], dph[2] + dp0[2]]
    e2 = dot3(e, e)
    if e2 < EPS * EPS:
        return ff
    c = -task_rate(0.5 * e2, g) + dot3(e, ff)
    return [e[0] / e2 * c, e[1] / e2 * c, e[2] / e2 * c]  # eq. (v2)


def avoidance_velocity(u: Vec, vo: Vec, d: float, g: BehaviourGains) -> list[float]:
    """The avoidance behaviour's velocity ``v_io``, paper eq. (v1), m/s.

    u: ``p_i - po``, from the nearest object to the robot, m. vo: that object's
    velocity, m/s. Meant for the active case (``rt = d^2/2 - |u|^2/2 > 0``, eq. (2)),
    where ``d rt/dt = -task_rate(rt)``. Guard: at ``|u| < EPS`` the direction is
    undefined; push along :data:`COINCIDENT_PUSH_DIRECTION` at the task rate.
    """
    u2 = dot3(u, u)
    rate = task_rate(0.5 * d * d - 0.5 * u2, g)
    if u2 < EPS * EPS:
        return [x * rate / d for x in COINCIDENT_PUSH_DIRECTION]
    c = rate + dot3(u, vo)
    return [u[0] / u2 * c, u[1] / u2 * c, u[2] / u2 * c]  # eq. (v1)


def merged_velocity(v_io: Vec, u: Vec, v_if: Vec) -> list[float]:
    """Null-space merge, paper eq. (v): ``v_io + (I - u u^T/|u|^2) v_if``, m/s."""
    u2 = dot3(u, u)
    if u2 < EPS * EPS:
        u, u2 = COINCIDENT_PUSH_DIRECTION, 1.0
    s = dot3(u, v_if) / u2
    return [v_io[0] + v_if[0] - u[0] * s, v_io[1] + v_if[1] - u[1] * s, v_io[2] + v_if[2] - u[2] * s]  # eq. (v)


# --- semi-implicit discretisation (scenario [controller] discretisation = "semi-implicit") ----------
#
# Explicit Euler on eq. (11) makes the sign term chatter: every tick it moves the estimate by
# K3*dt past the consensus of its neighbours and back. The semi-implicit step solves, per robot and
# per axis with the neighbours' values held at this tick, the implicit Euler equation of eq. (11);
# its sign term is set-valued at consensus, so the step lands exactly on consensus whenever that is
# within one step of it. The formation behaviour's step is chosen likewise so that the next task
# value rho is the implicit Euler solution of d rho/dt = -task_rate(rho) (SPEC section 3).


def _estimator_power_sum(x: float, ys: list[float], ws: Sequence[float], gains: EstimatorGains) -> tuple[float, float]:
    """``P(x)`` (the power terms of eq. (11), negated: ``dph = -P - K3 sign(eta3)``) and ``dP/dx``, one axis.

    Infinite slopes (a difference exactly 0 raised to a power below 1) come back as ``inf``.
    """
    al, be = gains.r3 / gains.r4, gains.r5 / gains.r6
    if gains.power == "aggregate":
        diffs, wts = [sum(w * (x - y) for w, y in zip(ws, ys))], [1.0]
        scale = sum(ws)  # d eta3 / dx
    else:
        diffs, wts, scale = [x - y for y in ys], ws, 1.0
    p = dp = 0.0
    for w, d in zip(wts, diffs):
        ad = abs(d)
        if ad == 0.0:
            dp += math.inf if (al < 1.0 or be < 1.0) else w * (gains.K1 * (al == 1.0) + gains.K2 * (be == 1.0))
            continue
        sd = 1.0 if d > 0 else -1.0
        pa, pb = ad**al, ad**be
        p += w * sd * (gains.K1 * pa + gains.K2 * pb)
        dp += w * (gains.K1 * al * pa + gains.K2 * be * pb) / ad
    return p, dp * scale


def _solve_increasing(fn, target: float, lo: float, hi: float, x: float) -> float:
    """The root of ``fn(x)[0] = target`` in ``[lo, hi]`` for an increasing ``fn`` returning
    ``(value, slope)``: Newton steps kept inside the bracket, bisection when they would leave it."""
    for _ in range(200):
        value, slope = fn(x)
        r = value - target
        if r > 0.0:
            hi = x
        elif r < 0.0:
            lo = x
        else:
            return x
        if hi - lo <= 4e-16 * max(1.0, abs(lo), abs(hi)):
            break
        step = x - r / slope if 0.0 < slope < math.inf else math.nan
        x = step if lo < step < hi else 0.5 * (lo + hi)
    return 0.5 * (lo + hi)


def estimator_step_semi_implicit(
    ph: Vec, rows: Sequence[Vec], ws: Sequence[float], gains: EstimatorGains, dt: float
) -> list[float]:
    """The next estimate ``ph_i(k+1)`` by a local semi-implicit step of eq. (11), m, shape (3,).

    Arguments as :func:`estimator_rate`; dt: the step, s. With the neighbours'
    values ``y_j`` held (those of tick k), each axis solves the implicit Euler
    equation ``x = x_k + dt * dph(x)`` of eq. (11),
    ``x - x_k + dt P(x) + dt K3 sign(eta3(x)) = 0``, where ``P`` collects the power
    terms (increasing in ``x``, pairwise or aggregate as ``gains.power``) and
    ``eta3(x) = sum_j a_ij (x - y_j)`` vanishes at the consensus ``x* = sum a y / sum a``.
    The left side is increasing with an upward jump of ``2 dt K3`` at ``x*`` (the
    sign is set-valued there, Filippov), so the solution is unique:

    - ``|G(x*)| <= dt K3`` with ``G(x) = x - x_k + dt P(x)``: ``x = x*`` (snap to consensus);
    - ``G(x*) > dt K3``: the root of ``G(x) = dt K3`` below ``x*``;
    - ``G(x*) < -dt K3``: the root of ``G(x) = -dt K3`` above ``x*``,

    each found by bracketed Newton. Far from consensus this is explicit Euler to
    first order in ``dt`` (so the fixed-time convergence is kept); near it the step
    cannot overshoot, which removes the sign term's ``K3 dt`` chattering. With no
    neighbour at all (m = 0) the estimate stays.
    """
    if not len(ws):
        return list(ph)
    total = sum(ws)
    out = []
    for c in range(3):
        xk = ph[c]
        ys = [row[c] for row in rows]
        xs = sum(w * y for w, y in zip(ws, ys)) / total

        def g(x: float, xk=xk, ys=ys) -> tuple[float, float]:
            p, dp = _estimator_power_sum(x, ys, ws, gains)
            return x - xk + dt * p, 1.0 + dt * dp

        g_star = g(xs)[0]
        jump = dt * gains.K3
        if abs(g_star) <= jump:
            out.append(xs)
            continue
        target = jump if g_star > 0.0 else -jump
        width = max(abs(xk - xs), jump, 1e-12 * max(1.0, abs(xs)))
        for _ in range(2100):  # bracket on the root's side of x*; G is unbounded, so this ends
            far = xs - width if g_star > 0.0 else xs + width
            if (g(far)[0] - target) * (g_star - target) <= 0.0:
                break
            width *= 2.0
        else:
            raise FloatingPointError(f"semi-implicit estimator step: no root bracketed on axis {c} (x_k = {xk!r})")
        lo, hi = (far, xs) if g_star > 0.0 else (xs, far)
        explicit = xk - dt * (_estimator_power_sum(xk, ys, ws, gains)[0] + target / dt)
        start = explicit if lo < explicit < hi else 0.5 * (lo + hi)
        out.append(_solve_increasing(g, target, lo, hi, start))
    return out


def implicit_task_value(rho: float, g: BehaviourGains, dt: float) -> float:
    """``rho_next`` solving ``rho_next + dt * task_rate(rho_next) = rho`` (implicit Euler), m^2.

    The left side increases from 0, so there is one root in ``[0, rho]``; it is found by
    bracketed Newton in ``u = ln(rho_next)``, where the slope stays finite.
    """
    if rho <= 0.0:
        return 0.0

    def h(u: float) -> tuple[float, float]:
        x = math.exp(u)
        s = g.b1 * x**g.r1 + g.b2 * x**g.r2
        rate = g.lam * s**g.r0
        x_rate_slope = g.lam * g.r0 * s ** (g.r0 - 1.0) * (g.b1 * g.r1 * x**g.r1 + g.b2 * g.r2 * x**g.r2)
        return x + dt * rate, x + dt * x_rate_slope

    hi = math.log(rho)
    lo = hi - 1400.0  # exp(lo) underflows to 0: below any root worth a float
    explicit = rho - dt * task_rate(rho, g)
    start = math.log(explicit) if explicit > 0.0 else 0.5 * (lo + hi)
    return math.exp(_solve_increasing(h, rho, lo, hi, start))


def formation_velocity_semi_implicit(e: Vec, dph: Vec, dp0: Vec, g: BehaviourGains, dt: float) -> list[float]:
    """The formation behaviour's velocity for a semi-implicit step of length ``dt`` (s), m/s.

    Arguments as :func:`formation_velocity`. Chooses ``v`` so that after the world's
    step ``p += dt v`` (with the estimate moving ``dt dph`` and the offset ``dt dp0``)
    the error is ``e * sqrt(rho_next/rho)``: same direction, and ``rho_next`` the
    implicit Euler solution of ``d rho/dt = -task_rate(rho)`` (:func:`implicit_task_value`):
    ``v = (sqrt(rho_next/rho) - 1) e / dt + dph + dp0``.
    As ``dt -> 0`` this is eq. (v2) plus ``(I - e e^T/|e|^2)(dph + dp0)``, the
    reference's motion across ``e``: a null-space term of ``J_if = e^T`` that leaves
    ``d rho/dt`` unchanged in continuous time, but without which a discrete step
    lets the error grow by ``dt |feedforward across e|`` every tick.
    Guard: for ``|e| < EPS`` the robot just follows its reference, as in eq. (v2).
    """
    ff = [dph[0] + dp0[0], dph[1] + dp0[1], dph[2] + dp0[2]]
    e2 = dot3(e, e)
    if e2 < EPS * EPS:
        return ff
    rho = 0.5 * e2
    c = (math.sqrt(implicit_task_value(rho, g, dt) / rho) - 1.0) / dt
    return [c * e[0] + ff[0], c * e[1] + ff[1], c * e[2] + ff[2]]
