"""`fxswarm campaign`'s pieces in one process: the plan, the law selection, the folder, the
statistics, the success criteria, and a run that raises recorded rather than fatal."""

from __future__ import annotations

import argparse
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fxswarm.core.scenario import ScenarioError, load, parse
from fxswarm.core.tomltext import dump_toml
from fxswarm.study import campaign
from fxswarm.study.campaign_plan import (
    CampaignError,
    Criteria,
    fault_seed,
    make_plan,
    parse_axis,
    scenario_table_with_law,
)
from fxswarm.study.campaign_store import RUNS, claim_folder, read_runs, wilson_interval

from support import PAPER_FAST

TETHER = Path(__file__).resolve().parents[2] / "configs" / "examples" / "tether" / "tether.toml"

CRITERIA = Criteria(min_distance_m=1.0, settle_within_s=None, final_error_m=0.2)
TEMPLATE = "agent:*->agent:* drop={loss} delay={delay}"


def plan_of(tmp_path: Path, grid=("loss=0,0.2", "delay=0,0.1"), laws=("fixed-time", "asymptotic"), seeds=2,
            templates=(TEMPLATE,), seed=0, criteria=CRITERIA):
    return make_plan(str(PAPER_FAST), load(PAPER_FAST), tmp_path, list(templates), [parse_axis(g) for g in grid],
                     list(laws), seeds, seed, criteria)


def test_the_plan_is_every_cell_law_and_seed_with_its_command_line(tmp_path):
    plan = plan_of(tmp_path)
    assert len(plan.runs) == 2 * 2 * 2 * 2
    assert len({r.id for r in plan.runs}) == len(plan.runs)
    run = next(r for r in plan.runs if r.law == "asymptotic" and r.cell == {"loss": 0.2, "delay": 0.1}
               and r.replicate == 1)
    assert run.faults == ("agent:*->agent:* drop=0.2 delay=0.1", f"seed={run.seed}")
    assert run.argv[:3] == ("fxswarm", "sim", run.scenario) and run.argv[-3:] == (
        "--quiet", "--out", str(tmp_path / "replay" / run.id))
    assert "--fault 'agent:*->agent:* drop=0.2 delay=0.1'" in run.command
    # The run's scenario flies its law through the law API: [controller] law, and the parsed
    # scenario has the asymptotic family's exponents (derived by the law API, as sweep --variants does).
    table = plan.tables[run.scenario]
    assert table["controller"]["law"] == "asymptotic" and "variant" not in table["controller"]
    sc = parse(table, run.scenario)
    assert sc.law == "asymptotic" and sc.variant == "asymptotic" and sc.law_params == {}


def test_fault_seeds_derive_from_the_campaign_seed_and_the_cell_and_are_paired_across_laws(tmp_path):
    plan = plan_of(tmp_path)
    by = {(r.law, tuple(r.cell.items()), r.replicate): r.seed for r in plan.runs}
    cells = {k[1:] for k in by}
    for cell in cells:
        assert by[("fixed-time", *cell)] == by[("asymptotic", *cell)]  # same faults for every law
    assert len({by[("fixed-time", *c)] for c in cells}) == len(cells)  # every cell and replicate its own
    again = plan_of(tmp_path)
    assert [r.seed for r in again.runs] == [r.seed for r in plan.runs]  # reproducible
    other = plan_of(tmp_path, seed=1)
    assert {r.seed for r in other.runs}.isdisjoint({r.seed for r in plan.runs})
    assert fault_seed(0, {"loss": 0.2}, 0) != fault_seed(0, {"loss": 0.2}, 1)


def test_a_scenario_axis_sets_that_value_in_each_runs_scenario(tmp_path):
    plan = plan_of(tmp_path, grid=("loss=0", "delay=0", "scenario.dt=0.01,0.02"), laws=())
    dts = sorted(plan.tables[r.scenario]["scenario"]["dt"] for r in plan.runs)
    assert dts == [0.01, 0.01, 0.02, 0.02]
    assert plan.laws == ("fixed-time",)  # the scenario's own law by default
    assert all(r.law == "fixed-time" for r in plan.runs)


@pytest.mark.parametrize("grid,templates,match", [
    (("loss=0,0.2",), (TEMPLATE,), r"placeholders \['delay'\] have no --grid axis"),
    (("loss=0", "delay=0", "speed=1"), (TEMPLATE,), r"axes \['speed'\] fill no --fault placeholder"),
    (("loss=0", "delay=0", "scenario.dt=-1"), (TEMPLATE,), r"scenario\.dt: expected a number > 0"),
    (("loss=2", "delay=0"), (TEMPLATE,), r"cell loss=2 delay=0: .*drop.*expected a probability"),
    (("loss",), ("agent:*->agent:* drop={loss}",), r"--grid 'loss': expected NAME=V1,V2"),
])
def test_a_wrong_grid_or_template_is_refused_before_any_run_naming_it(tmp_path, grid, templates, match):
    with pytest.raises((CampaignError, ScenarioError), match=match):
        plan_of(tmp_path, grid=grid, templates=templates)


def test_law_selection_maps_builtins_onto_the_variants_and_a_user_law_onto_controller_law():
    base = load(PAPER_FAST)
    for name in ("fixed-time", "asymptotic", "finite-time"):
        sc = parse(scenario_table_with_law(base, name), "x.toml")
        assert sc.variant == name and sc.estimator_variant == name
    tether = load(TETHER)
    user = scenario_table_with_law(base, "fxswarm.core.paper_law:BehaviouralLaw")
    assert user["controller"]["law"] == "fxswarm.core.paper_law:BehaviouralLaw" and "controller" not in base.raw
    with pytest.raises(CampaignError, match=r"--laws 'no such law': 'no such law' is neither a registered law"):
        scenario_table_with_law(base, "no such law")
    with pytest.raises(CampaignError, match=r"--laws 'nolaw:Nothing': cannot import 'nolaw'"):
        scenario_table_with_law(tether, "nolaw:Nothing")


def test_any_name_the_scenario_takes_is_accepted_and_runs_are_labelled_with_the_scenarios_own_law_name(tmp_path):
    """A law registered under its own module:Class name is taken (no pattern on names), and a
    scenario flying fixed-time with feedforward tracking is labelled so, not 'fixed-time'."""
    table = dict(load(PAPER_FAST).raw, estimator={"tracking": "feedforward"})
    config = tmp_path / "ff.toml"
    config.write_text(dump_toml(table))
    plan = make_plan(str(config), load(config), tmp_path / "c", [], [], [], 1, 0, CRITERIA)
    assert plan.laws == ("fixed-time+feedforward",) and {r.law for r in plan.runs} == {"fixed-time+feedforward"}
    plan = make_plan(str(config), load(config), tmp_path / "d", [], [],
                     ["fxswarm.core.paper_law:BehaviouralLaw", "fixed-time+feedforward"], 1, 0, CRITERIA)
    assert plan.laws == ("fxswarm.core.paper_law:BehaviouralLaw", "fixed-time+feedforward")


def test_only_the_scenarios_own_law_gets_its_controller_params(tmp_path):
    """The tether example against the paper's law in one campaign (docs/controllers.md's workflow):
    tether keeps its [controller.params], fixed-time gets none, and both fly."""
    out = tmp_path / "c"
    args = campaign_args(TETHER, out, laws="tether:Tether,fixed-time")
    assert campaign.main(args) == 0
    records = [json.loads(line) for line in (out / RUNS).read_text().splitlines()]
    assert sorted({r["law"] for r in records}) == ["fixed-time", "tether:Tether"] and len(records) == 8
    assert all(r["status"] == "done" and not r["metrics"]["law_errors"] for r in records), records
    tables = {r["law"]: tomllib.loads(Path(r["scenario"]).read_text()) for r in records}
    assert tables["tether:Tether"]["controller"]["params"] == load(TETHER).raw["controller"]["params"]
    assert "params" not in tables["fixed-time"]["controller"]
    # The tether module went with the scenarios (so a worker in any folder imports it).
    assert (out / "scenarios" / "tether.py").read_bytes() == (TETHER.parent / "tether.py").read_bytes()


def test_a_folder_holding_another_campaign_is_refused_naming_the_difference(tmp_path):
    claim_folder(tmp_path, plan_of(tmp_path))
    claim_folder(tmp_path, plan_of(tmp_path))  # the same campaign: taken up again
    with pytest.raises(CampaignError, match=r"another campaign's runs \(seeds: this folder's 2, this command's 3\)"):
        claim_folder(tmp_path, plan_of(tmp_path, seeds=3))


def test_reading_the_runs_cuts_a_torn_last_line_and_refuses_another_campaigns(tmp_path):
    path = tmp_path / RUNS
    whole = json.dumps({"id": "a", "campaign": "f1"}) + "\n"
    path.write_text(whole + '{"id": "b", "camp')
    assert list(read_runs(tmp_path, "f1")) == ["a"]
    assert path.read_text() == whole  # the torn line is gone: appending starts on a fresh line
    path.write_text(whole + json.dumps({"id": "c", "campaign": "f2"}) + "\n")
    with pytest.raises(CampaignError, match=r"runs.jsonl:2: a run of another campaign"):
        read_runs(tmp_path, "f1")


def test_wilson_interval():
    lo, hi = wilson_interval(5, 10)
    assert lo == pytest.approx(0.2366, abs=1e-4) and hi == pytest.approx(0.7634, abs=1e-4)
    lo, hi = wilson_interval(0, 4)
    assert lo == pytest.approx(0.0, abs=1e-12) and hi == pytest.approx(0.4899, abs=1e-4)
    assert wilson_interval(0, 0) is None


@pytest.mark.parametrize("confidence", [0.95, 0.8, 0.99])
def test_wilson_interval_is_scipys(confidence):
    """The closed form (with the standard library's normal quantile) against scipy's own, every
    success count of every run count up to 20."""
    from scipy.stats import binomtest

    for runs in range(1, 21):
        for successes in range(runs + 1):
            ci = binomtest(successes, runs).proportion_ci(confidence_level=confidence, method="wilson")
            assert wilson_interval(successes, runs, confidence) == pytest.approx((ci.low, ci.high), abs=1e-12), \
                (successes, runs)


def summary_like(**over) -> dict:
    s = {"min_object_distance_m": 1.9, "min_obstacle_distance_m": 2.5, "formation_settle_s": 10.0,
         "estimate_settle_s": 5.0, "formation_error_final_m": 0.1, "estimate_error_final_m": 0.05,
         "duration_s": 20.0, "faults": {"links": {"1->2/estimate": {"delivered": 5, "dropped": 2}},
                                        "degraded_ticks": {"no_leader": {"1": 3, "4": 2}}}}
    return s | over


def test_each_success_criterion_fails_a_run_on_its_own():
    assert campaign.outcome(summary_like(), CRITERIA)["success"]
    cases = {"collision": {"min_object_distance_m": 0.9}, "not_settled": {"formation_settle_s": None},
             "final_error": {"formation_error_final_m": 0.25}}
    for name, over in cases.items():
        out = campaign.outcome(summary_like(**over), CRITERIA)
        assert not out["success"] and out["failed"] == [name], name
    late = Criteria(1.0, settle_within_s=8.0, final_error_m=0.2)
    assert campaign.outcome(summary_like(), late)["failed"] == ["not_settled"]
    m = campaign.outcome(summary_like(), CRITERIA)["metrics"]
    assert m["messages"]["dropped"] == 2 and m["degraded_ticks"] == {"no_leader": 5}


def test_trajectory_differences_names_every_array_that_differs():
    a = {"p": np.zeros((3, 2)), "t": np.arange(3.0)}
    assert campaign.trajectory_differences(a, {k: v.copy() for k, v in a.items()}) == []
    b = {"p": np.zeros((3, 2)), "t": np.arange(3.0) + 1e-15, "extra": np.zeros(1)}
    assert campaign.trajectory_differences(b, a) == ["extra", "t"]
    assert campaign.trajectory_differences({"p": a["p"].astype(np.float32), "t": a["t"]}, a) == ["p"]


def campaign_args(config, out, **over) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    campaign.add_arguments(parser)
    argv = [str(config), "--out", str(out), "--fault", "agent:*->agent:* drop={loss}", "--grid", "loss=0,0.3",
            "--grid", "scenario.duration=0.5", "--seeds", "2", "--workers", "1", "--quiet"]
    for key, value in over.items():
        argv += [f"--{key.replace('_', '-')}", str(value)]
    return parser.parse_args(argv)


def test_a_run_that_raises_is_recorded_with_its_error_counted_and_the_campaign_goes_on_to_exit_1(tmp_path, monkeypatch,
                                                                                                 capsys):
    from fxswarm.launch.sim import Simulation

    real_run = Simulation.run
    bad_seed = make_plan(str(PAPER_FAST), load(PAPER_FAST), tmp_path / "c", ["agent:*->agent:* drop={loss}"],
                         [parse_axis("loss=0,0.3"), parse_axis("scenario.duration=0.5")], [], 2, 0,
                         CRITERIA).runs[3].seed

    def run(self, progress=None):  # one run's law blows up half-way, as a user's law might
        if self.plan.seed == bad_seed:
            raise ZeroDivisionError("the law divided by zero")
        return real_run(self, progress)

    monkeypatch.setattr(Simulation, "run", run)
    # Every run is recorded; the one that could not run makes the campaign's exit status 1.
    assert campaign.main(campaign_args(PAPER_FAST, tmp_path / "c", min_distance=1.0)) == 1
    assert "fxswarm campaign: 1 of 4 runs errored" in capsys.readouterr().err
    lines = (tmp_path / "c" / RUNS).read_text().splitlines()
    records = [json.loads(line) for line in lines]
    assert len(records) == 4
    bad = [r for r in records if r["status"] == "error"]
    assert len(bad) == 1 and bad[0]["seed"] == bad_seed and not bad[0]["success"]
    assert bad[0]["error"] == "ZeroDivisionError: the law divided by zero"
    doc = json.loads((tmp_path / "c" / "campaign.json").read_text())
    assert doc["totals"] == {"planned": 4, "runs": 4, "successes": 0, "errors": 1}
    cell = next(c for c in doc["cells"] if c["errors"])
    assert cell["runs"] == 2 and cell["error_messages"] == ["ZeroDivisionError: the law divided by zero"]
    assert doc["complete"]


LAW = '''
class Raising:
    """A user's law that raises once the run is under way."""

    def __init__(self, params, robot_id, scenario):
        self.robot_id = robot_id

    def estimate_rate(self, view):
        return (0.0, 0.0, 0.0)

    def velocity(self, view, estimate_rate):
        if view.t > 0.2:
            raise RuntimeError("the law gave up")
        return (0.0, 0.0, 0.0)
'''


def test_a_cell_whose_user_law_raises_is_recorded_and_counted_not_fatal(tmp_path):
    """With the law API, a law that raises is flagged per tick (law_error) and the run goes on:
    the campaign records its runs, counts them as failures, and flies the other law as usual."""
    config = tmp_path / "paper-fast.toml"
    config.write_text(Path(PAPER_FAST).read_text())
    (tmp_path / "raising.py").write_text(LAW)
    out = tmp_path / "c"
    assert campaign.main(campaign_args(config, out, laws="fixed-time,raising:Raising")) == 0
    records = [json.loads(line) for line in (out / RUNS).read_text().splitlines()]
    assert len(records) == 8
    doc = json.loads((out / "campaign.json").read_text())
    raising = [c for c in doc["cells"] if c["law"] == "raising:Raising"]
    assert [c["runs"] for c in raising] == [2, 2] and all(c["successes"] == 0 for c in raising)
    raised = [r for r in records if r["law"] == "raising:Raising"]
    assert all(r["status"] == "done" and "law_error" in r["failed"] and r["metrics"]["law_errors"]
               and "the law gave up" in r["metrics"]["law_error_first"] for r in raised)
    assert not any(r["metrics"]["law_errors"] for r in records if r["law"] == "fixed-time")
