"""Robustness sweep: paper-fast under iid loss (0-60 %) and delay (0-200 ms) on every estimate link.

For each delay compensation (``[controller] delay_compensation``: "leader-velocity", the default,
and "none", the paper's law on held values) and each (drop, delay) point, two in-memory lock-step
runs with the same seed:
  * links only: final formation and estimate error, the largest error after the formation
    first settled, min distance to any object, settle time;
  * links + agent 2 killed at 10 s and restarted at 12 s (fresh state): recovery_s, the time
    after the restart until robot 2 is back under the settle tolerance (None: never, which is
    the case whenever the delay alone keeps the formation above it), and recovery_excess_s,
    the time until robot 2's error is back within the tolerance of its error in the same run
    without the crash (the crash's own cost, separate from what the links cost everyone).
Writes plot-ready JSON to benchmarks/studies/results/faults.json: axes, then per compensation one 2-D grid
per metric (rows: drop, columns: delay), and the raw rows.

    .venv/bin/python benchmarks/studies/bench_faults.py [--quick] [--workers 2] [--compensation NAME]
"""

from __future__ import annotations

import argparse
import sys
import json
import os
import time
import tomllib
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from fxswarm.core.scenario import DELAY_COMPENSATIONS

# The maintained benchmarks this study imports (bench_io, ...) sit one folder up.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench_io import machine, write_json  # a sibling script

ROOT = Path(__file__).resolve().parents[2]
BASE = ROOT / "configs" / "paper-fast.toml"
DROPS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6)
DELAYS = (0.0, 0.05, 0.1, 0.15, 0.2)  # s
CRASH = {"target": "agent:2", "kill": 10.0, "restart": 12.0}
SEED = 7


def one_point(args: tuple[str, float, float]) -> dict:
    from fxswarm.core.metrics import formation_errors, settle_time
    from fxswarm.core.scenario import parse
    from fxswarm.launch.sim import Simulation

    compensation, drop, delay = args
    data = tomllib.loads(BASE.read_text())
    data.setdefault("controller", {})["delay_compensation"] = compensation
    link = {"link": "agent:*->agent:*", "kinds": ["estimate"], "drop": drop, "delay": delay}
    row = {"delay_compensation": compensation, "drop": drop, "delay_s": delay}
    for crash in (False, True):
        data["faults"] = {"seed": SEED, "links": [link], **({"processes": [CRASH]} if crash else {})}
        sc = parse(data, f"{BASE.name} {compensation} drop={drop} delay={delay}{' crash' if crash else ''}")
        start = time.perf_counter()
        sim = Simulation(sc)
        s = sim.run()
        wall = time.perf_counter() - start
        err = formation_errors(sim.trajectory())[:, 1]  # robot 2
        if crash:
            row["recovery_s"] = s["faults"]["recoveries"][0]["recovery_s"]
            t = sim.trajectory()["t"]
            after = t >= CRASH["restart"] - 1e-9
            back = settle_time(t[after], np.abs(err - err_links)[after], sc.settle_tolerance)
            row["recovery_excess_s"] = None if back is None else round(back - CRASH["restart"], 6)
            row["crash_formation_error_final_m"] = s["formation_error_final_m"]
        else:
            err_links = err
            row.update(formation_error_final_m=s["formation_error_final_m"],
                       estimate_error_final_m=s["estimate_error_final_m"],
                       max_formation_error_after_settle_m=s["max_formation_error_after_settle_m"],
                       min_object_distance_m=s["min_object_distance_m"],
                       formation_settle_s=s["formation_settle_s"],
                       dropped=sum(v["dropped"] for v in s["faults"]["links"].values()),
                       wall_s=round(wall, 2))
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="a 3 x 3 grid (drop 0/0.3/0.6, delay 0/0.1/0.2)")
    p.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    p.add_argument("--compensation", choices=DELAY_COMPENSATIONS, action="append",
                   help="only this delay compensation (repeatable; default: all)")
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "studies" / "results" / "faults.json"))
    args = p.parse_args()
    drops = (0.0, 0.3, 0.6) if args.quick else DROPS
    delays = (0.0, 0.1, 0.2) if args.quick else DELAYS
    compensations = tuple(args.compensation or DELAY_COMPENSATIONS)
    points = [(c, d, t) for c in compensations for d in drops for t in delays]
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(pool.map(one_point, points))
    metrics = ("formation_error_final_m", "estimate_error_final_m", "max_formation_error_after_settle_m",
               "min_object_distance_m", "formation_settle_s", "recovery_s", "recovery_excess_s")
    grid = {c: {m: [[next(r[m] for r in rows if r["delay_compensation"] == c and r["drop"] == d and r["delay_s"] == t)
                     for t in delays] for d in drops] for m in metrics}
            for c in compensations}
    result = {
        "benchmark": "faults",
        "scenario": str(BASE.relative_to(ROOT)),
        "what": "iid drop and fixed delay on every agent->agent estimate link; lock-step, in-memory; "
                "recovery_s: after agent 2 is killed at 10 s and restarted at 12 s",
        "seed": SEED,
        "settle_tolerance_m": 0.2,
        "axes": {"delay_compensation": list(compensations), "drop": list(drops), "delay_s": list(delays)},
        "grid": grid,
        "rows": rows,
        "machine": machine(),
        "wall_s": round(time.perf_counter() - start, 1),
    }
    out = Path(args.out)
    write_json(out, result)
    print(json.dumps({"axes": result["axes"], "grid": grid}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
