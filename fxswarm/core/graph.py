"""The communication graph: named topologies, its weights held sparsely, H = L + diag(b), its check."""

from __future__ import annotations

from dataclasses import dataclass

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


@dataclass(frozen=True, eq=False)
class SparseGraph:
    """Weights ``a_ij`` (n, n) held by rows (CSR): robot ``i``'s neighbours (0-based, ascending)
    are ``indices[indptr[i]:indptr[i + 1]]``, their weights (all > 0) the same run of
    ``weights``. A 10 000-robot swarm's dense matrix is 763 MB; this is its links only. Plain
    numpy, not scipy.sparse: scipy is the optional ``scale`` extra, and every scenario needs this."""

    indptr: np.ndarray  # (n + 1,) int
    indices: np.ndarray  # (links,) int, ascending within a row
    weights: np.ndarray  # (links,) float, > 0

    @property
    def n(self) -> int:
        return len(self.indptr) - 1

    @classmethod
    def from_entries(cls, n: int, rows: np.ndarray, cols: np.ndarray, weights: np.ndarray) -> "SparseGraph":
        """From 0-based entries ``(rows[k], cols[k]) = weights[k]``, no pair twice; those <= 0 dropped."""
        rows, cols, weights = (np.asarray(x) for x in (rows, cols, weights))
        keep = weights > 0
        rows, cols, weights = rows[keep].astype(np.intp), cols[keep].astype(np.intp), weights[keep].astype(float)
        order = np.lexsort((cols, rows))
        return cls(_indptr(rows, n), cols[order], weights[order])

    @classmethod
    def from_dense(cls, a: np.ndarray) -> "SparseGraph":
        a = np.asarray(a, dtype=float)
        rows, cols = np.nonzero(a > 0)
        return cls.from_entries(len(a), rows, cols, a[rows, cols])

    def row(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Robot ``i``'s (0-based) neighbours, ascending, and their weights."""
        lo, hi = self.indptr[i], self.indptr[i + 1]
        return self.indices[lo:hi], self.weights[lo:hi]

    def entry_rows(self) -> np.ndarray:
        """The row of every stored entry, (links,)."""
        return np.repeat(np.arange(self.n, dtype=np.intp), np.diff(self.indptr))

    def where(self, keep: np.ndarray) -> "SparseGraph":
        """Only the entries where ``keep`` (links,) holds."""
        return SparseGraph(_indptr(self.entry_rows()[keep], self.n), self.indices[keep], self.weights[keep])

    def dense(self) -> np.ndarray:
        """The (n, n) matrix: for small graphs only (analysis; 763 MB at 10 000 robots)."""
        a = np.zeros((self.n, self.n))
        a[self.entry_rows(), self.indices] = self.weights
        return a


def _indptr(rows: np.ndarray, n: int) -> np.ndarray:
    """Where each of the ``n`` rows starts among entries sorted by row (``rows``: their rows)."""
    indptr = np.zeros(n + 1, dtype=np.intp)
    np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
    return indptr


def graph_of(a) -> SparseGraph:
    """``a`` as a :class:`SparseGraph` (a dense (n, n) matrix converted)."""
    return a if isinstance(a, SparseGraph) else SparseGraph.from_dense(a)


def adjacency(n: int, edges: list[tuple[int, int]], weights: list[float] | None = None) -> SparseGraph:
    """Symmetric weights ``a_ij`` from 1-based undirected edges (an edge given twice: its last
    weight; weight 0: no link)."""
    e = np.asarray(edges, dtype=np.intp).reshape(-1, 2) - 1
    w = np.ones(len(e)) if weights is None else np.asarray(weights, dtype=float)
    key = np.minimum(e[:, 0], e[:, 1]) * n + np.maximum(e[:, 0], e[:, 1])
    _, last = np.unique(key[::-1], return_index=True)  # the last time each pair is given
    last = len(key) - 1 - last
    i, j, w = e[last, 0], e[last, 1], w[last]
    return SparseGraph.from_entries(n, np.concatenate([i, j]), np.concatenate([j, i]), np.concatenate([w, w]))


def h_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``H = L + diag(b)`` (n, n), where ``L`` is the Laplacian of ``a`` (dense)."""
    return np.diag(a.sum(axis=1)) - a + np.diag(b)


def unreached_robots(a: SparseGraph | np.ndarray, b: np.ndarray) -> list[int]:
    """Robots (1-based) with no path to a robot that hears the leader.

    ``H`` is positive definite iff this is empty (for a ``b >= 0``, ``a >= 0``).
    """
    g, n = graph_of(a), len(b)
    reached = {i for i in range(n) if b[i] > 0}
    frontier = list(reached)
    while frontier:
        i = frontier.pop()
        for j in g.row(i)[0]:
            if int(j) not in reached:
                reached.add(int(j))
                frontier.append(int(j))
    return [i + 1 for i in range(n) if i not in reached]


def hops_to_leader(a: SparseGraph | np.ndarray, b: np.ndarray) -> np.ndarray:
    """Graph distance (hops) from each robot to its nearest pinned robot, shape (n,).

    Unreached robots get ``-1``.
    """
    g, n = graph_of(a), len(b)
    dist = np.full(n, -1, dtype=int)
    frontier = [i for i in range(n) if b[i] > 0]
    for i in frontier:
        dist[i] = 0
    while frontier:
        nxt = []
        for i in frontier:
            for j in g.row(i)[0]:
                if dist[j] < 0:
                    dist[j] = dist[i] + 1
                    nxt.append(int(j))
        frontier = nxt
    return dist
