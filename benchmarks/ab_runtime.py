"""A/B of the distributed runtime: this tree against another checkout, runs interleaved.

    python benchmarks/ab_runtime.py BASELINE_TREE [--rounds 3] [--lockstep-ticks 2000]
        [--realtime-s 10] [--out benchmarks/results/ab_runtime.json]

On a shared machine the load drifts by more than most changes are worth, so
a change is judged by rounds that alternate baseline and this tree, each
side run with its own tree's venv and code: lock-step paper-fast (ticks/s
and CPU ms per tick, from bench_runtime's ``lockstep``) and real time at
100 Hz (sensing -> command latency, from its ``realtime``). Writes every
round and the medians. BASELINE_TREE is e.g. ``git worktree add /tmp/base REV``
with ``make .venv/.installed`` run there.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

from bench_io import write_json  # a sibling script

ROOT = Path(__file__).resolve().parents[1]

# Run inside one tree (cwd = that tree, its venv): one measurement, printed as one JSON line.
ONE = """
import json, sys, tempfile
from pathlib import Path
sys.path.insert(0, "benchmarks")
import bench_runtime as b
kind, arg = sys.argv[1], float(sys.argv[2])
cfg = Path("configs/paper-fast.toml").resolve()
with tempfile.TemporaryDirectory() as tmp:
    if kind == "lockstep":
        r = b.lockstep(cfg, Path(tmp), int(arg))
        out = {"ticks_per_s": r["ticks_per_s"]}
        if "cpu_ms_per_tick" in r:  # older trees do not measure it
            out["cpu_ms_per_tick"] = r["cpu_ms_per_tick"]["total"]
    else:
        r = b.realtime(cfg, Path(tmp), arg)
        lat = r["sense_to_command"]
        out = {"p50_ms": lat["p50_ms"], "p99_ms": lat["p99_ms"], "max_ms": lat["max_ms"]}
out["load_avg"] = r["load_avg"]
print(json.dumps(out))
"""


def measure(tree: Path, kind: str, arg: float) -> dict:
    done = subprocess.run([str(tree / ".venv" / "bin" / "python"), "-c", ONE, kind, str(arg)], cwd=tree,
                          capture_output=True, text=True, timeout=900)
    if done.returncode != 0:
        raise RuntimeError(f"{kind} in {tree} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def medians(rows: list[dict]) -> dict:
    return {k: statistics.median(r[k] for r in rows) for k in rows[0] if k != "load_avg"} | \
        {"load_avg": [round(r["load_avg"], 1) for r in rows]}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("baseline", type=Path, help="another checkout with its own .venv")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--lockstep-ticks", type=int, default=2000)
    p.add_argument("--realtime-s", type=float, default=10.0)
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "ab_runtime.json"))
    args = p.parse_args()
    trees = {"baseline": args.baseline.resolve(), "this": ROOT}
    result: dict = {"trees": {k: str(v) for k, v in trees.items()}}
    for kind, arg in (("lockstep", args.lockstep_ticks), ("realtime", args.realtime_s)):
        rounds = {name: [] for name in trees}
        for i in range(args.rounds):
            for name, tree in trees.items():
                rounds[name].append(measure(tree, kind, arg))
                print(kind, i, name, json.dumps(rounds[name][-1]), file=sys.stderr)
        result[kind] = {"rounds": rounds, "median": {name: medians(rows) for name, rows in rounds.items()}}
    write_json(args.out, result)
    print(json.dumps({k: result[k]["median"] for k in ("lockstep", "realtime")}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
