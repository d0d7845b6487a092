"""The paper's law family, registered like any user's law (pyproject.toml ``fxswarm.laws``):
the fixed-time estimator, eq. (11), and the behaviours merged in null space, eqs. (v1), (v2),
(v) (fxswarm.core.control holds the equations), with its exponent families and the
leader-velocity feedforward.

This is the one definition of the law the robots fly: the agent node, the in-process
simulator and every process call :class:`BehaviouralLaw` through the law API
(fxswarm.core.laws), and :func:`robot_control`, which the oracle and fidelity tests check,
runs that same class on one view with the same speed limit the node applies
(:func:`fxswarm.core.laws.limit_speed`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from fxswarm.core.control import (
    COINCIDENT_PUSH_DIRECTION, EPS, formation_velocity_semi_implicit, powers, ControlOutput, ControlParameters, Vec, behaviour_velocity, estimator_rate_step, in_repulsive_zone,
)
from fxswarm.core.laws import BatchUnsupported, LawError, LawView, limit_speed

#: The law families of the paper's law: the same equations, exponents chosen for fixed-time
#: (the paper), asymptotic or finite-time convergence (fxswarm.core.scenario VARIANTS).
FAMILIES = ("fixed-time", "asymptotic", "finite-time")
#: The suffix of a built-in name that runs the estimator with the leader-velocity feedforward
#: (``[estimator] tracking = "feedforward"``, docs/estimator.md).
FEEDFORWARD_SUFFIX = "+feedforward"
#: Every built-in law name: each family, alone and with feedforward tracking.
BUILTIN_LAWS = FAMILIES + tuple(f + FEEDFORWARD_SUFFIX for f in FAMILIES)
def split_builtin(name: str) -> tuple[str, str]:
    """``(family, tracking)`` of a built-in law name, e.g. ``("asymptotic", "feedforward")``."""
    if name.endswith(FEEDFORWARD_SUFFIX):
        return name[: -len(FEEDFORWARD_SUFFIX)], "feedforward"
    return name, "paper"


def builtin_name(family: str, tracking: str) -> str:
    """The built-in law name of a family and an estimator tracking (inverse of :func:`split_builtin`)."""
    return family + (FEEDFORWARD_SUFFIX if tracking == "feedforward" else "")


#: Effective large-error exponent of the finite-time family (``r1*r0`` and ``r3/r4``): close
#: enough to 1 that a sweep's largest scales settle in a few minutes of simulated time.
FINITE_TIME_TOP_EXPONENT = 0.9


def variant_gains(gains: dict, variant: str) -> dict:
    """The ``[gains]`` table of family ``variant``, derived from a fixed-time ``[gains]`` table.

    Only exponents change; ``lam_*``, ``b*`` and ``K*`` are the paper's, so that the
    families differ in the one property being compared.
    """
    if variant not in FAMILIES:
        raise ValueError(f"unknown controller variant {variant!r}; expected one of {', '.join(FAMILIES)}")
    g = dict(gains)
    if variant == "asymptotic":
        g.update(r0=1.0, r1=1.0, r2=1.0, r3=float(g["r4"]), r5=float(g["r6"]))
    elif variant == "finite-time":
        g.update(r1=FINITE_TIME_TOP_EXPONENT / float(g["r0"]), r3=FINITE_TIME_TOP_EXPONENT * float(g["r4"]))
    return g


def family_gains(gains: dict, family: str) -> dict:
    """``[gains]`` for ``law = "<family>"``: the paper's fixed-time exponents are turned into the
    family's (:func:`variant_gains`, as ``fxswarm sweep --variants`` does), so one scenario
    flies every family; gains already of another kind are left as given (and checked)."""
    keys = ("r0", "r1", "r2", "r3", "r4", "r5", "r6")
    values = [gains.get(k) for k in keys]
    if family == "fixed-time" or not all(type(x) in (int, float) and math.isfinite(x) and x > 0 for x in values):
        return gains
    r0, r1, r2, r3, r4, r5, r6 = (float(x) for x in values)
    if r1 * r0 > 1.0 and r2 * r0 < 1.0 and r3 / r4 > 1.0 and r5 / r6 < 1.0:
        return variant_gains(gains, family)
    return gains


class BehaviouralLaw:
    """The paper's law: the fixed-time estimator, eq. (11), and the behaviours merged in
    null space, eqs. (v1), (v2), (v) (fxswarm.core.control).

    Registered under every name of :data:`BUILTIN_LAWS`: the family only chooses the
    exponents of ``[gains]`` and the ``+feedforward`` suffix the estimator's tracking, both
    read by the scenario (fxswarm.core.scenario), so the law reads its gains, ``d``,
    ``[controller] discretisation`` and ``[estimator] tracking`` from the scenario it is given.
    """

    vectors = "floats"

    def __init__(self, params: dict, robot_id: int, scenario) -> None:
        if params:
            raise LawError(f"the built-in law takes no parameters (its gains are [gains]); got {sorted(params)}")
        if scenario is None:
            raise LawError("the built-in law needs its scenario")
        sc = scenario
        self._setup(ControlParameters(sc.formation, sc.avoidance, sc.estimator, sc.d,
                                      semi_implicit=sc.discretisation == "semi-implicit"),
                    sc.tracking == "feedforward")

    @classmethod
    def from_parameters(cls, gains: ControlParameters, feedforward: bool) -> "BehaviouralLaw":
        """The law on ``gains`` directly, without a scenario (:func:`robot_control`)."""
        law = cls.__new__(cls)
        law._setup(gains, feedforward)
        return law

    def _setup(self, gains: ControlParameters, feedforward: bool) -> None:
        self.gains = gains
        self.feedforward = feedforward
        self._explicit_feedforward = feedforward and not gains.semi_implicit

    def estimate_rate(self, view: LawView) -> list[float]:
        """``dph_i/dt``: eq. (11) (eq. (11ff) with feedforward; the semi-implicit step's mean rate)."""
        return estimator_rate_step(view.ph, view.rows, view.weights, self.gains, view.dt,
                                   view.vh if self.feedforward else None)

    def velocity(self, view: LawView, estimate_rate: Sequence[float]) -> list[float]:
        """``v_i``: eq. (v2) (eq. (v2ff): following ``vh`` under explicit Euler with feedforward,
        when the rate is eq. (11ff)'s, not an extrapolation's), merged with eq. (v1) by eq. (v)."""
        reference = view.vh if self._explicit_feedforward and view.weights else None
        nearest = view.nearest
        po, vo = (None, None) if nearest is None else nearest
        return behaviour_velocity(view.p, view.ph, estimate_rate, reference, view.offset, view.offset_rate,
                                  po, vo, self.gains, view.dt)[0]


def robot_control(
    p: Vec,
    ph: Vec,
    rows: Sequence[Vec],
    ws: Sequence[float],
    p0: Vec,
    dp0: Vec,
    po: Vec | None,
    vo: Vec | None,
    law: ControlParameters,
    dt: float,
    dph: Vec | None = None,
    feedforward: Vec | None = None,
) -> ControlOutput:
    """One robot's whole law from local data only, as the robots fly it: :class:`BehaviouralLaw`
    on one view, then the speed limit ``law.v_max`` (the node's, :func:`fxswarm.core.laws.limit_speed`).

    p: the robot's position, m. ph: its estimate of the leader, m.
    rows: the estimates it holds, shape (m, 3) (the leader's position as one more
    row when pinned and heard), with their weights ``ws`` (``a_ij``, ``b_i``), (m,).
    p0, dp0: its formation offset and the offset's rate (m, m/s).
    po, vo: the nearest object's position and velocity (None when it senses
    nothing); the avoidance task is on only inside the repulsive zone of radius
    ``law.d`` (SPEC section 4). dt: the step, s (used by the semi-implicit step).
    dph: given, the robot hears nobody and the node extrapolates its estimate at this rate
    (the law only steers: ``rows`` are not used); None: the law's eq. (11).
    feedforward: the observed leader velocity ``vh`` (m/s; ``[estimator] tracking =
    "feedforward"``, fxswarm.core.observer): eqs. (11ff) and, under explicit Euler, (v2ff)
    (docs/estimator.md).
    """
    flown = BehaviouralLaw.from_parameters(law, feedforward is not None)
    view = LawView(0, law.d)
    view.t, view.dt, view.p, view.ph, view.offset, view.offset_rate = 0.0, dt, p, ph, p0, dp0
    view.vh = feedforward
    view.nearest = None if po is None else (po, vo if vo is not None else (0.0, 0.0, 0.0))
    if dph is None:
        view.rows, view.weights = rows, ws
        dph = flown.estimate_rate(view)
    v, limited = limit_speed(flown.velocity(view, dph), law.v_max)
    e = [p[0] - ph[0] - p0[0], p[1] - ph[1] - p0[1], p[2] - ph[2] - p0[2]]  # eq. (ctbf)
    active = po is not None and in_repulsive_zone(p, po, law.d)
    return ControlOutput(v, list(dph), e, active, limited)


class BehaviouralBatch:
    """The batch form of :class:`BehaviouralLaw`: every robot's step at once, on arrays.

    The same law, operation for operation: each robot's sums run over its rows in the
    per-robot order (a loop over neighbour slots, vectorised across robots), every power is
    :func:`fxswarm.core.control.powers` (``np.float_power``: the C library's pow element by
    element, as ``**`` in the per-robot form), and the rest is elementwise +, -, *, /, sqrt,
    correctly rounded in both. So its
    trajectories equal the per-robot path's bit for bit (tests/unit/test_batch.py).

    With ``tracking = "feedforward"`` the leader-velocity observer, eq. (obs), and eqs. (11ff),
    (v2ff), as :class:`fxswarm.agents.node.AgentNode` runs them. Under ``discretisation =
    "semi-implicit"`` the implicit solves run robot by robot through the per-robot functions.

    ``slots``: (n, S) int, robot i's s-th row: an index into ``[ph of the n robots; p0]``;
    ``weights``: (n, S) its ``a_ij`` / ``b_i``; ``valid``: (n, S) bool, whether the slot holds a row.
    """

    def __init__(self, scenario, slots: np.ndarray, weights: np.ndarray, valid: np.ndarray) -> None:
        sc = scenario
        self.formation, self.avoidance, self.estimator, self.d = sc.formation, sc.avoidance, sc.estimator, sc.d
        # The semi-implicit step (bracketed Newton per robot and axis) is solved robot by robot by
        # the per-robot form's own functions, on the same numbers: exact by construction.
        self.semi_implicit = sc.discretisation == "semi-implicit"
        self._gains = ControlParameters(sc.formation, sc.avoidance, sc.estimator, sc.d, semi_implicit=True)
        self.feedforward = sc.tracking == "feedforward"
        if self.feedforward:  # eq. (obs)'s links: the upstream neighbours (oriented) or all, then the leader
            from fxswarm.core.observer import observer_links

            obs = observer_links(sc.graph, sc.b, sc.observer_graph)
            n = len(slots)
            o_slots, o_weights, o_valid = np.full(slots.shape, n), np.zeros(slots.shape), np.zeros(slots.shape, bool)
            for i in range(n):  # the upstream (or all) neighbours, ascending, then the leader
                ids, ws = (x.tolist() for x in obs.row(i))
                if sc.b[i] > 0:
                    ids.append(n)
                    ws.append(float(sc.b[i]))
                o_slots[i, :len(ids)], o_weights[i, :len(ws)], o_valid[i, :len(ids)] = ids, ws, True
            self.observer, self._observer = sc.observer, (o_slots, o_weights, o_valid)
        self.slots, self.weights, self.valid = slots, weights, valid
        self.pairwise = sc.estimator.power != "aggregate"
        # Pairwise powers once per link: robot i's |ph_i - ph_j| is robot j's |ph_j - ph_i|, the
        # same float (IEEE subtraction is antisymmetric), so its powers are the same too. Table of
        # |differences|: the undirected links (i < j), then each pinned robot's to the leader.
        n = len(slots)
        i_idx, s_idx = np.nonzero(valid)
        j_idx = slots[i_idx, s_idx]
        robot = j_idx < n
        lo, hi = np.minimum(i_idx, j_idx)[robot], np.maximum(i_idx, j_idx)[robot]
        links, inverse = np.unique(lo * n + hi, return_inverse=True)
        self._link_i, self._link_j = links // n, links % n
        self._pinned = i_idx[~robot]
        # Slot-major (S, n, 3) tables, full size (numpy's loops are slow on a broadcast axis of 3).
        # An empty slot reads the robot's own estimate with weight 0 and a zero power (the power
        # table's last row): its terms are +-0, which leave a sum as it was (a sum started at +0 is
        # never -0), as the per-robot form's absent row.
        own = np.broadcast_to(np.arange(n)[:, None], slots.shape)
        self._src_t = np.ascontiguousarray(np.where(valid, slots, own).T)
        self._w_t = np.ascontiguousarray(np.repeat(np.where(valid, weights, 0.0).T[:, :, None], 3, axis=2))
        table = np.full(slots.shape, len(links) + len(self._pinned), dtype=np.intp)
        table[i_idx[robot], s_idx[robot]] = inverse
        table[i_idx[~robot], s_idx[~robot]] = len(links) + np.arange(len(self._pinned))
        self._table_t = np.ascontiguousarray(table.T)
        # the two ends of each row of the power table: links, then pinned robots and the leader (n)
        self._ends = (np.concatenate([self._link_i, self._pinned]),
                      np.concatenate([self._link_j, np.full(len(self._pinned), n)]))

    def estimate_rates(self, ph: np.ndarray, p0: np.ndarray, dt: float = 0.0,
                       vh: np.ndarray | None = None) -> np.ndarray:
        """``dph/dt`` of every robot, (n, 3): eq. (11), as :func:`fxswarm.core.control.estimator_rate`
        (eq. (11ff) with the observed leader velocities ``vh``: added after, as there); under the
        semi-implicit step, :func:`fxswarm.core.control.estimator_rate_step` robot by robot."""
        if self.semi_implicit:
            src = np.concatenate([ph, p0.reshape(1, 3)]).tolist()
            phs, vhs = ph.tolist(), (None if vh is None else vh.tolist())
            out = []
            for i, (slots, weights, valid) in enumerate(zip(self.slots.tolist(), self.weights.tolist(),
                                                            self.valid.tolist())):
                rows = [src[j] for j, ok in zip(slots, valid) if ok]
                ws = [w for w, ok in zip(weights, valid) if ok]
                out.append(estimator_rate_step(phs[i], rows, ws, self._gains, dt, None if vhs is None else vhs[i]))
            return np.array(out, dtype=float).reshape(-1, 3)
        rates = self._explicit_rates(ph, p0)
        return rates if vh is None else rates + vh  # eq. (11ff)

    #: Robots summed at a time: a block's (S, block, 3) tables stay in a core's cache.
    BLOCK = 1024

    def _explicit_rates(self, ph: np.ndarray, p0: np.ndarray) -> np.ndarray:
        g = self.estimator
        a1, a2 = g.r3 / g.r4, g.r5 / g.r6
        src = np.concatenate([ph, p0.reshape(1, 3)])
        pw = None
        if self.pairwise:  # |d| ** a of every link and leader row, each computed once
            ad = np.abs(np.take(src, self._ends[0], axis=0) - np.take(src, self._ends[1], axis=0))
            pw = _power_table(ad, a1, a2)
        n = len(ph)
        total = np.zeros((3 if self.pairwise else 1, n, 3))
        for lo in range(0, n, self.BLOCK):
            self._slot_sums(total[:, lo:lo + self.BLOCK], ph, src, pw, slice(lo, lo + self.BLOCK))
        E = total[0]
        if self.pairwise:
            P, Q = total[1], total[2]
        else:
            P, Q = np.zeros_like(E), np.zeros_like(E)
            nz = E != 0.0
            e = E[nz]
            ad = np.abs(e)
            P[nz] = np.copysign(powers(ad, a1), e)
            Q[nz] = np.copysign(powers(ad, a2), e)
        sign = np.where(E > 0.0, g.K3, np.where(E < 0.0, -g.K3, 0.0))
        return -g.K1 * P - g.K2 * Q - sign

    def _slot_sums(self, total: np.ndarray, ph: np.ndarray, src: np.ndarray, pw: np.ndarray | None,
                   robots: slice) -> None:
        """Adds to ``total`` (zeros: (1 or 3, b, 3)) the sums of the robots ``robots`` over their
        slots: the weighted differences and, pairwise, ``w * sig(d, a)`` for both exponents
        (``pw``: :func:`_power_table`), in the per-robot order: a loop over the slots (np.sum
        would sum pairwise)."""
        W = self._w_t[:, robots]
        D = ph[robots] - np.take(src, self._src_t[:, robots], axis=0)  # (S, b, 3): d to each slot's row
        terms = np.empty((len(total),) + D.shape)
        np.multiply(W, D, out=terms[0])
        if pw is not None:
            np.take(pw, self._table_t[:, robots], axis=1, out=terms[1:])
            # copysign(w * |d| ** a, d) as copysign(w, d) * |d| ** a: the same magnitude and sign.
            # The per-robot form skips d == 0; here its term is +-0, which leaves the sum as it was.
            np.multiply(terms[1:], np.copysign(W, D), out=terms[1:])
        for s in range(len(D)):
            total += terms[:, s]

    def observer_rates(self, vh: np.ndarray, v0: np.ndarray) -> np.ndarray:
        """``dvh/dt`` of every robot, (n, 3): eq. (obs), as
        :func:`fxswarm.core.observer.velocity_observer_rate` (``tracking = "feedforward"``)."""
        g = self.observer
        a1, a2 = g.r3 / g.r4, g.r5 / g.r6
        pairwise = g.power != "aggregate"
        slots, weights, valid = self._observer
        src = np.concatenate([vh, v0.reshape(1, 3)])
        n = len(vh)
        P, Q, E = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
        for s in range(slots.shape[1]):
            rows = np.flatnonzero(valid[:, s])
            if not len(rows):
                continue
            D = vh[rows] - src[slots[rows, s]]
            W = weights[rows, s, None]
            E[rows] = E[rows] + W * D
            if pairwise:
                nz = D != 0.0
                r, ax = np.nonzero(nz)
                ad = np.abs(D[r, ax])
                w = W[r, 0]
                at = (rows[r], ax)
                P[at] = P[at] + np.copysign(w * powers(ad, a1), D[r, ax])
                Q[at] = Q[at] + np.copysign(w * powers(ad, a2), D[r, ax])
        if not pairwise:
            nz = E != 0.0
            e = E[nz]
            P[nz] = np.copysign(powers(np.abs(e), a1), e)
            Q[nz] = np.copysign(powers(np.abs(e), a2), e)
        sign = np.where(E > 0.0, 1.0, np.where(E < 0.0, -1.0, 0.0))
        return -g.K1 * P - g.K2 * Q - g.K3 * sign  # eq. (obs)

    @staticmethod
    def task_rates(x: np.ndarray, g) -> np.ndarray:
        """:func:`fxswarm.core.control.task_rate` of each element of ``x``."""
        pos = x > 0.0
        if pos.all():
            return g.lam * powers(g.b1 * powers(x, g.r1) + g.b2 * powers(x, g.r2), g.r0)
        out = np.zeros(len(x))
        xp = x[pos]
        out[pos] = g.lam * powers(g.b1 * powers(xp, g.r1) + g.b2 * powers(xp, g.r2), g.r0)
        return out

    def velocities(self, p, ph, dph, offset, offset_rate, po, vo, sensed,
                   reference: np.ndarray | None = None, dt: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """``(v, avoid_active)``: eq. (v2) (following ``reference``, the observed leader velocity,
        instead of ``dph`` when given: eq. (v2ff)) merged with eq. (v1) by eq. (v) inside the
        repulsive zone, as :func:`fxswarm.core.control.behaviour_velocity` (no speed limit).
        ``sensed``: (n,) whether the robot senses an object (``po``, ``vo`` rows are ignored where not)."""
        e = p - ph - offset  # eq. (ctbf)
        ff = (dph if reference is None else reference) + offset_rate
        e2 = _dot(e, e)
        big = ~(e2 < EPS * EPS)
        if self.semi_implicit:  # robot by robot, as behaviour_velocity (the estimate's own rate, no reference)
            g = self.formation
            v = np.array([formation_velocity_semi_implicit(ei, di, ri, g, dt) for ei, di, ri in
                          zip(e.tolist(), dph.tolist(), offset_rate.tolist())], dtype=float).reshape(-1, 3)
        elif big.all():  # the usual case: no robot exactly on its slot
            c = -self.task_rates(0.5 * e2, self.formation) + _dot(e, ff)
            v = e / e2[:, None] * c[:, None]  # eq. (v2)
        else:
            v = ff.copy()
            eb, e2b, ffb = e[big], e2[big], ff[big]
            c = -self.task_rates(0.5 * e2b, self.formation) + _dot(eb, ffb)
            v[big] = eb / e2b[:, None] * c[:, None]  # eq. (v2)
        d = self.d
        u = p - po
        uu = _dot(u, u)
        active = sensed & (0.5 * d * d - 0.5 * uu > 0.0)  # eq. (2), as in_repulsive_zone
        if active.any():
            ua, u2, voa, vf = u[active], uu[active], vo[active], v[active]
            rate = self.task_rates(0.5 * d * d - 0.5 * u2, self.avoidance)
            coincident = u2 < EPS * EPS
            with np.errstate(divide="ignore", invalid="ignore"):  # coincident rows: replaced below
                v_io = ua / u2[:, None] * (rate + _dot(ua, voa))[:, None]  # eq. (v1)
            push = np.array(COINCIDENT_PUSH_DIRECTION)
            if coincident.any():
                v_io[coincident] = push * rate[coincident, None] / d
                ua = ua.copy()
                ua[coincident] = push
                u2 = np.where(coincident, 1.0, u2)
            s = _dot(ua, vf) / u2
            v[active] = v_io + vf - ua * s[:, None]  # eq. (v)
        return v, active


def _power_table(ad: np.ndarray, a1: float, a2: float) -> np.ndarray:
    """(2, L + 1, 3): ``ad ** a1`` and ``ad ** a2`` (:func:`fxswarm.core.control.powers`), 0
    where ``ad`` is 0 (``pow(0, a)`` is 0 only for a > 0), and a last row of zeros: the power of
    an empty slot."""
    out = np.zeros((2, len(ad) + 1, 3))
    for k, a in enumerate((a1, a2)):
        out[k, :-1] = powers(ad, a)
        if not a > 0.0:
            out[k, :-1][ad == 0.0] = 0.0
    return out


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise ``a . b`` of (n, 3) arrays, summed left to right as :func:`fxswarm.core.control.dot3`."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


#: The law API's batch hook (fxswarm.core.laws): a law class's ``batch`` builds its batch form.
BehaviouralLaw.batch = BehaviouralBatch
