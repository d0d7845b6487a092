"""The communication graph: named topologies, the matrix H = L + diag(b), its check."""

from __future__ import annotations

import numpy as np

TOPOLOGIES = ("ring", "line", "star", "complete")


def topology_edges(name: str, n: int) -> list[tuple[int, int]]:
    """Edges (1-based robot ids) of a named topology on ``n`` robots.

    ring: 1-2-...-n-1; line: 1-2-...-n; star: 1 linked to all; complete: all pairs.
    """
    if name == "ring":
        return [(i, i % n + 1) for i in range(1, n + 1)] if n > 2 else topology_edges("line", n)
    if name == "line":
        return [(i, i + 1) for i in range(1, n)]
    if name == "star":
        return [(1, j) for j in range(2, n + 1)]
    if name == "complete":
        return [(i, j) for i in range(1, n + 1) for j in range(i + 1, n + 1)]
    raise ValueError(f"unknown topology {name!r}; expected one of {', '.join(TOPOLOGIES)}")


def adjacency(n: int, edges: list[tuple[int, int]], weights: list[float] | None = None) -> np.ndarray:
    """Symmetric weight matrix ``a_ij`` (n, n) from 1-based undirected edges."""
    a = np.zeros((n, n))
    for k, (i, j) in enumerate(edges):
        w = 1.0 if weights is None else float(weights[k])
        a[i - 1, j - 1] = a[j - 1, i - 1] = w
    return a


def h_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``H = L + diag(b)`` (n, n), where ``L`` is the Laplacian of ``a``."""
    return np.diag(a.sum(axis=1)) - a + np.diag(b)


def unreached_robots(a: np.ndarray, b: np.ndarray) -> list[int]:
    """Robots (1-based) with no path to a robot that hears the leader.

    ``H`` is positive definite iff this is empty (for a ``b >= 0``, ``a >= 0``).
    """
    n = len(b)
    reached = {i for i in range(n) if b[i] > 0}
    frontier = list(reached)
    while frontier:
        i = frontier.pop()
        for j in np.flatnonzero(a[i] > 0):
            if int(j) not in reached:
                reached.add(int(j))
                frontier.append(int(j))
    return [i + 1 for i in range(n) if i not in reached]


def hops_to_leader(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Graph distance (hops) from each robot to its nearest pinned robot, shape (n,).

    Unreached robots get ``-1``.
    """
    n = len(b)
    dist = np.full(n, -1, dtype=int)
    frontier = [i for i in range(n) if b[i] > 0]
    for i in frontier:
        dist[i] = 0
    while frontier:
        nxt = []
        for i in frontier:
            for j in np.flatnonzero(a[i] > 0):
                if dist[j] < 0:
                    dist[j] = dist[i] + 1
                    nxt.append(int(j))
        frontier = nxt
    return dist
