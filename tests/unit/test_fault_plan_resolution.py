"""The fault plan is resolved once (scenario [faults] + --fault flags + FXSWARM_FAULTS) into one
FaultPlan; its serialised form is what every process receives and validates on arrival."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

from fxswarm.core.scenario import ScenarioError, load, parse
from fxswarm.faults.plan import (FAULTS_ENV, PLAN_ENV, PLAN_FORMAT, dumps, load_plan, loads, parse_faults, plan_of,
                                 resolve)
from fxswarm.runtime.config import process_plan_or_exit

ROOT = Path(__file__).resolve().parents[2]
PAPER_FAST = ROOT / "configs" / "paper-fast.toml"

FILE_FAULTS = {"seed": 9, "links": [{"link": "agent:*->agent:2", "drop": 0.1}],
               "partitions": [{"start": 1, "end": 2, "isolate": [6]}]}
FLAGS = ["agent:*->agent:4 drop=0.2 delay=0.05 kinds=estimate", "leader->* burst=0.1,0.3,0.05,0.9",
         "partition 10-15 isolate=3 kinds=estimate", "leader-outage 5-8", "seed=5"]
ENV = "kill agent:2 at=10 restart=12; ; freeze leader at=3 thaw=4;partition 2-3 links=agent:1->agent:2 ;" \
      "world->agent:5 jitter=0.01 duplicate=0.3 reorder=0.2 reorder_delay=0.03; seed=7; staleness=0.3"


def scenario(faults: dict | None = None):
    data = tomllib.loads(PAPER_FAST.read_text())
    if faults is not None:
        data["faults"] = faults
    return parse(data, "paper-fast.toml")


@pytest.fixture(scope="module")
def rich():
    """A scenario with a [faults] table, and its plan with flags and FXSWARM_FAULTS on top."""
    sc = scenario(FILE_FAULTS)
    return sc, resolve(sc, FLAGS, {FAULTS_ENV: ENV})


def test_file_flags_and_variable_resolve_to_the_plan_of_the_one_equivalent_table(rich):
    sc, got = rich
    table = {
        "seed": 7, "staleness": 0.3,  # the last key=value wins: FXSWARM_FAULTS comes after the flags
        "links": [{"link": "agent:*->agent:2", "drop": 0.1},  # the file's rules first, then in order
                  {"link": "agent:*->agent:4", "drop": 0.2, "delay": 0.05, "kinds": ["estimate"]},
                  {"link": "leader->*", "burst": {"p_good_bad": 0.1, "p_bad_good": 0.3, "loss_good": 0.05,
                                                  "loss_bad": 0.9}},
                  {"link": "world->agent:5", "jitter": 0.01, "duplicate": 0.3, "reorder": 0.2,
                   "reorder_delay": 0.03}],
        "partitions": [{"start": 1, "end": 2, "isolate": [6]},
                       {"start": 10, "end": 15, "isolate": [3], "kinds": ["estimate"]},
                       {"start": 2, "end": 3, "links": ["agent:1->agent:2"]}],
        "leader_outages": [{"start": 5, "end": 8}],
        "processes": [{"target": "agent:2", "kill": 10, "restart": 12}, {"target": "leader", "freeze": 3, "thaw": 4}],
    }
    assert got == parse_faults(table, sc.seed, sc.n, "expected")
    assert got == resolve(sc, FLAGS, {FAULTS_ENV: ENV})  # the same inputs, the same (equal) plan
    assert got != resolve(sc, FLAGS)  # without the variable: another plan
    assert [r.dst for r in got.rules] == ["agent:2", "agent:4", "*", "agent:5"]


def test_without_flags_or_variable_the_plan_is_the_files():
    sc = scenario(FILE_FAULTS)
    assert resolve(sc) == resolve(sc, [], {}) == plan_of(sc)
    assert resolve(sc, None, {"PATH": "/bin"}) == plan_of(sc)  # other variables are not faults
    assert resolve(load(PAPER_FAST)).seed == load(PAPER_FAST).seed  # no table: the scenario's seed


def test_the_serialised_plan_round_trips_to_an_equal_plan_with_the_same_fates(rich, tmp_path):
    sc, plan = rich
    text = dumps(plan, sc)
    data = json.loads(text)
    assert data["format"] == PLAN_FORMAT and data["robots"] == sc.n
    back = loads(text, sc, "test")
    assert back == plan
    assert dumps(back, sc) == text  # a fixed point: re-serialising changes nothing
    # Equal means the same run: every fate on every link, kind and tick is the same.
    ends = ["world", "leader"] + [f"agent:{i}" for i in range(1, 7)]
    for tick in range(0, 400, 7):
        for s in ends:
            for r in ends:
                for kind in ("estimate", "leader", "sense", "command"):
                    assert back.fate(s, r, kind, tick, tick * sc.dt) == plan.fate(s, r, kind, tick, tick * sc.dt)
    path = tmp_path / "fault-plan.json"
    path.write_text(text + "\n")
    assert load_plan(str(path), sc, "--fault-plan") == plan == load_plan(text, sc, "--fault-plan")


def test_every_shipped_scenarios_plan_round_trips():
    for path in sorted((ROOT / "configs").glob("*.toml")):
        sc = load(path)
        assert loads(dumps(plan_of(sc), sc), sc, str(path)) == plan_of(sc), path.name


@pytest.mark.parametrize("flags, env, message", [
    (["partition 10"], None, "--fault 'partition 10': expected 'partition START-END ...' (seconds)"),
    (["*->* drop=3"], None, "--fault '*->* drop=3': faults.links[0].drop: expected a probability in [0, 1]"),
    (["kill agent:9 at=1"], None, "--fault 'kill agent:9 at=1': faults.processes[0].target: expected 'leader' or "
                                  "'agent:<id>' with id in 1..6"),
    (["freeze agent:2"], None, "--fault 'freeze agent:2': expected at=SECONDS"),
    (["leader->* burst=a,b"], None, "--fault 'leader->* burst=a,b': expected burst=p_gb,p_bg"),
    (["partition 1-2 isolate=x"], None, "--fault 'partition 1-2 isolate=x': expected isolate=ID"),
    (["bogus"], None, "--fault 'bogus': expected 'SRC->DST ...', 'partition'"),
    (["lossy=1"], None, "--fault 'lossy=1': faults.lossy: expected no such field here"),
    ([], "agent:1->agent:2 drop=0.1; leader-outage 8-5", "FXSWARM_FAULTS 'leader-outage 8-5': "
                                                         "faults.leader_outages[0].end: expected an end after start"),
    ([], "staleness=0", "FXSWARM_FAULTS 'staleness=0': faults.staleness: expected a number > 0, got 0"),
])
def test_a_bad_spec_names_the_flag_or_variable_the_spec_and_what_was_expected(flags, env, message):
    with pytest.raises(ScenarioError) as exc:
        resolve(load(PAPER_FAST), flags, {FAULTS_ENV: env} if env is not None else None)
    assert message in str(exc.value)


def test_a_bad_file_table_names_the_file_before_any_flag():
    with pytest.raises(ScenarioError, match=r"^paper-fast.toml: faults.links\[0\].drop: expected a probability"):
        resolve(scenario({"links": [{"link": "*->*", "drop": 2}]}), ["*->* drop=3"])


@pytest.mark.parametrize("mangle, message", [
    (lambda d: "{not json", "--fault-plan: expected a fault plan in JSON, got invalid JSON"),
    (lambda d: json.dumps({**d, "format": "fxswarm-fault-plan/0"}),
     "--fault-plan: format: expected 'fxswarm-fault-plan/1', got 'fxswarm-fault-plan/0'"),
    (lambda d: json.dumps({**d, "robots": 5}), "--fault-plan: scenario: expected a plan resolved from paper-fast.toml"),
    (lambda d: json.dumps({**d, "faults": {**d["faults"], "links": [{"link": "*->*", "delay": -1}]}}),
     "--fault-plan: faults.links[0].delay: expected a number >= 0, got -1"),
    (lambda d: json.dumps({**d, "faults": {**d["faults"], "seed": "x"}}),
     "--fault-plan: faults.seed: expected an integer"),
])
def test_a_received_plan_is_validated_on_arrival_naming_its_source(mangle, message):
    sc = scenario(FILE_FAULTS)
    text = mangle(json.loads(dumps(plan_of(sc), sc)))
    with pytest.raises(ScenarioError) as exc:
        loads(text, sc, "--fault-plan")
    assert message in str(exc.value)


def test_a_plan_from_another_scenario_file_is_refused_one_with_the_same_seed_and_faults_is_not():
    lossy = load(ROOT / "configs" / "faults-lossy.toml")
    with pytest.raises(ScenarioError, match=r"expected a plan resolved from .*paper-fast.toml .* got one from 'faults-lossy'"):
        loads(dumps(plan_of(lossy), lossy), load(PAPER_FAST), "FXSWARM_FAULT_PLAN")
    paper, fast = load(ROOT / "configs" / "paper.toml"), load(PAPER_FAST)  # no [faults], the same seed
    assert loads(dumps(plan_of(fast), fast), paper, "x") == plan_of(paper)


def test_a_role_process_takes_the_given_plan_else_the_variable_else_resolves_its_own_flags(rich, capsys):
    sc, plan = rich
    text = dumps(plan, sc)
    assert process_plan_or_exit(sc, text, None, "fxswarm agent 2", env={}) == plan
    assert process_plan_or_exit(sc, None, None, "fxswarm agent 2", env={PLAN_ENV: text}) == plan
    assert process_plan_or_exit(sc, None, FLAGS, "fxswarm agent 2", env={}) == resolve(sc, FLAGS)
    # By hand it reads no FXSWARM_FAULTS: that variable is the compose writer's.
    assert process_plan_or_exit(sc, None, None, "fxswarm agent 2", env={FAULTS_ENV: ENV}) == plan_of(sc)


@pytest.mark.parametrize("given, flags, env, message", [
    ("PLAN", ["seed=3"], {}, "fxswarm agent 2: --fault: expected either a resolved plan (--fault-plan) or --fault "
                             "flags, got both"),
    (None, None, {PLAN_ENV: "PLAN", FAULTS_ENV: "seed=3"},
     "fxswarm agent 2: FXSWARM_FAULTS: expected it when the compose file is written"),
    (None, ["partition 10"], {}, "fxswarm: --fault 'partition 10': expected 'partition START-END"),
    ("/nonexistent/plan.json", None, {}, "--fault-plan /nonexistent/plan.json: expected a fault plan file, cannot "
                                         "read it"),
])
def test_a_role_process_refuses_a_bad_or_ambiguous_plan_with_exit_2(rich, capsys, given, flags, env, message):
    sc, plan = rich
    text = dumps(plan, sc)
    given = text if given == "PLAN" else given
    env = {k: (text if v == "PLAN" else v) for k, v in env.items()}
    with pytest.raises(SystemExit) as exc:
        process_plan_or_exit(sc, given, flags, "fxswarm agent 2", env=env)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err
