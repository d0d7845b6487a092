"""The Zenoh bus: the :class:`fxswarm.core.bus.Bus` interface over Eclipse Zenoh.

Keys are ``fxswarm/<swarm>/<topic>``. Zenoh delivers samples on its own
threads; the process's main loop calls :meth:`ZenohBus.poll`, and handlers
only ever run while a ``poll`` is in progress, one at a time. By default the
callbacks enqueue the raw bytes and ``poll`` decodes, validates and hands
them to the handlers on the calling thread. ``poll(timeout, stay=True)``
(lock-step loops) instead lets the callback thread run the handler itself
while the caller sleeps: one thread hand-over less per message, which is
most of what a message costs a Python process (benchmarks/studies/bench_transport.py).
Liveliness changes always go through the queue, so they end a ``poll`` at
once and a loop reacts to a departure without waiting out its timeout.

Invalid payloads (not msgpack, wrong schema, wrong shape, non-finite values,
or a sender that does not match its key, e.g. ``agent/3/cmd`` signed by
robot 4) are dropped, counted in ``counters.invalid`` and warned about once
per key.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import queue
import sys
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import zenoh

from fxswarm.core import bus as topics
from fxswarm.core.bus import Counters, Handler
from fxswarm.core.messages import Clock, Command, Estimate, LeaderState, Message, Sense, WireError, WorldState, decode, encode
from fxswarm.core.scenario import ZENOH_MODES
from fxswarm.runtime.numbers import non_negative, positive_int, swarm_name
from fxswarm.runtime.tls import SECURE_ENV, TlsFiles, checked, load_access, session_rules, tls_endpoints

AliveHandler = Callable[[str, bool], None]  # (``role/id``, up?)


@dataclass(frozen=True)
class ZenohOptions:
    """How a process joins the Zenoh network.

    mode: ``peer`` | ``client`` | ``router``; connect/listen: endpoints such as
    ``tcp/127.0.0.1:7447``; multicast: UDP multicast scouting (off in what
    ``fxswarm run`` starts: peers meet at the router instead, and a multicast
    mesh does not scale, notes/zenoh.md);
    lease_ms: how long a silent (e.g. frozen) session stays alive to others;
    connect_timeout_ms: how long ``open`` waits for its router (-1: forever);
    tls: secure mode's files (mutual TLS on ``tls/`` endpoints; docs/security.md), or None;
    access: secure mode, a mesh peer: the swarm's rules file, which it enforces on its direct links.
    """

    mode: str = "peer"
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    multicast: bool = True
    lease_ms: int | None = None
    connect_timeout_ms: int = 30_000
    tls: TlsFiles | None = None
    access: Path | None = None

    def config(self) -> zenoh.Config:
        if self.mode not in ZENOH_MODES:
            raise ValueError(f"zenoh mode: expected one of {', '.join(ZENOH_MODES)}, got {self.mode!r}")
        conf = zenoh.Config()
        conf.insert_json5("mode", f'"{self.mode}"')
        if self.connect:
            conf.insert_json5("connect/endpoints", _json_list(self.connect))
            conf.insert_json5("connect/timeout_ms", str(self.connect_timeout_ms))
            # A lost router is retried (Zenoh reconnects by itself, also to the next router listed)
            # every 0.1 s at first, at most every 1 s: a restarted router is rejoined at once.
            conf.insert_json5("connect/retry", RECONNECT)
        if self.listen:
            conf.insert_json5("listen/endpoints", _json_list(self.listen))
        conf.insert_json5("scouting/multicast/enabled", "true" if self.multicast else "false")
        if self.lease_ms is not None:
            conf.insert_json5("transport/link/tx/lease", str(int(self.lease_ms)))
        if self.tls is not None:
            self.tls.insert_into(conf, listen=bool(self.listen))
            rules = session_rules(self.mode, load_access(self.access) if self.access is not None else None)
            conf.insert_json5("access_control", json.dumps(rules))
        return conf

    def as_args(self) -> list[str]:
        """The command-line form of these options, for a child process."""
        out = ["--mode", self.mode]
        for e in self.connect:
            out += ["--connect", e]
        for e in self.listen:
            out += ["--listen", e]
        out.append("--multicast" if self.multicast else "--no-multicast")
        if self.lease_ms is not None:
            out += ["--lease-ms", str(self.lease_ms)]
        if self.tls is not None:
            out += ["--secure", str(self.tls.ca.parent)]  # each child takes its own pair from the folder
        if self.access is not None:
            out += ["--access", str(self.access)]
        return out


RECONNECT_RETRY = {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2}
RECONNECT = json.dumps(RECONNECT_RETRY)  # JSON is JSON5


def _json_list(items) -> str:
    return "[" + ",".join(f'"{x}"' for x in items) + "]"


def log_zenoh_warnings() -> None:
    """Zenoh's own warnings (e.g. a TLS handshake refused) to stderr, the process's log; once per
    process, and ``RUST_LOG`` wins."""
    zenoh.init_log_from_env_or("warn")


class ConnectError(RuntimeError):
    """No Zenoh session: the router stayed unreachable, or the configuration was refused."""


def open_session(options: ZenohOptions, who: str = "fxswarm",
                 on_wait: Callable[[], None] | None = None) -> zenoh.Session:
    """``zenoh.open``, for a client in attempts of at most 1 s until ``connect_timeout_ms``.

    A client blocks in ``zenoh.open`` until its router answers, deaf to Ctrl-C (a signal is
    handled only between Python steps) and silent. In 1 s steps a signal ends the wait within
    a second, and a wait is announced once. Raises :class:`ConnectError`, never a traceback.
    ``on_wait()``, if given, is called after each failed attempt instead of the announcement,
    and may raise to end the wait (the launcher: the router it started has died).
    """
    if options.mode != "client" or not options.connect:
        try:
            return zenoh.open(options.config())
        except zenoh.ZError as exc:
            raise ConnectError(f"{who}: could not open a Zenoh session ({options.mode}): {exc}") from None
    total_s = options.connect_timeout_ms / 1000
    deadline = None if total_s < 0 else time.monotonic() + total_s
    attempt = replace(options, connect_timeout_ms=1000 if deadline is None else min(1000, options.connect_timeout_ms))
    where = ", ".join(options.connect)
    announced = False
    while True:
        try:
            return zenoh.open(attempt.config())
        except zenoh.ZError as exc:
            if deadline is not None and time.monotonic() >= deadline:
                raise ConnectError(f"{who}: no router answered at {where} within {total_s:g} s "
                                   f"(is it running, and is the address right?): {exc}") from None
        if on_wait is not None:
            on_wait()
        elif not announced:
            announced = True
            limit = "until it answers" if deadline is None else f"up to {total_s:g} s"
            print(f"{who}: waiting for the router at {where} ({limit})", file=sys.stderr, flush=True)


def add_zenoh_arguments(p: argparse.ArgumentParser, default_swarm: str = "default") -> None:
    """The options every process shares: swarm name and how to join Zenoh."""
    g = p.add_argument_group("zenoh")
    g.add_argument("--swarm", type=swarm_name, default=None,
                   help=f"key prefix fxswarm/<swarm>/...: two swarms never cross-talk "
                        f"(default: the scenario's [zenoh] swarm, else {default_swarm!r})")
    g.add_argument("--mode", choices=ZENOH_MODES, default=None, help="zenoh session mode (default: peer)")
    g.add_argument("--connect", action="append", default=None, metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable: a client uses the first "
                        "router that answers and fails over to the others when it is lost)")
    g.add_argument("--listen", action="append", default=None, metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable)")
    g.add_argument("--multicast", dest="multicast", action="store_true", default=None,
                   help="enable UDP multicast scouting (default for peers)")
    g.add_argument("--no-multicast", dest="multicast", action="store_false",
                   help="disable UDP multicast scouting")
    g.add_argument("--lease-ms", type=positive_int, default=None,
                   help="session lease: how fast a frozen process is seen as gone")
    g.add_argument("--connect-timeout", type=non_negative, default=30.0, metavar="S",
                   help="a client: how long to wait for its router before giving up (default 30; 0: forever)")
    g.add_argument("--secure", default=os.environ.get(SECURE_ENV) or None, metavar="KEYS",
                   help="secure mode: the keys folder of `fxswarm keys` (this process uses its own certificate "
                        "and key from it); tls/ endpoints only, a client of the router or a mesh peer "
                        f"(docs/security.md; default ${SECURE_ENV})")
    g.add_argument("--access", default=None, metavar="FILE",
                   help="secure mesh peer: the swarm's access rules it enforces on its direct links "
                        "(default KEYS/access.json)")


def options_from_args(args: argparse.Namespace, table: dict | None = None,
                      identity: str | None = None) -> tuple[str, ZenohOptions]:
    """(swarm, options) from the command line, falling back to a scenario's ``[zenoh]`` table
    (``Scenario.zenoh``, checked when the scenario was read).

    With ``--secure KEYS``: ``identity``'s files from KEYS, checked (a
    :class:`~fxswarm.runtime.tls.KeyFileError`, a ValueError, names the file), ``tls/``
    endpoints only, and the process either a client of the router (which enforces the
    swarm's rules) or a mesh peer that enforces them on its own links too (docs/security.md).
    """
    table = table or {}
    swarm = args.swarm or table.get("swarm") or "default"
    mode = args.mode or table.get("mode") or "peer"
    # [zenoh] routers: the swarm's routers, all listed, so a process fails over among them.
    connect = tuple(args.connect or table.get("connect") or table.get("routers") or ())
    listen = tuple(args.listen or table.get("listen") or ())
    multicast = args.multicast if args.multicast is not None else table.get("multicast", mode == "peer")
    lease = args.lease_ms if args.lease_ms is not None else table.get("lease_ms")
    wait_ms = int(args.connect_timeout * 1000) if args.connect_timeout > 0 else -1
    tls = access = None
    if getattr(args, "secure", None):
        mode, listen, multicast = _secure_shape(args, connect, listen)
        tls = checked(args.secure, identity or "observer", server=mode == "peer")
        if mode == "peer":
            access = Path(getattr(args, "access", None) or Path(args.secure) / "access.json")
            load_access(access)  # a missing or broken rules file is named now, not at open
    elif getattr(args, "access", None):
        raise ValueError("--access: rules go by certificate, give --secure KEYS too")
    return swarm, ZenohOptions(mode, connect, listen, bool(multicast), lease, wait_ms, tls, access)


def _secure_shape(args, connect: tuple, listen: tuple) -> tuple[str, tuple, bool]:
    """Secure mode's (mode, listen, multicast): a client of the router, or a mesh peer that meets
    the others at the router and listens for their links on ``tls/`` only; nothing in plaintext,
    no multicast (who is in the swarm comes from the router)."""
    mode = args.mode or "client"
    if mode not in ("client", "peer"):
        raise ValueError(f"--mode {mode}: secure mode runs a process as a client of the router or as a mesh "
                         f"peer (docs/security.md)")
    if not connect:
        raise ValueError("--secure: give the router's endpoint, --connect tls/HOST:PORT")
    tls_endpoints(connect, "--connect")
    if mode == "client" and listen:
        raise ValueError("--listen: a secure client listens on nothing (its router does)")
    if mode == "peer":
        listen = listen or ("tls/127.0.0.1:0",)
        tls_endpoints(listen, "--listen")
    return mode, listen, False


# --- who may say what ----------------------------------------------------------------------


def check_sender(topic: str, msg: Message) -> None:
    """Raise :class:`WireError` unless ``msg`` is the kind, role and robot its key promises.

    ``world/sense/3`` carries a world Sense for robot 3, ``agent/3/estimate`` an
    Estimate signed by robot 3, and so on: a stranger cannot speak for a robot.
    """
    rule = _sender_rule(topic)
    if rule is None:
        return  # topics of other roles (e.g. a logger's) are theirs to check
    kind, role, robot, signed = rule
    if not (type(msg) is kind or isinstance(msg, kind)) or msg.role != role or (
            robot is not None and (msg.robot != robot or (signed and msg.sender != robot))):
        raise WireError(f"a {type(msg).__name__} from {msg.role}:{msg.sender} does not belong on {topic!r}")


class _Nobody:
    """The kind of message a key promises when no message can belong on it."""


@functools.lru_cache(maxsize=4096)
def _sender_rule(topic: str) -> tuple[type | tuple[type, ...], str, int | None, bool] | None:
    """What ``topic`` promises, parsed once per key (a message costs a dict look-up, not a split):
    (message class, sender's role, robot id or None, whether the sender must be that robot);
    None: not ours to check. A robot id must be written as ``str(id)`` writes it."""
    parts = topic.split("/")
    robot = None
    if len(parts) == 3 and parts[0] in ("world", "agent"):
        chunk = parts[2] if parts[0] == "world" else parts[1]
        robot = int(chunk) if chunk.isdigit() and str(int(chunk)) == chunk else -1  # -1: matches nobody
    if parts[0] == "world" and len(parts) == 3 and parts[1] == "sense":
        return Sense, "world", robot, False
    if parts[0] == "agent" and len(parts) == 3:
        # A robot's first estimate goes on its command key (later ones ride on its commands).
        kind = {"estimate": Estimate, "cmd": (Command, Estimate)}.get(parts[2], _Nobody)
        return kind, "agent", robot, True
    if topic == topics.LEADER_STATE:
        return LeaderState, "leader", None, False
    if topic in (topics.CLOCK, topics.RESYNC):
        return Clock, "world", None, False
    if topic == topics.WORLD_STATE:
        return WorldState, "world", None, False
    return None


# --- the bus -------------------------------------------------------------------------------

_WAKE = object()  # queued by wake(): lets a blocked poll() return at once (e.g. on a signal)
_ALIVE = object()  # tags a queued liveliness change
_RAW = object()  # tags a payload handed over undecoded (any other tag: the subscription's reader)


class ZenohBus:
    """One Zenoh session of one process, with the :class:`~fxswarm.core.bus.Bus` interface."""

    def __init__(self, swarm: str, options: ZenohOptions, validate: bool = True, drop_when_congested: bool = False,
                 batch: bool = False, who: str = "fxswarm", on_wait: Callable[[], None] | None = None,
                 direct: bool | None = None) -> None:
        """``drop_when_congested``: publish with Zenoh's DROP congestion control instead of BLOCK.

        Lock-step needs every message (BLOCK); in real time a message is worth less than
        not waiting for it: with BLOCK, one robot cut off the network fills the router's
        queue towards it and pauses every publisher, the world's clock included.

        ``batch``: publish without Zenoh's ``express`` flag, so messages sent back to back
        (the lock-step world's 8 per tick) may share a write: lock-step paper-fast spent
        ~15 % less CPU per tick; in real time it added 0.5-2 ms to the median
        sense-to-command latency, so real time keeps ``express`` (docs/design.md "Transport cost").

        ``who`` names the process in what :func:`open_session` says or raises; ``on_wait`` is
        its hook between attempts to reach a router.
        """
        self.swarm = swarm
        self._congestion = zenoh.CongestionControl.DROP if drop_when_congested else zenoh.CongestionControl.BLOCK
        self._express = not batch
        self.options = options
        self.root = topics.prefix(swarm)
        self.counters = Counters()
        self.validate = validate
        self.direct = direct if direct is not None else os.environ.get("FXSWARM_DIRECT_CALLBACKS", "0") == "1"
        self._inbox: queue.SimpleQueue = queue.SimpleQueue()
        # poll(stay=True) in progress: callbacks may dispatch on their own thread, one at a
        # time (the gate); _failed carries a handler's exception back to the polling thread.
        self._staying = False
        self._gate = threading.Lock()
        self._delivered = 0
        self._failed: BaseException | None = None
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._subscribers: list = []
        self._tokens: list = []
        self._warned: set[str] = set()
        self.session = open_session(options, who, on_wait)

    # --- Bus protocol ---------------------------------------------------------------------

    def publish(self, topic: str, msg: Message) -> None:
        self.publish_bytes(topic, encode(msg))

    def publish_all(self, outgoing) -> None:
        for topic, msg in outgoing:
            self.publish(topic, msg)

    def publish_bytes(self, topic: str, payload: bytes) -> None:
        """Put raw bytes on a topic (tests use it to send garbage)."""
        pub = self._publishers.get(topic)
        if pub is None:
            pub = self.session.declare_publisher(
                f"{self.root}/{topic}", congestion_control=self._congestion,
                priority=zenoh.Priority.REAL_TIME, express=self._express)
            self._publishers[topic] = pub
        pub.put(payload)
        self.counters.sent += 1

    def subscribe(self, pattern: str, handler: Handler, raw: bool = False,
                  reader: Callable[[bytes], Message] = decode) -> None:
        """Hand every valid message on ``pattern`` to ``handler(topic, msg)`` from :meth:`poll`.

        ``reader``: how a payload becomes a message (:func:`~fxswarm.core.messages.decode`; a
        neighbour reads only the estimate a command carries,
        :func:`~fxswarm.core.messages.decode_carried`); it raises ``WireError`` on what it refuses.
        ``raw=True``: hand over the undecoded payload instead (``handler(topic, bytes)``),
        for a reader that only wants the latest of many (e.g. a progress line).
        """
        cut = len(self.root) + 1
        tag = _RAW if raw else reader
        arrive = self._arrive

        if "*" in pattern or "$" in pattern:
            def on_sample(sample, handler=handler) -> None:  # a Zenoh callback thread
                arrive((handler, str(sample.key_expr)[cut:], sample.payload.to_bytes(), tag))
        else:  # one key: its samples' key is the pattern (no key expression turned into a str each)
            def on_sample(sample, handler=handler, topic=pattern) -> None:
                arrive((handler, topic, sample.payload.to_bytes(), tag))

        self._subscribers.append(self.session.declare_subscriber(f"{self.root}/{pattern}", self._callback(on_sample)))

    def _callback(self, fn):
        """``fn`` as a subscriber's callback: run by Zenoh's receiving thread itself when
        :attr:`direct`, else (zenoh-python's default) handed to a Python thread of the
        subscriber's own, one thread wake-up more per message."""
        return zenoh.handlers.Callback(fn, indirect=False) if self.direct else fn

    def declare_alive(self, role: str, ident: int | str) -> None:
        self.declare_token(topics.alive_topic(role, ident))

    def declare_token(self, topic: str) -> None:
        """Declare a liveliness token on ``topic``; it goes when the session closes (or is lost)."""
        self._tokens.append(self.session.liveliness().declare_token(f"{self.root}/{topic}"))

    def watch_alive(self, pattern: str, handler: AliveHandler) -> None:
        """Call ``handler("role/id", up)`` from :meth:`poll` for tokens under ``alive/<pattern>``.

        Tokens already present are reported first (history).
        """
        self.watch_tokens(f"alive/{pattern}", handler, cut="alive/")

    def watch_tokens(self, pattern: str, handler: AliveHandler, cut: str = "") -> None:
        """Call ``handler(topic, up)`` from :meth:`poll` for liveliness tokens on ``pattern``
        (``topic`` without the swarm prefix nor ``cut``); tokens already present come first."""
        skip = len(self.root) + 1 + len(cut)
        put = self._inbox.put

        def on_change(sample, handler=handler) -> None:
            put((handler, str(sample.key_expr)[skip:], sample.kind == zenoh.SampleKind.PUT, _ALIVE))

        self._subscribers.append(self.session.liveliness().declare_subscriber(
            f"{self.root}/{pattern}", self._callback(on_change), history=True))

    def watch_router_links(self, handler: AliveHandler) -> None:
        """Call ``handler("router/link-<zid>", up)`` from :meth:`poll` when this session's own link
        to a router opens or closes: a router that declares no token of its own (``zenohd``) is
        lost as surely as one that does."""
        put = self._inbox.put

        def on_event(event, handler=handler) -> None:
            if event.transport.whatami == zenoh.WhatAmI.ROUTER:
                put((handler, f"router/link-{event.transport.zid}", event.kind == zenoh.SampleKind.PUT, _ALIVE))

        self._subscribers.append(self.session.info.declare_transport_events_listener(on_event, history=True))

    def wake(self) -> None:
        """Make a blocked :meth:`poll` return now (safe from a signal handler and from a handler)."""
        self._inbox.put(_WAKE)

    def _arrive(self, item) -> None:
        """A Zenoh callback thread: dispatch here if a ``poll(stay=True)`` lets us, else enqueue."""
        if self._staying:
            with self._gate:
                # An empty inbox keeps each subscriber's order: its earlier samples may wait there.
                if self._staying and self._failed is None and self._inbox.empty():
                    try:
                        self._delivered += self._dispatch(item)
                    except BaseException as exc:  # noqa: BLE001 - re-raised by poll, on its thread
                        self._failed = exc
                        self._inbox.put(_WAKE)
                    return
        self._inbox.put(item)

    def poll(self, timeout: float | None, stay: bool = False) -> int:
        """Wait up to ``timeout`` s for traffic and deliver it; return how many messages.

        ``stay=False``: return after the first batch (all that is queued by then).
        ``stay=True``: stay the whole ``timeout``, handlers running on Zenoh's callback
        threads (one at a time, never after ``poll`` returns) so the caller is not woken
        per message; returns early on :meth:`wake`, a liveliness change, or a sample that
        had to be queued. For loops whose work happens in the handlers (lock-step).
        """
        before = self._delivered
        if stay and self._inbox.empty():
            self._staying = True
        try:
            if timeout is None or timeout > 0:
                item = self._inbox.get(timeout=timeout)
            else:
                item = self._inbox.get_nowait()
        except queue.Empty:
            item = _WAKE
        finally:
            if self._staying:
                with self._gate:  # wait for a handler running on a callback thread
                    self._staying = False
        if self._failed is not None:
            exc, self._failed = self._failed, None
            raise exc
        if item is _WAKE and self._delivered == before and self._inbox.empty():
            return 0
        get = self._inbox.get_nowait  # no callback dispatches now: the queue is ours
        while True:
            if item is not _WAKE:
                self._delivered += self._dispatch(item)
            try:
                item = get()
            except queue.Empty:
                return self._delivered - before

    def _dispatch(self, item) -> int:
        handler, topic, payload, tag = item
        if tag is _ALIVE or tag is _RAW:
            handler(topic, payload)
            return 0
        try:
            msg = tag(payload)
            if self.validate:
                check_sender(topic, msg)
        except WireError as exc:
            self.counters.invalid += 1
            if topic not in self._warned:
                self._warned.add(topic)
                print(f"fxswarm: warning: dropped an invalid message on {self.root}/{topic}: {exc} "
                      f"(further ones on this key are only counted)", file=sys.stderr)
            return 0
        self.counters.received += 1
        handler(topic, msg)
        return 1

    def close(self) -> None:
        """Close the session (undeclares everything; never leave a session open at exit)."""
        if not self.session.is_closed():
            self.session.close()

    def __enter__(self) -> "ZenohBus":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def wait_until(bus: ZenohBus, done: Callable[[], bool], timeout: float, step: float = 0.05) -> bool:
    """Poll ``bus`` until ``done()`` or ``timeout`` seconds pass; return ``done()``."""
    end = time.monotonic() + timeout
    while not done():
        left = end - time.monotonic()
        if left <= 0:
            return done()
        bus.poll(min(step, left))
    return True
