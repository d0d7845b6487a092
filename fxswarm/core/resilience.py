"""Resilient consensus: W-MSR trimming of a robot's neighbour values, and the graph conditions
it needs (docs/resilience.md).

W-MSR (LeBlanc, Zhang, Koutsoukos, Sundaram, "Resilient asymptotic consensus in robust
networks", IEEE JSAC 31(4), 2013): per axis, a robot sorts its neighbours' values; of those
above its own it discards the F largest (all of them if fewer than F), of those below the F
smallest (likewise), and runs its update on the rest. Here a discarded value is *replaced by the
robot's own value* on that axis: every law that sums functions of differences ``ph_i - ph_j``
per axis (eq. (11), pairwise or aggregate) then sums over the kept values alone, and the view
keeps one row per neighbour. The leader's row (a pinned robot's last row) is trusted: never
discarded, never counted among the values sorted.

Pure functions, no I/O.
"""

from __future__ import annotations

import numpy as np

from fxswarm.core.graph import SparseGraph, graph_of

#: [estimator] resilience choices: "none" (the paper's: every value used) or "w-msr".
RESILIENCE = ("none", "w-msr")
#: Up to this many robots the r-robustness of the graph is computed exactly (2^n subsets).
EXACT_ROBUSTNESS_MAX_N = 20


def wmsr_trim(own: list[float], rows: list[list[float]], tolerate: int, trusted: int = 0
              ) -> tuple[list[list[float]], int]:
    """``rows`` with W-MSR's discarded values replaced by ``own``'s, and how many were discarded.

    own: the robot's own value (3 floats); rows: its neighbours' values (3 floats each), then
    ``trusted`` rows (0 or 1: the leader's) that are kept as they are; tolerate: F >= 0.
    Per axis, of the untrusted values strictly above own, the ``min(F, count)`` largest are
    discarded, of those strictly below, the ``min(F, count)`` smallest; values equal to own are
    kept (they weigh nothing in a difference). Ties are broken by position: of equal values
    the later row (the higher neighbour id) is discarded first. Returns new lists; ``rows`` is
    not changed.
    """
    m = len(rows) - trusted
    if tolerate <= 0 or m <= 0:
        return rows, 0
    out = [r[:] for r in rows]
    discarded = 0
    for c in range(3):
        x = own[c]
        col = [r[c] for r in rows[:m]]
        if tolerate == 1:  # the common case, on builtins: the last index of the max / the min
            top = max(col)
            if top > x:
                out[m - 1 - col[::-1].index(top)][c] = x
                discarded += 1
            bottom = min(col)
            if bottom < x:
                out[m - 1 - col[::-1].index(bottom)][c] = x
                discarded += 1
            continue
        above = [(v, j) for j, v in enumerate(col) if v > x]
        below = [(v, -j) for j, v in enumerate(col) if v < x]
        if above:
            above.sort(reverse=True)  # largest first; of equal values the later row first
            for _, j in above[:tolerate]:
                out[j][c] = x
                discarded += 1
        if below:
            below.sort()  # smallest first; of equal values the later row first (key -j)
            for _, j in below[:tolerate]:
                out[-j][c] = x
                discarded += 1
    return out, discarded


# --- the graph conditions -----------------------------------------------------------------


def leader_reach(a: SparseGraph | np.ndarray, b: np.ndarray, r: int) -> list[int]:
    """Robots (1-based) *not* reached by the rule: a robot is reached if it is pinned
    (``b_i > 0``) or has at least ``r`` graph neighbours already reached. Empty means every
    nonempty set C of robots holds a robot that is pinned or has ``r`` neighbours outside C
    (the first robot of C the rule reaches is one): the condition of docs/resilience.md with
    ``r = 2F + 1``. Exact, polynomial, any size."""
    n, g = len(b), graph_of(a)
    rows = g.entry_rows()
    reached = np.asarray(b) > 0
    while True:
        counts = np.bincount(rows, weights=reached[g.indices], minlength=n)
        grow = ~reached & (counts >= r)
        if not grow.any():
            break
        reached = reached | grow
    return [i + 1 for i in range(n) if not reached[i]]


def reachability(a: np.ndarray) -> np.ndarray:
    """For every subset S of the robots (bit mask, ``2^n`` of them): the largest number of
    neighbours outside S that a robot in S has (0 for the empty set)."""
    adj = np.asarray(a) > 0
    n = len(adj)
    masks = np.arange(1 << n, dtype=np.int64)
    best = np.zeros(1 << n, dtype=np.int64)
    for i in range(n):
        nbr = np.flatnonzero(adj[i])
        outside = np.zeros(1 << n, dtype=np.int64)
        for j in nbr:
            outside += ((masks >> int(j)) & 1) == 0
        inside = ((masks >> i) & 1) == 1
        best = np.where(inside, np.maximum(best, outside), best)
    return best


def robustness(a: SparseGraph | np.ndarray) -> int | None:
    """The largest r such that the robots' graph is r-robust (LeBlanc et al. 2013, Def. 4: of
    any two disjoint nonempty sets of robots, one holds a robot with at least r neighbours
    outside its set); exact, by enumeration, for up to :data:`EXACT_ROBUSTNESS_MAX_N` robots,
    else None (unknown: the check is coNP-complete in general)."""
    g = graph_of(a)
    n = g.n
    if n > EXACT_ROBUSTNESS_MAX_N:
        return None
    if n < 2:
        return 0
    reach = reachability(g.dense())
    full = (1 << n) - 1
    best = 0
    for r in range(1, n):
        bad = np.zeros(1 << n, dtype=bool)  # sets none of whose robots has r outside neighbours
        bad[1:] = reach[1:] < r
        # below[T]: T holds a bad subset (sum over subsets, bit by bit)
        below = bad.copy()
        masks = np.arange(1 << n, dtype=np.int64)
        for i in range(n):
            has = ((masks >> i) & 1) == 1
            below[has] |= below[masks[has] ^ (1 << i)]
        complement = full ^ masks
        if (bad & below[complement]).any():  # two disjoint bad sets: not r-robust
            return best
        best = r
    return best


def check_graph(a: SparseGraph | np.ndarray, b: np.ndarray, tolerate: int) -> dict:
    """What docs/resilience.md's checker says about a graph (``a``, pins ``b``) for F = ``tolerate``.

    ``meets``: True if every robot is reached by :func:`leader_reach` with r = 2F + 1 (the
    sufficient condition; exact to decide), else False; ``unreached``: the robots it leaves;
    ``robustness``: the robots' graph's exact r-robustness (None past
    :data:`EXACT_ROBUSTNESS_MAX_N` robots), for reference (the leaderless W-MSR's condition:
    (2F+1)-robust for F-local liars)."""
    r = 2 * tolerate + 1
    unreached = leader_reach(a, b, r)
    return {"tolerate": tolerate, "r": r, "meets": not unreached, "unreached": unreached,
            "robustness": robustness(a)}
