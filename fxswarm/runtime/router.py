"""``fxswarm router``: a Zenoh router as a Python session in router mode.

Clients (``--mode client --connect tcp/HOST:PORT``) route through it, so no
separate ``zenohd`` binary is needed. It declares the liveliness token
``fxswarm/<swarm>/alive/router/0`` so a launcher can wait for it, and closes
its session on SIGINT/SIGTERM.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading

import zenoh

from fxswarm.core.bus import alive_topic, prefix
from fxswarm.runtime.process import PARENT_ENV

DEFAULT_LISTEN = "tcp/0.0.0.0:7447"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--listen", action="append", default=None, metavar="ENDPOINT",
                   help=f"endpoint to listen on (repeatable; default {DEFAULT_LISTEN})")
    p.add_argument("--swarm", default="default", help="swarm whose alive/router/0 token this router declares")
    p.add_argument("--multicast", action="store_true",
                   help="also answer UDP multicast scouting (off by default)")


def router_config(listen: list[str], multicast: bool) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", "[" + ",".join(f'"{e}"' for e in listen) + "]")
    conf.insert_json5("scouting/multicast/enabled", "true" if multicast else "false")
    return conf


def main(args: argparse.Namespace) -> int:
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    parent = os.environ.get(PARENT_ENV)
    listen = args.listen or [DEFAULT_LISTEN]
    try:
        session = zenoh.open(router_config(listen, args.multicast))
    except zenoh.ZError as exc:  # e.g. the port is taken
        print(f"fxswarm router: cannot listen on {', '.join(listen)}: {exc}", file=sys.stderr)
        return 1
    try:
        token = session.liveliness().declare_token(f"{prefix(args.swarm)}/{alive_topic('router', 0)}")
        while not stop.wait(0.2):
            if parent and os.getppid() != int(parent):
                break  # the launcher is gone: do not outlive it
        token.undeclare()
    finally:
        session.close()
    return 0
