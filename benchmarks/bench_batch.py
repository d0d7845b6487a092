"""Robot-ticks per second of ``fxswarm sim``: the per-robot path against the batch path.

    python benchmarks/bench_batch.py [--sizes 10,100,1000,10000] [--ticks 200] [--repeat 2]
        [--per-robot-ticks 10000:5,1000:20] [--out benchmarks/results/batch.json]

Each size N is a generated swarm (:func:`swarm_raw`: a grid 2 m apart, a 4-nearest graph,
5 % pinned, a seeded 6 m start box, 4 static obstacles, dt = 0.01 s, no faults), run in this
process by :class:`fxswarm.launch.sim.Simulation` on each path, interleaved (A B A B) ``--repeat``
times. robot-ticks/s = N x ticks / ``summary.json`` ``wall_s`` (the stepping time: building the
scenario and the nodes is not in it). Large N per robot costs minutes a run, so it may run
fewer ticks (``--per-robot-ticks N:T``): its figure is then an estimate from those ticks, marked
``estimated_from_ticks``. ``real_time_factor``: simulated s per wall s (at or above 1: real time).
``peak_rss_mb_so_far``: the process's peak resident memory after the size (ascending sizes: the
largest's peak); ``weight_graph_mb``: the scenario's weights (by rows, :class:`fxswarm.core.graph.SparseGraph`) within it.
Where both paths ran the same ticks their trajectories are compared (``bit_equal``).
"""

from __future__ import annotations

import argparse
import dataclasses
import resource
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_io import machine, write_json  # noqa: E402

DT = 0.01


def swarm_raw(n: int, ticks: int) -> dict:
    return {
        "scenario": {"name": f"bench-{n}", "duration": ticks * DT, "dt": DT, "d": 1.0, "seed": 1},
        "gains": {"b1": 0.6, "b2": 0.6, "r0": 0.9, "r1": 1.2, "r2": 0.6, "lam_f": 1.0, "lam_o": 1.0,
                  "K1": 0.4, "K2": 0.6, "K3": 1.0, "r3": 6.0, "r4": 5.0, "r5": 3.0, "r6": 5.0},
        "leader": {"kind": "helix", "centre": [0.0, 0.0, 0.0], "radius": 2.0, "rate": 0.05, "climb": 0.5},
        "swarm": {"count": n, "formation": "grid", "spacing": 2.0, "graph": "k-nearest", "k": 4,
                  "pinned": 0.05, "start": "box", "box": 6.0, "seed": 7},
        "obstacles": [{"kind": "static", "position": [x, y, 3.0]} for x, y in ((-4, -4), (4, -4), (-4, 4), (4, 4))],
    }


def run_one(sc, path: str):
    from fxswarm.launch.sim import Simulation

    sim = Simulation(sc, path=path)
    summary = sim.run()
    return summary["wall_s"], sim.trajectory()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="10,100,1000,10000")
    ap.add_argument("--ticks", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--per-robot-ticks", default="10000:5,1000:40", help="N:T pairs: per-robot runs of N robots run T ticks")
    ap.add_argument("--out", default="benchmarks/results/batch.json")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    from fxswarm.core.scenario import parse

    fewer = dict(tuple(int(x) for x in pair.split(":")) for pair in args.per_robot_ticks.split(",") if pair)
    result = {"machine": machine(), "dt": DT, "ticks": args.ticks, "repeat": args.repeat, "sizes": []}
    for n in (int(x) for x in args.sizes.split(",")):
        t0 = time.perf_counter()
        sc = parse(swarm_raw(n, args.ticks), f"bench-{n}.toml")
        build_s = time.perf_counter() - t0
        pr_ticks = min(args.ticks, fewer.get(n, args.ticks))
        sc_pr = dataclasses.replace(sc, duration=pr_ticks * DT) if pr_ticks != args.ticks else sc
        walls = {"per-robot": [], "batch": []}
        equal = None
        for _ in range(args.repeat):  # interleaved: A B A B
            w_pr, traj_pr = run_one(sc_pr, "per-robot")
            w_b, traj_b = run_one(sc, "batch")
            walls["per-robot"].append(w_pr)
            walls["batch"].append(w_b)
            if pr_ticks == args.ticks:
                equal = all(traj_pr[k].tobytes() == traj_b[k].tobytes() for k in traj_pr)
            else:
                short = {k: v[:pr_ticks] for k, v in traj_b.items() if k != "offsets"}
                equal = all(traj_pr[k].tobytes() == short[k].tobytes() for k in short)
            print(f"N={n}: per-robot {w_pr:.3f} s ({pr_ticks} ticks), batch {w_b:.3f} s ({args.ticks} ticks)",
                  file=sys.stderr)
        # peak resident memory of this process so far (sizes run in ascending order: the largest's
        # peak), and the scenario's weights (held by rows) within it
        entry = {"robots": n, "scenario_build_s": round(build_s, 3), "bit_equal": equal,
                 "peak_rss_mb_so_far": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024),
                 "weight_graph_mb": round(sum(x.nbytes for x in (sc.graph.indptr, sc.graph.indices,
                                                                 sc.graph.weights)) / 2**20, 2)}
        for path, ticks in (("per-robot", pr_ticks), ("batch", args.ticks)):
            best = min(walls[path])
            entry[path] = {"ticks": ticks, "wall_s": [round(w, 4) for w in walls[path]],
                           "robot_ticks_per_s_best": round(n * ticks / best),
                           "robot_ticks_per_s_median": round(n * ticks / statistics.median(walls[path])),
                           "real_time_factor_best": round(ticks * DT / best, 3)}
            if ticks != args.ticks:
                entry[path]["estimated_from_ticks"] = ticks
        entry["speedup_best"] = round(entry["batch"]["robot_ticks_per_s_best"]
                                      / entry["per-robot"]["robot_ticks_per_s_best"], 2)
        result["sizes"].append(entry)
        write_json(args.out, result)
    result["machine"]["load_avg_at_end"] = round(__import__("os").getloadavg()[0], 2)
    write_json(args.out, result)
    for e in result["sizes"]:
        print(f"{e['robots']:>6} robots: per-robot {e['per-robot']['robot_ticks_per_s_best']:>10,} robot-ticks/s, "
              f"batch {e['batch']['robot_ticks_per_s_best']:>10,} (x{e['speedup_best']}), "
              f"batch real-time factor {e['batch']['real_time_factor_best']}, bit_equal {e['bit_equal']}")
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
