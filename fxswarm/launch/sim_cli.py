"""``fxswarm sim CONFIG --out DIR``: the in-process simulator."""

from __future__ import annotations

import argparse
import json
import sys

from fxswarm.core.laws import BatchUnsupported
from fxswarm.faults.plan import CLI_HELP as FAULT_HELP
from fxswarm.launch.batch import PATHS
from fxswarm.runtime.config import load_or_exit, plan_or_exit
from fxswarm.runtime.output import prepare_run_folder, write_run
from fxswarm.launch.sim import Simulation, progress_line


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="scenario file (TOML)")
    p.add_argument("--out", default=None, help="run folder for summary.json and trajectory.npz "
                   "(default: runs/<scenario name>-sim)")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.add_argument("--fault", action="append", default=None, metavar="SPEC", help=FAULT_HELP)
    p.add_argument("--path", choices=PATHS, default="auto",
                   help="auto (default): step every robot's law at once on arrays when the run allows it "
                   "(no faults, a law with a batch form), else per robot, said on stderr; the two give the "
                   "same trajectory bit for bit. batch: that or exit 2; per-robot: one agent node per robot")
    p.add_argument("--record-every", type=int, default=1, metavar="K",
                   help="keep every K-th tick in trajectory.npz (default 1: all); its size is about "
                   "ticks/K x robots x 80 bytes")


def main(args: argparse.Namespace) -> int:
    sc = load_or_exit(args.config)
    plan = plan_or_exit(sc, args.fault)  # the [faults] table and every --fault, resolved once
    if args.record_every < 1:
        print(f"fxswarm sim: --record-every: expected an integer >= 1, got {args.record_every}", file=sys.stderr)
        return 2
    try:
        sim = Simulation(sc, plan, path=args.path, record_every=args.record_every)
    except BatchUnsupported as exc:
        print(f"fxswarm sim: --path batch: {exc}", file=sys.stderr)
        return 2
    if sim.path_reason is not None and args.path == "auto":
        print(f"fxswarm sim: per-robot path: {sim.path_reason}", file=sys.stderr)
    out = prepare_run_folder(args.out or f"runs/{sc.name}-sim", "fxswarm sim")
    summary = sim.run(progress=None if args.quiet else progress_line)
    if not args.quiet:
        sys.stderr.write("\n")
    write_run(out, summary, sim.trajectory())
    if not args.quiet:
        keys = ("robots", "ticks", "path", "wall_s", "min_object_distance_m", "formation_error_final_m",
                "estimate_error_final_m", "formation_settle_s", "estimate_settle_s")
        print(json.dumps({k: summary[k] for k in keys}, indent=2))
        print(f"wrote {out}/summary.json and {out}/trajectory.npz")
    return 0
