"""A/B of the drive models' cost on the paper's ideal world (issue 37): `fxswarm sim` of
configs/paper-fast.toml (4000 ticks, in-process, no [world] table) in this tree against the
tree before the models, and, for scale, the same run here with unicycles and 2 cm pose noise.

    python benchmarks/ab_models.py BASELINE_TREE [--rounds 6] [--out benchmarks/results/ab_models.json]

Each side runs with its own tree's venv and code, in rounds that alternate the trees (A B, then
B A). The figure to judge is the CPU seconds of the process (on a shared machine the wall time
is mostly waiting for a core); a fixed pure-Python float workload is timed in each round too
(ab_law.cpu_floor), so a change of load shows there and not between the trees. Reported: every
round, the medians, and this/baseline as the median of the per-round ratios.
BASELINE_TREE: e.g. ``git archive ef4b474 | tar -x -C /tmp/base`` and ``make .venv/.installed`` there.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

from bench_io import cpu_floor, machine, ratio, run_in_tree, write_json

ROOT = Path(__file__).resolve().parents[1]

SIM = """
import json, os, sys, time, tomllib
from fxswarm.core.scenario import parse
raw = tomllib.load(open("configs/paper-fast.toml", "rb"))
if sys.argv[1:] == ["unicycle"]:
    raw["world"] = {"model": "unicycle", "pose_noise": 0.02}
from fxswarm.launch.sim import Simulation
sim = Simulation(parse(raw, "configs/paper-fast.toml"))
start, cpu = time.perf_counter(), time.process_time()
summary = sim.run()
wall, cpu = time.perf_counter() - start, time.process_time() - cpu
print(json.dumps({"sim_wall_s": wall, "sim_cpu_s": cpu, "final_formation_error_m": summary["formation_error_final_m"],
                  "load_avg": os.getloadavg()[0]}))
"""


def sim(tree: Path, *args: str) -> dict:
    return run_in_tree(tree, SIM, *args, what="sim")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("baseline", type=Path, help="another checkout with its own .venv")
    p.add_argument("--rounds", type=int, default=6)
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "ab_models.json"))
    args = p.parse_args()
    trees = {"baseline": args.baseline.resolve(), "this": ROOT}
    rounds: dict[str, list] = {"baseline": [], "this": [], "this_unicycle": [], "floor": []}
    for i in range(args.rounds):
        order = list(trees.items()) if i % 2 == 0 else list(trees.items())[::-1]
        for name, tree in order:
            rounds[name].append(sim(tree))
            print(i, name, json.dumps(rounds[name][-1]), file=sys.stderr)
        rounds["this_unicycle"].append(sim(ROOT, "unicycle"))
        rounds["floor"].append(cpu_floor())
        print(i, "this_unicycle", json.dumps(rounds["this_unicycle"][-1]), file=sys.stderr)
    # Same ideal run, same arithmetic: the two trees must agree on the result to the bit.
    same = {r["final_formation_error_m"] for r in rounds["baseline"] + rounds["this"]}
    result = {
        "benchmark": "fxswarm sim configs/paper-fast.toml (ideal world) in this tree against the tree "
                     "before the drive models (baseline), rounds interleaved A B / B A",
        "command": f"python benchmarks/ab_models.py {args.baseline} --rounds {args.rounds}",
        "machine": machine(),
        "trees": {k: str(v) for k, v in trees.items()},
        "rounds": rounds,
        "median": {name: {k: statistics.median(r[k] for r in rows) for k in rows[0]} for name, rows in rounds.items()},
        "this_over_baseline": {k: ratio(rounds["this"], rounds["baseline"], k) for k in ("sim_cpu_s", "sim_wall_s")},
        "unicycle_over_ideal": ratio(rounds["this_unicycle"], rounds["this"], "sim_cpu_s"),
        "same_result": len(same) == 1,
        "target": "this/baseline sim CPU s <= 1.05 (no slower, within the machine's noise)",
    }
    result["target_met"] = result["this_over_baseline"]["sim_cpu_s"]["median"] <= 1.05 and result["same_result"]
    write_json(args.out, result)
    print(json.dumps({k: result[k] for k in ("median", "this_over_baseline", "unicycle_over_ideal", "same_result",
                                             "target_met")}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
