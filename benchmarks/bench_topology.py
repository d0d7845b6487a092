"""Mesh against routed (``fxswarm run --topology``), lock-step, by swarm size.

    python benchmarks/bench_topology.py [--sizes 6,8,12,24] [--rounds 3] [--ticks 1500]
        [--out benchmarks/results/topology.json]

Where ``auto`` stops meshing (launcher.MESH_MAX_ROBOTS) comes from this: a
mesh takes the router's hop out of every message, but each process links to
every other, and the links' cost grows with the square of the swarm. Sizes:
6 is paper-fast, 24 is large; any other n is the first n robots of
``large.toml`` in a ring, pinned where large pins them. Each round runs every
size routed then mesh, so the machine's drifting load hits both alike; the
JSON holds every run (ticks/s, CPU ms per tick by role, load) and the
medians per size and topology.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_io import write_json  # noqa: E402  (sibling scripts)
from bench_runtime import load, lockstep  # noqa: E402

from fxswarm.testing import dump_toml  # noqa: E402

TOPOLOGIES = ("routed", "mesh")


def scenario_of_size(n: int, folder: Path) -> Path:
    """paper-fast for 6, large for 24, else the first ``n`` robots of large in a ring."""
    if n == 6:
        return ROOT / "configs" / "paper-fast.toml"
    large = ROOT / "configs" / "large.toml"
    if n == 24:
        return large
    data = tomllib.loads(large.read_text())
    if not 2 < n < len(data["robots"]):
        raise SystemExit(f"bench_topology: --sizes: expected 6, 24 or 3..{len(data['robots']) - 1}, got {n}")
    data["robots"] = data["robots"][:n]
    data["graph"] = {"edges": [[i, i % n + 1] for i in range(1, n + 1)],
                     "pinned": [p for p in data["graph"]["pinned"] if p <= n] or [1],
                     "pin_gain": data["graph"].get("pin_gain", 1.0)}
    data["scenario"]["name"] = f"large-first-{n}"
    path = folder / f"large-first-{n}.toml"
    path.write_text(dump_toml(data))
    return path


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", default="6,8,12,24", help="robots per swarm, comma-separated")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--ticks", type=int, default=1500)
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "topology.json"))
    args = p.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    runs: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        configs = {n: scenario_of_size(n, folder) for n in sizes}
        for r in range(args.rounds):
            for n in sizes:
                for topology in TOPOLOGIES:
                    row = lockstep(configs[n], folder, args.ticks, topology)
                    runs.append({"round": r, "robots": n, **row})
                    print(f"round {r} robots {n:3d} {topology:6s} {row['ticks_per_s']:7.1f} ticks/s "
                          f"{row['cpu_ms_per_tick']['total']:6.2f} ms CPU/tick  load {row['load_avg']:.1f}",
                          file=sys.stderr, flush=True)
    medians = {
        str(n): {t: {"ticks_per_s": statistics.median(x["ticks_per_s"] for x in runs
                                                      if x["robots"] == n and x["topology"] == t),
                     "cpu_ms_per_tick": statistics.median(x["cpu_ms_per_tick"]["total"] for x in runs
                                                          if x["robots"] == n and x["topology"] == t)}
                 for t in TOPOLOGIES}
        for n in sizes}
    result = {"ticks": args.ticks, "rounds": args.rounds, "load_avg_at_end": load(), "medians": medians, "runs": runs}
    write_json(args.out, result)
    print(json.dumps(medians, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
