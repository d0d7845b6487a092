"""summary.json has one builder: the same inputs give the same summary whichever runner calls it
(``fxswarm sim`` in one process; the world process and the launcher of ``fxswarm run`` or compose)."""

from __future__ import annotations

import dataclasses
import json
import os
import time
from pathlib import Path

import pytest

from fxswarm.core.scenario import load
from fxswarm.faults.plan import resolve
from fxswarm.faults.summary import add_processes, build_summary, merged_links
from fxswarm.launch.sim import Simulation
from fxswarm.runtime.output import read_process_counters

ROOT = Path(__file__).resolve().parents[2]

#: The keys users and tests read (as `fxswarm sim` wrote them before the builder was shared).
COMMON_KEYS = {"scenario", "source", "robots", "ticks", "dt", "duration_s", "wall_s", "min_object_distance_m",
               "min_obstacle_distance_m", "formation_error_final_m", "estimate_error_final_m", "formation_settle_s",
               "estimate_settle_s", "settle_tolerance_m", "avoidance_episodes", "fixed_time_bounds_s",
               "max_formation_error_after_settle_m", "faults", "degraded", "router_outages", "law"}
FAULT_KEYS = {"seed", "links", "recoveries", "degraded_ticks", "restarts"}


@pytest.fixture(scope="module")
def lossy_run():
    """2.5 s of paper-fast with lossy, late links, a partition and a crash (robot 2 at 1 s, back at 1.5 s)."""
    sc = load(ROOT / "configs" / "paper-fast.toml")
    sc = dataclasses.replace(sc, duration=2.5)
    plan = resolve(sc, ["agent:*->agent:* drop=0.2 delay=0.03", "partition 0.5-1 isolate=3",
                        "kill agent:2 at=1 restart=1.5"])
    sim = Simulation(sc, plan)
    summary = sim.run()
    return sc, plan, sim, summary


def per_receiver(links: dict[str, dict[str, int]]) -> dict[str, dict]:
    """The in-process per-link counts split as each role process would count its own inbox."""
    out: dict[str, dict] = {}
    for key, counts in links.items():
        receiver = key.split("/")[0].split("->")[1]
        name = "world-0" if receiver == "world" else receiver.replace(":", "-")
        out.setdefault(name, {"role": name.split("-")[0], "links": {}})["links"][key] = counts
    return out


def test_the_simulator_summary_is_the_builders_with_its_own_facts(lossy_run):
    sc, plan, sim, summary = lossy_run
    assert COMMON_KEYS <= set(summary) and FAULT_KEYS <= set(summary["faults"])
    # the simulator's own facts (path: which path stepped it, fxswarm.launch.batch)
    assert set(summary) - COMMON_KEYS == {"counters", "speed_limited_ticks", "path", "path_reason"}
    runner = {k: summary[k] for k in ("counters", "speed_limited_ticks", "path", "path_reason")}
    again = build_summary(sc, sim.trajectory(), plan, wall_s=summary["wall_s"], world=sim.world,
                          links=sim.faults.link_counts(), restarts=sim.faults.restarts(), runner=runner)
    assert json.dumps(again) == json.dumps(summary)  # same keys, same values, same order
    assert summary["faults"]["restarts"] == {"agent:2": 1}
    assert sum(c["dropped"] for c in summary["faults"]["links"].values()) > 0


def test_the_process_runners_summary_equals_the_simulators_on_the_same_inputs(lossy_run, tmp_path):
    """The world process builds from the processes' counters files; the launcher then adds every
    process's counters and the process faults it sent: all but the runners' own facts is sim's."""
    sc, plan, sim, sim_summary = lossy_run
    processes = per_receiver(sim_summary["faults"]["links"])
    world_runner = {"clock": "lockstep", "speed": None, "complete": True, "missed_ticks": 0,
                    "missed_ticks_per_robot": {str(r.id): 0 for r in sc.robots}}
    # The world process: the counters the others wrote before it left (here, all but agent 6).
    early = {k: v for k, v in processes.items() if k != "agent-6"}
    world_summary = build_summary(sc, sim.trajectory(), plan, wall_s=sim_summary["wall_s"], world=sim.world,
                                  runner=world_runner, processes=early)
    assert world_summary["faults"]["links"] != sim_summary["faults"]["links"]  # agent 6's inbox still missing
    # The launcher, once every process has stopped: the summary as the world wrote it, re-read.
    events = [{"action": "kill", "target": "agent:2", "t_s": 1.0}, {"action": "restart", "target": "agent:2", "t_s": 1.5}]
    run_summary = add_processes(json.loads(json.dumps(world_summary)), processes, events)
    run_summary["launcher"] = {"topology": "mesh"}

    def common(s: dict) -> dict:
        out = {k: v for k, v in s.items() if k in COMMON_KEYS}
        out["faults"] = {k: v for k, v in s["faults"].items() if k in FAULT_KEYS}
        return json.loads(json.dumps(out))

    assert common(run_summary) == common(sim_summary)
    assert set(run_summary) - COMMON_KEYS == set(world_runner) | {"processes", "launcher"}
    assert run_summary["faults"]["process_events"] == events
    assert run_summary["processes"] == processes


def test_merged_links_sum_every_process_inbox():
    processes = {"agent-1": {"links": {"agent:2->agent:1/estimate": {"delivered": 3, "dropped": 1}}},
                 "agent-2": {"links": {"agent:1->agent:2/estimate": {"delivered": 2, "delayed": 2, "duplicated": 1}}},
                 "world-0": {"stop_reason": "done"}}
    assert merged_links(processes) == {
        "agent:1->agent:2/estimate": {"delivered": 2, "dropped": 0, "delayed": 2, "duplicated": 1},
        "agent:2->agent:1/estimate": {"delivered": 3, "dropped": 1, "delayed": 0, "duplicated": 0},
    }


def test_a_reused_run_folder_gives_only_this_runs_counters(tmp_path):
    folder = tmp_path / "processes"
    folder.mkdir()
    (folder / "agent-1.json").write_text('{"role": "agent"}')
    (folder / "agent-2.json").write_text('{"role": "agent"}')
    old = time.time() - 60
    os.utime(folder / "agent-2.json", (old, old))  # an earlier run's
    (folder / "world-0.json").write_text("{not json")  # half written: skipped, not fatal
    assert set(read_process_counters(tmp_path)) == {"agent-1", "agent-2"}
    assert set(read_process_counters(tmp_path, since=time.time() - 30)) == {"agent-1"}
