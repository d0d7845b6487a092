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
#: Robots whose candidates' distances are computed at a time: the block's arrays stay in cache.
BLOCK = 2048


def distances(p: np.ndarray, objects: np.ndarray) -> np.ndarray:
    """``|p_i - objects_ij|`` for p (n, 3) and objects (n, c, 3): the world's formula."""
    return norms(p[:, None, :] - objects)


def norms(diff: np.ndarray) -> np.ndarray:
    """``|diff_ij|`` of differences (n, c, 3): the world's distance (world.node.nearest_objects),
    one definition, so that every search gives its bits."""
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
        dist = norms(p[rows, None, :] - objects[None, :, :])
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
    objects, object_v, own, obstacle_all, obstacle_dist = _objects(p, v, obstacles, obstacle_v)
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


class NearestCache:
    """:func:`nearest_objects_tree` with the tree's candidates kept for many ticks (Verlet lists).

    At a rebuild each robot gets its ``CACHED`` nearest other robots from a KD-tree, and the
    distance ``R_i`` of the farthest of them: every other robot was at least ``R_i`` away. At a
    later tick, with ``delta_i`` how far robot i has moved since and ``M`` the most any robot has,
    a robot outside the list is still at least ``R_i - delta_i - M`` away; a robot whose nearest
    candidate (or obstacle) is closer than that, with a margin for rounding, is decided by its
    list alone, with the world's own distances and tie rule. The others (a few) are decided over
    the obstacles and the robots the rebuild's tree finds near enough to have come as near, or,
    past :data:`REBUILD_SHARE` of the robots, the lists are built again. The
    answer is the dense one, bit for bit (tests/unit/test_nearest.py).
    """

    CACHED = 8  # a lattice's 4 equally near neighbours and the next ring: margin to move before a rebuild
    REBUILD_SHARE = 0.01

    def __init__(self) -> None:
        self.p0: np.ndarray | None = None
        self.idx: np.ndarray | None = None
        self.reach: np.ndarray | None = None
        self.rebuilds = 0
        self.searched = 0  # robots decided off their lists (by the rebuild's tree), all ticks

    def _rebuild(self, p: np.ndarray) -> None:
        from scipy.spatial import cKDTree

        n = len(p)
        k = min(self.CACHED + 1, n)
        self.tree = cKDTree(p)
        far, idx = self.tree.query(p, k=k)
        # each list in ascending id, so that the first of its nearest (argmin) is the lowest id,
        # the world's tie rule; the robot itself (usually listed) is masked by an infinite distance
        idx = np.sort(idx, axis=1)
        self.p0, self.idx = p.copy(), idx
        self._own = np.flatnonzero(idx == np.arange(n)[:, None])
        self._robots = np.arange(n)
        self._rows = np.broadcast_to(self._robots[:, None], idx.shape).copy()  # p[rows] - p[idx]: no broadcast
        # every robot not listed was at least this far (the tree's distances, less a rounding margin)
        self.reach = far[:, -1] * (1.0 - ROUNDING) if k < n else np.full(n, np.inf)
        self.rebuilds += 1

    def __call__(self, p: np.ndarray, v: np.ndarray, obstacles: np.ndarray, obstacle_v: np.ndarray):
        n, m = len(p), len(obstacles)
        if self.p0 is None or self.p0.shape != p.shape:
            self._rebuild(p)
        moved = p - self.p0
        delta = np.sqrt(np.einsum("ij,ij->i", moved, moved))  # for the bound only (margins of ROUNDING)
        bound = self.reach - delta - delta.max()  # the nearest any unlisted robot can be now
        objects, object_v, own, obstacle_all, obstacle_dist = _objects(p, v, obstacles, obstacle_v)
        idx = self.idx
        robot_dist = np.empty(idx.shape)
        for lo in range(0, n, BLOCK):  # as distances(), a block of robots at a time (in a core's cache)
            rows = slice(lo, lo + BLOCK)
            robot_dist[rows] = norms(np.take(p, self._rows[rows], axis=0) - np.take(p, idx[rows], axis=0))
        robot_dist.flat[self._own] = np.inf  # a robot is not its own nearest object
        # columns: the obstacles, then the listed robots by id; the first nearest is the lowest object
        dist = np.concatenate([obstacle_all, robot_dist], axis=1)
        column = dist.argmin(axis=1)
        robots = self._robots
        best = dist[robots, column]
        decided = best * (1.0 + ROUNDING) + 1e-300 < bound
        undecided = np.flatnonzero(~decided)
        if len(undecided) > self.REBUILD_SHARE * n + 1:
            self._rebuild(p)
            return self(p, v, obstacles, obstacle_v)
        robot = column >= m
        choice = np.where(robot, m + idx[robots, np.where(robot, column - m, 0)], column)
        if len(undecided):
            # Any robot as near as the best candidate (at most best_i away now) was at most best_i +
            # delta_i + M away at the rebuild: those, from the rebuild's tree, and the obstacles
            # are decided with the world's distances and tie rule (candidates in ascending id).
            radius = (best[undecided] + delta[undecided] + delta.max()) * (1.0 + ROUNDING) + 1e-300
            balls = self.tree.query_ball_point(self.p0[undecided], radius, return_sorted=True)
            self.searched += len(undecided)
            for i, ball in zip(undecided.tolist(), balls):
                ball = np.array(ball, dtype=np.intp)
                row = np.concatenate([obstacle_all[i], distances(p[i:i + 1], p[None, ball])[0]])
                row[m:][ball == i] = np.inf  # a robot is not its own nearest object
                k = int(row.argmin())
                choice[i], best[i] = (k if k < m else m + ball[k - m]), row[k]
        return np.take(objects, choice, axis=0), np.take(object_v, choice, axis=0), best, choice < m, obstacle_dist


def _objects(p: np.ndarray, v: np.ndarray, obstacles: np.ndarray, obstacle_v: np.ndarray):
    """What both tree searches start from: every object (obstacles, then robots) and its
    velocity, the robots' own indices, each robot's distance to every obstacle (n, m) and to the
    nearest one (n,)."""
    n, m = len(p), len(obstacles)
    if m:
        obstacle_all = distances(p, np.broadcast_to(obstacles, (n, m, 3)))
        obstacle_dist = obstacle_all.min(axis=1)
    else:
        obstacle_all, obstacle_dist = np.zeros((n, 0)), np.full(n, np.inf)
    return (np.concatenate([obstacles, p]), np.concatenate([obstacle_v, v]), np.arange(n), obstacle_all,
            obstacle_dist)
