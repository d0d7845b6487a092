"""The batch path of ``fxswarm sim`` (fxswarm.launch.batch): the same trajectory as the
per-robot path, bit for bit, on every shipped config it takes and on generated swarms; the
runs it does not take fall back to the per-robot path and say why."""

from __future__ import annotations

import copy
import dataclasses
import glob
import json
import re
import tomllib
import warnings

import numpy as np
import pytest

from fxswarm.core.laws import BatchUnsupported
from fxswarm.core.scenario import load, parse
from fxswarm.launch.sim import Simulation

warnings.simplefilter("ignore")  # scenario warnings (K3 below the leader's speed) are not the subject here


def both(sc, **kw):
    """(per-robot summary, batch summary, per-robot trajectory, batch trajectory)."""
    a, b = Simulation(sc, path="per-robot", **kw), Simulation(sc, path="batch", **kw)
    sa, sb = a.run(), b.run()
    assert (sa["path"], sb["path"]) == ("per-robot", "batch")
    return sa, sb, a.trajectory(), b.trajectory()


def assert_same(ta, tb):
    assert ta.keys() == tb.keys()
    differ = [k for k in ta if ta[k].shape != tb[k].shape or ta[k].tobytes() != tb[k].tobytes()]
    assert not differ, f"batch differs from per-robot in {differ}"


def shortened(sc, ticks):
    return dataclasses.replace(sc, duration=sc.dt * ticks)


CONFIGS = sorted(glob.glob("configs/*.toml"))


@pytest.mark.parametrize("path", CONFIGS)
def test_every_shipped_config_batch_equals_per_robot_or_falls_back_saying_why(path):
    sc = load(path)
    auto = Simulation(sc, path="auto")
    if auto.batch_law is None:  # a shipped config falls back only for what the batch path does not take
        table = {"faults": "faults", "estimator_graph": "estimator", "resilience": "estimator", "[world]": "world"}
        why = next((w for w in table if w in auto.path_reason), None)
        assert why is not None and sc.raw.get(table[why]), auto.path_reason
        return
    sa, sb, ta, tb = both(shortened(sc, 40 if sc.n > 20 else 120))
    assert_same(ta, tb)
    # the summaries too, but for the stepping time, the bus's counts and the path itself
    own = ("wall_s", "counters", "path")
    assert json.dumps({k: v for k, v in sa.items() if k not in own}) == \
        json.dumps({k: v for k, v in sb.items() if k not in own})


def law_exponents() -> set[float]:
    """Every exponent the built-in laws raise to on the shipped configs and the generated swarms."""
    from fxswarm.core.paper_law import FAMILIES, variant_gains

    out = set()
    for gains in [GAINS] + [sc.raw["gains"] for sc in map(load, CONFIGS) if "gains" in sc.raw]:
        for family in FAMILIES:
            g = {k: float(v) for k, v in variant_gains(gains, family).items() if k.startswith("r")}
            out |= {g["r0"], g["r1"], g["r2"], g["r3"] / g["r4"], g["r5"] / g["r6"]}
    return out


def test_the_batch_power_is_the_per_robot_power_bit_for_bit():
    # control.powers (np.float_power: the C library's pow per element) must give exactly the
    # bits of Python's ** for every float: a numpy that vectorised float_power would part the paths.
    from fxswarm.core.control import powers

    rng = np.random.default_rng(38)
    x = np.concatenate([rng.uniform(0.0, 30.0, 100_000), rng.uniform(0.0, 1e-3, 20_000),
                        10.0 ** rng.uniform(-300.0, 30.0, 20_000), [0.0, 5e-324, 1.0, 2.0, 1e10]])
    exponents = law_exponents() | {0.5, 0.7, 1.3, 1.5, 2.2}
    assert len(exponents) > 6
    for a in sorted(exponents):
        want = np.array([v ** a for v in x.tolist()])
        got = powers(x, a)
        differ = np.flatnonzero(got.view(np.int64) != want.view(np.int64))
        assert not len(differ), f"{len(differ)} of {len(x)} differ for a = {a}, e.g. x = {x[differ[0]]!r}"


LEADER = {"kind": "helix", "centre": [0.0, 0.0, 0.0], "radius": 2.0, "rate": 0.05, "climb": 0.5}
GAINS = {"b1": 0.6, "b2": 0.6, "r0": 0.9, "r1": 1.2, "r2": 0.6, "lam_f": 1.0, "lam_o": 1.0,
         "K1": 0.4, "K2": 0.6, "K3": 1.0, "r3": 6.0, "r4": 5.0, "r5": 3.0, "r6": 5.0}


def generated(swarm: dict, ticks=60, dt=0.02, **top) -> dict:
    raw = {"scenario": {"name": "gen", "duration": ticks * dt, "dt": dt, "d": 1.5, "seed": 3},
           "gains": dict(GAINS), "leader": dict(LEADER), "swarm": swarm,
           "formation": {"amplitude": [0.1, 0.0, 0.05], "omega": [0.2, 0.0, 0.3]}}
    for key, value in top.items():
        raw.setdefault(key, {}).update(value) if isinstance(value, dict) else raw.__setitem__(key, value)
    return raw


SWARMS = [
    {"count": 30, "formation": "grid", "spacing": 1.2, "graph": "k-nearest", "k": 3, "pinned": 0.1, "box": 3.0},
    {"count": 25, "formation": "circle", "spacing": 1.0, "graph": "ring", "pinned": [1, 13], "box": 2.0},
    {"count": 40, "formation": "sphere", "spacing": 1.0, "graph": "random-geometric", "radius": 2.5,
     "pinned": 0.05, "box": 4.0, "seed": 11},
    {"count": 20, "formation": "line", "spacing": 1.0, "graph": "tree", "branching": 3, "box": 1.0},
    {"count": 16, "formation": "grid", "spacing": 1.0, "graph": "grid", "pinned": [6], "start": "slots",
     "weights": 0.7, "pin_gain": 2.0},
    {"count": 12, "formation": "grid", "spacing": 1.0, "graph": "complete", "box": 6.0},
]


@pytest.mark.parametrize("swarm", SWARMS, ids=lambda s: f"{s['formation']}-{s['graph']}")
def test_generated_swarms_batch_equals_per_robot_with_avoidance_and_the_speed_limit(swarm):
    # spacing below d and a speed limit: robots avoid each other and are limited, so both branches run
    sc = parse(generated(swarm, scenario={"v_max": 1.5},
                         obstacles=[{"kind": "static", "position": [2.0, 0.0, 0.3]},
                                    {"kind": "circle", "centre": [0.0, 0.0, 0.5], "radius": 1.5, "rate": 0.4}]),
               "gen.toml")
    sa, sb, ta, tb = both(sc)
    assert_same(ta, tb)
    assert ta["avoid_active"].any(), "the run never entered a repulsive zone: the test would not see that branch"
    assert sa["speed_limited_ticks"] == sb["speed_limited_ticks"] > 0


@pytest.mark.parametrize("power", ["pairwise", "aggregate"])
def test_robots_summed_in_blocks_batch_equals_per_robot(power, monkeypatch):
    # large swarms sum their slots a block of robots at a time; blocks of 7 here, some partial
    from fxswarm.core.paper_law import BehaviouralBatch

    monkeypatch.setattr(BehaviouralBatch, "BLOCK", 7)
    sc = parse(generated(SWARMS[0], ticks=40, estimator={"power": power}), "gen.toml")
    assert sc.n % 7
    _, _, ta, tb = both(sc)
    assert_same(ta, tb)


@pytest.mark.parametrize("law,power", [("asymptotic", "pairwise"), ("finite-time", "aggregate"),
                                       ("fixed-time", "aggregate")])
def test_other_built_in_families_and_the_aggregate_power_batch_equals_per_robot(law, power):
    sc = parse(generated(SWARMS[0], ticks=80, controller={"law": law}, estimator={"power": power}), "gen.toml")
    _, _, ta, tb = both(sc)
    assert_same(ta, tb)


@pytest.mark.parametrize("law,estimator", [
    ("fixed-time+feedforward", {}),
    ("fixed-time+feedforward", {"power": "aggregate"}),
    ("asymptotic+feedforward", {"observer_K3": 0.5}),
])
def test_the_feedforward_laws_batch_equals_per_robot(law, estimator):
    # the leader-velocity observer, eq. (obs), with eqs. (11ff) and (v2ff): vh travels with ph
    sc = parse(generated(SWARMS[0], ticks=80, controller={"law": law}, estimator=estimator,
                         scenario={"v_max": 2.0}), "gen.toml")
    assert sc.tracking == "feedforward"
    sa, sb, ta, tb = both(sc)
    assert_same(ta, tb)
    assert sa["speed_limited_ticks"] == sb["speed_limited_ticks"]


@pytest.mark.parametrize("controller", [{"discretisation": "semi-implicit"},
                                        {"discretisation": "semi-implicit", "law": "fixed-time+feedforward"}])
def test_the_semi_implicit_step_batch_equals_per_robot(controller):
    sc = parse(generated(SWARMS[0], ticks=60, controller=controller, scenario={"v_max": 2.0},
                         obstacles=[{"kind": "static", "position": [2.0, 0.0, 0.3]}]), "gen.toml")
    sa, sb, ta, tb = both(sc)
    assert_same(ta, tb)
    assert ta["avoid_active"].any()


@pytest.mark.parametrize("change,why", [
    ({"faults": {"links": [{"link": "agent:*->agent:*", "kinds": ["estimate"], "drop": 0.2}]}}, "faults"),
    ({"faults": {"links": [{"link": "agent:*->agent:3", "kinds": ["estimate"], "delay": 0.05}]}}, "faults"),
    ({"faults": {"lies": [{"target": "agent:2", "at": 0.02, "drift": [0.5, 0.0, 0.0]}]}}, "faults"),
    ({"world": {"model": "unicycle"}}, "[world] table"),
    ({"world": {"pose_noise": 0.02}}, "[world] table"),
    ({"estimator": {"resilience": "w-msr", "tolerate": 1}}, "resilience"),
    ({"estimator": {"estimator_graph": "oriented"}}, "estimator_graph"),
])
def test_what_the_batch_path_does_not_take_runs_per_robot_and_says_why(change, why):
    sc = parse(generated(SWARMS[3], ticks=5, **change), "gen.toml")
    auto = Simulation(sc, path="auto")
    assert auto.batch_law is None and why in auto.path_reason
    summary = auto.run()
    assert summary["path"] == "per-robot" and why in summary["path_reason"]
    with pytest.raises(BatchUnsupported, match=re.escape(why)):
        Simulation(sc, path="batch")


def test_record_every_keeps_every_kth_tick_of_the_full_record():
    sc = parse(generated(SWARMS[1], ticks=23), "gen.toml")
    full, every = Simulation(sc, path="batch"), Simulation(sc, path="per-robot", record_every=5)
    sa, sb = full.run(), every.run()
    a, b = full.trajectory(), every.trajectory()
    assert len(b["t"]) == 5  # ticks 0, 5, 10, 15, 20
    assert (sb["ticks"], sb["duration_s"], sb["record_every"]) == (23, sa["duration_s"], 5) and sa["ticks"] == 23
    for key in a:
        assert np.array_equal(a[key][::5], b[key]), key


def test_the_guards_robot_on_its_slot_and_robot_on_an_obstacle_batch_equals_per_robot():
    # Robots start exactly on their slots with exact estimates (|e| = 0: the formation guard), and an
    # obstacle sits exactly on robot 5 (|u| = 0: the coincident-push guard of SPEC section 4).
    raw = generated({"count": 9, "formation": "grid", "spacing": 2.0, "graph": "grid", "start": "slots"}, ticks=30)
    raw["leader"] = {"kind": "static", "position": [0.0, 0.0, 0.0]}
    raw["formation"] = {}
    raw["obstacles"] = [{"kind": "static", "position": [0.0, 0.0, 0.0]}]  # robot 5's slot: the grid's centre
    sc = parse(raw, "gen.toml")
    assert sc.robots[4].position == (0.0, 0.0, 0.0)
    _, _, ta, tb = both(sc)
    assert_same(ta, tb)
    assert ta["avoid_active"][0, 4] and ta["nearest_distance"][0, 4] == 0.0
    assert ta["v"][0, 0].tolist() == [0.0, 0.0, 0.0]  # robot 1 on its slot, a still leader: it holds
    assert ta["v"][0, 4, 2] > 0.0  # robot 5 pushed straight up


def test_above_the_dense_limit_the_kd_tree_world_gives_both_paths_the_same_run():
    from fxswarm.world.node import DENSE_NEAREST_MAX

    n = DENSE_NEAREST_MAX + 50  # the world's nearest object from the KD-tree (fxswarm.core.nearest)
    sc = parse(generated({"count": n, "formation": "grid", "spacing": 1.0, "graph": "k-nearest", "k": 3,
                          "pinned": 0.05, "box": 1.0}, ticks=3), "gen.toml")
    _, _, ta, tb = both(sc)
    assert_same(ta, tb)
    assert ta["avoid_active"].any()


def test_a_generated_10000_robot_swarm_parses_and_steps_without_an_n_by_n_array():
    # the scenario holds its graph by rows (fxswarm.core.graph.SparseGraph): a dense n x n
    # float array anywhere on the way (parse, the batch path, the summary) would be 763 MB
    import tracemalloc

    n = 10_000
    raw = generated({"count": n, "formation": "grid", "spacing": 2.0, "graph": "k-nearest", "k": 4,
                     "pinned": 0.05, "box": 6.0}, ticks=3, dt=0.01)
    tracemalloc.start()
    try:
        sc = parse(raw, "gen.toml")
        sim = Simulation(sc, path="batch")
        summary = sim.run()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert summary["path"] == "batch" and summary["robots"] == n and summary["ticks"] == 3
    assert sim.trajectory()["p"].shape == (3, n, 3)
    assert peak < n * n * 8 / 10, f"peak {peak / 2**20:.0f} MB: an n x n array is {n * n * 8 / 2**20:.0f} MB"


def test_a_law_that_only_inherits_a_batch_form_runs_per_robot(tmp_path, monkeypatch):
    (tmp_path / "louder.py").write_text(
        "from fxswarm.core.paper_law import BehaviouralLaw\n"
        "class Louder(BehaviouralLaw):\n"
        "    vectors = 'floats'\n"
        "    def velocity(self, view, rate):\n"
        "        return [2.0 * x for x in super().velocity(view, rate)]\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    sc = parse(generated(SWARMS[3], ticks=3, controller={"law": "louder:Louder"}), str(tmp_path / "gen.toml"),
               str(tmp_path))
    auto = Simulation(sc, path="auto")
    assert auto.batch_law is None and "inherits" in auto.path_reason


def test_fxswarm_sim_says_which_path_and_why(tmp_path, fxswarm_here):
    import json

    from fxswarm.core.tomltext import dump_toml

    path = tmp_path / "gen.toml"
    path.write_text(dump_toml(generated(SWARMS[3], ticks=5)))
    run = ["sim", path, "--quiet"]
    fault = ["--fault", "agent:*->agent:* drop=0.2"]
    code, _, err = fxswarm_here(*run, "--out", tmp_path / "a")
    assert code == 0 and err == "", err
    assert json.loads((tmp_path / "a" / "summary.json").read_text())["path"] == "batch"
    code, _, err = fxswarm_here(*run, *fault, "--out", tmp_path / "b")
    assert code == 0 and "fxswarm sim: per-robot path: the run has faults" in err, err
    summary = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert summary["path"] == "per-robot" and "faults" in summary["path_reason"]
    code, _, err = fxswarm_here(*run, *fault, "--path", "batch", "--out", tmp_path / "c")
    assert code == 2 and "--path batch: the run has faults" in err and not (tmp_path / "c").exists()


def test_a_non_finite_value_on_the_batch_path_runs_it_again_per_robot(monkeypatch, capsys):
    from fxswarm.core.paper_law import BehaviouralBatch

    sc = parse(generated(SWARMS[3], ticks=20), "gen.toml")
    want = Simulation(sc, path="per-robot")
    want.run()
    real = BehaviouralBatch.estimate_rates
    calls = []

    def flaky(self, *args):  # the batch form going wrong at its 5th tick (the per-robot law does not)
        calls.append(1)
        out = real(self, *args)
        if len(calls) == 5:
            out[3, 1] = np.nan
        return out

    monkeypatch.setattr(BehaviouralBatch, "estimate_rates", flaky)
    sim = Simulation(sc, path="auto")
    summary = sim.run()
    assert summary["path"] == "per-robot" and "non-finite value at tick 4" in summary["path_reason"]
    assert "running again per robot" in capsys.readouterr().err
    assert_same(want.trajectory(), sim.trajectory())


def test_a_power_overflow_on_the_batch_path_runs_it_again_per_robot(capsys):
    # The observer over the undirected ring diverges here: a power overflows at tick 79, which per
    # robot is that robot's law_error (zero velocity, flagged), not a crash. The batch path does not
    # model law errors: it starts again per robot.
    sc = parse(generated(SWARMS[1], ticks=80, controller={"law": "fixed-time+feedforward"},
                         estimator={"observer_graph": "undirected"}, scenario={"v_max": 2.0}), "gen.toml")
    want = Simulation(sc, path="per-robot")
    want_summary = want.run()
    sim = Simulation(sc, path="auto")
    summary = sim.run()
    assert summary["path"] == "per-robot" and "overflow" in summary["path_reason"]
    assert "running again per robot" in capsys.readouterr().err
    assert want_summary["law"]["errors"] and summary["law"] == want_summary["law"]
    assert_same(want.trajectory(), sim.trajectory())
