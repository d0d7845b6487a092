"""A/B of the law API's cost (issue 27): the paper's law through the API against the tree before it.

    python benchmarks/studies/ab_law.py BASELINE_TREE [--rounds 5] [--lockstep-ticks 2000]
        [--out benchmarks/studies/results/ab_law.json]

Two figures, each side run with its own tree's venv and code, in rounds that alternate
the trees (A B, then B A):

- lock-step ticks/s of configs/paper-fast.toml over real processes and Zenoh
  (bench_runtime's ``lockstep``, as benchmarks/ab_runtime.py runs it), with the
  message floor of bench_floor.py measured in the same round;
- ``fxswarm sim`` of configs/paper-fast.toml (4000 ticks, in-process): wall seconds and
  CPU seconds of the process (on a machine shared by many, wall time is mostly waiting for a
  core: the CPU seconds are the figure to judge), with a CPU floor measured in the same
  round (a fixed pure-Python float workload, the kind of work the agent's law does), so a
  change in the machine's load shows as a change in the floor, not in the trees;
- the agent's ``act`` alone (where the law is called), thread CPU microseconds per act, the
  least over batches, averaged over the six robots: the figure least moved by load.

Reported: every round, the medians, and per figure this tree / baseline as the median of
the per-round ratios (and of the ratios to the floor). BASELINE_TREE: e.g.
``git worktree add /tmp/base 76521a3`` with ``make .venv/.installed`` run there.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

# The maintained benchmarks this study imports (bench_io, ...) sit one folder up.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import ab_runtime  # a sibling script: the lock-step measurement and its floor, per tree
from bench_io import ACT_CPU, cpu_floor, machine, ratio, run_in_tree, write_json

ROOT = Path(__file__).resolve().parents[2]

SIM = """
import json, os, time
from fxswarm.core.scenario import load
from fxswarm.launch.sim import Simulation
sc = load("configs/paper-fast.toml")
sim = Simulation(sc)
start, cpu = time.perf_counter(), time.process_time()
sim.run()
wall, cpu = time.perf_counter() - start, time.process_time() - cpu
# The agent's act alone (the law's call site), per robot: the least thread CPU time per act over
# 30 batches of 200 acts, after 9 s of flight (robots near obstacles: both behaviours at work).
import tomllib
from fxswarm.core.scenario import parse
raw = tomllib.load(open("configs/paper-fast.toml", "rb"))
raw["scenario"]["duration"] = 9.0
held = Simulation(parse(raw, "act"))
held.run()
""" + ACT_CPU + """
print(json.dumps({"sim_wall_s": wall, "sim_cpu_s": cpu, "sim_ticks_per_s": sc.ticks / wall,
                  "act_cpu_us": sum(acts) / len(acts), "load_avg": os.getloadavg()[0]}))
"""


def sim(tree: Path) -> dict:
    return run_in_tree(tree, SIM, what="sim")


def rounds_from_log(path: Path) -> dict[str, list]:
    """The rounds a stopped run printed on stderr (``ROUND NAME JSON`` lines), whole rounds only."""
    rounds: dict[str, list] = {"baseline": [], "this": [], "floor": []}
    for line in path.read_text().splitlines():
        parts = line.split(" ", 2)
        if len(parts) == 3 and parts[0].isdigit() and parts[1] in rounds:
            rounds[parts[1]].append(json.loads(parts[2]))
    whole = min(len(rows) for rows in rounds.values())
    return {name: rows[:whole] for name, rows in rounds.items()}


def summary(rounds: dict[str, list], trees: dict[str, Path], command: str) -> dict:
    """Medians, per-round ratios this/baseline and to the floors, and the target."""
    keys = ("ticks_per_s", "cpu_ms_per_tick", "sim_wall_s", "sim_cpu_s", "sim_ticks_per_s", "act_cpu_us")
    result = {
        "benchmark": "the paper's law through the law API (this) against the tree before it (baseline), "
                     "configs/paper-fast.toml, rounds interleaved A B / B A",
        "command": command,
        "machine": machine(),
        "trees": {k: str(v) for k, v in trees.items()},
        "rounds": rounds,
        "median": {name: ab_runtime.medians(rows) for name, rows in rounds.items()},
        # per round this/baseline (same load): > 1 is faster for ticks/s, slower for seconds and us
        "this_over_baseline": {k: ratio(rounds["this"], rounds["baseline"], k) for k in keys
                               if all(k in row for row in rounds["this"] + rounds["baseline"])},
        "vs_floor": {
            name: {"lockstep_ticks_per_s": ratio(rounds[name], rounds["floor"], "ticks_per_s"),
                   "sim_cpu_s_over_cpu_floor": ratio(rounds[name], [
                       {"sim_cpu_s": f["cpu_floor_s"]} for f in rounds["floor"]], "sim_cpu_s")}
            for name in trees},
        "target": "this/baseline within 5 % (lock-step ticks/s >= 0.95, sim CPU s <= 1.05)",
    }
    ratios = result["this_over_baseline"]
    result["target_met"] = ratios["ticks_per_s"]["median"] >= 0.95 and ratios["sim_cpu_s"]["median"] <= 1.05
    return result


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("baseline", type=Path, help="another checkout with its own .venv")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--lockstep-ticks", type=int, default=2000)
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "studies" / "results" / "ab_law.json"))
    p.add_argument("--from-log", type=Path, default=None, metavar="LOG",
                   help="no runs: summarise the whole rounds a stopped run wrote to its stderr LOG")
    args = p.parse_args()
    trees = {"baseline": args.baseline.resolve(), "this": ROOT}
    command = f"python benchmarks/studies/ab_law.py {args.baseline} --rounds {args.rounds} --lockstep-ticks {args.lockstep_ticks}"
    if args.from_log is not None:
        rounds = rounds_from_log(args.from_log)
        command += f"  (stopped after {len(rounds['floor'])} whole rounds; summarised with --from-log)"
    else:
        rounds = {"baseline": [], "this": [], "floor": []}
        for i in range(args.rounds):
            order = list(trees.items()) if i % 2 == 0 else list(trees.items())[::-1]
            for name, tree in order:
                row = ab_runtime.measure(tree, "lockstep", args.lockstep_ticks) | sim(tree)
                rounds[name].append(row)
                print(i, name, json.dumps(row), file=sys.stderr)
            floor = ab_runtime.measure_floor("lockstep", args.lockstep_ticks)
            rounds["floor"].append({"ticks_per_s": floor["ticks_per_s"], "load_avg": floor["load_avg"]} | cpu_floor())
            print(i, "floor", json.dumps(rounds["floor"][-1]), file=sys.stderr)
    result = summary(rounds, trees, command)
    write_json(args.out, result)
    print(json.dumps({k: result[k] for k in ("median", "this_over_baseline", "vs_floor", "target_met")}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
