"""``fxswarm sim CONFIG --out DIR``: the in-process simulator."""

from __future__ import annotations

import argparse
import json
import sys

from fxswarm.faults.plan import CLI_HELP as FAULT_HELP
from fxswarm.runtime.config import load_or_exit, plan_or_exit
from fxswarm.runtime.output import prepare_run_folder, write_run
from fxswarm.launch.sim import Simulation, progress_line


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="scenario file (TOML)")
    p.add_argument("--out", default=None, help="run folder for summary.json and trajectory.npz "
                   "(default: runs/<scenario name>-sim)")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.add_argument("--fault", action="append", default=None, metavar="SPEC", help=FAULT_HELP)


def main(args: argparse.Namespace) -> int:
    sc = load_or_exit(args.config)
    plan = plan_or_exit(sc, args.fault)  # the [faults] table and every --fault, resolved once
    out = prepare_run_folder(args.out or f"runs/{sc.name}-sim", "fxswarm sim")
    sim = Simulation(sc, plan)
    summary = sim.run(progress=None if args.quiet else progress_line)
    if not args.quiet:
        sys.stderr.write("\n")
    write_run(out, summary, sim.trajectory())
    if not args.quiet:
        keys = ("robots", "ticks", "wall_s", "min_object_distance_m", "formation_error_final_m",
                "estimate_error_final_m", "formation_settle_s", "estimate_settle_s")
        print(json.dumps({k: summary[k] for k in keys}, indent=2))
        print(f"wrote {out}/summary.json and {out}/trajectory.npz")
    return 0
