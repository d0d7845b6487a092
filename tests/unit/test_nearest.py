"""The world's nearest object from a KD-tree (fxswarm.core.nearest) equals the n x (n + m)
matrix's (world/node.py), bit for bit, ties included."""

import numpy as np
import pytest

from fxswarm.core.nearest import nearest_objects_tree
from fxswarm.world import node as world_node


def dense(p, v, obstacles, obstacle_v, monkeypatch):
    monkeypatch.setattr(world_node, "DENSE_NEAREST_MAX", 10**9)
    return world_node.nearest_objects(p, v, obstacles, obstacle_v)


def lattice(n, spacing=2.0):
    side = int(np.ceil(np.sqrt(n)))
    return np.array([[i % side, i // side, 0.0] for i in range(n)]) * spacing


@pytest.mark.parametrize("case", ["random", "lattice", "lattice-obstacle-tie", "duplicates", "no-obstacles"])
def test_tree_gives_the_dense_answer_ties_included(case, monkeypatch):
    rng = np.random.default_rng(5)
    n, m = 700, 3
    p = lattice(n) if case.startswith("lattice") else rng.uniform(-30, 30, (n, 3))
    if case == "duplicates":  # robots on the same spot: distance 0 to each other
        p[10] = p[11] = p[12]
    if case == "no-obstacles":
        m = 0
    obstacles, obstacle_v = rng.uniform(-30, 30, (m, 3)), rng.normal(size=(m, 3))
    if case == "lattice-obstacle-tie":  # an obstacle exactly as near as the lattice neighbours
        obstacles[0] = p[40] + [0.0, 0.0, 2.0]
    v = rng.normal(size=(n, 3))
    want = dense(p, v, obstacles, obstacle_v, monkeypatch)
    got = nearest_objects_tree(p, v, obstacles, obstacle_v)
    for name, a, b in zip(("po", "vo", "dist", "is_obstacle", "obstacle_dist"), want, got):
        assert a.tobytes() == b.tobytes(), name
    if case == "lattice-obstacle-tie":
        assert want[3][40]  # the tie went to the obstacle (the first object), in both


def test_the_world_uses_the_tree_above_the_dense_limit(monkeypatch):
    calls = []
    monkeypatch.setattr(world_node, "nearest_objects_tree", lambda *a: calls.append(1) or nearest_objects_tree(*a))
    p = lattice(world_node.DENSE_NEAREST_MAX + 1)
    world_node.nearest_objects(p, np.zeros_like(p), np.zeros((0, 3)), np.zeros((0, 3)))
    assert calls


def test_without_scipy_the_world_computes_the_same_in_blocks_of_rows(monkeypatch):
    from fxswarm.core import nearest

    rng = np.random.default_rng(9)
    p = lattice(600)
    p[:50] += rng.uniform(-0.5, 0.5, (50, 3))
    v, obstacles, obstacle_v = rng.normal(size=(600, 3)), rng.uniform(-20, 20, (2, 3)), rng.normal(size=(2, 3))
    want = dense(p, v, obstacles, obstacle_v, monkeypatch)
    got = nearest.nearest_objects_blocked(p, v, obstacles, obstacle_v, block=97)
    for a, b in zip(want, got):
        assert a.tobytes() == b.tobytes()
    monkeypatch.setattr(world_node, "DENSE_NEAREST_MAX", 400)
    monkeypatch.setattr(world_node, "have_tree", lambda: False)
    monkeypatch.setattr(world_node, "nearest_objects_tree", None)  # would fail if called
    for a, b in zip(want, world_node.nearest_objects(p, v, obstacles, obstacle_v)):
        assert a.tobytes() == b.tobytes()


def test_the_cached_candidate_lists_give_the_dense_answer_tick_after_tick(monkeypatch):
    from fxswarm.core import nearest
    from fxswarm.core.nearest import NearestCache

    monkeypatch.setattr(nearest, "BLOCK", 97)  # candidates' distances in blocks of robots, one partial
    rng = np.random.default_rng(4)
    p = lattice(500)  # exact ties at first, then random steps; a jump forces lists to be rebuilt
    obstacles, obstacle_v = np.array([[10.0, 10.0, 0.5], [30.0, 4.0, 0.0]]), np.zeros((2, 3))
    cache = NearestCache()
    for tick in range(40):
        v = rng.normal(size=p.shape)
        want = dense(p, v, obstacles, obstacle_v, monkeypatch)
        got = cache(p, v, obstacles, obstacle_v)
        for name, a, b in zip(("po", "vo", "dist", "is_obstacle", "obstacle_dist"), want, got):
            assert a.tobytes() == b.tobytes(), (tick, name)
        p = p + (3.0 if tick == 20 else 0.05) * v
    assert 2 <= cache.rebuilds < 10  # kept across ticks, rebuilt after the jump
    assert cache.searched  # some robots were decided off their lists


def test_the_world_keeps_candidate_lists_above_the_dense_limit():
    from fxswarm.core.nearest import NearestCache
    from fxswarm.core.scenario import parse
    import tomllib

    raw = tomllib.loads(open("configs/paper-fast.toml").read())
    del raw["robots"], raw["graph"]
    raw["swarm"] = {"count": world_node.DENSE_NEAREST_MAX + 1, "graph": "line", "start": "slots"}
    world = world_node.WorldNode(parse(raw, "big.toml"), record=False)
    assert isinstance(world._nearest, NearestCache)
