"""The fixed-time behavioural control law, as pure functions on numpy arrays.

Equation references are to the LaTeX labels of
``shared/paper/fixed-time-behavioral-formation.tex`` (the paper numbers its
equations by those labels' order): (11) the estimator, (v1) the avoidance
behaviour, (v2) the formation behaviour, (v) the null-space merge.
Where SPEC.md settles a point the paper leaves open, the docstring says so.

All vectors are in R^3 (shape ``(3,)``); distances in metres, times in
seconds. No I/O, no clocks, no globals.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Below this norm a behaviour's Jacobian pseudo-inverse is undefined and the
#: guards of SPEC sections 3-4 take over.
EPS = 1e-9

#: The fixed direction the avoidance behaviour pushes along when a robot sits
#: exactly on the object it avoids (SPEC section 4 guard): straight up, since
#: the paper's swarm climbs and up is away from the ground plane.
COINCIDENT_PUSH_DIRECTION = np.array([0.0, 0.0, 1.0])


def dot3(a, b) -> float:
    """``a . b`` of two 3-vectors in plain float arithmetic, summed left to right.

    Not ``a @ b``: numpy hands that to BLAS (ddot), whose kernel OpenBLAS picks per CPU or
    from ``OPENBLAS_CORETYPE``, and the kernels round differently. A trajectory would then
    depend on the machine's BLAS: a container (which does not inherit the variable) parted
    from ``fxswarm sim`` on the host by 1e-15 m at the first avoidance (docs/DESIGN.md).
    """
    return float(a[0]) * float(b[0]) + float(a[1]) * float(b[1]) + float(a[2]) * float(b[2])


def sig(x: np.ndarray | float, a: float) -> np.ndarray | float:
    """``|x|^a * sign(x)`` element by element (the paper's ``x^[a]``)."""
    return np.sign(x) * np.abs(x) ** a


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

    @property
    def exponents(self) -> np.ndarray:
        """``[r3/r4, r5/r6]`` shaped (2, 1, 1) to raise a (m, 3) array to both powers at once."""
        cached = self.__dict__.get("_exponents")
        if cached is None:
            cached = np.array([[[self.r3 / self.r4]], [[self.r5 / self.r6]]])
            object.__setattr__(self, "_exponents", cached)
        return cached


def task_rate(x: float, g: BehaviourGains) -> float:
    """``lam*(b1*x^r1 + b2*x^r2)^r0`` for ``x >= 0``: the decay rate of a task function.

    Both behaviours make their task function obey ``dx/dt = -task_rate(x)``.
    """
    if x <= 0.0:
        return 0.0
    return g.lam * (g.b1 * x**g.r1 + g.b2 * x**g.r2) ** g.r0


def estimator_rate(
    ph_i: np.ndarray,
    neighbours: np.ndarray,
    weights: np.ndarray,
    gains: EstimatorGains,
) -> np.ndarray:
    """``dph_i/dt`` of the fixed-time estimator, paper eq. (11).

    ph_i: this robot's estimate of the leader, shape (3,).
    neighbours: the estimates it holds of its neighbours, shape (m, 3); the
        leader, when heard, is one more row with ``ph_0 := p0``.
    weights: ``a_ij`` (or ``b_i`` for the leader row), shape (m,).
    With no neighbour at all (m = 0) the rate is zero.

    ``power="pairwise"`` applies ``sig(., r3/r4)`` and ``sig(., r5/r6)`` to each
    difference before summing (eq. (11) as printed); ``"aggregate"`` applies
    them to the weighted sum (the form its proof uses; SPEC section 2).
    """
    if len(weights) == 0:
        return np.zeros(3)
    return np.array(_estimator_rate_floats(ph_i.tolist(), neighbours.tolist(), weights.tolist(), gains))


def _estimator_rate_floats(ph: list[float], rows: list[list[float]], ws: list[float], gains: EstimatorGains) -> list[float]:
    """:func:`estimator_rate` on Python floats (m >= 1): per-axis sums, eq. (11)."""
    # Python floats on 3-vectors: each numpy call costs ~1 us, more than the arithmetic itself;
    # the three axes are unrolled (same sums in the same order as a loop over axes).
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


def formation_error(p_i: np.ndarray, ph_i: np.ndarray, p_i0: np.ndarray) -> np.ndarray:
    """``e_i = p_i - ph_i - p_i0``: the formation task's error vector (eq. (ctbf)), m."""
    return p_i - ph_i - p_i0


def formation_velocity(
    e_i: np.ndarray,
    dph_i: np.ndarray,
    dp_i0: np.ndarray,
    g: BehaviourGains,
) -> np.ndarray:
    """The formation behaviour's velocity ``v_if``, paper eq. (v2), m/s.

    With ``J_if = e^T``, ``J_ihat = J_i0 = -e^T`` and ``rho_tilde = -rho``
    substituted (SPEC section 3), so that ``d rho/dt = -task_rate(rho)``.
    Guard: for ``|e| < EPS`` the pseudo-inverse is undefined and the robot
    just follows its reference, ``dph_i + dp_i0``.
    """
    return np.array(_formation_velocity_floats(e_i.tolist(), dph_i.tolist(), dp_i0.tolist(), g))


def _formation_velocity_floats(e: list[float], dph: list[float], dp0: list[float], g: BehaviourGains) -> list[float]:
    """:func:`formation_velocity` on Python floats (3-vectors: cheaper than numpy calls)."""
    ff = [dph[0] + dp0[0], dph[1] + dp0[1], dph[2] + dp0[2]]
    e2 = e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
    if e2 < EPS * EPS:
        return ff
    c = -task_rate(0.5 * e2, g) + (e[0] * ff[0] + e[1] * ff[1] + e[2] * ff[2])
    return [e[0] / e2 * c, e[1] / e2 * c, e[2] / e2 * c]  # eq. (v2)


def avoidance_task(u: np.ndarray, d: float) -> float:
    """``rt = d^2/2 - |u|^2/2``, the avoidance task error (eq. (2)); active iff positive."""
    return 0.5 * d * d - 0.5 * dot3(u, u)


def avoidance_velocity(u: np.ndarray, vo: np.ndarray, d: float, g: BehaviourGains) -> np.ndarray:
    """The avoidance behaviour's velocity ``v_io``, paper eq. (v1), m/s.

    u: ``p_i - po``, from the nearest object to the robot, shape (3,).
    vo: that object's velocity. Meant for the active case (``rt > 0``), where
    ``d rt/dt = -task_rate(rt)``. Guard: at ``|u| < EPS`` the direction is
    undefined; push along :data:`COINCIDENT_PUSH_DIRECTION` at the task rate.
    """
    rt = avoidance_task(u, d)
    u2 = dot3(u, u)
    if u2 < EPS * EPS:
        return COINCIDENT_PUSH_DIRECTION * task_rate(rt, g) / d
    return u / u2 * (task_rate(rt, g) + dot3(u, vo))  # eq. (v1)


def merged_velocity(v_io: np.ndarray | None, u: np.ndarray, v_if: np.ndarray) -> np.ndarray:
    """Null-space merge, paper eq. (v): ``v_io + (I - u u^T/|u|^2) v_if``.

    ``v_io is None`` means the avoidance task is inactive: the formation
    velocity passes unchanged.
    """
    if v_io is None:
        return v_if
    u2 = dot3(u, u)
    if u2 < EPS * EPS:
        u = COINCIDENT_PUSH_DIRECTION
        u2 = 1.0
    return v_io + v_if - u * (dot3(u, v_if) / u2)  # eq. (v)


def null_space_projector(u: np.ndarray) -> np.ndarray:
    """``I - u u^T / |u|^2``, shape (3, 3): the projector eq. (v) applies to ``v_if``."""
    u2 = dot3(u, u)
    if u2 < EPS * EPS:
        u, u2 = COINCIDENT_PUSH_DIRECTION, 1.0
    return np.eye(3) - np.outer(u, u) / u2


def limit_speed(v: np.ndarray, v_max: float | None) -> tuple[np.ndarray, bool]:
    """Clip ``|v|`` to ``v_max`` (not in the paper; off when ``v_max`` is None).

    Returns the velocity and whether the limit bit.
    """
    if v_max is None:
        return v, False
    speed = math.sqrt(dot3(v, v))
    if speed <= v_max:
        return v, False
    return v * (v_max / speed), True


@dataclass(frozen=True)
class ControlOutput:
    """One robot's control step: the command and what it is made of."""

    v: np.ndarray  # merged (and possibly limited) velocity command, m/s
    dph: np.ndarray  # estimator rate, m/s
    e: np.ndarray  # formation error against the robot's own estimate, m
    avoid_active: bool
    speed_limited: bool


def robot_control(
    p_i: np.ndarray,
    ph_i: np.ndarray,
    neighbours: np.ndarray,
    weights: np.ndarray,
    p_i0: np.ndarray,
    dp_i0: np.ndarray,
    po: np.ndarray | None,
    vo: np.ndarray | None,
    d: float,
    formation: BehaviourGains,
    avoidance: BehaviourGains,
    estimator: EstimatorGains,
    v_max: float | None = None,
    dph: np.ndarray | None = None,
    semi_implicit_dt: float | None = None,
) -> ControlOutput:
    """One robot's whole law from local data only: eqs. (11), (v2), (v1), (v).

    ``po``/``vo`` are the nearest object's position and velocity (None when
    the robot senses nothing). The avoidance task is switched on only inside
    the repulsive zone of radius ``d`` (SPEC section 4).
    ``semi_implicit_dt`` (the control period, s; scenario ``discretisation =
    "semi-implicit"``): the estimator and the formation behaviour take the
    semi-implicit step (:func:`estimator_step_semi_implicit`,
    :func:`formation_velocity_semi_implicit`) and ``dph`` is the step's mean rate
    ``(ph_next - ph_i)/dt``, so that ``ph_i + dt*dph`` is the implicit solution.
    None (the default): explicit Euler, SPEC section 7.
    """
    if semi_implicit_dt is None:
        v, dph_l, e, active, limited = robot_control_floats(
            p_i.tolist(), ph_i.tolist(), neighbours.tolist(), weights.tolist(), p_i0.tolist(), dp_i0.tolist(),
            None if po is None else po.tolist(), None if vo is None else vo.tolist(), d,
            formation, avoidance, estimator, v_max, None if dph is None else dph.tolist())
        return ControlOutput(v=np.array(v), dph=np.array(dph_l) if dph is None else dph, e=np.array(e),
                             avoid_active=active, speed_limited=limited)
    if dph is None:  # given: the estimate's rate when it is extrapolated (nobody heard)
        if semi_implicit_dt is None:
            dph = estimator_rate(ph_i, neighbours, weights, estimator)
        else:
            ph_next = estimator_step_semi_implicit(ph_i, neighbours, weights, estimator, semi_implicit_dt)
            dph = (ph_next - ph_i) / semi_implicit_dt
    e = formation_error(p_i, ph_i, p_i0)
    if semi_implicit_dt is None:
        v_if = formation_velocity(e, dph, dp_i0, formation)
    else:
        v_if = formation_velocity_semi_implicit(e, dph, dp_i0, formation, semi_implicit_dt)
    active = False
    if po is not None:
        u = p_i - po
        if avoidance_task(u, d) > 0.0:
            active = True
            v_io = avoidance_velocity(u, vo if vo is not None else np.zeros(3), d, avoidance)
            v_if = merged_velocity(v_io, u, v_if)
    v, limited = limit_speed(v_if, v_max)
    return ControlOutput(v=v, dph=dph, e=e, avoid_active=active, speed_limited=limited)


def robot_control_floats(
    p: list[float],
    ph: list[float],
    rows: list[list[float]],
    ws: list[float],
    p0: list[float],
    dp0: list[float],
    po: list[float] | None,
    vo: list[float] | None,
    d: float,
    formation: BehaviourGains,
    avoidance: BehaviourGains,
    estimator: EstimatorGains,
    v_max: float | None = None,
    dph: list[float] | None = None,
) -> tuple[list[float], list[float], list[float], bool, bool]:
    """:func:`robot_control` with explicit Euler (SPEC section 7) on Python lists: eqs. (11), (v2), (v1), (v).

    3-vectors are ``[x, y, z]`` lists (m, m/s); ``rows`` the (m, 3) estimates held, ``ws`` their
    weights (m,). Returns ``(v, dph, e, avoid_active, speed_limited)``, vectors as lists.
    """
    # Python floats on 3-vectors: each numpy call costs ~1 us, more than the arithmetic itself
    # (the agent's per-tick hot path, issue 2); the rare avoidance case uses the numpy functions.
    if dph is None:
        dph = _estimator_rate_floats(ph, rows, ws, estimator) if ws else [0.0, 0.0, 0.0]
    e = [p[0] - ph[0] - p0[0], p[1] - ph[1] - p0[1], p[2] - ph[2] - p0[2]]  # eq. (ctbf)
    v = _formation_velocity_floats(e, dph, dp0, formation)  # eq. (v2)
    active = False
    if po is not None:
        u = [p[0] - po[0], p[1] - po[1], p[2] - po[2]]
        if 0.5 * d * d - 0.5 * (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]) > 0.0:  # eq. (2): in the zone
            active = True
            u_arr = np.array(u)
            v_io = avoidance_velocity(u_arr, np.array(vo) if vo is not None else np.zeros(3), d, avoidance)
            v = merged_velocity(v_io, u_arr, np.array(v)).tolist()  # eqs. (v1), (v)
    limited = False
    if v_max is not None:
        speed = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        if speed > v_max:  # as limit_speed
            v, limited = [x * (v_max / speed) for x in v], True
    return v, dph, e, active, limited


# --- semi-implicit discretisation (scenario [controller] discretisation = "semi-implicit") ----------
#
# Explicit Euler on eq. (11) makes the sign term chatter: every tick it moves the estimate by
# K3*dt past the consensus of its neighbours and back. The semi-implicit step solves, per robot and
# per axis with the neighbours' values held at this tick, the implicit Euler equation of eq. (11);
# its sign term is set-valued at consensus, so the step lands exactly on consensus whenever that is
# within one step of it. The formation behaviour's step is chosen likewise so that the next task
# value rho is the implicit Euler solution of d rho/dt = -task_rate(rho) (SPEC section 3).


def _estimator_power_sum(x: float, ys: list[float], ws: list[float], gains: EstimatorGains) -> tuple[float, float]:
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
    ph_i: np.ndarray,
    neighbours: np.ndarray,
    weights: np.ndarray,
    gains: EstimatorGains,
    dt: float,
) -> np.ndarray:
    """The next estimate ``ph_i(k+1)`` by a local semi-implicit step of eq. (11), m, shape (3,).

    With the neighbours' values ``y_j`` held (those of tick k), each axis solves the
    implicit Euler equation ``x = x_k + dt * dph(x)`` of eq. (11),
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
    if len(weights) == 0:
        return np.array(ph_i, dtype=float)
    ws = [float(w) for w in weights]
    total = sum(ws)
    out = np.empty(3)
    for c in range(3):
        xk = float(ph_i[c])
        ys = [float(y) for y in neighbours[:, c]]
        xs = sum(w * y for w, y in zip(ws, ys)) / total

        def g(x: float, xk=xk, ys=ys) -> tuple[float, float]:
            p, dp = _estimator_power_sum(x, ys, ws, gains)
            return x - xk + dt * p, 1.0 + dt * dp

        g_star = g(xs)[0]
        jump = dt * gains.K3
        if abs(g_star) <= jump:
            out[c] = xs
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
        out[c] = _solve_increasing(g, target, lo, hi, start)
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


def formation_velocity_semi_implicit(
    e_i: np.ndarray,
    dph_i: np.ndarray,
    dp_i0: np.ndarray,
    g: BehaviourGains,
    dt: float,
) -> np.ndarray:
    """The formation behaviour's velocity for a semi-implicit step of length ``dt``, m/s.

    Chooses ``v`` so that after the world's step ``p += dt v`` (with the estimate moving
    ``dt dph_i`` and the offset ``dt dp_i0``) the error is ``e_i * sqrt(rho_next/rho)``:
    same direction, and ``rho_next`` the implicit Euler solution of
    ``d rho/dt = -task_rate(rho)`` (:func:`implicit_task_value`):
    ``v = (sqrt(rho_next/rho) - 1) e_i / dt + dph_i + dp_i0``.
    As ``dt -> 0`` this is eq. (v2) plus ``(I - e e^T/|e|^2)(dph_i + dp_i0)``, the
    reference's motion across ``e``: a null-space term of ``J_if = e^T`` that leaves
    ``d rho/dt`` unchanged in continuous time, but without which a discrete step
    lets the error grow by ``dt |feedforward across e|`` every tick.
    Guard: for ``|e| < EPS`` the robot just follows its reference, as in eq. (v2).
    """
    feedforward = dph_i + dp_i0
    e2 = dot3(e_i, e_i)
    if e2 < EPS * EPS:
        return feedforward
    rho = 0.5 * e2
    shrink = math.sqrt(implicit_task_value(rho, g, dt) / rho)
    return (shrink - 1.0) / dt * e_i + feedforward
