"""Nearest object among thousands of robots without an n x n matrix: a KD-tree finds each
robot's candidates, the world's own distance formula decides among them.

:func:`nearest_objects` in the world (world/node.py) computes every robot-object distance,
n x (n + m) of them: 800 MB a tick at 10 000 robots. This gives the same answer (the same
distances, bit for bit, and the same tie rule: among equally near objects the first of
``[obstacles..., robots by id...]``) from a KD-tree (scipy.spatial.cKDTree) over the robots:
it proposes each robot's ``k`` nearest others, their distances are computed with the world's
formula (``sqrt(einsum)`` on the differences, the same per element whatever the array's
length), and a robot whose candidates might miss a tie (its k-th candidate no farther than its
best, within rounding) is decided over all objects, as the world does.
"""

from __future__ import annotations

import numpy as np

#: Robots' candidates per query: the nearest other robot, and slack for ties and rounding.
CANDIDATES = 4
#: cKDTree's distances and the world's may differ in the last bits: a candidate set is
#: trusted only if its farthest is farther than the best by more than this (relative).
ROUNDING = 1e-9


def distances(p: np.ndarray, objects: np.ndarray) -> np.ndarray:
    """``|p_i - objects_ij|`` for p (n, 3) and objects (n, c, 3): the world's formula."""
    diff = p[:, None, :] - objects
    return np.sqrt(np.einsum("ijk,ijk->ij", diff, diff))


def have_tree() -> bool:
    """Whether scipy (the ``scale`` extra) is installed."""
    try:
        import scipy.spatial  # noqa: F401
    except ImportError:
        return False
    return True


def nearest_objects_blocked(p: np.ndarray, v: np.ndarray, obstacles: np.ndarray, obstacle_v: np.ndarray,
                            block: int = 256):
    """As ``world.node.nearest_objects``, the same computation a block of robots at a time: the
    same answer with ``block`` x (n + m) distances in memory, not n x (n + m) (without scipy)."""
    n, m = len(p), len(obstacles)
    objects = np.concatenate([obstacles, p])
    object_v = np.concatenate([obstacle_v, v])
    choice, best, obstacle_dist = np.zeros(n, dtype=np.intp), np.zeros(n), np.full(n, np.inf)
    for start in range(0, n, block):
        rows = np.arange(start, min(n, start + block))
        diff = p[rows, None, :] - objects[None, :, :]
        dist = np.sqrt(np.einsum("ijk,ijk->ij", diff, diff))
        dist[rows - start, m + rows] = np.inf
        if m:
            obstacle_dist[rows] = dist[:, :m].min(axis=1)
        k = dist.argmin(axis=1)
        choice[rows], best[rows] = k, dist[rows - start, k]
    return objects[choice], object_v[choice], best, choice < m, obstacle_dist


def nearest_objects_tree(p: np.ndarray, v: np.ndarray, obstacles: np.ndarray, obstacle_v: np.ndarray):
    """As ``world.node.nearest_objects`` (same returns, same values) for n > CANDIDATES robots."""
    from scipy.spatial import cKDTree  # only for large swarms: small ones never import scipy

    n, m = len(p), len(obstacles)
    objects = np.concatenate([obstacles, p])
    object_v = np.concatenate([obstacle_v, v])
    own = np.arange(n)
    if m:
        obstacle_all = distances(p, np.broadcast_to(obstacles, (n, m, 3)))
        obstacle_dist = obstacle_all.min(axis=1)
    else:
        obstacle_all, obstacle_dist = np.zeros((n, 0)), np.full(n, np.inf)
    tree = cKDTree(p)
    choice, best = np.zeros(n, dtype=np.intp), np.zeros(n)
    rows = own
    for k in (CANDIDATES + 1, 4 * CANDIDATES + 1):  # the robot itself is among its own nearest
        k = min(k, n)
        _, idx = tree.query(p[rows], k=k)
        cand = np.concatenate([np.broadcast_to(np.arange(m), (len(rows), m)), m + idx], axis=1)
        dist = np.concatenate([obstacle_all[rows], distances(p[rows], p[idx])], axis=1)
        dist[cand == m + rows[:, None]] = np.inf  # a robot is not its own nearest object
        row_best = dist.min(axis=1)
        # trusted: the farthest proposed robot is clearly farther than the best, so no robot
        # outside the proposals can be as near (the tree's distance to them is at least that far)
        trusted = dist[:, m:].max(axis=1, initial=-np.inf, where=np.isfinite(dist[:, m:])) \
            > row_best * (1.0 + ROUNDING) + 1e-300
        if k == n:
            trusted[:] = True  # every robot was proposed
        # the first object (lowest index) among the nearest: the world's argmin over [obstacles, robots]
        key = np.where(dist == row_best[:, None], cand, np.iinfo(np.intp).max)
        choice[rows], best[rows] = key.min(axis=1), row_best
        rows = rows[~trusted]
        if not len(rows):
            break
    for i in rows:  # rare (many robots equally near): decide over every object, as the world does
        row = distances(p[i:i + 1], objects[None, :, :])[0]
        row[m + i] = np.inf
        choice[i] = int(row.argmin())
        best[i] = row[choice[i]]
    return objects[choice], object_v[choice], best, choice < m, obstacle_dist
