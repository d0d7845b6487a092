"""``fxswarm expand SCENARIO``: a scenario's explicit form on stdout (its ``[swarm]`` table
written out as ``[[robots]]`` and ``[graph]``: fxswarm.core.swarm), checked as ``fxswarm sim``
checks it (a broken one: the file and the field on stderr, exit 2)."""

from __future__ import annotations

import argparse
import sys

from fxswarm.core.swarm import expand
from fxswarm.core.tomltext import dump_toml
from fxswarm.runtime.config import load_or_exit


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="scenario file (TOML)")


def main(args: argparse.Namespace) -> int:
    sc = load_or_exit(args.config)  # every check, [swarm] expanded inside: exit 2 naming the field
    data = dict(sc.raw)
    sys.stdout.write(dump_toml(expand(data, sc.source)))
    return 0
