"""Scenario files: every validation error names the file, the field and what was expected."""

import tomllib
import warnings

import numpy as np
import pytest

from fxswarm.core.scenario import ScenarioError, ScenarioWarning, load, parse
from fxswarm.testing import dump_toml

PAPER_FAST = "configs/paper-fast.toml"


def paper_data() -> dict:
    with open(PAPER_FAST, "rb") as fh:
        return tomllib.load(fh)


def write(tmp_path, data: dict, name: str = "x.toml") -> str:
    path = tmp_path / name
    path.write_text(dump_toml(data))
    return str(path)


def error_of(tmp_path, mutate) -> str:
    data = paper_data()
    mutate(data)
    path = write(tmp_path, data)
    with pytest.raises(ScenarioError) as info:
        load(path)
    message = str(info.value)
    assert message.startswith(path + ": "), message
    return message


def test_paper_scenarios_load_as_spec_section_8():
    for path, climb, duration in (("configs/paper.toml", 0.1, 300.0), (PAPER_FAST, 1.0, 40.0)):
        sc = load(path)
        assert sc.n == 6 and sc.duration == duration and sc.dt == 0.01 and sc.d == 2.0
        assert sc.leader.climb == climb and sc.leader.radius == 2.0 and sc.leader.rate == 0.05
        assert sc.neighbours(1) == [2, 6] and sc.neighbours(4) == [3, 5]
        assert [r.id for r in sc.robots if sc.is_pinned(r.id)] == [1, 4]
        assert np.allclose(sc.robots[1].position, [3, 3 + np.sqrt(3), 0])
        assert np.allclose(sc.robots[0].offset.position(0.0), [3 * np.sqrt(3) / 2, 1.5, 0])
        assert np.allclose(sc.robots[0].offset.position(np.pi / 0.2), [3 * np.sqrt(3) / 2 + 0.1, 1.5, 0])
        assert len(sc.obstacles) == 4 and np.allclose(sc.obstacles[0].position(5.0), [0, 2, 23])
        assert sc.formation.r1 == 1.2 and sc.estimator.r3 == 6 and sc.estimator.power == "pairwise"


def test_wrong_vector_length_names_file_field_and_count(tmp_path):
    msg = error_of(tmp_path, lambda d: d["robots"][3].update(position=[1.0, 2.0]))
    assert msg.endswith("robots[3].position: expected 3 numbers, got 2")


@pytest.mark.parametrize(
    "mutate, field, expected",
    [
        (lambda d: d["scenario"].pop("dt"), "scenario.dt", "a number"),
        (lambda d: d["scenario"].update(dt=-0.1), "scenario.dt", "a number > 0"),
        (lambda d: d["scenario"].update(duration="long"), "scenario.duration", "a finite number"),
        (lambda d: d["scenario"].update(speed=3), "scenario.speed", "no such field"),
        (lambda d: d["gains"].update(r1=1.0), "gains.r1", "r1*r0 > 1"),
        (lambda d: d["gains"].update(r2=1.5), "gains.r2", "r2*r0 < 1"),
        (lambda d: d["gains"].update(r3=4.0), "gains.r3", "r3/r4 > 1"),
        (lambda d: d["gains"].update(r5=6.0), "gains.r5", "r5/r6 < 1"),
        (lambda d: d["gains"].pop("K3"), "gains.K3", "a number"),
        (lambda d: d["estimator"].update(power="sum"), "estimator.power", "one of 'pairwise', 'aggregate'"),
        (lambda d: d["graph"].update(topology="torus"), "graph.topology", "one of 'ring'"),
        (lambda d: d["graph"].update(edges=[[1, 2]]), "graph.topology", "exactly one of"),
        (lambda d: d["graph"].update(pinned=[]), "graph.pinned", "at least one robot that hears the leader"),
        (lambda d: d["graph"].update(pinned=[9]), "graph.pinned", "robot ids in 1..6, got [9]"),
        (lambda d: d["leader"].update(kind="spiral"), "leader.kind", "one of 'static'"),
        (lambda d: d["leader"].pop("radius"), "leader.radius", "a number"),
        (lambda d: d["obstacles"][2].update(position=[0, "a", 1]), "obstacles[2].position", "3 finite numbers"),
        (lambda d: d["robots"][0].update(offset=5), "robots[0].offset", "3 numbers"),
        (lambda d: d.pop("robots"), "robots", "an array of tables"),
        (lambda d: d["formation"].update(amplitude=[0.1, 0]), "formation.amplitude", "3 numbers"),
        (lambda d: d.update(extra={"a": 1}), "extra", "no such field"),
        (lambda d: d["graph"].update(weights=[5.0] * 6), "graph.weights", "weights only with 'edges'"),
        (lambda d: d.update(logging={"rate": 5}), "logging.rate", "no such field"),
        (lambda d: d.update(logging={"rate_hz": 0}), "logging.rate_hz", "a number > 0"),
        (lambda d: d.update(logging={"velocities": "yes"}), "logging.velocities", "true or false"),
        (lambda d: d.update(logging={"trail_s": -3}), "logging.trail_s", "a number >= 0"),
        (lambda d: d.update(logging={"stale_ticks": 1.5}), "logging.stale_ticks", "an integer"),
        (lambda d: d.update(logging={"flush_frames": 0}), "logging.flush_frames", "an integer >= 1"),
        (lambda d: d.update(logging={"link_health": False}), "logging.link_health", "no such field"),
        (lambda d: d.update(zenoh={"port": 1}), "zenoh.port", "no such field"),
        (lambda d: d.update(zenoh={"mode": "mesh"}), "zenoh.mode", "one of 'peer', 'client', 'router'"),
        (lambda d: d.update(zenoh={"connect": "tcp/a:1"}), "zenoh.connect", "a list of strings"),
        (lambda d: d.update(zenoh={"multicast": 1}), "zenoh.multicast", "true or false"),
        (lambda d: d.update(zenoh={"lease_ms": 0}), "zenoh.lease_ms", "an integer >= 1"),
        (lambda d: d.update(zenoh={"topology": "star"}), "zenoh.topology", "one of 'auto', 'mesh', 'routed'"),
        (lambda d: d.update(zenoh={"swarm": 7}), "zenoh.swarm", "a string"),
        (lambda d: d.update(zenoh={"swarm": "lab/1"}), "zenoh.swarm", "a swarm name (not empty, without / * $ ? or #)"),
        (lambda d: d["scenario"].update(name="run*"), "scenario.name", "a name for the run folder and the swarm"),
        (lambda d: d["scenario"].update(name=""), "scenario.name", "not empty"),
    ],
)
def test_each_validation_error_names_its_field(tmp_path, mutate, field, expected):
    msg = error_of(tmp_path, mutate)
    assert f": {field}: expected " in msg and expected in msg, msg


def test_the_logging_and_zenoh_tables_are_read_with_the_scenario(tmp_path):
    """Their consumers (the logger, every process's Zenoh options, `fxswarm run`) take them
    from the scenario, checked: a wrong key fails at load, before any process starts."""
    data = paper_data()
    data["logging"] = {"rate_hz": 5, "velocities": True, "stale_ticks": 0}
    data["zenoh"] = {"swarm": "lab", "connect": ["tcp/10.0.0.1:7447"], "lease_ms": 2000, "topology": "routed"}
    sc = load(write(tmp_path, data, "ok.toml"))
    assert sc.logging == {"rate_hz": 5.0, "velocities": True, "stale_ticks": 0}
    assert sc.zenoh == data["zenoh"]
    assert load(PAPER_FAST).logging == {} and load(PAPER_FAST).zenoh == {}


def test_explicit_edges_weights_and_their_errors(tmp_path):
    def edges(d, e, w=None):
        d["graph"].pop("topology")
        d["graph"]["edges"] = e
        if w is not None:
            d["graph"]["weights"] = w

    data = paper_data()
    edges(data, [[1, 2], [2, 3], [3, 4], [4, 5], [5, 6]], [1.0, 2.0, 1.0, 1.0, 0.5])
    sc = load(write(tmp_path, data, "ok.toml"))
    assert sc.a[1, 2] == sc.a[2, 1] == 2.0 and sc.a[0, 5] == 0.0
    assert "graph.edges[1]: expected two different robot ids in 1..6" in error_of(
        tmp_path, lambda d: edges(d, [[1, 2], [2, 2]]))
    assert "graph.weights: expected one weight per edge (2), got 1" in error_of(
        tmp_path, lambda d: edges(d, [[1, 2], [2, 3]], [1.0]))


def test_graph_that_leaves_robots_unreached_is_refused_naming_them(tmp_path):
    def cut(d):
        d["graph"].pop("topology")
        d["graph"]["edges"] = [[1, 2], [2, 3], [5, 6]]
        d["graph"]["pinned"] = [1]

    msg = error_of(tmp_path, cut)
    assert "robots [4, 5, 6] are cut off from pinned robots [1]" in msg


@pytest.mark.parametrize("topology, degree", [("line", [1, 2, 2, 2, 2, 1]), ("star", [5, 1, 1, 1, 1, 1]),
                                              ("complete", [5] * 6), ("ring", [2] * 6)])
def test_named_topologies(tmp_path, topology, degree):
    data = paper_data()
    data["graph"]["topology"] = topology
    sc = load(write(tmp_path, data))
    assert list(sc.a.sum(axis=1).astype(int)) == degree


def test_leader_paths_and_moving_obstacles(tmp_path):
    data = paper_data()
    data["leader"] = {"kind": "waypoints", "times": [0.0, 10.0, 20.0], "points": [[0, 0, 0], [10, 0, 0], [10, 10, 0]]}
    data["obstacles"] = [{"kind": "constant_velocity", "position": [0, 0, 5], "velocity": [1, 0, 0]},
                         {"kind": "circle", "centre": [0, 0, 8], "radius": 3.0, "rate": 0.5}]
    sc = load(write(tmp_path, data))
    assert np.allclose(sc.leader.position(15.0), [10, 5, 0]) and np.allclose(sc.leader.velocity(15.0), [0, 1, 0])
    assert np.allclose(sc.obstacles[0].position(2.0), [2, 0, 5])
    assert np.allclose(np.linalg.norm(sc.obstacles[1].velocity(1.3)), 1.5)
    data["leader"] = {"kind": "waypoints", "times": [0.0, 0.0], "points": [[0, 0, 0], [1, 0, 0]]}
    with pytest.raises(ScenarioError, match=r"leader.times: expected strictly increasing times"):
        load(write(tmp_path, data))


def test_k3_below_leader_speed_warns():
    data = paper_data()
    data["gains"]["K3"] = 0.5
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        parse(data, "mem.toml")
    assert any(issubclass(w.category, ScenarioWarning) and "gains.K3" in str(w.message) for w in caught)


def test_missing_and_unparsable_files(tmp_path):
    with pytest.raises(ScenarioError, match="no such scenario file"):
        load(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[scenario\nname=")
    with pytest.raises(ScenarioError, match=r"bad.toml: not valid TOML"):
        load(bad)
    with pytest.raises(ScenarioError, match=f"{tmp_path}: cannot read the scenario file: Is a directory"):
        load(tmp_path)
