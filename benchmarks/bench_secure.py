"""What secure mode costs: lock-step ticks/s and real-time p99 latency, secure against plain.

    python benchmarks/bench_secure.py [--rounds 3] [--lockstep-ticks 1500] [--realtime-s 8]
        [--out benchmarks/results/secure.json]

Four variants of paper-fast (6 robots, no logger), run interleaved round by
round (A B C D A B C D ...) so the shared machine's drifting load falls on all alike:

- ``plain``: what ``fxswarm run`` does by default (``auto``: a mesh for 6 robots);
- ``secure``: ``--secure``, the same mesh with mutual TLS on every link and the rules
  enforced by every peer;
- ``plain-routed`` and ``secure-routed``: the same, every message through the router.

``secure`` against ``plain``, and ``secure-routed`` against ``plain-routed``, is the
price of TLS and the rules in each topology. Each
figure is the median of the rounds; every round is kept. The floor measured in
the same rounds: ``fxswarm sim`` (one process, in-memory bus) on the same ticks,
for the machine's speed at that moment. Writes JSON.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_io import machine, write_json  # noqa: E402  (a sibling script)
from bench_runtime import load, run_swarm  # noqa: E402

from fxswarm.core.scenario import load as load_scenario  # noqa: E402
from fxswarm.launch.sim import Simulation  # noqa: E402
from fxswarm.security.keys import write_keys  # noqa: E402
from fxswarm.testing import scenario_with  # noqa: E402

CONFIG = ROOT / "configs" / "paper-fast.toml"
VARIANTS = {"plain": {"topology": None}, "secure": {"topology": None, "secure": True},
            "plain-routed": {"topology": "routed"}, "secure-routed": {"topology": "routed", "secure": True}}


def run(config: Path, out: Path, clock: str, keys: Path, variant: str) -> dict:
    """One run of ``config`` as processes (no logger) in this variant (bench_runtime's run_swarm)."""
    opts = VARIANTS[variant]
    return run_swarm(config, out, clock, topology=opts.get("topology"),
                     secure=str(keys) if opts.get("secure") else None)


def floor_ticks_per_s(config: Path) -> float:
    sc = load_scenario(str(config))
    sim = Simulation(sc)
    t0 = time.perf_counter()
    sim.run()
    return sc.ticks / (time.perf_counter() - t0)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--lockstep-ticks", type=int, default=1500)
    p.add_argument("--realtime-s", type=float, default=8.0)
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "secure.json"))
    args = p.parse_args()
    result: dict = {"machine": machine(), "scenario": CONFIG.name, "rounds": args.rounds,
                    "lockstep_ticks": args.lockstep_ticks, "realtime_s": args.realtime_s,
                    "lockstep": {v: [] for v in VARIANTS}, "realtime": {v: [] for v in VARIANTS}, "floor": []}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        keys = folder / "keys"
        write_keys(keys, load_scenario(str(CONFIG)))
        lock_cfg = scenario_with(CONFIG, folder, duration=args.lockstep_ticks * 0.01)
        real_cfg = scenario_with(CONFIG, folder, duration=args.realtime_s)
        for i in range(args.rounds):
            result["floor"].append({"sim_ticks_per_s": floor_ticks_per_s(lock_cfg), "load_avg": load()})
            for v in VARIANTS:
                r = run(lock_cfg, folder / f"lock-{v}-{i}", "lockstep", keys, v)
                row = {"ticks_per_s": r["world"]["ticks_per_s"], "topology": r["topology"], "load_avg": load()}
                result["lockstep"][v].append(row)
                print("lockstep", i, v, row, file=sys.stderr, flush=True)
            for v in VARIANTS:
                r = run(real_cfg, folder / f"real-{v}-{i}", "realtime", keys, v)
                lat = r["summary"]["sense_to_command"]
                row = {"p50_ms": lat["p50_ms"], "p99_ms": lat["p99_ms"], "max_ms": lat["max_ms"],
                       "achieved_speed": r["summary"]["achieved_speed"], "topology": r["topology"],
                       "load_avg": load()}
                result["realtime"][v].append(row)
                print("realtime", i, v, row, file=sys.stderr, flush=True)
    med = {"lockstep_ticks_per_s": {v: statistics.median(r["ticks_per_s"] for r in rows)
                                    for v, rows in result["lockstep"].items()},
           "realtime_p99_ms": {v: statistics.median(r["p99_ms"] for r in rows)
                               for v, rows in result["realtime"].items()},
           "realtime_p50_ms": {v: statistics.median(r["p50_ms"] for r in rows)
                               for v, rows in result["realtime"].items()},
           "floor_sim_ticks_per_s": statistics.median(r["sim_ticks_per_s"] for r in result["floor"])}
    lk, rt = med["lockstep_ticks_per_s"], med["realtime_p99_ms"]
    # Cost in %: fewer ticks/s, or a longer p99, than the plain variant (positive = secure is worse).
    med["secure_cost_pct"] = {
        "lockstep_vs_plain": round(100 * (1 - lk["secure"] / lk["plain"]), 1),
        "lockstep_routed_vs_plain_routed": round(100 * (1 - lk["secure-routed"] / lk["plain-routed"]), 1),
        "realtime_p99_vs_plain": round(100 * (rt["secure"] / rt["plain"] - 1), 1),
        "realtime_p99_routed_vs_plain_routed": round(100 * (rt["secure-routed"] / rt["plain-routed"] - 1), 1)}
    # The same, round by round (each pair ran back to back, under the same load), then the median:
    # steadier than the ratio of medians on a machine whose load drifts between rounds.
    def paired(part: str, key: str, a: str, b: str, worse_is_lower: bool) -> float:
        ratios = [(x[key] / y[key]) for x, y in zip(result[part][a], result[part][b])]
        r = statistics.median(ratios)
        return round(100 * ((1 - r) if worse_is_lower else (r - 1)), 1)

    med["secure_cost_pct_paired"] = {
        "lockstep_vs_plain": paired("lockstep", "ticks_per_s", "secure", "plain", True),
        "lockstep_routed_vs_plain_routed": paired("lockstep", "ticks_per_s", "secure-routed", "plain-routed", True),
        "realtime_p99_vs_plain": paired("realtime", "p99_ms", "secure", "plain", False),
        "realtime_p99_routed_vs_plain_routed": paired("realtime", "p99_ms", "secure-routed", "plain-routed", False)}
    med["target_pct"] = 15
    result["median"] = med
    write_json(args.out, result)
    print(f"wrote {args.out}", file=sys.stderr)
    print(med)
    return 0


if __name__ == "__main__":
    sys.exit(main())
