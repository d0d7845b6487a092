"""Real-time scale: the largest swarm this machine runs at 50 Hz with under 1 % late ticks.

    python benchmarks/bench_scale.py [--sizes 12,24,48,64,100] [--duration 20] [--repeat 1]
        [--floor] [--out benchmarks/results/scale.json]
    python benchmarks/bench_scale.py --write-config 100 configs/scale-100.toml

Each size N is a scenario of the same design (:func:`scenario_toml`: a grid
formation 3 m apart, a ring-with-chords graph of degree 4, one robot in
eight pinned, static obstacles on the climb, dt = 0.02 s), run as processes
(`fxswarm run --clock realtime`, routed, no logger) for ``--duration`` s of
simulation. A size keeps up when fewer than 1 % of its ticks start late
(``late_ticks``, the world's count), the world held its clock for fewer
than 1 % (``held_ticks``: a robot more than 10 ticks behind) and the p99
latency from each sensing message to the matching command's arrival at
the world is under 20 ms (issue 19's definition of a real-time swarm);
reported with its achieved speed (simulation s per wall s), p50/p99 latency
and message crossings per tick, and, for a size that does not keep up,
which of the three it missed (``missed``). Sizes are tried in ascending order and the
search stops after the first size that does not keep up. ``--floor`` pairs
each size with the floor (benchmarks/bench_floor.py, the same pattern with
nothing else) at the same rate, interleaved.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_floor import floor_realtime  # noqa: E402  (a sibling script)
from bench_io import machine, write_json  # noqa: E402
from bench_runtime import crossings_per_tick, load, run_swarm  # noqa: E402

DT = 0.02  # 50 Hz
LATE_LIMIT = 0.01
P99_LIMIT_MS = 20.0


def missed(late_fraction: float, held_fraction: float, p99_ms: float | None) -> list[str]:
    """Which of the real-time criteria a run missed (none: it keeps up)."""
    out = []
    if late_fraction >= LATE_LIMIT:
        out.append("late ticks")
    if held_fraction >= LATE_LIMIT:
        out.append("held ticks")
    if p99_ms is None or p99_ms >= P99_LIMIT_MS:
        out.append("p99 latency")
    return out


def chord_edges(n: int) -> list[tuple[int, int]]:
    """A ring 1-2-...-n-1 with chords i -- i+k (k about sqrt(n)): degree 4, diameter about sqrt(n)."""
    if n < 3:
        return [(i, i + 1) for i in range(1, n)]
    edges = {tuple(sorted((i, i % n + 1))) for i in range(1, n + 1)}
    k = max(2, round(math.sqrt(n)))
    if n > 2 * k:
        edges |= {tuple(sorted((i, (i + k - 1) % n + 1))) for i in range(1, n + 1)}
    return sorted(edges)


def scenario_toml(n: int, duration: float = 30.0) -> str:
    """A scenario of ``n`` robots: grid formation, ring-with-chords graph, static obstacles."""
    side = math.ceil(math.sqrt(n))
    spacing = 3.0
    offsets = [((k % side - (side - 1) / 2) * spacing, (k // side - (side - 1) / 2) * spacing) for k in range(n)]
    pinned = sorted({1 + (k * n) // max(1, n // 8) for k in range(max(1, n // 8))})
    lines = [
        f"# {n} robots in a grid {spacing:g} m apart on a ring-with-chords graph of degree 4 (i -- i+1,",
        "# i -- i+k, k ~ sqrt(n)), one robot in eight pinned, climbing past static obstacles at 50 Hz.",
        "# Written by benchmarks/bench_scale.py (--write-config); real-time scale, not from the paper.",
        "", "[scenario]", f'name = "scale-{n}"', f"duration = {duration:g}", f"dt = {DT}", "seed = 1",
        "settle_tolerance = 0.3", "d = 1.0", "",
        "[gains]", "b1 = 0.6", "b2 = 0.6", "r0 = 0.9", "r1 = 1.2", "r2 = 0.6", "lam_f = 1.0", "lam_o = 1.0",
        "K1 = 0.4", "K2 = 0.6", "K3 = 1.0", "r3 = 6.0", "r4 = 5.0", "r5 = 3.0", "r6 = 5.0", "",
        "[estimator]", 'power = "pairwise"', "",
        "[leader]", 'kind = "helix"', "centre = [0.0, 0.0, 0.0]", "radius = 2.0", "rate = 0.05", "climb = 0.5", "",
        "[formation]", "amplitude = [0.1, 0.0, 0.0]", "omega = [0.1, 0.0, 0.0]", "",
        "[graph]", "edges = [" + ", ".join(f"[{i}, {j}]" for i, j in chord_edges(n)) + "]",
        f"pinned = {pinned}", "pin_gain = 1.0", "",
    ]
    for k, (ox, oy) in enumerate(offsets):
        # Start a little off the formation, spread out: the first seconds gather it.
        px, py = 1.2 * ox + 0.5 * math.cos(k), 1.2 * oy + 0.5 * math.sin(k)
        lines += ["[[robots]]", f"position = [{px:.6f}, {py:.6f}, 0.0]", f"offset = [{ox:.6f}, {oy:.6f}, 0.0]", ""]
    half = (side - 1) / 2 * spacing
    for z, (fx, fy) in ((6.0, (0.5, 0.5)), (10.0, (-0.5, 0.25)), (14.0, (0.25, -0.5))):
        lines += ["[[obstacles]]", 'kind = "static"',
                  f"position = [{fx * half + spacing / 2:.3f}, {fy * half + spacing / 2:.3f}, {z}]", ""]
    return "\n".join(lines)


def measure(n: int, folder: Path, duration: float) -> dict:
    config = folder / f"scale-{n}.toml"
    config.write_text(scenario_toml(n, duration))
    r = run_swarm(config, folder / f"run-{n}", "realtime", speed=1.0, topology="routed", start_timeout=600)
    s = r["summary"]
    w = s["processes"]["world-0"]
    ticks = max(int(w.get("ticks", 0)), 1)
    lat = s["sense_to_command"]
    miss = missed(s["late_ticks"] / ticks, s["held_ticks"] / ticks, lat.get("p99_ms"))
    return {"robots": n, "rate_hz": 1 / DT, "duration_s": duration, "ticks": ticks,
            "late_ticks": s["late_ticks"], "late_fraction": s["late_ticks"] / ticks,
            "held_ticks": s["held_ticks"], "held_fraction": s["held_ticks"] / ticks,
            "achieved_speed": s["achieved_speed"],
            "p50_ms": lat.get("p50_ms"), "p99_ms": lat.get("p99_ms"), "max_ms": lat.get("max_ms"),
            "crossings_per_tick": crossings_per_tick(s, ticks),
            "keeps_up": not miss, "missed": miss, "load_avg": load()}


def floor_measure(n: int, folder: Path, duration: float) -> dict:
    config = folder / f"scale-{n}.toml"
    config.write_text(scenario_toml(n, duration))
    r = floor_realtime(config, duration, "routed")
    miss = missed(r["late_fraction"], 0.0, r["sense_to_command"].get("p99_ms"))  # the floor's world never holds
    return {"robots": n, "late_fraction": r["late_fraction"], "achieved_speed": r["achieved_speed"],
            "p50_ms": r["sense_to_command"].get("p50_ms"), "p99_ms": r["sense_to_command"].get("p99_ms"),
            "crossings_per_tick": r["crossings_per_tick"], "keeps_up": not miss, "missed": miss,
            "load_avg": r["load_avg"]}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", default="12,24,48,64,100")
    p.add_argument("--duration", type=float, default=20.0, help="simulation seconds per run")
    p.add_argument("--repeat", type=int, default=1, help="runs per size; the median run (by p99) is kept")
    p.add_argument("--floor", action="store_true", help="also the floor at each size, interleaved")
    p.add_argument("--keep-going", action="store_true", help="try every size, not stopping at the first failure")
    p.add_argument("--write-config", nargs=2, metavar=("N", "PATH"), help="write the N-robot scenario and exit")
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "scale.json"))
    a = p.parse_args()
    if a.write_config:
        Path(a.write_config[1]).write_text(scenario_toml(int(a.write_config[0])))
        return 0
    sizes = sorted(int(x) for x in a.sizes.split(","))
    result: dict = {"machine": machine(), "rate_hz": 1 / DT, "late_limit": LATE_LIMIT, "p99_limit_ms": P99_LIMIT_MS,
                    "sizes": []}
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            runs, floors = [], []
            for _ in range(a.repeat):
                try:
                    runs.append(measure(n, Path(tmp), a.duration))
                except RuntimeError as exc:  # a swarm that could not even finish: it did not keep up
                    runs.append({"robots": n, "keeps_up": False, "error": str(exc)[-500:], "load_avg": load()})
                print("runtime", json.dumps(runs[-1]), file=sys.stderr, flush=True)
                if a.floor:
                    floors.append(floor_measure(n, Path(tmp), a.duration))
                    print("floor", json.dumps(floors[-1]), file=sys.stderr, flush=True)
            ok = [r for r in runs if "p99_ms" in r]
            entry = {"robots": n, "runs": runs,
                     "keeps_up": statistics.median(1.0 if r["keeps_up"] else 0.0 for r in runs) >= 0.5}
            if ok:
                entry["median_p50_ms"] = statistics.median(r["p50_ms"] for r in ok)
                entry["median_p99_ms"] = statistics.median(r["p99_ms"] for r in ok)
            if floors:
                entry["floor"] = floors
            result["sizes"].append(entry)
            if not entry["keeps_up"] and not a.keep_going:
                break
    kept = [e["robots"] for e in result["sizes"] if e["keeps_up"]]
    result["largest_real_time"] = max(kept) if kept else None
    write_json(a.out, result)
    print(json.dumps({"largest_real_time": result["largest_real_time"],
                      "sizes": [{k: e.get(k) for k in ("robots", "keeps_up", "median_p50_ms", "median_p99_ms")}
                                for e in result["sizes"]]}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
