"""Campaign throughput: a campaign's wall time against the sum of its runs' single-process times
divided by the workers (the floor a perfect pool would reach).

    .venv/bin/python benchmarks/bench_campaign.py [--workers 1,2] [--repeats 2] [--duration 20] [--seeds 2,9]
        [--out benchmarks/results/campaign.json]

A (campaign): ``fxswarm campaign configs/paper-fast.toml`` as a user runs it (a fresh process
and a fresh folder: planning, worker start-up, each run appended to runs.jsonl), over
loss 0,0.2,0.4,0.6 x laws fixed-time,asymptotic x N seeds (8 N runs: 16 and 72, the size of
docs/campaigns.md's campaign), ``--grid scenario.duration=D``. B (floor): the same runs one
after the other in this process (:func:`fxswarm.study.campaign.run_case`, what a worker calls),
their times summed and divided by the workers. Interleaved A B A B per worker count; overhead = A / B - 1. On a shared machine
two workers also slow each other (the floor assumes perfect scaling): ``in_campaign_runs_s`` is
the sum of the runs' own times inside the campaign, divided by the workers, to tell the pool's
cost from the machine's. ``extra_s`` = A - B: a fixed cost (process and pool start-up, the
summary) stays the same at both sizes, a per-run cost grows with the runs.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_io import machine, write_json  # a sibling script

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "paper-fast.toml"
FAULT = "agent:*->agent:* drop={loss}"
LOSSES = "0,0.2,0.4,0.6"
LAWS = "fixed-time,asymptotic"


def campaign_argv(out: Path, workers: int, duration: float, seeds: int) -> list[str]:
    return [sys.executable, "-m", "fxswarm.cli", "campaign", str(CONFIG), "--out", str(out), "--fault", FAULT,
            "--grid", f"loss={LOSSES}", "--grid", f"scenario.duration={duration:g}", "--laws", LAWS,
            "--seeds", str(seeds), "--workers", str(workers), "--quiet"]


def time_campaign(workers: int, duration: float, seeds: int) -> dict:
    folder = Path(tempfile.mkdtemp(prefix="bench-campaign-"))
    try:
        start = time.perf_counter()
        subprocess.run(campaign_argv(folder / "c", workers, duration, seeds), check=True, stdin=subprocess.DEVNULL,
                       capture_output=True)
        wall = time.perf_counter() - start
        runs = [json.loads(line) for line in (folder / "c" / "runs.jsonl").read_text().splitlines()]
        return {"wall_s": wall, "runs": len(runs), "in_campaign_runs_s": sum(r["wall_s"] for r in runs) / workers}
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def time_floor(workers: int, duration: float, seeds: int) -> dict:
    """The same runs, each alone in this process, one after the other."""
    from fxswarm.core.scenario import load
    from fxswarm.study.campaign import run_case
    from fxswarm.study.campaign_plan import Criteria, make_plan, parse_axis

    base = load(CONFIG)
    folder = Path(tempfile.mkdtemp(prefix="bench-floor-"))
    try:
        plan = make_plan(str(CONFIG), base, folder, [FAULT], [parse_axis(f"loss={LOSSES}"),
                         parse_axis(f"scenario.duration={duration:g}")], LAWS.split(","), seeds, 0,
                         Criteria(base.d / 2, None, base.settle_tolerance))
        times = []
        for run in plan.runs:
            start = time.perf_counter()
            run_case(plan.tables[run.scenario], run.scenario, run.faults, plan.criteria.as_dict())
            times.append(time.perf_counter() - start)
        return {"sum_s": sum(times), "floor_s": sum(times) / workers, "runs": len(times)}
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--workers", default="1,2")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--duration", type=float, default=20.0)
    p.add_argument("--seeds", default="2,9", help="replicates per cell and law, one row per value")
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "campaign.json"))
    args = p.parse_args()
    rows = []
    for workers in [int(w) for w in args.workers.split(",")]:
        for seeds in [int(n) for n in args.seeds.split(",")]:
            pairs = []
            for _ in range(args.repeats):  # A B A B
                a = time_campaign(workers, args.duration, seeds)
                b = time_floor(workers, args.duration, seeds)
                pairs.append({"campaign": a, "floor": b, "overhead": a["wall_s"] / b["floor_s"] - 1.0,
                              "extra_s": a["wall_s"] - b["floor_s"], "load_avg": round(os.getloadavg()[0], 2)})
                print(f"workers {workers}, {a['runs']} runs: campaign {a['wall_s']:.2f} s, floor {b['floor_s']:.2f} s "
                      f"(runs in the campaign {a['in_campaign_runs_s']:.2f} s), overhead {pairs[-1]['overhead']:+.1%} "
                      f"({pairs[-1]['extra_s']:+.2f} s)", file=sys.stderr)
            overheads = sorted(p_["overhead"] for p_ in pairs)  # of two middle ones, the worse
            rows.append({"workers": workers, "runs": pairs[0]["campaign"]["runs"], "seeds": seeds, "pairs": pairs,
                         "overhead_median": overheads[len(overheads) // 2], "goal": "overhead under 10 %"})
    write_json(args.out, {"benchmark": "campaign throughput", "command": " ".join(sys.argv),
                          "config": str(CONFIG.relative_to(ROOT)), "fault": FAULT, "losses": LOSSES, "laws": LAWS,
                          "duration_s": args.duration, "machine": machine(), "rows": rows})
    print(f"wrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
