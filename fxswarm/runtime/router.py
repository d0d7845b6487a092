"""``fxswarm router``: a Zenoh router as a Python session in router mode.

Clients (``--mode client --connect tcp/HOST:PORT``) route through it, so no
separate ``zenohd`` binary is needed. It declares the liveliness token
``fxswarm/<swarm>/alive/router/<id>`` so a launcher can wait for it, and every process can
tell a router's outage (its clients' tokens go with its own) from a process's death, and closes
its session on SIGINT/SIGTERM.

Secure mode (``--secure KEYS``, docs/security.md): it listens on ``tls/``
endpoints only, with mutual TLS (a client must show a certificate of the
swarm's CA), and enforces ``KEYS/access.json`` (or ``--access FILE``): Zenoh's
access control by certificate common name, default deny. It is then the one
place where rights are enforced: every process is its client. A peer refused
by TLS is logged here (Zenoh's warning, e.g. ``invalid peer certificate``);
with ``--audit`` each message refused by the rules is too, once per
(process, action, key), and counted at exit.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import sys
import threading
from collections import Counter
from pathlib import Path

import zenoh

from fxswarm.core.bus import SCENARIO, alive_topic, prefix
from fxswarm.runtime.numbers import swarm_name
from fxswarm.runtime.process import PARENT_ENV
from fxswarm.runtime.tls import SECURE_ENV, KeyFileError, TlsFiles, checked, load_access, tls_endpoints
from fxswarm.runtime.zenoh_bus import RECONNECT_RETRY

DEFAULT_LISTEN = "tcp/0.0.0.0:7447"
DEFAULT_SECURE_LISTEN = "tls/0.0.0.0:7447"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--listen", action="append", default=None, metavar="ENDPOINT",
                   help=f"endpoint to listen on (repeatable; default {DEFAULT_LISTEN}, "
                        f"with --secure {DEFAULT_SECURE_LISTEN})")
    p.add_argument("--swarm", type=swarm_name, default="default", help="swarm whose alive/router/ID token this router declares")
    p.add_argument("--id", type=int, default=0, help="this router's number among the swarm's routers (its token "
                                                     "alive/router/ID; default 0)")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="another router to mesh with (repeatable): one router per host, each connected to "
                        "the others, every process a client of its own host's router (docs/deploy.md)")
    p.add_argument("--multicast", action="store_true",
                   help="also answer UDP multicast scouting (off by default)")
    p.add_argument("--scenario", default=None, metavar="FILE",
                   help="serve this scenario file's text at <swarm prefix>/scenario, for observers that "
                        "join from elsewhere (`fxswarm attach` without --config)")
    g = p.add_argument_group("secure mode (docs/security.md)")
    g.add_argument("--secure", default=os.environ.get(SECURE_ENV) or None, metavar="KEYS",
                   help=f"keys folder from `fxswarm keys`: mutual TLS with router.pem/router.key, rules from "
                        f"access.json (default: ${SECURE_ENV})")
    g.add_argument("--access", default=None, metavar="FILE",
                   help="access rules (JSON, Zenoh's access_control section; default KEYS/access.json)")
    g.add_argument("--audit", action="store_true",
                   help="log every message the rules refuse (first per process, action and key) and count them")


def router_settings(listen: list[str], multicast: bool = False, tls: TlsFiles | None = None,
                    access: dict | None = None, connect: list[str] = ()) -> dict:
    """A router's Zenoh configuration as plain data: what ``fxswarm router`` opens its session
    with and what the launcher writes as the official router's (zenohd) file, built here only."""
    conf: dict = {"mode": "router", "listen": {"endpoints": list(listen)},
                  "scouting": {"multicast": {"enabled": multicast}}}
    if connect:
        # Routers on several hosts start in any order: a peer router not up yet is retried in
        # the background (no time limit, no exit on failure). A limit of 0 would mean a single
        # attempt and no retry, so a router started before its peer never meshed with it.
        # The retry period: a restarted peer router is met again at once.
        conf["connect"] = {"endpoints": list(connect), "timeout_ms": -1, "exit_on_failure": False,
                           "retry": dict(RECONNECT_RETRY)}
    if tls is not None:
        conf["transport"] = {"link": {"tls": tls.zenoh_tls(listen=True)}}
    if access is not None:
        conf["access_control"] = access
    return conf


def router_config(listen: list[str], multicast: bool, tls: TlsFiles | None = None,
                  access: dict | None = None, connect: list[str] = ()) -> zenoh.Config:
    return zenoh.Config.from_json5(json.dumps(router_settings(listen, multicast, tls, access, connect)))


# --- audit: the access-control interceptor's own decisions, from Zenoh's log ------------------

# Zenoh evaluates every action for a key when a face first meets it ("caching permissions",
# with the subject's certificate name), then logs each real decision as "Using cached result".
_DECISION = re.compile(r"Using cached result: (?P<zid>[0-9a-f]+) is unauthorized to (?P<what>.+?) on (?P<key>\S+)")
_CN = re.compile(r"(?P<zid>[0-9a-f]{16,32}) on \S*CertCommonName\((?P<cn>[^)]*)\)")
AUDIT_LOG_FILTER = "warn,zenoh::net::routing::interceptor::access_control=trace"


class Audit:
    """Reads Zenoh's log (our stdout, where Zenoh writes it, through a pipe), keeps refusals.

    Zenoh reports access-control decisions only at trace level, allowed ones included
    (and decisions it evaluates ahead, for keys a peer declares): so this is opt-in, and
    only lines saying ``unauthorized`` for a put, a subscription or a token are kept.
    """

    KINDS = ("Put", "Declare Subscriber", "Liveliness Token", "Declare/Undeclare Liveliness Token")

    def __init__(self) -> None:
        self.counts: Counter = Counter()
        self.names: dict[str, str] = {}
        read_fd, write_fd = os.pipe()
        os.environ["NO_COLOR"] = "1"  # plain lines to parse
        self._out = os.fdopen(os.dup(1), "w", buffering=1)  # the real stdout
        os.dup2(write_fd, 1)
        os.close(write_fd)
        self._in = os.fdopen(read_fd, "r", errors="replace")
        self._thread = threading.Thread(target=self._pump, name="audit", daemon=True)
        self._thread.start()

    def _pump(self) -> None:
        for line in self._in:
            if "access_control" not in line:
                self._out.write(line)
                continue
            cn = _CN.search(line)
            if cn is not None:
                self.names[cn.group("zid")] = cn.group("cn")
                continue
            m = _DECISION.search(line)
            if m is None or not m.group("what").startswith(self.KINDS):
                continue
            who = self.names.get(m.group("zid"), m.group("zid")[:8])
            key = (who, m.group("what"), m.group("key"))
            self.counts[key] += 1
            if self.counts[key] == 1:
                self._out.write(f"fxswarm router: refused: {who}: {m.group('what')} on {m.group('key')} "
                                f"(further ones only counted)\n")

    def report(self) -> None:
        if self.counts:
            self._out.write("fxswarm router: refusals by the access rules (process, action, key: count):\n")
            for (who, what, key), n in sorted(self.counts.items()):
                self._out.write(f"    {who}, {what}, {key}: {n}\n")
        else:
            self._out.write("fxswarm router: no message refused by the access rules\n")


def main(args: argparse.Namespace) -> int:
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    parent = os.environ.get(PARENT_ENV)
    tls = access = None
    listen = args.listen or [DEFAULT_SECURE_LISTEN if args.secure else DEFAULT_LISTEN]
    if args.secure:
        try:
            tls_endpoints(listen, "--listen")
            tls = checked(args.secure, "router")
            access = load_access(args.access or Path(args.secure) / "access.json")
        except (KeyFileError, ValueError) as exc:
            print(f"fxswarm router: {exc}", file=sys.stderr)
            return 2
    elif args.access or args.audit:
        print("fxswarm router: --access and --audit need --secure KEYS (rules go by certificate)", file=sys.stderr)
        return 2
    audit = None
    if args.secure:
        # TLS refusals (no certificate, another CA) are Zenoh warnings: show them in this log.
        if args.audit:
            audit = Audit()
            zenoh.init_log_from_env_or(AUDIT_LOG_FILTER)
        else:
            zenoh.init_log_from_env_or("warn")
    try:
        session = zenoh.open(router_config(listen, args.multicast, tls, access, args.connect))
    except zenoh.ZError as exc:  # e.g. the port is taken
        print(f"fxswarm router: cannot listen on {', '.join(listen)}: {exc}", file=sys.stderr)
        return 1
    if args.secure:
        print(f"fxswarm router: secure: mutual TLS on {', '.join(listen)}, rules of "
              f"{args.access or Path(args.secure) / 'access.json'}", file=sys.stderr, flush=True)
    try:
        served = None
        if args.scenario:
            text = open(args.scenario, "rb").read()  # read once: an observer gets the file the run started with
            key = f"{prefix(args.swarm)}/{SCENARIO}"
            served = session.declare_queryable(key, lambda query: query.reply(key, text))
        token = session.liveliness().declare_token(f"{prefix(args.swarm)}/{alive_topic('router', args.id)}")
        while not stop.wait(0.2):
            if parent and os.getppid() != int(parent):
                break  # the launcher is gone: do not outlive it
        token.undeclare()
        if served is not None:
            served.undeclare()
    finally:
        session.close()
        if audit is not None:
            audit.report()
    return 0
