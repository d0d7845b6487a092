"""Swarms written in a few lines: a scenario's ``[swarm]`` table, expanded to explicit robots.

A scenario may describe its robots instead of listing them (docs/guide.md "Generated swarms")::

    [swarm]
    count = 1000
    formation = "grid"      # line | circle | grid | sphere | file
    spacing = 2.0           # m between neighbouring slots
    graph = "k-nearest"     # line | ring | grid | k-nearest | random-geometric | tree | complete
    k = 4                   # k-nearest: neighbours per robot; random-geometric: radius = ...; tree: branching = ...
    pinned = 0.05           # share of robots that hear the leader (spread over the formation), or ids
    start = "box"           # random start in a cube of side `box` around each slot ("slots": on the slot)
    box = 20.0
    seed = 7
    weights = 1.0           # every edge's a_ij; pin_gain = b_i of the pinned robots

:func:`expand` turns that into today's explicit form (``[[robots]]`` with ``position`` and
``offset``, ``[graph]`` with ``edges``, ``pinned`` and ``pin_gain``), the same document for
the same file: offsets and edges use correctly rounded arithmetic (but for the C library's
sin/cos of circle and sphere slots, the same only where that library is), starts come from
numpy's PCG64 generator seeded with ``seed``. ``fxswarm expand SCENARIO`` prints that form.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

FORMATIONS = ("line", "circle", "grid", "sphere", "file")
GRAPHS = ("line", "ring", "grid", "k-nearest", "random-geometric", "tree", "complete")
STARTS = ("box", "slots")
KEYS = {"count", "formation", "spacing", "file", "graph", "k", "radius", "branching", "pinned", "start", "box",
        "seed", "weights", "pin_gain", "estimate"}
#: Slots of "grid" are linked when they are one spacing apart (within this relative tolerance).
GRID_TOLERANCE = 1e-9
#: A complete graph's edges grow as count^2: refused above this count (name one that scales).
COMPLETE_MAX = 2000


def expand(data: dict, source: str, folder: str | None = None) -> dict:
    """``data`` (a parsed scenario) with its ``[swarm]`` table replaced by ``[[robots]]`` and
    ``[graph]``; ``data`` itself if it has none. Raises ``ScenarioError`` naming ``source``
    and the field (``swarm.graph: expected ...``), and, for a graph in which the leader cannot
    reach every robot, the robots it cannot reach."""
    from fxswarm.core.scenario import ScenarioError, _Fields  # the scenario module calls this one

    if "swarm" not in data:
        return data
    top = _Fields(source, data)
    f = top.table_at("swarm", required=True)
    for other in ("robots", "graph"):
        if other in data:
            top.fail(other, f"no [{other}] beside [swarm] (the swarm table writes it)", show_got=False)
    f.check_known(KEYS)
    formation = f.string("formation", "grid", FORMATIONS)
    offsets = None
    if formation == "file":
        offsets = _offsets_file(f, folder)
        count = f.integer("count", len(offsets), minimum=1)
        if count != len(offsets):
            f.fail("count", f"the number of offsets in the file ({len(offsets)})", count)
    else:
        if not f.has("count"):
            f.fail("count", "an integer >= 1 (the number of robots)", show_got=False)
        count = f.integer("count", 0, minimum=1)
    spacing = f.number("spacing", 2.0, positive=True)
    if offsets is None:
        offsets = formation_offsets(formation, count, spacing)
    graph = f.string("graph", "k-nearest", GRAPHS)
    k = f.integer("k", 4, minimum=1)
    branching = f.integer("branching", 2, minimum=1)
    radius = None
    if graph == "random-geometric":
        radius = f.number("radius", positive=True) if f.has("radius") else f.fail(
            "radius", "a number > 0 (m): random-geometric links robots whose slots are this close", show_got=False)
    if graph == "complete" and count > COMPLETE_MAX:
        f.fail("graph", f"a graph that scales to {count} robots ('complete' is limited to {COMPLETE_MAX}: "
               f"its edges grow as count^2)", graph)
    edges = graph_edges(graph, offsets, spacing, k=k, radius=radius, branching=branching)
    pinned = _pinned(f, count, offsets)
    lost = unreachable(count, edges, pinned)
    if lost:
        shown = ", ".join(str(x) for x in lost[:20]) + (f" and {len(lost) - 20} more" if len(lost) > 20 else "")
        f.fail("graph", f"a graph in which the leader reaches every robot through pinned robots {_short(pinned)}; "
               f"it cannot reach robots {shown} ({len(lost)} of {count}; graph = {graph!r})", show_got=False)
    weight = f.number("weights", 1.0, positive=True)
    pin_gain = f.number("pin_gain", 1.0, positive=True)
    start = f.string("start", "box", STARTS)
    box = f.number("box", 0.0, nonnegative=True) if start == "box" else 0.0
    seed = f.integer("seed", 0, minimum=0)
    estimate = f.vector("estimate", (0.0, 0.0, 0.0))
    origin = _leader_start(data, source)
    jitter = np.random.default_rng(seed).uniform(-0.5 * box, 0.5 * box, (count, 3)) if box > 0 \
        else np.zeros((count, 3))
    robots = []
    for i, (off, dj) in enumerate(zip(offsets, jitter.tolist())):
        pos = [origin[a] + off[a] + dj[a] for a in range(3)]
        robot = {"position": pos, "offset": list(off)}
        if estimate != (0.0, 0.0, 0.0):
            robot["estimate"] = list(estimate)
        robots.append(robot)
    out = {key: value for key, value in data.items() if key != "swarm"}
    out["graph"] = {"edges": [list(e) for e in edges], "pinned": pinned, "pin_gain": pin_gain}
    if weight != 1.0:
        out["graph"]["weights"] = [weight] * len(edges)
    out["robots"] = robots
    return out


def _short(ids: list[int]) -> str:
    return str(ids) if len(ids) <= 12 else f"[{', '.join(map(str, ids[:12]))}, ...] ({len(ids)})"


def _leader_start(data: dict, source: str) -> tuple[float, float, float]:
    """The leader's position at t = 0 (the swarm's slots are around it); the origin if the
    [leader] table is missing or broken (the scenario's own checks then name it)."""
    from fxswarm.core.scenario import LEADER_KINDS, ScenarioError, _Fields, _path

    try:
        path = _path(_Fields(source, data.get("leader") or {}, "leader"), LEADER_KINDS)
    except ScenarioError:
        return (0.0, 0.0, 0.0)
    return tuple(float(x) for x in np.asarray(path.position(0.0)).tolist())


def _offsets_file(f, folder: str | None) -> list[tuple[float, float, float]]:
    """The offsets of ``formation = "file"``: a text file beside the scenario, one ``x y z``
    (or ``x, y, z``) per line; ``#`` starts a comment."""
    if not f.has("file"):
        f.fail("file", "a file of offsets (one 'x y z' per line, m) with formation = 'file'", show_got=False)
    name = f.string("file")
    path = Path(name) if folder is None or Path(name).is_absolute() else Path(folder) / name
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        f.fail("file", f"a readable file of offsets ({path}: {exc.strerror})", show_got=False)
    out = []
    for number, line in enumerate(lines, 1):
        text = line.split("#", 1)[0].replace(",", " ").split()
        if not text:
            continue
        try:
            xyz = tuple(float(x) for x in text)
        except ValueError:
            xyz = ()
        if len(xyz) != 3 or not all(math.isfinite(x) for x in xyz):
            f.fail("file", f"3 finite numbers per line in {path} (line {number})", line.strip())
        out.append(xyz)
    if not out:
        f.fail("file", f"at least one offset in {path}", show_got=False)
    return out


def _pinned(f, count: int, offsets) -> list[int]:
    """The pinned robots: a list of ids, or a share (0, 1] of them spread over the formation
    (:func:`spread`), so that no robot is many hops from one that hears the leader."""
    value = f.table.get("pinned", [1])
    if isinstance(value, list):
        if not value or not all(isinstance(x, int) and not isinstance(x, bool) and 1 <= x <= count for x in value):
            f.fail("pinned", f"a share in (0, 1] or a non-empty list of robot ids in 1..{count}", value)
        return sorted(set(value))
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 < value <= 1.0:
        f.fail("pinned", f"a share in (0, 1] or a non-empty list of robot ids in 1..{count}", value)
    return spread(offsets, max(1, round(value * count)))


def spread(offsets, m: int) -> list[int]:
    """``m`` robot ids (ascending) spread over the slots by farthest-point sampling: robot 1, then
    each time the robot whose slot is farthest from those already chosen (ties: the lower id).
    Squared distances in correctly rounded arithmetic: the same choice on every machine."""
    pts = np.asarray(offsets, dtype=float)
    chosen = [0]
    d = pts - pts[0]
    gap = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]  # to the nearest chosen slot
    for _ in range(m - 1):
        k = int(np.argmax(gap))  # the first (lowest id) of the farthest
        chosen.append(k)
        d = pts - pts[k]
        gap = np.minimum(gap, d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])
    return sorted(i + 1 for i in chosen)


def formation_offsets(shape: str, count: int, spacing: float) -> list[tuple[float, float, float]]:
    """Slots of a formation, centred on the leader, neighbouring slots ``spacing`` m apart."""
    s = spacing
    if shape == "line":
        return [((i - (count - 1) / 2) * s, 0.0, 0.0) for i in range(count)]
    if shape == "grid":  # a square grid in the horizontal plane, row by row
        side = math.ceil(math.sqrt(count))
        rows = math.ceil(count / side)
        return [((i % side - (side - 1) / 2) * s, (i // side - (rows - 1) / 2) * s, 0.0) for i in range(count)]
    if shape == "circle":  # chord between neighbours = spacing
        if count == 1:
            return [(0.0, 0.0, 0.0)]
        r = s / (2.0 * math.sin(math.pi / count))
        return [(r * math.cos(2.0 * math.pi * i / count), r * math.sin(2.0 * math.pi * i / count), 0.0)
                for i in range(count)]
    if shape == "sphere":  # Fibonacci sphere: each slot has about spacing^2 of the surface
        if count == 1:
            return [(0.0, 0.0, 0.0)]
        r = s * math.sqrt(count / (4.0 * math.pi))
        golden = math.pi * (3.0 - math.sqrt(5.0))
        out = []
        for i in range(count):
            z = 1.0 - 2.0 * (i + 0.5) / count
            rho = math.sqrt(max(0.0, 1.0 - z * z))
            out.append((r * rho * math.cos(golden * i), r * rho * math.sin(golden * i), r * z))
        return out
    raise ValueError(f"unknown formation {shape!r}")


def _squared_distances(pts: np.ndarray, rows: slice) -> np.ndarray:
    """``|p_i - p_j|^2`` for the ``rows`` i against all j: elementwise, correctly rounded (same on every machine)."""
    d = pts[rows, None, :] - pts[None, :, :]
    return d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2]


def graph_edges(graph: str, offsets, spacing: float, *, k: int = 4, radius: float | None = None,
                branching: int = 2) -> list[tuple[int, int]]:
    """Undirected edges ``(i, j)``, ``i < j``, 1-based, sorted, of a named graph on the slots."""
    n = len(offsets)
    if graph == "line":
        edges = [(i, i + 1) for i in range(1, n)]
    elif graph == "ring":
        edges = [(i, i + 1) for i in range(1, n)] + ([(1, n)] if n > 2 else [])
    elif graph == "complete":
        edges = [(i, j) for i in range(1, n + 1) for j in range(i + 1, n + 1)]
    elif graph == "tree":  # robot 1 the root, robot i's parent (i - 2) // branching + 1
        edges = [((i - 2) // branching + 1, i) for i in range(2, n + 1)]
    else:
        edges = _metric_edges(graph, np.asarray(offsets, dtype=float), spacing, k, radius)
    return sorted({(min(i, j), max(i, j)) for i, j in edges})


#: Above this many slots, with scipy, a KD-tree proposes the candidate pairs (the same edges).
TREE_SLOTS = 2000


def _metric_edges(graph: str, pts: np.ndarray, spacing: float, k: int, radius: float | None) -> list:
    """Edges chosen by the slots' distances, in blocks of rows (no n x n matrix at once).
    k-nearest: each robot with its k nearest (ties: the lower id), both ways; grid: slots one
    spacing apart; random-geometric: slots at most ``radius`` apart."""
    n = len(pts)
    if n > TREE_SLOTS:
        from fxswarm.core.nearest import have_tree

        if have_tree():
            return _tree_edges(graph, pts, spacing, k, radius)
    edges: list[tuple[int, int]] = []
    block = max(1, 2_000_000 // max(n, 1))
    limit = {"grid": (spacing * (1.0 + GRID_TOLERANCE)) ** 2,
             "random-geometric": None if radius is None else radius * radius}.get(graph)
    ids = np.arange(n)
    for start in range(0, n, block):
        rows = slice(start, min(n, start + block))
        d2 = _squared_distances(pts, rows)
        own = np.arange(rows.start, rows.stop)
        d2[own - rows.start, own] = np.inf
        if graph == "k-nearest":
            kk = min(k, n - 1)
            if kk <= 0:
                continue
            # the k smallest by (distance, id): all within the k-th distance, ordered, the first k kept
            kth = np.partition(d2, kk - 1, axis=1)[:, kk - 1]
            ii, jj = np.nonzero(d2 <= kth[:, None])
            order = np.lexsort((jj, d2[ii, jj], ii))
            ii, jj = ii[order], jj[order]
            first = np.searchsorted(ii, np.arange(len(kth)))
            rank = np.arange(len(ii)) - first[ii]
            keep = rank < kk
            edges += list(zip((ii[keep] + rows.start + 1).tolist(), (jj[keep] + 1).tolist()))
        else:
            ii, jj = np.nonzero(d2 <= limit)
            ii = ii + rows.start
            keep = ii < jj
            edges += list(zip((ii[keep] + 1).tolist(), (ids[jj[keep]] + 1).tolist()))
    return edges


def _tree_edges(graph: str, pts: np.ndarray, spacing: float, k: int, radius: float | None) -> list:
    """:func:`_metric_edges`' edges with a KD-tree proposing candidates: every pair the exact rule
    could keep is within the tree's radius (widened for its rounding), and the exact squared
    distances, in the same arithmetic and with the same tie rule, decide."""
    from scipy.spatial import cKDTree

    n = len(pts)
    tree = cKDTree(pts)
    slack = 1.0 + 1e-9
    if graph == "k-nearest":
        kk = min(k, n - 1)
        if kk <= 0:
            return []
        far, _ = tree.query(pts, k=kk + 1)  # itself and its kk nearest, by the tree's distances
        lists = tree.query_ball_point(pts, far[:, -1] * slack + 1e-300)
        lens = np.fromiter((len(x) for x in lists), dtype=np.intp, count=n)
        ii = np.repeat(np.arange(n), lens)
        jj = np.fromiter((j for x in lists for j in x), dtype=np.intp, count=int(lens.sum()))
        d = pts[ii] - pts[jj]
        d2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]
        d2[ii == jj] = np.inf
        order = np.lexsort((jj, d2, ii))
        ii, jj = ii[order], jj[order]
        first = np.searchsorted(ii, np.arange(n))
        keep = np.arange(len(ii)) - first[ii] < kk
        return list(zip((ii[keep] + 1).tolist(), (jj[keep] + 1).tolist()))
    limit = (spacing * (1.0 + GRID_TOLERANCE)) ** 2 if graph == "grid" else radius * radius
    pairs = tree.query_pairs(np.sqrt(limit) * slack, output_type="ndarray")
    ii, jj = pairs[:, 0], pairs[:, 1]
    d = pts[ii] - pts[jj]
    keep = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2] <= limit
    return list(zip((np.minimum(ii, jj)[keep] + 1).tolist(), (np.maximum(ii, jj)[keep] + 1).tolist()))


def unreachable(count: int, edges, pinned: list[int]) -> list[int]:
    """Robots (1-based, ascending) with no path from a pinned robot: the leader cannot reach them."""
    adj: list[list[int]] = [[] for _ in range(count + 1)]
    for i, j in edges:
        adj[i].append(j)
        adj[j].append(i)
    seen = [False] * (count + 1)
    frontier = [p for p in pinned]
    for p in frontier:
        seen[p] = True
    while frontier:
        i = frontier.pop()
        for j in adj[i]:
            if not seen[j]:
                seen[j] = True
                frontier.append(j)
    return [i for i in range(1, count + 1) if not seen[i]]
