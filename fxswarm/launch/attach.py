"""``fxswarm attach ENDPOINT --swarm NAME --out DIR``: observe a running swarm from anywhere.

A Zenoh client of the swarm's router (e.g. ``tcp/node1:7447``, the port a
stack publishes) that does the logger's work remotely: it takes every
``world/state`` of the run for progress and the live recording, and when the
world ends the run (its ``run/over`` token) it fetches the world's own record
(``world/record``, :mod:`fxswarm.runtime.record`: the files the world wrote,
checked by size, digest and tick count) and writes into ``DIR``, on this machine:

* ``trajectory.npz``: the world's own file, every tick, however lossy the live
  stream was (it drops under load);
* ``summary.json``: the world's own, plus what only an observer knows: states
  the live stream missed, and which processes went and came back, the logger
  included (a dead logger is reported, not silent), and ``record`` (where the
  folder came from);
* ``recording.rrd`` (and any ``--rerun`` output: ``web`` or ``grpc`` is a
  live viewer attached the same way), when Rerun is installed
  (``fxswarm[logger]``).

Without the world's record (the world left without ending the run, or never
answered), it rebuilds the folder from the states it saw and says so.

The scenario comes from ``--config`` or, without it, from the router
(``fxswarm router --scenario``; a stack's router serves it) into
``DIR/scenario.toml``. It declares the liveliness token
``alive/observer/0`` (``--name``): a world started with ``--wait-for
observer/0`` starts its clock only once the observer listens, so nothing of
the run is missed.

Secure mode (``--secure KEYS``): a client of the router over mutual TLS only
(``tls/`` endpoint), showing the ``observer`` certificate from KEYS, whose
rights are exactly what this needs: hear ``world/state``, watch liveliness,
ask the router for the scenario and the world for its record, declare
``alive/observer/<id>`` (docs/security.md).
"""

from __future__ import annotations

import argparse
import hashlib
import math
import os
import signal
import socket
import sys
import time
from pathlib import Path

import numpy as np

from fxswarm.core import bus as topics
from fxswarm.core.messages import WorldState
from fxswarm.core.metrics import summarise
from fxswarm.core.scenario import Scenario
from fxswarm.runtime.connectivity import Connectivity
from fxswarm.runtime.files import write_atomic
from fxswarm.runtime.numbers import positive, swarm_name
from fxswarm.runtime.output import prepare_run_folder, write_run, write_summary
from fxswarm.runtime.record import Record, RecordError, fetch_record
from fxswarm.runtime.tls import SECURE_ENV, checked
from fxswarm.runtime.zenoh_bus import ConnectError, ZenohBus, ZenohOptions
from fxswarm.world.node import nearest_objects

SCENARIO_KEY = topics.SCENARIO  # under the swarm's prefix: the scenario file's text, from the router
#: Secure mode: the certificate attach shows (its rights: docs/security.md, fxswarm.security.policy).
IDENTITY = "observer"
PROGRESS_EVERY_S = 2.0
SETTLE_S = 1.0  # after run/over: states still in flight
#: A departure seen at most this long (s) before the world's run/over token is the run's end, not a
#: death: everyone leaves once the world ends the run, and their departures can overtake its token
#: (by 0.08 s, seen here) while a live stream that lags on a loaded host still brings states a
#: second or more of simulation old.
END_S = 2.0
#: The world's token gone without run/over (killed, frozen or cut off past its lease): the run
#: cannot go on (the world is the simulation). Its run/over may still be on the way: wait this long.
WORLD_GONE_S = 3.0
#: After run/over: how long to keep asking the world for its record (it serves it once written).
RECORD_TIMEOUT_S = 120.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("endpoint", help="the swarm's router, e.g. tcp/127.0.0.1:7447")
    p.add_argument("--swarm", type=swarm_name, required=True, help="swarm name (the key-expression prefix)")
    p.add_argument("--out", required=True, metavar="DIR", help="run folder to write here")
    p.add_argument("--config", default=None, help="scenario file (default: ask the router for it)")
    p.add_argument("--name", default="observer/0", metavar="ROLE/ID",
                   help="liveliness name this observer declares (default observer/0)")
    p.add_argument("--rerun", default="file", metavar="OUTPUTS",
                   help="Rerun outputs as `fxswarm logger --rerun` takes them (default file: DIR/recording.rrd); "
                        "none: no recording")
    p.add_argument("--timeout", type=positive, default=600.0, metavar="S",
                   help="give up after S s without the router, the scenario or a first state from the world "
                        "(default 600); once the run is seen, attach stays to its end, or writes what it has "
                        "when the world leaves without ending it")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--secure", default=os.environ.get(SECURE_ENV) or None, metavar="KEYS",
                   help=f"secure swarm: keys folder of `fxswarm keys` (this uses its {IDENTITY}.pem/.key and "
                        f"ca.pem); ENDPOINT must be tls/HOST:PORT (docs/security.md; default ${SECURE_ENV})")


class Observer:
    """The run as the world's states tell it: arrays by tick, plus who came and went."""

    def __init__(self, sc: Scenario, cut_around=lambda _when: False, clock=time.monotonic) -> None:
        self.sc = sc
        self.clock = clock
        # (monotonic s) -> whether this observer had lost every router itself about then: tokens
        # that go with our own link went nowhere (Connectivity.cut_around)
        self.cut_around = cut_around
        # role/id -> when its token last went (monotonic s), and whether that went into gone_at
        self.left_at: dict[str, tuple[float, bool]] = {}
        n, ticks = sc.n, sc.ticks
        self.seen = np.zeros(ticks, dtype=bool)
        self.t = np.arange(ticks) * sc.dt
        self.p = np.zeros((ticks, n, 3))
        self.ph = np.zeros((ticks, n, 3))
        self.v = np.zeros((ticks, n, 3))
        self.near = np.full((ticks, n), np.inf)
        self.near_obstacle = np.full((ticks, n), np.inf)
        self.avoid = np.zeros((ticks, n), dtype=bool)
        self.obstacles: list[np.ndarray | None] = [None] * ticks
        self.last_tick = -1
        self.last_t = 0.0
        self.alive: set[str] = set()
        self.ever: set[str] = set()
        # role/id -> (the last tick seen, when (monotonic s)) each time its token went
        self.gone_at: dict[str, list[tuple[int, float]]] = {}
        self.back: dict[str, int] = {}  # role/id -> times it came back after that
        self.run_over = False
        self.over_at: float | None = None  # when run/over was seen (monotonic s)

    def take(self, msg: WorldState) -> None:
        k = msg.tick
        if not 0 <= k < self.sc.ticks or self.seen[k]:
            return
        self.seen[k] = True
        self.p[k], self.ph[k], self.v[k] = msg.p, msg.ph, msg.v
        self.near[k] = np.where(msg.nearest < 0, np.inf, msg.nearest)  # the world sends inf as -1
        self.avoid[k] = msg.avoid
        obstacles = np.asarray(msg.obstacles, dtype=float).reshape(-1, 3)
        self.obstacles[k] = obstacles
        # Not on the wire: the distance to the nearest obstacle alone, as the world computes it.
        self.near_obstacle[k] = nearest_objects(msg.p, msg.v, obstacles, np.zeros_like(obstacles))[4]
        if k > self.last_tick:
            self.last_tick, self.last_t = k, msg.t

    def on_alive(self, name: str, up: bool) -> None:
        if up:
            if name in self.ever and name not in self.alive:
                when, counted = self.left_at.get(name, (-math.inf, False))
                if self.cut_around(when):
                    # It never left: our own link was down. Its departure, if counted, is withdrawn.
                    if counted:
                        self.gone_at[name].pop()
                else:
                    self.back[name] = self.back.get(name, 0) + 1
            self.alive.add(name)
            self.ever.add(name)
        elif name in self.alive:
            self.alive.discard(name)
            now = self.clock()
            self.left_at[name] = (now, not self.run_over)
            if not self.run_over:  # judged in deaths(): the world's last states may still be on their way
                self.gone_at.setdefault(name, []).append((self.last_tick, now))

    def deaths(self) -> dict[str, int]:
        """role/id -> times it went during the run. Everyone leaves once the world ends the run,
        and those departures can reach us before the world's last states and its run/over token:
        a departure counts only if the process came back after it, or if the world went on
        ticking for a second of simulation time after it and its run/over came more than
        :data:`END_S` later (a live stream that lags brings that second after the departure)."""
        grace = max(1, math.ceil(1.0 / self.sc.dt))
        out = {}
        for name, went in self.gone_at.items():
            n = sum(1 for i, (k, when) in enumerate(went)
                    if i < self.back.get(name, 0) or (self.last_tick - k > grace and not self.ends_run(when)))
            if n:
                out[name] = n
        return out

    def world_gone(self) -> bool:
        """The world was seen and its liveliness token is gone, and it has not ended the run."""
        return "world/0" in self.ever and "world/0" not in self.alive and not self.run_over

    def ends_run(self, when: float) -> bool:
        """Whether a departure seen at ``when`` came with the world's end of the run."""
        return self.over_at is not None and self.over_at - when <= END_S

    def on_run_over(self, _topic: str, up: bool) -> None:
        if up and not self.run_over:
            self.run_over = True
            self.over_at = self.clock()

    def trajectory(self) -> dict[str, np.ndarray]:
        """The ticks from 0 to the last one seen (rows of missed ticks stay zero; counted)."""
        k = self.last_tick + 1
        sc = self.sc
        t = self.t[:k]
        m = max((len(o) for o in self.obstacles[:k] if o is not None), default=0)
        obstacles = np.zeros((k, m, 3))
        for i, o in enumerate(self.obstacles[:k]):
            if o is not None and len(o) == m:
                obstacles[i] = o
        return {
            "t": t, "p": self.p[:k], "ph": self.ph[:k],
            "p0": np.array([sc.leader.position(x) for x in t]).reshape(-1, 3),
            "v": self.v[:k], "nearest_distance": self.near[:k], "obstacle_distance": self.near_obstacle[:k],
            "avoid_active": self.avoid[:k], "obstacles": obstacles,
            "offsets": np.stack([r.offset.positions(t) for r in sc.robots], axis=1).reshape(-1, sc.n, 3),
        }

    def states_missed(self) -> int:
        """Ticks up to the last one seen whose state the live stream did not bring."""
        k = self.last_tick + 1
        return int(k - self.seen[:k].sum())

    def observed(self) -> dict:
        """What only an observer knows, added to either summary: the live stream's misses, and
        who went and came back."""
        deaths = self.deaths()
        return {
            "observed_by": "fxswarm attach",
            "states_missed": self.states_missed(),
            # role/id -> [times gone during the run, times back]: e.g. a killed agent task and its replacement
            "restarts": {name: [n, self.back.get(name, 0)] for name, n in sorted(deaths.items())},
            "logger": {"seen": "logger/0" in self.ever, "died": deaths.get("logger/0", 0) > 0,
                       "alive_at_end": "logger/0" in self.alive},
        }

    def summary(self, wall_s: float) -> dict:
        """The run as the live stream told it (without the world's record)."""
        out = summarise(self.sc, self.trajectory(), wall_s)
        observed = self.observed()
        out.update(complete=self.run_over and self.last_tick + 1 == self.sc.ticks and observed["states_missed"] == 0,
                   **observed, record={"from": "live stream"})
        return out

    def summary_with(self, record: Record) -> dict:
        """The world's own summary, with what this observer saw added."""
        digest = hashlib.sha256(record.trajectory).hexdigest()
        return {**record.summary, **self.observed(),
                "record": {"from": "world", "ticks": record.summary["ticks"], "sha256": digest}}


def fetch_scenario(bus: ZenohBus, out: Path, deadline: float) -> Path:
    """The scenario file's text as the router serves it, saved to ``out/scenario.toml``."""
    key = f"{bus.root}/{SCENARIO_KEY}"
    while time.monotonic() < deadline:
        for reply in bus.session.get(key, timeout=2.0):
            if reply.ok is not None:
                path = out / "scenario.toml"
                path.write_bytes(reply.ok.payload.to_bytes())
                return path
        time.sleep(0.5)
    raise SystemExit(f"fxswarm attach: no scenario from the router at {key} (start it with --scenario, "
                     "or pass --config)")


def zenoh_options(args: argparse.Namespace) -> ZenohOptions:
    """A client of the router at ``args.endpoint``; with ``--secure``, over mutual TLS with the
    observer's key, checked now (raises ValueError naming the file or the endpoint)."""
    tls = None
    if args.secure:
        if not args.endpoint.startswith("tls/"):
            raise ValueError(f"ENDPOINT {args.endpoint}: a secure swarm's router takes tls/HOST:PORT only")
        role, _, ident = args.name.partition("/")
        if role != IDENTITY or "/" in ident:
            # The rules let the observer's key declare alive/observer/<id> only: another token would be dropped.
            raise ValueError(f"--name {args.name}: with the {IDENTITY} certificate, {IDENTITY}/<id> only")
        tls = checked(args.secure, IDENTITY)
    return ZenohOptions("client", (args.endpoint,), (), False, connect_timeout_ms=int(args.timeout * 1000), tls=tls)


def listening(endpoint: str, timeout_s: float = 2.0) -> bool:
    """Whether something accepts TCP at ``endpoint``'s address: Zenoh's error is the same for a
    router that is not there and one that refused the handshake, and they need different fixes."""
    host, _, port = endpoint.partition("/")[2].rpartition(":")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s):
            return True
    except (OSError, ValueError):
        return False


def _connect(args: argparse.Namespace, options: ZenohOptions) -> ZenohBus | int:
    """The observer's session, or the exit status of a failed attempt (said on stderr)."""
    try:
        return ZenohBus(args.swarm, options, who="fxswarm attach")
    except ConnectError as exc:
        if options.tls is not None and listening(args.endpoint):
            print(f"fxswarm attach: no session with the router at {args.endpoint}: it answers, but the TLS "
                  f"handshake failed (are {options.tls.cert} and {options.tls.ca} of this swarm's "
                  f"CA, not of another `fxswarm keys` run?); the router's log says why", file=sys.stderr)
        else:
            print(exc, file=sys.stderr)
        return 1


def _watch(args: argparse.Namespace, bus: ZenohBus, obs: Observer, link: Connectivity, sc: Scenario,
           stop: dict, deadline: float) -> int | None:
    """Follow the run until it is over (and settled), the world has left, or a signal; 3 if
    the world never said anything in time, else None."""
    said = 0.0
    settle_until = None
    world_gone_since = None
    while stop["signal"] is None:
        bus.poll(0.1)
        now = time.monotonic()
        if obs.run_over and settle_until is None:
            settle_until = now + SETTLE_S
        if settle_until is not None and now >= settle_until:
            return None
        # Cut off from every router ourselves, we cannot tell whether the world is there.
        world_gone_since = (world_gone_since or now) if obs.world_gone() and not link.lost else None
        if world_gone_since is not None and now - world_gone_since >= WORLD_GONE_S:
            print(f"fxswarm attach: the world left at t = {obs.last_t:.2f} s without ending the run; "
                  "writing what it sent", file=sys.stderr)
            return None
        if obs.last_tick < 0 and now > deadline:
            print(f"fxswarm attach: no state from the world of swarm {args.swarm!r} in {args.timeout:g} s",
                  file=sys.stderr)
            return 3
        if not args.quiet and now - said >= PROGRESS_EVERY_S:
            said = now
            agents = sum(1 for n in obs.alive if n.startswith("agent/"))
            print(f"fxswarm attach: t = {obs.last_t:6.2f} / {sc.duration:g} s, {agents}/{sc.n} agents alive, "
                  f"logger {'up' if 'logger/0' in obs.alive else 'DOWN' if 'logger/0' in obs.ever else 'not seen'}",
                  file=sys.stderr)
    return None


def _write(out: Path, bus: ZenohBus, obs: Observer, link: Connectivity, stop: dict, started: float) -> int:
    """Write the run folder: the world's own record if it serves one, else what the stream told."""
    record = world_record(bus, obs, link, stop) if obs.run_over and stop["signal"] is None else None
    link.close()
    bus.close()  # our token goes with it: the world serving its record may leave now
    if record is not None:
        summary = obs.summary_with(record)
        write_record(out, summary, record)
        how = f"the world's own record, {summary['ticks']} ticks; the live stream missed {summary['states_missed']}"
    elif obs.last_tick < 0:
        print("fxswarm attach: stopped before the world sent anything; nothing written", file=sys.stderr)
        return 1
    else:
        summary = obs.summary(time.monotonic() - started)
        write_run(out, summary, obs.trajectory())
        how = f"from the live stream, {obs.last_tick + 1} ticks, {summary['states_missed']} missed"
    print(f"fxswarm attach: wrote {out} ({how}; formation error {summary['formation_error_final_m']:.3f} m, "
          f"nearest object {summary['min_object_distance_m']} m)", file=sys.stderr)
    say_warnings(summary)
    return 0 if summary.get("complete") else 1


def main(args: argparse.Namespace) -> int:
    from fxswarm.runtime.config import load_or_exit

    try:
        options = zenoh_options(args)  # a bad key file: one line naming it, before any session or folder
    except ValueError as exc:
        print(f"fxswarm attach: --secure: {exc}" if args.secure else f"fxswarm attach: {exc}", file=sys.stderr)
        return 2
    out = prepare_run_folder(args.out, "fxswarm attach")
    deadline = time.monotonic() + args.timeout
    # While it waits for the router there is nothing to write: Ctrl-C (KeyboardInterrupt) and
    # SIGTERM end it between two connect attempts.
    signal.signal(signal.SIGTERM, lambda signum, _frame: sys.exit(128 + signum))
    bus = _connect(args, options)
    if isinstance(bus, int):
        return bus
    link = Connectivity(bus.session, "fxswarm attach")  # says when its own path to the swarm breaks
    stop = {"signal": None}

    def on_signal(signum, _frame) -> None:  # from here on, a signal ends the watch and writes what was seen
        stop["signal"] = signal.Signals(signum).name

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    recorder = None
    try:
        # An observer flies nothing: a user's law need not be importable here (docs/controllers.md).
        sc = load_or_exit(args.config or str(fetch_scenario(bus, out, deadline)), check_law=False)
        obs = Observer(sc, link.cut_around)
        if args.rerun != "none":
            recorder = open_recorder(sc, args.rerun, out, args.swarm)

        def on_state(_topic: str, msg) -> None:
            obs.take(msg)
            if recorder is not None:
                recorder.take(topics.WORLD_STATE, msg, time.monotonic())

        bus.subscribe(topics.WORLD_STATE, on_state)
        bus.watch_alive("*/*", obs.on_alive)
        bus.watch_tokens(topics.RUN_OVER, obs.on_run_over)
        role, _, ident = args.name.partition("/")
        bus.declare_alive(role, ident or "0")
        started = time.monotonic()
        code = _watch(args, bus, obs, link, sc, stop, deadline)
        return code if code is not None else _write(out, bus, obs, link, stop, started)
    finally:
        if recorder is not None:
            recorder.close(timeout_s=10.0)
        link.close()
        bus.close()


def world_record(bus: ZenohBus, obs: Observer, link: Connectivity, stop: dict) -> Record | None:
    """The world's own record (fxswarm.runtime.record), asked for until it answers, the world
    leaves, a signal or :data:`RECORD_TIMEOUT_S`; None (said) without it."""
    give_up_at = time.monotonic() + RECORD_TIMEOUT_S

    def give_up() -> str | None:
        if stop["signal"] is not None:
            return f"stopped by {stop['signal']}"
        if "world/0" not in obs.alive and not link.lost:
            return "the world left without serving it"
        if time.monotonic() > give_up_at:
            return f"no answer in {RECORD_TIMEOUT_S:g} s"
        return None

    try:
        return fetch_record(bus.session, f"{bus.root}/{topics.WORLD_RECORD}", give_up, bus.poll)
    except RecordError as exc:
        print(f"fxswarm attach: {exc}; writing the run as the live stream told it", file=sys.stderr)
        return None


def write_record(out: Path, summary: dict, record: Record) -> None:
    """``trajectory.npz`` as the world wrote it (byte for byte), then ``summary.json``."""
    write_atomic(out / "trajectory.npz", record.trajectory)
    write_summary(out, summary)


def say_warnings(summary: dict) -> None:
    """What a user must not miss in the summary: a dead logger, a degraded run, router outages."""
    if summary["logger"]["seen"] and summary["logger"]["died"]:
        print("fxswarm attach: warning: the swarm's logger died during the run", file=sys.stderr)
    degraded = summary.get("degraded") or {}
    if degraded.get("ticks"):
        print(f"fxswarm attach: warning: degraded run: {degraded['ticks']} ticks ran with robots the world could not "
              f"hear (robots {', '.join(map(str, degraded['robots']))})", file=sys.stderr)
    if summary.get("router_outages"):
        print(f"fxswarm attach: warning: the world lost every router {len(summary['router_outages'])} time(s)",
              file=sys.stderr)


def open_recorder(sc: Scenario, spec: str, out: Path, swarm: str):
    """The logger's recorder on this machine (needs ``fxswarm[logger]``), or None without Rerun."""
    try:
        from fxswarm.logger.recorder import RecorderOptions, SwarmRecorder
        from fxswarm.logger.sinks import OutputError, open_recording, parse_outputs
    except ModuleNotFoundError as exc:
        print(f"fxswarm attach: no Rerun recording ({exc.name} is not installed: pip install 'fxswarm[logger]')",
              file=sys.stderr)
        return None
    try:
        outputs = parse_outputs(spec, out)
    except OutputError as exc:
        raise SystemExit(f"fxswarm attach: {exc}") from None
    rec, said = open_recording(outputs, f"{sc.name}-{swarm}-attach")
    for line in said:
        print(f"fxswarm attach: {line}", file=sys.stderr)
    recorder = SwarmRecorder(sc, rec, RecorderOptions.from_scenario(sc), wall_clock=time.monotonic)
    recorder.start()
    return recorder
