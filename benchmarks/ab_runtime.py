"""A/B of the distributed runtime: this tree against another checkout, runs interleaved.

    python benchmarks/ab_runtime.py BASELINE_TREE [--rounds 3] [--lockstep-ticks 2000]
        [--realtime-s 10] [--out benchmarks/results/ab_runtime.json]

On a shared machine the load drifts by more than most changes are worth, so
a change is judged by rounds that alternate baseline and this tree, each
side run with its own tree's venv and code: lock-step paper-fast (ticks/s
and CPU ms per tick, from bench_runtime's ``lockstep``) and real time at
100 Hz (sensing -> command latency, from its ``realtime``). Each round also
runs the floor (bench_floor.py: the same message pattern with nothing else),
so both trees are read as ratios to a floor measured under the same load.
Writes every round, the medians and the per-round ratios to the floor. BASELINE_TREE is e.g. ``git worktree add /tmp/base REV``
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
        out["rss_mb_per_agent"] = r["rss_mb_per_agent"]["max"]
        if "pss_mb_per_agent" in r:
            out["pss_mb_per_agent"] = r["pss_mb_per_agent"]["max"]
    if "crossings_per_tick" in r:
        out["crossings_per_tick"] = r["crossings_per_tick"]
out["load_avg"] = r["load_avg"]
print(json.dumps(out))
"""


def measure_floor(kind: str, arg: float) -> dict:
    """The floor (bench_floor.py, from this tree) for the same measurement."""
    import bench_floor as f

    cfg = ROOT / "configs" / "paper-fast.toml"
    if kind == "lockstep":
        r = f.floor_lockstep(cfg, int(arg))
        return {"ticks_per_s": r["ticks_per_s"], "cpu_ms_per_tick": r["cpu_ms_per_tick"],
                "crossings_per_tick": r["crossings_per_tick"], "load_avg": r["load_avg"]}
    r = f.floor_realtime(cfg, arg)
    lat = r["sense_to_command"]
    return {"p50_ms": lat["p50_ms"], "p99_ms": lat["p99_ms"], "max_ms": lat["max_ms"],
            "crossings_per_tick": r["crossings_per_tick"], "load_avg": r["load_avg"]}


def ratios(rounds: dict, tree: str) -> dict:
    """Per figure: the median and range of tree/floor over the rounds (each round under one load)."""
    out = {}
    for k in rounds["floor"][0]:
        if k == "load_avg" or k not in rounds[tree][0]:
            continue
        r = [a[k] / b[k] for a, b in zip(rounds[tree], rounds["floor"]) if b.get(k)]
        if r:
            out[k] = {"median": statistics.median(r), "range": [min(r), max(r)]}
    return out


def measure(tree: Path, kind: str, arg: float) -> dict:
    done = subprocess.run([str(tree / ".venv" / "bin" / "python"), "-c", ONE, kind, str(arg)], cwd=tree,
                          capture_output=True, text=True, timeout=900)
    if done.returncode != 0:
        raise RuntimeError(f"{kind} in {tree} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def medians(rows: list[dict]) -> dict:
    return {k: statistics.median(r[k] for r in rows if r.get(k) is not None) for k in rows[0]
            if k != "load_avg" and any(r.get(k) is not None for r in rows)} | \
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
        rounds: dict[str, list] = {name: [] for name in [*trees, "floor"]}
        for i in range(args.rounds):
            # A B, then B A: neither tree always runs right after the other's swarm shut down.
            for name, tree in (list(trees.items()) if i % 2 == 0 else list(trees.items())[::-1]):
                rounds[name].append(measure(tree, kind, arg))
                print(kind, i, name, json.dumps(rounds[name][-1]), file=sys.stderr)
            rounds["floor"].append(measure_floor(kind, arg))
            print(kind, i, "floor", json.dumps(rounds["floor"][-1]), file=sys.stderr)
        result[kind] = {"rounds": rounds, "median": {name: medians(rows) for name, rows in rounds.items()},
                        "vs_floor": {name: ratios(rounds, name) for name in trees}}
    write_json(args.out, result)
    print(json.dumps({k: {"median": result[k]["median"], "vs_floor": result[k]["vs_floor"]}
                      for k in ("lockstep", "realtime")}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
