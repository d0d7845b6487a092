"""The CPU one robot process takes at 50 Hz in real time, and so the cores N robots need.

    python benchmarks/bench_robot_cpu.py [--robots 10] [--short 10] [--long 30] [--repeat 1]
        [--out benchmarks/results/robot_cpu.json]

Runs ``fxswarm run --clock realtime --no-logger`` on a generated swarm (:func:`scenario`: a
grid 2 m apart, a 4-nearest graph, 10 % pinned, dt = 0.02 s: 50 Hz) for ``--short`` and
``--long`` simulated seconds, reading every process's CPU time from ``/proc`` as
benchmarks/bench_threads.py does. The agents' CPU of the long run less the short one's,
divided by the seconds between them and by the robots, is one robot process's share of a core
at 50 Hz, start-up cancelled out. ``cores_for`` extrapolates linearly to N robots (agents
only; the world and router grow too and are listed apart).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_io import machine, write_json  # noqa: E402
from fxswarm.core.tomltext import dump_toml  # noqa: E402
from bench_threads import cpu_by_thread  # noqa: E402

def scenario(n: int, duration: float) -> dict:
    """A generated ``n``-robot swarm on the paper's gains (configs/paper-fast.toml), 50 Hz."""
    gains = tomllib.loads((ROOT / "configs" / "paper-fast.toml").read_text())["gains"]
    return {"scenario": {"name": f"cpu-{n}", "duration": duration, "dt": 0.02, "d": 1.0}, "gains": gains,
            "leader": {"kind": "helix", "radius": 2.0, "rate": 0.05, "climb": 0.5},
            "swarm": {"count": n, "formation": "grid", "spacing": 2.0, "graph": "k-nearest", "k": 4,
                      "pinned": 0.1, "box": 2.0, "seed": 1}}


def role_cpu(n: int, seconds: float, folder: Path) -> dict[str, float]:
    path = folder / f"cpu-{n}-{seconds:g}.toml"
    path.write_text(dump_toml(scenario(n, seconds)))
    argv = [sys.executable, "-m", "fxswarm.cli", "run", str(path), "--clock", "realtime", "--no-logger", "--quiet",
            "--out", str(folder / f"run-{seconds:g}")]
    cpu, _ = cpu_by_thread(argv)
    out: dict[str, float] = {}
    for key, value in cpu.items():
        role = key.split("/", 1)[0]
        out[role] = out.get(role, 0.0) + value
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robots", type=int, default=10)
    p.add_argument("--short", type=float, default=10.0)
    p.add_argument("--long", type=float, default=30.0)
    p.add_argument("--repeat", type=int, default=1)
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "robot_cpu.json"))
    a = p.parse_args()
    at_start = machine()
    rounds = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(a.repeat):
            short = role_cpu(a.robots, a.short, Path(tmp))
            long = role_cpu(a.robots, a.long, Path(tmp))
            span = a.long - a.short
            share = {role: (long.get(role, 0.0) - short.get(role, 0.0)) / span for role in sorted(set(short) | set(long))}
            rounds.append({"core_share": {k: round(v, 4) for k, v in share.items()},
                           "load_avg": round(os.getloadavg()[0], 2)})
            print(rounds[-1], file=sys.stderr)
    per_robot = statistics.median(r["core_share"].get("agent", 0.0) for r in rounds) / a.robots
    result = {"machine": at_start | {"load_avg_at_end": round(os.getloadavg()[0], 2)}, "robots": a.robots, "rate_hz": 50, "short_s": a.short, "long_s": a.long,
              "rounds": rounds, "agent_core_share_per_robot": round(per_robot, 4),
              "cores_for": {str(n): round(n * per_robot, 2) for n in (10, 100, 1000)}}
    write_json(a.out, result)
    print(f"one robot process at 50 Hz: {100 * per_robot:.1f} % of a core; "
          f"agents of 100 robots: {100 * per_robot:.1f} cores, 1000: {1000 * per_robot:.0f} cores")
    return 0


if __name__ == "__main__":
    sys.exit(main())
