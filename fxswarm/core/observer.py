"""The leader-velocity observer of ``[estimator] tracking = "feedforward"`` (beyond the paper).

Each robot i keeps ``vh_i``, its estimate of the leader's velocity ``v0 = dp0/dt``, by the
same distributed fixed-time law as the paper's estimator, eq. (11), applied to velocities
(the leader plays j = 0 with weight ``b_i`` and ``vh_0 := v0``, which it publishes):

    xi1 = sum_j a_ij sig(vh_i - vh_j, r3/r4)
    xi2 = sum_j a_ij sig(vh_i - vh_j, r5/r6)
    xi3 = sum_j a_ij (vh_i - vh_j)
    dvh_i/dt = -L1 xi1 - L2 xi2 - L3 sign(xi3)                        eq. (obs)

on the graph *oriented toward the leader* (``[estimator] observer_graph = "oriented"``, the
default): robot i sums over the neighbours j strictly fewer hops from a pinned robot than
itself (and the leader if pinned), ``abar_ij = a_ij [hops_j < hops_i]``. On the undirected
graph (``"undirected"``) consensus spreads by diffusion, ~n^2 steps along a chain of n,
and the estimates miss the leader's motion all that while; oriented, the observer is a
cascade of single-robot fixed-time systems, one hop per level (docs/estimator.md).

and feeds it forward in the position estimator:

    dph_i/dt = (eq. (11)'s rate) + vh_i                                 eq. (11ff)

and, under explicit Euler, in the formation behaviour in place of ``dph_i/dt``: eq. (v2ff)
(fxswarm.core.paper_law.robot_control), since eq. (11)'s part of the rate is then only its
sign term's chatter.

Conditions (docs/estimator.md): ``L1, L2, L3 > 0``, the exponents of eq. (11)
(``r3/r4 > 1``, ``r5/r6 < 1``) and ``L3 >= sup_t max_axis |d2p0/dt2|``: the sign
term must dominate the leader's acceleration, as ``K3`` must dominate its velocity
in eq. (11). Then ``vh_i = v0`` for every robot after a fixed time, and from then
on eq. (11ff) is eq. (11) for a leader at rest: no velocity left for the consensus
terms to make up, hence no lag growing with the hops.

Pure functions on Python floats (3-vectors; numpy calls cost more than the
arithmetic on the agent's per-tick path). Velocities in m/s, accelerations m/s^2.
"""

from __future__ import annotations

import math

import numpy as np

from fxswarm.core import motion
from fxswarm.core.control import EstimatorGains
from fxswarm.core.graph import SparseGraph, graph_of, hops_to_leader

#: ``[estimator] tracking``: the paper's estimator as printed, or with the observed leader
#: velocity fed forward.
TRACKINGS = ("paper", "feedforward")
#: ``[estimator] observer_graph``: which links eq. (obs) sums over.
OBSERVER_GRAPHS = ("oriented", "undirected")

#: Default gains ``L1, L2, L3`` of eq. (obs) (``[estimator] observer_K1..3``), 1/s^..., m/s^2.
#: ``L3`` sits above the leader acceleration of every shipped scenario (the paper's helix:
#: 0.005 m/s^2) and stays small, since with explicit Euler the sign term makes ``vh`` chatter by
#: about ``L3*dt`` per tick and the chatter is fed forward. ``L1, L2`` are large because on a
#: long chain consensus spreads by diffusion (docs/estimator.md): the faster ``vh`` settles, the
#: less leader motion the estimates miss meanwhile. Their limit is explicit Euler's: the
#: linearised step ``dt * L1 * (r3/r4) * |dv|^(r3/r4 - 1) * (sum_j a_ij + b_i)`` must stay below
#: 2 (0.72 at ``|dv|`` = 1 m/s on the paper's ring), and ``L2``'s chatter amplitude
#: ``(dt * L2 * degree)^(1/(1 - r5/r6))`` small (9e-3 m/s there). Chosen on configs/line-16.toml.
DEFAULT_OBSERVER_GAINS = (20.0, 5.0, 0.05)


def velocity_observer_rate(
    vh: list[float],
    rows: list[list[float]],
    ws: list[float],
    gains: EstimatorGains,
) -> list[float]:
    """``dvh_i/dt`` of eq. (obs), m/s^2, as a list of 3.

    vh: this robot's estimate of the leader's velocity, m/s.
    rows: the velocity estimates it holds of its neighbours, then the leader's velocity
        if heard, shape (m, 3) as lists; ws: their weights ``a_ij`` / ``b_i``, shape (m,).
    gains: ``K1, K2, K3`` play ``L1, L2, L3``; exponents and ``power`` ("pairwise": the
        powers per difference, "aggregate": on the weighted sum) as in eq. (11).
    With no row at all the rate is zero: the estimate holds.
    """
    if not ws:
        return [0.0, 0.0, 0.0]
    a1, a2 = gains.r3 / gains.r4, gains.r5 / gains.r6
    pairwise = gains.power != "aggregate"
    copysign = math.copysign
    out = []
    for c in range(3):
        x = vh[c]
        s1 = s2 = s3 = 0.0  # per axis: xi1, xi2, xi3
        for w, row in zip(ws, rows):
            d = x - row[c]
            s3 += w * d
            if pairwise and d:
                ad = abs(d)
                s1 += copysign(w * ad**a1, d)
                s2 += copysign(w * ad**a2, d)
        if not pairwise and s3:
            ad = abs(s3)
            s1, s2 = copysign(ad**a1, s3), copysign(ad**a2, s3)
        sign = 1.0 if s3 > 0.0 else -1.0 if s3 < 0.0 else 0.0
        out.append(-gains.K1 * s1 - gains.K2 * s2 - gains.K3 * sign)  # eq. (obs)
    return out


def max_acceleration_inf(path: motion.Path) -> float:
    """``sup_t max_axis |d2p/dt2|`` of a leader path, m/s^2 (what ``L3`` must dominate).

    Infinite for waypoints with a corner: the velocity jumps there, so after each corner
    the observer re-converges within its fixed time instead of tracking throughout.
    """
    if isinstance(path, (motion.Static, motion.ConstantVelocity)):
        return 0.0
    if isinstance(path, (motion.Helix, motion.Circle)):
        return abs(path.radius) * path.rate * path.rate  # per horizontal axis, at its peak
    if isinstance(path, motion.Waypoints):
        times = path.times
        v = [tuple((path.points[k + 1][c] - path.points[k][c]) / (times[k + 1] - times[k]) for c in range(3))
             for k in range(len(times) - 1)]
        jumps = [v[0]] + [tuple(b[c] - a[c] for c in range(3)) for a, b in zip(v, v[1:])] + [v[-1]] if v else []
        return math.inf if any(any(x != 0.0 for x in j) for j in jumps) else 0.0
    raise TypeError(f"no acceleration bound for {type(path).__name__}")


def observer_links(a: SparseGraph | np.ndarray, b: np.ndarray, graph: str = "oriented") -> SparseGraph:
    """The weights ``abar_ij`` eq. (obs) sums over, by rows; the leader's stay ``b``.

    ``"oriented"``: ``a_ij`` where robot j is strictly fewer hops from a pinned robot than
    robot i (its *upstream* neighbours), else 0: a directed acyclic graph in which every
    unpinned robot has an upstream neighbour (the graph is connected to a pinned robot).
    ``"undirected"``: ``a`` itself.
    """
    g = graph_of(a)
    if graph == "undirected":
        return g
    if graph != "oriented":
        raise ValueError(f"unknown observer graph {graph!r}; expected one of {', '.join(OBSERVER_GRAPHS)}")
    hops = hops_to_leader(g, b)
    return g.where(hops[g.indices] < hops[g.entry_rows()])


def observer_weights(a: SparseGraph | np.ndarray, b: np.ndarray, graph: str = "oriented") -> np.ndarray:
    """:func:`observer_links` as a dense (n, n) matrix (small swarms: analysis)."""
    return observer_links(a, b, graph).dense()


def oriented_settling_bound(a: np.ndarray, b: np.ndarray, gains: EstimatorGains) -> float:
    """A fixed-time bound ``T_V`` on eq. (obs) over the oriented graph, s (docs/estimator.md).

    Level by level (hops from a pinned robot): once a robot's upstream neighbours hold
    ``v0`` exactly, its own error obeys, per axis, ``d|x|/dt <= -L1 w^c1 |x|^al - L2 w^c2 |x|^be``
    (``w`` = its upstream weight sum, ``al = r3/r4 > 1``, ``be = r5/r6 < 1``; ``c = 1`` for
    pairwise powers, ``c = al`` / ``be`` for aggregate; the sign term has taken the leader's
    acceleration), which settles within ``1/(L1 w^c1 (al-1)) + 1/(L2 w^c2 (1-be))`` whatever
    the error it starts from. Summed over the levels: the worst robot of each, added up.
    Infinite unless ``al > 1`` and ``be < 1``.
    """
    al, be = gains.r3 / gains.r4, gains.r5 / gains.r6
    if al <= 1.0 or be >= 1.0:
        return math.inf
    w = observer_weights(a, b, "oriented").sum(axis=1) + np.asarray(b, dtype=float)
    hops = hops_to_leader(a, b)
    aggregate = gains.power == "aggregate"
    total = 0.0
    for level in range(int(hops.max()) + 1):
        ws = w[hops == level]
        c1, c2 = (al, be) if aggregate else (1.0, 1.0)
        total += max(1.0 / (gains.K1 * x**c1 * (al - 1.0)) + 1.0 / (gains.K2 * x**c2 * (1.0 - be)) for x in ws)
    return total
