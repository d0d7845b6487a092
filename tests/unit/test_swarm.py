"""Generated swarms (fxswarm.core.swarm): the [swarm] table expands deterministically to the
explicit form, ``fxswarm expand`` prints it, and bad input is refused naming file and field."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from fxswarm.core.scenario import ScenarioError, load, parse
from fxswarm.core.swarm import formation_offsets, graph_edges, unreachable

BASE = """
[scenario]
name = "gen"
duration = 1
dt = 0.01
d = 1.0
[gains]
b1 = 0.6
b2 = 0.6
r0 = 0.9
r1 = 1.2
r2 = 0.6
K1 = 0.4
K2 = 0.6
K3 = 1.0
r3 = 6.0
r4 = 5.0
r5 = 3.0
r6 = 5.0
[leader]
kind = "static"
position = [1.0, 2.0, 3.0]
"""


def scenario(swarm: str, tmp_path=None, name="gen.toml"):
    text = BASE + "[swarm]\n" + swarm
    if tmp_path is None:
        return parse(tomllib.loads(text), name)
    path = tmp_path / name
    path.write_text(text)
    return load(path)


def test_a_swarm_expands_to_robots_graph_and_pins_the_same_way_every_time():
    table = 'count = 50\nformation = "grid"\nspacing = 2.0\ngraph = "k-nearest"\nk = 4\npinned = 0.1\nbox = 5.0\nseed = 3\n'
    a, b = scenario(table), scenario(table)
    assert a.n == 50 and np.array_equal(a.a, b.a) and np.array_equal(a.b, b.b)
    assert [r.position for r in a.robots] == [r.position for r in b.robots]
    # 5 pinned, spread over the formation by farthest-point sampling: robot 1, then the far corners
    assert [int(i) + 1 for i in np.flatnonzero(a.b)] == [1, 7, 20, 48, 50]
    from fxswarm.core.graph import hops_to_leader
    assert hops_to_leader(a.a, a.b).max() <= 3  # (the first 5 ids, one row of the grid, leave robots 5 hops away)
    offsets = np.array([r.offset.base for r in a.robots])
    start = np.array([r.position for r in a.robots]) - offsets - [1.0, 2.0, 3.0]  # around leader + slot
    assert np.abs(start).max() <= 2.5 and np.abs(start).max() > 1.0
    assert (a.a > 0).sum(axis=1).min() >= 4  # k-nearest, both ways
    other = scenario(table.replace("seed = 3", "seed = 4"))
    assert [r.position for r in other.robots] != [r.position for r in a.robots]


@pytest.mark.parametrize("shape", ["line", "circle", "grid", "sphere"])
def test_neighbouring_slots_are_spacing_apart(shape):
    pts = np.array(formation_offsets(shape, 200, 1.5))
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2) + np.eye(200) * 1e9
    nearest = d.min(axis=1)
    assert np.allclose(pts.max(axis=0) + pts.min(axis=0), 0.0, atol=0.3 if shape == "sphere" else 1e-9)  # centred
    assert 1.0 < np.median(nearest) < 2.0 if shape == "sphere" else np.allclose(nearest, 1.5)


def test_named_graphs():
    off = formation_offsets("grid", 9, 1.0)
    assert graph_edges("line", off, 1.0) == [(1, 2), (2, 3), (3, 4), (4, 5), (5, 6), (6, 7), (7, 8), (8, 9)]
    assert (1, 9) in graph_edges("ring", off, 1.0)
    assert len(graph_edges("complete", off, 1.0)) == 36
    assert graph_edges("tree", off, 1.0, branching=2)[:4] == [(1, 2), (1, 3), (2, 4), (2, 5)]
    assert len(graph_edges("grid", off, 1.0)) == 12  # a 3 x 3 lattice
    assert len(graph_edges("random-geometric", off, 1.0, radius=1.5)) == 12 + 8  # and the diagonals


def test_offsets_from_a_file(tmp_path):
    (tmp_path / "slots.txt").write_text("# x y z\n0 0 0\n1, 0, 0\n2 0 0.5\n")
    sc = scenario('formation = "file"\nfile = "slots.txt"\ngraph = "line"\nstart = "slots"\n', tmp_path)
    assert sc.n == 3 and sc.robots[2].offset.base == (2.0, 0.0, 0.5)
    assert sc.robots[2].position == (3.0, 2.0, 3.5)  # on its slot around the leader


@pytest.mark.parametrize("table,field,expected", [
    ('count = 10\nformation = "hexagon"\n', "swarm.formation", "one of 'line'"),
    ('count = 10\ngraph = "small-world"\n', "swarm.graph", "one of 'line'"),
    ("count = 0\n", "swarm.count", "an integer >= 1"),
    ('formation = "grid"\n', "swarm.count", "an integer >= 1"),
    ('count = 5\npinned = [9]\n', "swarm.pinned", "a share in (0, 1] or a non-empty list of robot ids in 1..5"),
    ('count = 5\npinned = 1.5\n', "swarm.pinned", "a share in (0, 1]"),
    ('count = 5\ngraph = "random-geometric"\n', "swarm.radius", "a number > 0"),
    ('count = 5\nshape = "grid"\n', "swarm.shape", "no such field"),
    ('count = 5\nformation = "file"\n', "swarm.file", "a file of offsets"),
])
def test_bad_swarm_input_names_the_file_and_field(table, field, expected):
    with pytest.raises(ScenarioError) as err:
        scenario(table)
    assert str(err.value).startswith(f"gen.toml: {field}: expected {expected}"), str(err.value)


def test_a_graph_the_leader_cannot_span_names_the_robots_it_cannot_reach():
    with pytest.raises(ScenarioError) as err:  # 2 m apart, linked only within 1.5 m: all alone
        scenario('count = 6\nformation = "line"\ngraph = "random-geometric"\nradius = 1.5\npinned = [2]\n')
    assert "swarm.graph" in str(err.value) and "cannot reach robots 1, 3, 4, 5, 6 (5 of 6" in str(err.value)
    assert unreachable(4, [(1, 2), (3, 4)], [1]) == [3, 4]


def test_robots_or_graph_beside_a_swarm_table_is_refused():
    with pytest.raises(ScenarioError, match=r"gen.toml: graph: expected no \[graph\] beside \[swarm\]"):
        parse(tomllib.loads(BASE + "[graph]\ntopology = 'line'\npinned = [1]\n[swarm]\ncount = 3\n"), "gen.toml")


def test_fxswarm_expand_prints_the_explicit_form_and_exits_2_on_bad_input(tmp_path, fxswarm_here):
    good = tmp_path / "good.toml"
    good.write_text(BASE + '[swarm]\ncount = 12\nformation = "circle"\ngraph = "ring"\nbox = 1.0\nseed = 2\n')
    code, printed, err = fxswarm_here("expand", good)
    assert code == 0, err
    explicit = tmp_path / "explicit.toml"
    explicit.write_text(printed)
    data = tomllib.loads(printed)
    assert "swarm" not in data and len(data["robots"]) == 12
    a, b = load(good), load(explicit)  # the printed form is the same scenario
    assert np.array_equal(a.a, b.a) and [r.position for r in a.robots] == [r.position for r in b.robots]
    bad = tmp_path / "bad.toml"
    bad.write_text(BASE + '[swarm]\ncount = 12\ngraph = "star-of-david"\n')
    code, printed, err = fxswarm_here("expand", bad)
    assert code == 2 and f"{bad}: swarm.graph: expected one of" in err and not printed


def test_a_campaign_grid_over_swarm_count_and_graph_parameters(tmp_path):
    from fxswarm.study.campaign_plan import CampaignError, Criteria, make_plan, parse_axis

    config = tmp_path / "gen.toml"
    config.write_text(BASE + '[swarm]\ncount = 10\nformation = "grid"\ngraph = "k-nearest"\nk = 3\nbox = 1.0\n')
    axes = [parse_axis("swarm.count=10,40"), parse_axis("swarm.k=3,5")]
    plan = make_plan(str(config), load(config), tmp_path / "c", [], axes, [None], 1, 1, Criteria(1.0, None, 0.2))
    cells = sorted((r.cell["swarm.count"], r.cell["swarm.k"]) for r in plan.runs)
    assert cells == [(10, 3), (10, 5), (40, 3), (40, 5)]
    for run in plan.runs:  # each run's scenario is a [swarm] table, expanded when it is parsed
        table = plan.tables[run.scenario]
        assert "robots" not in table and table["swarm"]["count"] == run.cell["swarm.count"]
        sc = parse(table, run.scenario)
        assert sc.n == run.cell["swarm.count"] and (sc.a > 0).sum(axis=1).min() >= run.cell["swarm.k"]
    listed = tmp_path / "listed.toml"
    listed.write_text(open("configs/paper-fast.toml").read())
    with pytest.raises(CampaignError, match="no \\[swarm\\] table"):
        make_plan(str(listed), load(listed), tmp_path / "d", [], axes[:1], [None], 1, 1, Criteria(1.0, None, 0.2))


@pytest.mark.parametrize("shape,graph,kw", [("grid", "k-nearest", {"k": 4}), ("sphere", "k-nearest", {"k": 6}),
                                            ("grid", "grid", {}), ("sphere", "random-geometric", {"radius": 2.2})])
def test_a_kd_tree_proposes_the_same_edges_the_exact_rule_keeps(shape, graph, kw, monkeypatch):
    from fxswarm.core import swarm

    off = formation_offsets(shape, 900, 2.0)  # a grid's exact ties included
    monkeypatch.setattr(swarm, "TREE_SLOTS", 10**9)
    brute = graph_edges(graph, off, 2.0, **kw)
    monkeypatch.setattr(swarm, "TREE_SLOTS", 100)
    assert graph_edges(graph, off, 2.0, **kw) == brute and len(brute) > 900
