"""``fxswarm sim CONFIG --out DIR``: the in-process simulator."""

from __future__ import annotations

import argparse
import json
import sys
import warnings

from fxswarm.core.scenario import ScenarioError, ScenarioWarning, load
from fxswarm.faults.plan import CLI_HELP as FAULT_HELP
from fxswarm.faults.plan import with_cli_faults
from fxswarm.runtime.output import prepare_run_folder, write_run
from fxswarm.runtime.sim import Simulation, progress_line


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="scenario file (TOML)")
    p.add_argument("--out", default=None, help="run folder for summary.json and trajectory.npz "
                   "(default: runs/<scenario name>-sim)")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.add_argument("--fault", action="append", default=None, metavar="SPEC", help=FAULT_HELP)


def load_or_exit(path: str):
    """Load a scenario; on error print it and exit 2 (scenario warnings go to stderr)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ScenarioWarning)
        try:
            sc = load(path)
        except ScenarioError as exc:
            print(f"fxswarm: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
    for w in caught:
        print(f"fxswarm: warning: {w.message}", file=sys.stderr)
    return sc


def with_faults_or_exit(sc, specs: list[str] | None):
    """``sc`` with the command line's ``--fault`` specs; on error print it and exit 2."""
    try:
        return with_cli_faults(sc, specs)
    except ScenarioError as exc:
        print(f"fxswarm: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


def main(args: argparse.Namespace) -> int:
    sc = with_faults_or_exit(load_or_exit(args.config), args.fault)
    out = prepare_run_folder(args.out or f"runs/{sc.name}-sim", "fxswarm sim")
    sim = Simulation(sc)
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
