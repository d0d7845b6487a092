"""``fxswarm campaign CONFIG --out DIR``: how much loss and delay a law survives, with statistics.

A grid fills fault templates (``--fault 'agent:*->agent:* drop={loss}' --grid loss=0,0.2``)
and scenario values (``--grid scenario.dt=0.01,0.005``); every cell runs under every law
(``--laws``) and ``--seeds`` fault seeds. Each run is the in-process simulator
(:class:`fxswarm.launch.sim.Simulation`, what ``fxswarm sim`` runs), judged against stated
criteria; runs go to local worker processes or a Dask scheduler
(:func:`fxswarm.study.parallel.completed`), and each finished run is appended to
``DIR/runs.jsonl`` at once with the ``fxswarm sim`` command line it equals
(:mod:`.campaign_store`). ``DIR/campaign.json`` has the statistics; ``fxswarm report DIR``
draws them. docs/campaigns.md is the user's page.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import time
import traceback
import warnings
from pathlib import Path

import numpy as np

from fxswarm.core.laws import registered_laws
from fxswarm.core.scenario import ScenarioError, ScenarioWarning, parse
from fxswarm.faults.plan import CLI_HELP as FAULT_HELP
from fxswarm.faults.plan import resolve
from fxswarm.faults.summary import LINK_COUNTS
from fxswarm.runtime.numbers import positive, positive_int
from fxswarm.runtime.output import prepare_run_folder
from fxswarm.study.campaign_plan import (
    CampaignError,
    Criteria,
    Plan,
    Run,
    cell_text,
    make_plan,
    parse_axis,
    write_scenarios,
)
from fxswarm.study.campaign_store import RunLog, campaign_document, claim_folder, read_runs, write_document
from fxswarm.study.parallel import DASK_PREFIX, WorkerLost, completed, start_workers_early

CONFIRM = "confirm.json"


# --- one run (in a worker) ---------------------------------------------------------------


def metrics(summary: dict) -> dict:
    """What a campaign keeps of a run's ``summary.json``."""
    faults = summary.get("faults") or {}
    links = faults.get("links") or {}
    out = {
        "min_distance_m": summary["min_object_distance_m"],
        "min_obstacle_distance_m": summary["min_obstacle_distance_m"],
        "formation_settle_s": summary["formation_settle_s"],
        "estimate_settle_s": summary["estimate_settle_s"],
        "formation_error_final_m": summary["formation_error_final_m"],
        "estimate_error_final_m": summary["estimate_error_final_m"],
        "max_formation_error_after_settle_m": summary.get("max_formation_error_after_settle_m"),
        "duration_s": summary["duration_s"],
        "messages": {k: sum(int(c.get(k, 0)) for c in links.values()) for k in LINK_COUNTS},
        "degraded_ticks": {name: sum(per.values()) for name, per in (faults.get("degraded_ticks") or {}).items()},
    }
    errors = (summary.get("law") or {}).get("errors") or {}
    out["law_errors"] = {robot: e["ticks"] for robot, e in errors.items()}  # ticks a law failed, per robot
    if errors:
        out["law_error_first"] = next(iter(errors.values()))["first"]
    return out


def outcome(summary: dict, criteria: Criteria) -> dict:
    """A run's success against ``criteria``, the criteria it failed, and its metrics."""
    m = metrics(summary)
    failed = []
    if m["min_distance_m"] is not None and m["min_distance_m"] <= criteria.min_distance_m:
        failed.append("collision")
    settle = m["formation_settle_s"]
    if settle is None or (criteria.settle_within_s is not None and settle > criteria.settle_within_s):
        failed.append("not_settled")
    if not m["formation_error_final_m"] < criteria.final_error_m:
        failed.append("final_error")
    if m["law_errors"]:  # a law that failed flew some ticks at zero: not the law's own result
        failed.append("law_error")
    return {"success": not failed, "failed": failed, "metrics": m}


def run_case(table: dict, source: str, faults: tuple[str, ...], criteria: dict) -> dict:
    """Run one campaign run as ``fxswarm sim SOURCE --fault ...`` would; never raises on the
    run's own failure: an exception becomes ``status = "error"`` with its message."""
    from fxswarm.launch.sim import Simulation  # imported in the worker

    start = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ScenarioWarning)
            sc = parse(table, source)
        summary = Simulation(sc, resolve(sc, list(faults)), path="auto").run()  # as fxswarm sim: batch when it can
        result = {"status": "done", "error": None} | outcome(summary, Criteria(**criteria))
    except Exception as exc:  # a law or a run that raises is a result, not the campaign's end
        result = {"status": "error", "error": f"{type(exc).__name__}: {exc}", "success": False, "failed": [],
                  "metrics": None, "traceback": "".join(traceback.format_exception(exc)[-3:])[-2000:]}
    result["wall_s"] = time.perf_counter() - start
    return result


def record_of(run: Run, fingerprint: str, result: dict) -> dict:
    """The ``runs.jsonl`` line of a finished run: what it was, how to replay it, what it gave."""
    return {"id": run.id, "campaign": fingerprint, "law": run.law, "cell": run.cell, "replicate": run.replicate,
            "seed": run.seed, "scenario": run.scenario, "faults": list(run.faults), "command": run.command,
            "argv": list(run.argv)} | result


# --- command line --------------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="scenario file (TOML)")
    p.add_argument("--out", default=None, help="campaign folder (default: runs/<scenario name>-campaign); "
                   "running again on it runs only the runs not done yet")
    p.add_argument("--fault", action="append", default=[], metavar="TEMPLATE",
                   help="a fault spec with {NAME} placeholders filled by --grid (repeatable); " + FAULT_HELP)
    p.add_argument("--grid", action="append", default=[], metavar="NAME=V1,V2,...",
                   help="an axis of the grid (repeatable): a --fault placeholder, or a scenario value as "
                        "table.key (e.g. scenario.dt=0.01,0.005); every combination is a cell")
    p.add_argument("--laws", default="", metavar="L1,L2,...",
                   help="laws to fly in every cell: any name a scenario's [controller] law takes (registered: "
                        f"{', '.join(sorted(registered_laws()))}; or module:Class, looked for beside the scenario "
                        "first); default: the scenario's own. Only the scenario's own law gets its [controller.params]")
    p.add_argument("--seeds", type=positive_int, default=1, metavar="N",
                   help="runs per cell and law, each with its own fault seed (default 1)")
    p.add_argument("--seed", type=int, default=0, help="the campaign's seed: every fault seed derives from it "
                   "and the cell (default 0)")
    p.add_argument("--workers", type=positive_int, default=None,
                   help="local worker processes (default: the machine's cores)")
    p.add_argument("--executor", default="local", metavar="local|dask://HOST:PORT",
                   help="where the runs go: local worker processes, or a Dask distributed scheduler")
    g = p.add_argument_group("success criteria (a run succeeds when it meets these three and its law never failed)")
    g.add_argument("--min-distance", type=positive, default=None, metavar="M",
                   help="no collision: the closest approach to any object stays above M m "
                        "(default: half the scenario's repulsive radius d)")
    g.add_argument("--settle-within", type=positive, default=None, metavar="S",
                   help="the formation settles (within the scenario's settle_tolerance) by S s "
                        "(default: within the run)")
    g.add_argument("--final-error", type=positive, default=None, metavar="M",
                   help="the final formation error is under M m (default: the scenario's settle_tolerance)")
    p.add_argument("--confirm", type=positive_int, default=None, metavar="K",
                   help="then run K runs drawn at random again as a distributed lock-step swarm over Zenoh "
                        "(`fxswarm run`) and report whether each equals its in-process run bit for bit")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def main(args: argparse.Namespace) -> int:
    from fxswarm.runtime.config import load_or_exit

    base = load_or_exit(args.config)
    if args.executor == "local" and local_workers(args) > 1:
        # The workers' fork server imports what a run needs while this process plans the runs.
        start_workers_early([__name__, "fxswarm.launch.sim"])
    criteria = Criteria(min_distance_m=args.min_distance or base.d / 2, settle_within_s=args.settle_within,
                        final_error_m=args.final_error or base.settle_tolerance)
    out = Path(args.out or f"runs/{base.name}-campaign")
    try:
        if args.executor != "local" and not args.executor.startswith(DASK_PREFIX):
            raise CampaignError(f"--executor: expected local or {DASK_PREFIX}HOST:PORT, got {args.executor!r}")
        laws = [x.strip() for x in args.laws.split(",") if x.strip()]
        plan = make_plan(args.config, base, out, list(args.fault), [parse_axis(a) for a in args.grid], laws,
                         args.seeds, args.seed, criteria)
        out = prepare_run_folder(out, "fxswarm campaign")
        claim_folder(out, plan)
        records = read_runs(out, plan.fingerprint)
        write_scenarios(plan)
    except (CampaignError, ScenarioError) as exc:
        print(f"fxswarm campaign: {exc}", file=sys.stderr)
        return 2
    code = run_campaign(plan, out, records, args)
    records = read_runs(out, plan.fingerprint)  # the file is the truth: a Ctrl-C may fall between write and dict
    doc = campaign_document(plan, records)
    path = write_document(out, doc)
    t = doc["totals"]
    print(f"fxswarm campaign: {t['runs']}/{t['planned']} runs, {t['successes']} succeeded, {t['errors']} errors; "
          f"wrote {path} (figures: fxswarm report {out})", file=sys.stderr)
    if code == 0 and t["errors"]:  # a run that could not run is no result: the campaign did not do its job
        print(f"fxswarm campaign: {t['errors']} of {t['runs']} runs errored (could not run; see 'error' in "
              f"{out / 'runs.jsonl'}): exit 1", file=sys.stderr)
        code = 1
    if code == 0 and args.confirm:
        code = confirm(plan, out, records, args.confirm, args.seed, quiet=args.quiet)
    return code


def run_campaign(plan: Plan, out: Path, records: dict[str, dict], args: argparse.Namespace) -> int:
    """Run the runs not in ``records`` yet, appending each to ``runs.jsonl`` (and ``records``)."""
    todo = [r for r in plan.runs if r.id not in records]
    workers = local_workers(args)
    where = args.executor if args.executor != "local" else f"{min(workers, max(len(todo), 1))} local workers"
    say = (lambda *a: None) if args.quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    say(f"fxswarm campaign: {len(plan.runs)} runs ({len(plan.laws)} laws x {len(plan.runs) // len(plan.laws)} "
        f"per law), {len(records)} already done, {len(todo)} to run on {where}")
    cases = [(plan.tables[r.scenario], r.scenario, r.faults, plan.criteria.as_dict()) for r in todo]
    log = RunLog(out)
    signal.signal(signal.SIGTERM, _interrupted)  # SIGTERM stops the workers too, like Ctrl-C
    start, done = time.monotonic(), 0
    try:
        executor = None if args.executor == "local" else args.executor
        for k, result in completed(run_case, cases, workers, executor, modules=[Path(m) for m in plan.files]):
            run = todo[k]
            record = record_of(run, plan.fingerprint, result)
            log.append(record)
            records[run.id] = record
            done += 1
            rate = done / max(time.monotonic() - start, 1e-9)
            verdict = "ok" if record["success"] else (f"error: {record['error']}" if record["status"] == "error"
                                                      else "failed: " + ",".join(record["failed"]))
            say(f"  [{len(records)}/{len(plan.runs)}] {rate * 60:.1f} runs/min, {(len(todo) - done) / rate:.0f} s "
                f"left   {run.law} {cell_text(run.cell)} #{run.replicate}: {verdict}")
        return 0
    except KeyboardInterrupt:
        print(f"\nfxswarm campaign: interrupted; {len(records)} finished runs are in {out / 'runs.jsonl'}: "
              "the same command runs the rest", file=sys.stderr)
        return 130
    except WorkerLost as exc:
        print(f"fxswarm campaign: {exc}; {len(records)} finished runs are in "
              f"{out / 'runs.jsonl'}: the same command runs the rest", file=sys.stderr)
        return 1
    except ValueError as exc:  # the executor could not be reached
        print(f"fxswarm campaign: {exc}", file=sys.stderr)
        return 2
    finally:
        log.close()
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def local_workers(args: argparse.Namespace) -> int:
    """``--workers``, else the machine's cores."""
    return args.workers or os.cpu_count() or 1


def _interrupted(signum, frame) -> None:
    raise KeyboardInterrupt


# --- --confirm: the same runs as a distributed lock-step swarm --------------------------------


def trajectory_differences(got: dict[str, np.ndarray], expected: dict[str, np.ndarray]) -> list[str]:
    """The arrays of two trajectories that are not bit for bit the same (a name in only one, another
    dtype, shape or any value), sorted."""
    return sorted(set(got) ^ set(expected)) + [
        key for key in sorted(set(got) & set(expected))
        if got[key].dtype != expected[key].dtype or not np.array_equal(got[key], expected[key])]


def confirm(plan: Plan, out: Path, records: dict[str, dict], k: int, seed: int, quiet: bool = False) -> int:
    """Run ``k`` finished runs, drawn with ``seed``, as ``fxswarm run --clock lockstep`` over Zenoh and
    compare each trajectory with the in-process simulator's, bit for bit; write ``confirm.json``.
    Returns 0 when every one is equal, else 1."""
    from fxswarm.launch.sim import Simulation
    from fxswarm.runtime.output import load_trajectory

    by_id = {r.id: r for r in plan.runs}
    done = sorted(i for i, r in records.items() if r["status"] == "done")
    chosen = random.Random(seed).sample(done, min(k, len(done)))
    results = []
    for run_id in chosen:
        run = by_id[run_id]
        folder = out / "confirm" / run_id
        argv = ["fxswarm", "run", run.scenario, *run.argv[3:run.argv.index("--quiet")], "--clock", "lockstep",
                "--no-logger", "--quiet", "--out", str(folder)]
        proc = subprocess.run([sys.executable, "-m", "fxswarm.cli", *argv[1:]], stdin=subprocess.DEVNULL,
                              capture_output=True, text=True)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ScenarioWarning)
            sc = parse(plan.tables[run.scenario], run.scenario)
        sim = Simulation(sc, resolve(sc, list(run.faults)))
        sim.run()
        expected = sim.trajectory()
        differs = trajectory_differences(load_trajectory(folder), expected) if proc.returncode == 0 \
            else ["(no trajectory)"]
        entry = {"id": run_id, "law": run.law, "cell": run.cell, "replicate": run.replicate,
                 "command": " ".join(argv), "exit_code": proc.returncode, "equal": not differs, "differs": differs}
        if proc.returncode != 0:
            entry["stderr"] = proc.stderr[-2000:]
        results.append(entry)
        if not quiet:
            print(f"  confirm {run.law} {cell_text(run.cell)} #{run.replicate}: "
                  + ("bit for bit equal" if not differs else f"DIFFERS in {', '.join(differs)}"), file=sys.stderr)
    path = out / CONFIRM
    path.write_text(json.dumps({"runs": results, "equal": sum(r["equal"] for r in results),
                                "confirmed": len(results)}, indent=2) + "\n")
    print(f"fxswarm campaign: --confirm: {sum(r['equal'] for r in results)}/{len(results)} lock-step runs equal "
          f"their in-process runs bit for bit; wrote {path}", file=sys.stderr)
    return 0 if all(r["equal"] for r in results) else 1
