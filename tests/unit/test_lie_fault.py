"""The lie fault (a compromised robot sends false estimates) and the resilient estimator it meets,
in one process (docs/resilience.md). Over Zenoh: tests/integration/test_resilience_zenoh.py."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from fxswarm.agents.node import AgentNode
from fxswarm.core.messages import Sense
from fxswarm.core.scenario import ScenarioError, load, parse
from fxswarm.faults.plan import Lie, dumps, loads, resolve
from fxswarm.launch.sim import Simulation
from support import CONFIGS

LIAR_8 = CONFIGS / "liar-8.toml"


def liar_scenario(duration: float, resilience: bool, faults: dict | None = None):
    data = tomllib.loads(LIAR_8.read_text())
    data["scenario"]["duration"] = duration
    if resilience:
        data["estimator"] |= {"resilience": "w-msr", "tolerate": 1}
    if faults is not None:
        data["faults"] = faults
    return parse(data, str(LIAR_8))


def test_the_flag_and_the_table_say_the_same_lie_and_it_survives_serialising():
    sc = load(LIAR_8)
    flag = resolve(sc, ["lie agent:3 at=5 drift=0.5,0,0 until=20 noise=0.1 freeze"])
    table = liar_scenario(40.0, False, {"lies": [{"target": "agent:3", "at": 5, "drift": [0.5, 0, 0],
                                                  "until": 20, "noise": 0.1, "freeze": True}]})
    want = Lie(3, 5.0, 20.0, (0.0, 0.0, 0.0), (0.5, 0.0, 0.0), 0.1, True)
    assert flag.lies == resolve(table).lies == (want,)
    assert flag.lie_of(3) == want and flag.lie_of(2) is None
    assert loads(dumps(flag, sc), sc, "test").lies == (want,)
    assert want.label == "lie agent:3 at=5 until=20 drift=0.5,0,0 noise=0.1 freeze"


@pytest.mark.parametrize("spec, expected", [
    ("lie agent:9 at=1 drift=1,0,0", "id in 1..8"),
    ("lie leader at=1 offset=1,0,0", "the leader is trusted"),
    ("lie agent:3 at=5", "at least one of offset, drift, noise or freeze"),
    ("lie agent:3 at=5 until=4 offset=1,0,0", "a time after at"),
    ("lie agent:3 at=5 drift=1,0", "3 numbers"),
    ("lie agent:3 drift=1,0,0", "at=SECONDS"),
    ("lie agent:3 at=1 drift=a,0,0", "drift=x,y,z"),
    ("lie agent:3 at=1 lies=1", "lies"),
])
def test_a_wrong_lie_is_refused_naming_the_spec(spec, expected):
    with pytest.raises(ScenarioError) as err:
        resolve(load(LIAR_8), [spec])
    assert expected in str(err.value) and spec in str(err.value)


def test_two_lies_for_one_robot_are_refused():
    with pytest.raises(ScenarioError, match="one lie per robot"):
        resolve(load(LIAR_8), ["lie agent:3 at=1 offset=1,0,0", "lie agent:3 at=2 drift=1,0,0"])


def sent(node: AgentNode, tick: int) -> np.ndarray:
    """What ``node`` tells its neighbours for ``tick`` (the estimate sent alone)."""
    return node.estimate_message(tick, tick * node.sc.dt)[1].ph


def test_the_liar_tells_offset_drift_and_seeded_noise_from_at_on_and_the_truth_after_until():
    sc = load(LIAR_8)
    lie = Lie(3, 0.5, 1.0, (1.0, 0.0, 0.0), (0.0, 2.0, 0.0), 0.0, False)
    node = AgentNode(sc, 3, lie=lie, seed=7)
    true = node.ph.copy()
    assert np.array_equal(sent(node, 10), true)  # 0.1 s: before at
    assert np.allclose(sent(node, 75), true + [1.0, 2.0 * 0.25, 0.0])  # 0.75 s
    assert np.array_equal(sent(node, 100), true)  # until: the truth again
    assert np.array_equal(node.ph, true)  # what it flies is its own, true estimate
    noisy = Lie(3, 0.0, None, noise=0.2)
    a, b = AgentNode(sc, 3, lie=noisy, seed=7), AgentNode(sc, 3, lie=noisy, seed=7)
    c = AgentNode(sc, 3, lie=noisy, seed=8)
    assert np.array_equal(sent(a, 5), sent(b, 5)) and not np.array_equal(sent(a, 5), sent(c, 5))
    draws = np.array([sent(a, k) - true for k in range(400)])
    assert 0.15 < draws.std() < 0.25 and abs(draws.mean()) < 0.05


def test_a_frozen_liar_keeps_telling_the_estimate_it_held_when_it_began():
    sc = load(LIAR_8)
    node = AgentNode(sc, 3, lie=Lie(3, 0.0, freeze=True), seed=0)
    first = sent(node, 0)
    node.ph = node.ph + 5.0  # its true estimate moves on
    assert np.array_equal(sent(node, 1), first)


def test_w_msr_counts_what_it_discards_and_the_law_sees_the_trimmed_rows():
    """Robot 4 (not pinned) of liar-8 hears 1, 2, 3, 5, 6, 7; one row far above the rest on x is
    discarded with the lowest on each axis."""
    sc = liar_scenario(1.0, True)
    node = AgentNode(sc, 4)
    node.ph = np.zeros(3)
    rows = [[0.1 * j, 0.1 * j, 0.0] for j in range(6)]
    rows[2][0] = 100.0  # robot 3's
    node._held_rows = lambda fresh_by, now: ([list(r) for r in rows], [1.0] * 6, False, False)
    node.sense = Sense("world", 0, 1, 0, 0.0, 4, np.zeros(3), None, None)
    node.sensed_t = 0.0
    node.act(sc.dt)
    seen = np.asarray(node.view.rows, dtype=float).tolist()
    assert seen[2][0] == 0.0 and seen[5][0] == 0.5  # the liar's x replaced by own, the next largest kept
    assert seen[5][1] == 0.0 and seen[4][1] == pytest.approx(0.4)  # on y the largest (robot 7's) goes
    assert node.discarded == 2  # x: 100 above; y: 0.5 above; nothing below 0 on x, y; z all equal


def test_in_the_simulator_the_liar_drags_the_paper_law_and_w_msr_holds():
    """2 s of liar-8 with robot 3 drifting 4 m/s on x from 0.5 s (the full 40 s claim is in
    docs/resilience.md and the slow test below). Without a liar both estimators are within
    0.12 m of the leader at 2 s (the paper's 0.116 m, W-MSR's 0.071 m, measured)."""
    lie = {"lies": [{"target": "agent:3", "at": 0.5, "drift": [4.0, 0.0, 0.0]}]}
    paper = Simulation(liar_scenario(2.0, False, lie)).run()
    resilient = Simulation(liar_scenario(2.0, True, lie)).run()
    assert paper["resilience"]["liars"] == [3] and paper["resilience"]["discarded"] is None
    assert paper["resilience"]["honest_estimate_error_final_m"] > 1.0  # 3.69 m measured
    r = resilient["resilience"]
    assert r["honest_estimate_error_final_m"] < 0.12  # 0.060 m measured
    assert set(r["discarded"]) == {str(i) for i in range(1, 9)} and all(v > 0 for v in r["discarded"].values())


@pytest.mark.slow
def test_forty_seconds_of_a_drifting_liar_on_liar_8_and_on_the_paper_ring():
    """The issue's claim (docs/resilience.md's numbers): on liar-8 (meets the condition for F = 1)
    the paper's law is dragged tens of metres; W-MSR keeps every honest robot within 0.3 m of its
    slot at the end and above d/2 from every object. On the paper's ring (does not meet it) W-MSR
    leaves robots 2, 3, 5, 6 behind, liar or not."""
    lie = {"lies": [{"target": "agent:3", "at": 5.0, "drift": [0.5, 0.0, 0.0]}]}
    paper = Simulation(liar_scenario(40.0, False, lie)).run()["resilience"]
    held = Simulation(liar_scenario(40.0, True, lie)).run()["resilience"]
    assert paper["honest_formation_error_final_m"] > 10.0
    assert held["honest_formation_error_final_m"] < 0.3
    assert held["honest_min_object_distance_m"] > 2.0 / 2
    data = tomllib.loads((CONFIGS / "paper-fast.toml").read_text())
    data["estimator"] |= {"resilience": "w-msr", "tolerate": 1}
    data["faults"] = lie
    with pytest.warns(UserWarning, match="robots 2, 3, 5, 6 do not"):
        ring = parse(data, "ring")
    assert Simulation(ring).run()["resilience"]["honest_formation_error_final_m"] > 10.0


def test_a_campaign_grids_the_liar_its_drift_and_the_estimator(tmp_path):
    """Which robot lies and how much are fault-template placeholders, the estimator a scenario
    value: every cell is planned and validated before any run (docs/resilience.md)."""
    from fxswarm.study.campaign_plan import CampaignError, Criteria, make_plan, parse_axis

    axes = [parse_axis("liar=3,6"), parse_axis("rate=0.1,2"), parse_axis("estimator.resilience=none,w-msr")]
    template = "lie agent:{liar} at=5 drift={rate},0,0"
    plan = make_plan(str(LIAR_8), load(LIAR_8), tmp_path, [template], axes, [], 2, 0, Criteria(1.0, None, 0.3))
    assert len(plan.runs) == 2 * 2 * 2 * 2
    run = next(r for r in plan.runs if r.cell == {"liar": 6, "rate": 2, "estimator.resilience": "w-msr"})
    assert run.faults[0] == "lie agent:6 at=5 drift=2,0,0"
    assert plan.tables[run.scenario]["estimator"]["resilience"] == "w-msr"
    with pytest.raises(CampaignError, match="liar=9.*id in 1..8"):  # no robot 9: refused before any run
        make_plan(str(LIAR_8), load(LIAR_8), tmp_path, ["lie agent:{liar} at=5 drift=1,0,0"],
                  [parse_axis("liar=3,9")], [], 1, 0, Criteria(1.0, None, 0.3))


def test_freeze_may_be_written_as_in_the_table():
    sc = load(LIAR_8)
    assert resolve(sc, ["lie agent:2 at=1 freeze=true"]).lies == resolve(sc, ["lie agent:2 at=1 freeze"]).lies
    with pytest.raises(ScenarioError, match="true or false"):
        resolve(sc, ["lie agent:2 at=1 offset=1,0,0 freeze=maybe"])
