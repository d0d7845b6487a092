"""The scenario's weights held by rows (fxswarm.core.graph.SparseGraph): the same matrix, the
same neighbours in the same order, as the dense form, and what reads them without it."""

import math
import sys

import numpy as np
import pytest

from fxswarm.core.bounds import DENSE_EIGEN_LIMIT, DENSE_EIGEN_MAX, estimator_bound_printed, h_of
from fxswarm.core.graph import SparseGraph, adjacency, h_matrix, hops_to_leader, unreached_robots
from fxswarm.core.observer import observer_links, observer_weights
from fxswarm.core.resilience import leader_reach


def dense_adjacency(n, edges, weights=None):
    """The dense construction the rows must equal: each edge sets both entries, the last one wins."""
    a = np.zeros((n, n))
    for k, (i, j) in enumerate(edges):
        a[i - 1, j - 1] = a[j - 1, i - 1] = 1.0 if weights is None else weights[k]
    return a


def random_graph(n, seed, p=0.2):
    rng = np.random.default_rng(seed)
    edges = [(i, j) for i in range(1, n + 1) for j in range(1, n + 1) if i != j and rng.random() < p]
    return edges, rng.choice([0.0, 0.5, 0.7, 1.0, 2.25], size=len(edges)).tolist()


@pytest.mark.parametrize("seed", range(6))
def test_rows_equal_the_dense_matrix_with_repeated_edges_and_zero_weights(seed):
    edges, weights = random_graph(15, seed)  # (i, j) and (j, i) both given, some weights 0
    g, a = adjacency(15, edges, weights), dense_adjacency(15, edges, weights)
    assert g.dense().tobytes() == a.tobytes()
    for i in range(15):
        ids, ws = g.row(i)
        assert ids.tolist() == np.flatnonzero(a[i] > 0).tolist()  # ascending, as the laws sum them
        assert ws.tolist() == a[i, ids].tolist()
    b = np.zeros(15)
    b[[0, 7]] = 1.0
    assert unreached_robots(g, b) == unreached_robots(a, b)
    assert hops_to_leader(g, b).tolist() == hops_to_leader(a, b).tolist()
    for r in (1, 2, 3):
        assert leader_reach(g, b, r) == leader_reach(a, b, r)
    for graph in ("oriented", "undirected"):
        assert observer_weights(g, b, graph).tobytes() == observer_weights(a, b, graph).tobytes()
        assert observer_links(g, b, graph).dense().tobytes() == observer_weights(a, b, graph).tobytes()


def test_no_edges_no_links():
    g = adjacency(3, [])
    assert g.n == 3 and g.dense().tolist() == np.zeros((3, 3)).tolist() and g.row(1)[0].tolist() == []


def ring(n):
    return adjacency(n, [(i, i % n + 1) for i in range(1, n + 1)], [0.5 + (i % 3) for i in range(n)])


def test_h_of_the_rows_is_the_dense_h_below_and_above_the_dense_eigen_size():
    pytest.importorskip("scipy")
    for n in (DENSE_EIGEN_MAX, DENSE_EIGEN_MAX + 7):
        g = ring(n)
        b = np.zeros(n)
        b[::50] = 1.0
        H = h_of(g, b)
        got = H.toarray() if hasattr(H, "toarray") else H
        assert got.tobytes() == h_matrix(g.dense(), b).tobytes()


def test_without_scipy_a_large_swarm_gets_no_estimator_bound_and_no_dense_matrix(monkeypatch):
    monkeypatch.setitem(sys.modules, "scipy.sparse", None)  # import fails as without the scale extra
    monkeypatch.setattr(SparseGraph, "dense", lambda self: pytest.fail("an n x n matrix was built"))
    n = DENSE_EIGEN_LIMIT + 1
    b = np.zeros(n)
    b[0] = 1.0
    from fxswarm.core.control import EstimatorGains

    g = EstimatorGains(K1=0.4, K2=0.6, K3=1.0, r3=6.0, r4=5.0, r5=3.0, r6=5.0)
    H = h_of(ring(n), b)
    assert H is None and math.isnan(estimator_bound_printed(H, g))
