"""A/B of issue 39 on the agent's hot path: this tree against a baseline tree, resilience off
(the default path must cost nothing more), and this tree's W-MSR on against off.

    python benchmarks/ab_resilience.py BASELINE_TREE [--rounds 4] [--out benchmarks/results/ab_resilience.json]

Per side, in its own venv: the agent's ``act`` alone, thread CPU microseconds per act, the least
over 30 batches of 200 acts, averaged over the robots, after 9 s of flight of
configs/paper-fast.toml (the figure least moved by a shared machine's load; as
benchmarks/studies/ab_law.py measures it). Rounds alternate the order (A B, then B A). This tree also
measures configs/liar-8.toml with ``resilience = "w-msr"`` and without, the same way.
BASELINE_TREE: e.g. ``git worktree add /tmp/base ef4b474`` with ``make .venv/.installed`` there.
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

from bench_io import ACT_CPU, machine, run_in_tree, write_json

ROOT = Path(__file__).resolve().parents[1]

ACT = """
import json, sys, time, tomllib
from fxswarm.core.scenario import parse
from fxswarm.launch.sim import Simulation
path, resilient = sys.argv[1], sys.argv[2] == "1"
raw = tomllib.load(open(path, "rb"))
raw["scenario"]["duration"] = 9.0
if resilient:
    raw["estimator"] |= {"resilience": "w-msr", "tolerate": 1}
held = Simulation(parse(raw, path))
held.run()
""" + ACT_CPU + """
print(json.dumps({"act_cpu_us": sum(acts) / len(acts)}))
"""


def act_us(tree: Path, config: str, resilient: bool = False) -> float:
    return run_in_tree(tree, ACT, config, "1" if resilient else "0", what="act")["act_cpu_us"]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("baseline", type=Path)
    p.add_argument("--rounds", type=int, default=4)
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "ab_resilience.json"))
    args = p.parse_args()
    rows = []
    for k in range(args.rounds):
        sides = [("this", ROOT), ("baseline", args.baseline)]
        if k % 2:
            sides.reverse()
        row = {name: act_us(tree, "configs/paper-fast.toml") for name, tree in sides}
        off, on = (act_us(ROOT, "configs/liar-8.toml", r) for r in ((False, True) if k % 2 == 0 else (True, False)))
        row |= {"liar8_off": off, "liar8_wmsr": on}
        rows.append(row)
        print(k, json.dumps(row), flush=True)

    def med(f):
        return statistics.median(f(r) for r in rows)

    result = {"machine": machine(), "rounds": rows,
              "paper_fast_act_us": {"this": med(lambda r: r["this"]), "baseline": med(lambda r: r["baseline"])},
              "this_over_baseline": med(lambda r: r["this"] / r["baseline"]),
              "liar8_act_us": {"off": med(lambda r: r["liar8_off"]), "w-msr": med(lambda r: r["liar8_wmsr"])},
              "wmsr_over_off": med(lambda r: r["liar8_wmsr"] / r["liar8_off"])}
    write_json(args.out, result)
    print(json.dumps({k: v for k, v in result.items() if k not in ("machine", "rounds")}, indent=2))


if __name__ == "__main__":
    main()
