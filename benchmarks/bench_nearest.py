"""The world's nearest object per tick: the dense matrix, a KD-tree each tick, the kept candidate lists.

    python benchmarks/bench_nearest.py [--sizes 1000,10000] [--ticks 50] [--repeat 3]
        [--out benchmarks/results/nearest.json]

A swarm of N robots on a grid 2 m apart, each starting within 1 m of its slot, moving by a
random 0.5 m/s step each tick of 0.02 s, 4 obstacles. Per tick, interleaved A B C A B C:
``world.node.nearest_objects`` dense (N <= 2000: n x (n + m) distances), the KD-tree each tick
(:func:`fxswarm.core.nearest.nearest_objects_tree`) and the kept lists
(:class:`fxswarm.core.nearest.NearestCache`); ms per tick, best of ``--repeat``. Every answer is
checked equal to the tree's (and the dense one's, where run).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_io import machine, write_json  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000,10000")
    ap.add_argument("--ticks", type=int, default=50)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "nearest.json"))
    a = ap.parse_args()
    from fxswarm.core.nearest import NearestCache, nearest_objects_tree
    from fxswarm.world import node as world_node

    world_node.DENSE_NEAREST_MAX = 10**9  # nearest_objects: always the dense matrix here
    result = {"machine": machine(), "ticks": a.ticks, "repeat": a.repeat, "sizes": []}
    for n in (int(x) for x in a.sizes.split(",")):
        side = int(np.ceil(np.sqrt(n)))
        rng = np.random.default_rng(1)
        start = np.array([[i % side, i // side, 0.0] for i in range(n)]) * 2.0 + rng.uniform(-1, 1, (n, 3))
        obstacles, obstacle_v = rng.uniform(-side, side, (4, 3)), np.zeros((4, 3))
        steps = [rng.normal(size=(n, 3)) * 0.5 for _ in range(a.ticks)]
        methods = {"tree": lambda: nearest_objects_tree, "cached": NearestCache}
        if n <= 2000:
            methods["dense"] = lambda: world_node.nearest_objects
        best = {name: np.inf for name in methods}
        for _ in range(a.repeat):
            answers = {}
            for name, make in methods.items():
                fn, p, total, out = make(), start.copy(), 0.0, []
                for v in steps:
                    t0 = time.perf_counter()
                    got = fn(p, v, obstacles, obstacle_v)
                    total += time.perf_counter() - t0
                    out.append(got[2].tobytes() + got[0].tobytes())
                    p = p + 0.02 * v
                answers[name] = out
                best[name] = min(best[name], total / a.ticks)
            assert all(answers[name] == answers["tree"] for name in answers), "answers differ"
        entry = {"robots": n, "ms_per_tick_best": {k: round(v * 1e3, 3) for k, v in best.items()}}
        result["sizes"].append(entry)
        print(entry, file=sys.stderr)
    result["machine"]["load_avg_at_end"] = round(__import__("os").getloadavg()[0], 2)
    write_json(a.out, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
