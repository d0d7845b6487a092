"""In-process simulator speed: wall time and ticks/s of paper.toml (30 000 ticks, 6 robots)
and of the large scenario (24 robots). Prints JSON and writes benchmarks/results/sim.json.

Target (issue 2): paper.toml in under 10 s on a 2-core machine. Each figure is the
median of --repeats runs (default 3).

    .venv/bin/python benchmarks/bench_sim.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

from fxswarm.core.scenario import load
from fxswarm.launch.sim import Simulation

from bench_io import machine, write_json  # a sibling script

SCENARIOS = ("configs/paper.toml", "configs/large.toml")


def measure(path: str, repeats: int) -> dict:
    walls = []
    for _ in range(repeats):
        sc = load(path)
        sim = Simulation(sc)
        start = time.perf_counter()
        sim.run()
        walls.append(time.perf_counter() - start)
    wall = statistics.median(walls)
    return {"scenario": path, "robots": sc.n, "ticks": sc.ticks, "wall_s_median": round(wall, 3),
            "wall_s_all": [round(w, 3) for w in walls], "ticks_per_s": round(sc.ticks / wall, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default="benchmarks/results/sim.json")
    args = parser.parse_args()
    results = {
        "benchmark": "in-process simulator (lock-step, in-memory bus)",
        "machine": machine(),
        "target": {"configs/paper.toml": "wall_s_median < 10"},
        "runs": [measure(path, args.repeats) for path in SCENARIOS],
    }
    paper = results["runs"][0]
    results["paper_target_met"] = paper["wall_s_median"] < 10.0
    write_json(args.out, results)
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
