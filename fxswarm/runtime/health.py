"""``fxswarm health ROLE [ID]``: is this process of the swarm alive? Exit 0 if so, 1 if not.

The answer comes from the system's own liveliness: every role process
declares the token ``fxswarm/<swarm>/alive/<role>/<id>`` once it is ready
(subscribed, recording open, ...), and Zenoh withdraws it when the process
dies or its session's lease runs out. This command opens a short client
session, asks for that token and exits; it is what the compose file's
health checks run, and what a person can run to ask the same question::

    fxswarm health agent 3 --swarm paper-fast --connect tcp/127.0.0.1:7447

Defaults come from the environment, so a container's health check needs no
options: ``FXSWARM_SWARM`` (swarm name) and ``FXSWARM_CONNECT`` (router
endpoint, default ``tcp/router:7447``, the router service of the compose file).
Secure mode (``--secure KEYS`` or ``FXSWARM_SECURE``): it shows a certificate from
KEYS, by default the asked process's own (a container holds only its own), or
``--as NAME`` (``observer`` for a person); every identity may ask for tokens.
"""

from __future__ import annotations

import argparse
import os
import sys

from fxswarm.runtime.numbers import positive, swarm_name

ROLES = ("router", "world", "leader", "agent", "logger")
DEFAULT_CONNECT = "tcp/router:7447"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("role", choices=ROLES, help="the role whose liveliness token to ask for")
    p.add_argument("id", nargs="?", default="0", help="robot id for an agent (default 0: the only one)")
    p.add_argument("--swarm", type=swarm_name, default=os.environ.get("FXSWARM_SWARM", "default"),
                   help="swarm name (default: $FXSWARM_SWARM, else 'default')")
    p.add_argument("--connect", default=os.environ.get("FXSWARM_CONNECT", DEFAULT_CONNECT), metavar="ENDPOINT",
                   help=f"router to ask (default: $FXSWARM_CONNECT, else {DEFAULT_CONNECT})")
    p.add_argument("--timeout", type=positive, default=2.0, metavar="S",
                   help="how long to wait for the router and for the answer (default 2 s)")
    p.add_argument("--quiet", action="store_true", help="no line on stdout")
    p.add_argument("--router-down-ok", action="store_true",
                   help="exit 0 when the router cannot be reached (the process cannot be judged then): a "
                        "container's health check must not have a router's restart kill every process")
    p.add_argument("--secure", default=os.environ.get("FXSWARM_SECURE") or None, metavar="KEYS",
                   help="keys folder (secure mode; default $FXSWARM_SECURE): ask over mutual TLS")
    p.add_argument("--as", dest="identity", default=None, metavar="NAME",
                   help="secure: whose certificate to show (default: the asked process's own)")


def token_key(swarm: str, role: str, ident: str) -> str:
    """The liveliness key a process of ``role``/``ident`` declares (fxswarm.core.bus)."""
    from fxswarm.core.bus import alive_topic, prefix

    return f"{prefix(swarm)}/{alive_topic(role, ident)}"


def is_alive(swarm: str, role: str, ident: str, connect: str, timeout: float, tls=None) -> bool:
    """Whether the token of ``role``/``ident`` is declared, as seen through the router at ``connect``.

    Raises ``OSError`` (with the endpoint named) if the router cannot be reached in ``timeout`` s.
    """
    import zenoh  # here, so that `fxswarm health --help` stays instant

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", f'["{connect}"]')
    conf.insert_json5("connect/timeout_ms", str(int(timeout * 1000)))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if tls is not None:
        tls.insert_into(conf)
    try:
        session = zenoh.open(conf)
    except Exception as exc:  # zenoh raises its own ZError
        raise OSError(f"cannot reach the router at {connect}: {exc}") from None
    try:
        # The first reply is enough; the get ends as soon as the router has answered.
        for reply in session.liveliness().get(token_key(swarm, role, ident), timeout=timeout):
            if reply.ok is not None:
                return True
        return False
    finally:
        session.close()


def main(args: argparse.Namespace) -> int:
    ident = args.id
    name = f"{args.role}/{ident}"
    tls = None
    if args.secure:
        from fxswarm.runtime.tls import KeyFileError, checked, identity, tls_endpoints

        try:
            tls_endpoints([args.connect], "--connect")
            tls = checked(args.secure, args.identity or identity(args.role, ident))
        except (KeyFileError, ValueError) as exc:
            print(f"fxswarm health: {exc}", file=sys.stderr)
            return 2
    try:
        alive = is_alive(args.swarm, args.role, ident, args.connect, args.timeout, tls)
    except OSError as exc:
        print(f"fxswarm health: {name} of swarm {args.swarm!r}: {exc}"
              f"{' (not judged: --router-down-ok)' if args.router_down_ok else ''}", file=sys.stderr)
        return 0 if args.router_down_ok else 1
    if not args.quiet:
        print(f"{name} of swarm {args.swarm!r}: {'alive' if alive else 'not alive'}")
    return 0 if alive else 1
