"""``fxswarm check CONFIG [--tolerate F]``: does the scenario's graph, with its pinned robots,
meet the condition W-MSR needs for F liars (docs/resilience.md "The graph condition")?

Exit status 0: it does; 1: it does not; 2: the scenario is broken.
"""

from __future__ import annotations

import argparse
import json
import warnings

from fxswarm.core.resilience import EXACT_ROBUSTNESS_MAX_N, check_graph
from fxswarm.core.scenario import ScenarioWarning
from fxswarm.runtime.config import load_or_exit


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="scenario file (TOML)")
    p.add_argument("--tolerate", type=int, default=None, metavar="F",
                   help="liars to check for (default: the scenario's [estimator] tolerate, else 1)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def main(args: argparse.Namespace) -> int:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ScenarioWarning)  # this command says it itself, below
        sc = load_or_exit(args.config)
    f = args.tolerate if args.tolerate is not None else (sc.tolerate if sc.resilience == "w-msr" else 1)
    if f < 1:
        print(f"fxswarm check: --tolerate: expected an integer >= 1, got {f}")
        return 2
    got = check_graph(sc.graph, sc.b, f)
    pinned = [r.id for r in sc.robots if sc.is_pinned(r.id)]
    if args.json:
        print(json.dumps({"scenario": sc.name, "robots": sc.n, "pinned": pinned, **got}))
        return 0 if got["meets"] else 1
    r = got["r"]
    print(f"{sc.source}: {sc.n} robots, pinned {', '.join(map(str, pinned))}, checking for F = {f} "
          f"liar{'s' * (f > 1)} (W-MSR discards {f} above and {f} below, per axis)")
    if got["meets"]:
        print(f"meets the condition: every robot is pinned or linked to at least {r} robots that meet it "
              f"(so every set of robots holds one pinned or with {r} links out of the set): the graph "
              f"condition W-MSR needs against {f} liar{'s' * (f > 1)} among each robot's neighbours holds")
    else:
        print(f"does NOT meet the condition: robots {', '.join(map(str, got['unreached']))} are neither "
              f"pinned nor linked to {r} robots that meet it; one liar can hold them off the leader, and "
              f"W-MSR without a liar may too (a robot with fewer than {2 * f + 1} values can discard "
              f"all its neighbours' on an axis)")
    rob = got["robustness"]
    print("robots' graph alone: " + (f"{rob}-robust (exact)" if rob is not None else
                                     f"r-robustness unknown (exact only up to {EXACT_ROBUSTNESS_MAX_N} robots)")
          + f"; leaderless W-MSR needs {r}-robust for {f} local liar{'s' * (f > 1)}")
    return 0 if got["meets"] else 1
