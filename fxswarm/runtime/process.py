"""What every role process shares: options, signals, the session's life, delivery, counters.

A role process (``fxswarm world|leader|agent``) is a node (sans I/O) on a
:class:`~fxswarm.runtime.zenoh_bus.ZenohBus`, driven by one of the loops in
the role's module. Everything a process receives reaches its node through
ONE function, :meth:`RoleProcess.deliver`; the node itself is built in one
function per role (``build_node``), and :func:`wrap_node` is the single place
where an inbox filter (e.g. the fault filter of ``fxswarm.faults``) can
be slotted around it. A wrapper must keep ``subscriptions()``/``handle()``
and expose the wrapped node as ``.inner`` (the loops read the node's state
through :func:`unwrap`).

Lifecycle: the session is opened in the process itself (never inherited
across a fork), subscriptions are declared before the liveliness token (so
whoever sees the token may already send to us), and the session is always
closed, also on SIGTERM/SIGINT, since an open session hangs the exit.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import time
from pathlib import Path

from fxswarm.core import bus as topics
from fxswarm.core.messages import Message, decode
from fxswarm.core.pacing import Deadline, Pacer, SimClock, WallClock
from fxswarm.core.scenario import Scenario
from fxswarm.faults.apply import process_counters, wrap_for_process
from fxswarm.faults.plan import CLI_HELP as FAULT_HELP
from fxswarm.faults.plan import PLAN_ENV, FaultPlan
from fxswarm.faults.process import PlannedKill
from fxswarm.runtime.connectivity import Connectivity
from fxswarm.runtime.files import write_atomic
from fxswarm.runtime.numbers import non_negative, positive
from fxswarm.runtime.output import prepare_run_folder
from fxswarm.runtime.config import process_plan_or_exit
from fxswarm.runtime.liveness import REJOIN_S, Liveness
from fxswarm.runtime.tls import identity
from fxswarm.runtime.zenoh_bus import (ConnectError, ZenohBus, add_zenoh_arguments, log_zenoh_warnings,
                                       options_from_args, wait_until)

#: Set by the launcher: a child whose parent is gone (even SIGKILLed) stops by itself.
PARENT_ENV = "FXSWARM_PARENT_PID"
CLOCKS = ("lockstep", "realtime")
DEFAULT_WORLD_TIMEOUT_S = 60.0
#: Lock-step: how long a process stays after the run is over for messages still on their way.
DRAIN_S = 2.0


def add_process_arguments(p: argparse.ArgumentParser) -> None:
    """Options common to world, leader and agent processes."""
    p.add_argument("config", help="scenario file (TOML)")
    p.add_argument("--clock", choices=CLOCKS, default="lockstep",
                   help="lockstep: the tick protocol, bit-identical to `fxswarm sim`; "
                        "realtime: each process loops at its own rate on the latest data")
    p.add_argument("--speed", type=positive, default=1.0,
                   help="real time only: simulation seconds per wall second (default 1)")
    p.add_argument("--stale-after", type=positive, default=None, metavar="S",
                   help="real time: a message older than S simulation seconds is counted stale "
                        "(default: 5 control periods)")
    p.add_argument("--out", default=None,
                   help="run folder; this process writes its counters to OUT/processes/<role>-<id>.json")
    p.add_argument("--fault", action="append", default=None, metavar="SPEC",
                   help=FAULT_HELP + " (started by hand; a launcher passes --fault-plan)")
    p.add_argument("--fault-plan", default=None, metavar="JSON|FILE",
                   help="the run's resolved fault plan (as `fxswarm run` and `fxswarm compose` hand it to every "
                        f"process; default: ${PLAN_ENV}, else the scenario's [faults] and --fault)")
    p.add_argument("--world-timeout", type=non_negative, default=DEFAULT_WORLD_TIMEOUT_S, metavar="S",
                   help="agents, leader, logger: how long to wait for a world that is gone without having "
                        "ended the run (a network cut longer than the Zenoh lease, a frozen or crashed world) "
                        f"before giving up, exit status 1 (default {DEFAULT_WORLD_TIMEOUT_S:g}; 0: forever)")
    p.add_argument("--rejoin-timeout", type=positive, default=REJOIN_S, metavar="S",
                   help="how long a process that went with a router is waited for (lock-step: the tick held) "
                        f"before it counts as gone (default {REJOIN_S:g})")
    add_zenoh_arguments(p)


def wrap_node(node, role: str, ident: int, plan: FaultPlan, scenario: Scenario, args: argparse.Namespace):
    """The one place where an inbox filter wraps a node: the run's fault plan (fxswarm.faults).
    Lock-step: a process with a planned kill falls silent at its tick (:class:`PlannedKill`), as
    in ``fxswarm sim``, before the launcher's SIGKILL lands."""
    lockstep = args.clock == "lockstep"
    node = wrap_for_process(node, role, ident, plan, scenario.dt, lockstep, float(args.speed))
    target = "leader" if role == "leader" else f"{role}:{ident}"
    kills = [f for f in plan.processes if f.target == target and f.action == "kill"]
    return PlannedKill(node, kills) if lockstep and kills else node


def unwrap(node):
    """The node under any wrappers (they expose it as ``.inner``)."""
    while hasattr(node, "inner"):
        node = node.inner
    return node


class RoleProcess:
    """One role's process: its bus, its node, its signals, its counters file."""

    def __init__(self, role: str, ident: int, scenario: Scenario, args: argparse.Namespace,
                 wall_clock: WallClock = time.monotonic) -> None:
        self.role, self.ident, self.sc, self.args = role, ident, scenario, args
        self.wall_clock = wall_clock  # every wall-time decision (pacing, timeouts) reads this
        self.name = f"{role}/{ident}"
        self.stopping = False
        self.stop_reason = ""
        self.lockstep = args.clock == "lockstep"
        # Real time: a message older than --stale-after simulation s is counted stale.
        self.clock = SimClock(args.speed, args.stale_after if args.stale_after is not None else 5 * scenario.dt)
        # Tokens up (role/id) and judged gone; and who went with a router (fxswarm.runtime.liveness).
        self.liveness = Liveness(wall_clock, rejoin_s=args.rejoin_timeout)
        self.alive, self.gone = self.liveness.alive, self.liveness.gone
        self.run_over = False  # the world's RUN_OVER token was seen: the run is over, this process leaves
        self.world_lost: Deadline | None = None  # running while the world is gone without ending the run
        self.drain_until: Deadline | None = None  # the run is over: waiting for its last messages
        self.ended = False  # the world has ended the run (end_run): deliver nothing more
        self.node = None
        self.core = None
        self.after_deliver = None  # called after each delivered message (run_periodic_loop's early act)
        parent = os.environ.get(PARENT_ENV)
        self.parent_pid = int(parent) if parent else None
        # A busy main thread delays Zenoh's callback threads by the switch interval (5 ms
        # by default, notes/zenoh.md): our callbacks only enqueue, so switch sooner.
        sys.setswitchinterval(float(os.environ.get("FXSWARM_SWITCH_INTERVAL", "0.0005")))
        who = f"fxswarm {role}" + (f" {ident}" if role == "agent" else "")  # in what it says
        try:
            swarm, options = options_from_args(args, scenario.zenoh, identity(role, ident))  # --secure: its own key, checked
        except ValueError as exc:
            print(f"{who}: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
        # The run's fault plan, received (or resolved from --fault when started by hand) once, and
        # refused before the session opens (bad input: one line, exit 2, nothing to close).
        self.plan = process_plan_or_exit(scenario, getattr(args, "fault_plan", None), getattr(args, "fault", None), who)
        if args.out:
            prepare_run_folder(args.out, who)
        if options.tls is not None:
            log_zenoh_warnings()  # TLS refusals at this process's own links (a mesh peer) go to its log
        # Installed first: a client waiting for its router must hear Ctrl-C too (and a
        # SIGINT ignored where the process was started, e.g. a background job, is heard).
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, self._on_signal)
        try:
            self.bus = ZenohBus(swarm, options, drop_when_congested=not self.lockstep, batch=self.lockstep, who=who)
        except ConnectError as exc:
            print(exc, file=sys.stderr)
            raise SystemExit(1) from None
        # Says at once when every router is lost, and when one is back (no per-tick cost).
        self.connectivity = Connectivity(self.bus.session, who, now=self.sim_now())

    def sim_now(self):
        """``() -> (simulation time s, tick)`` for the outage record, or None (role-specific)."""
        return None

    # --- signals and liveness ------------------------------------------------------------

    def _on_signal(self, signum, frame) -> None:
        if getattr(self, "bus", None) is None:  # still opening its session: nothing to close yet
            raise KeyboardInterrupt
        self.stop(signal.Signals(signum).name)

    def stop(self, reason: str) -> None:
        if not self.stopping:
            self.stopping, self.stop_reason = True, reason
        self.bus.wake()

    def check_parent(self) -> None:
        """Stop if the launcher is gone; judge departures (:meth:`settle`): every loop calls this."""
        self.settle()
        if self.parent_pid is not None and os.getppid() != self.parent_pid:
            self.stop("launcher gone")

    def watch(self, names: list[str]) -> None:
        """Track the liveliness of these ``role/id`` names in :attr:`alive` / :attr:`gone`
        (and, with the world's, whether it has ended the run: :meth:`exit_with_world`)."""
        for name in [*names, "router/*"]:
            self.bus.watch_alive(name, self._on_alive)
        self.bus.watch_router_links(self._on_alive)  # its own routers, token or not
        if "world/0" in names:
            self.bus.watch_tokens(topics.RUN_OVER, self._on_run_over)

    def _on_run_over(self, topic: str, up: bool) -> None:
        if up:
            self.run_over = True

    def _on_alive(self, name: str, up: bool) -> None:
        self.liveness.change(name, up)

    def settle(self) -> None:
        """Judge departures (:class:`~fxswarm.runtime.liveness.Liveness`); say who, lost with a
        router, never came back."""
        for name in self.liveness.settle():
            print(f"fxswarm {self.role} {self.ident}: {name} went with a router {self.liveness.rejoin_s:g} s ago "
                  f"and is not back: counted gone", file=sys.stderr)

    @property
    def rejoined(self) -> int:
        """Router outages over so far (everyone lost with a router is back, or judged gone)."""
        return self.liveness.rejoined

    def unsure(self) -> set[str]:
        """Processes that left without being judged gone yet, or went with a router (expected back)."""
        return self.liveness.unsure()

    def exit_with_world(self) -> None:
        """Stop once the world has ended the run (its ``RUN_OVER`` token, :meth:`end_run`).

        A world gone without ending the run is lost, not finished: a network cut longer than
        the Zenoh lease, a frozen or a crashed world. It may come back (Zenoh reconnects), so
        wait for it, as a robot in the field would, up to ``--world-timeout`` s (0: forever);
        then stop as ``world lost`` (exit status 1).
        """
        if self.run_over:
            if self.lockstep and not self.drained():
                # What a sender put before the run ended may still be on its way: its fate
                # (delivered, dropped, delayed) is counted on arrival, as the simulator counts it.
                if self.drain_until is None:
                    self.drain_until = Deadline(DRAIN_S, self.wall_clock)
                if not self.drain_until.passed():
                    return
            self.stop("run over")
            return
        if "world/0" not in self.gone:
            if self.world_lost is not None:
                self.world_lost = None
                print(f"fxswarm {self.role} {self.ident}: the world is back", file=sys.stderr)
            return
        timeout = self.args.world_timeout
        if self.world_lost is None:
            self.world_lost = Deadline(timeout, self.wall_clock)
            wait = f"up to {timeout:g} s" if timeout > 0 else "for as long as it takes"
            print(f"fxswarm {self.role} {self.ident}: lost the world before it ended the run; "
                  f"waiting {wait} for it to come back", file=sys.stderr)
        elif self.world_lost.passed():
            print(f"fxswarm {self.role} {self.ident}: the world has been gone {timeout:g} s; giving up",
                  file=sys.stderr)
            self.stop("world lost")

    def end_run(self, waited_for: tuple[str, ...] = ("agent/", "leader/"), timeout: float = 1.5) -> None:
        """The world: say the run is over (``RUN_OVER``), then give the processes it watched up to
        ``timeout`` s to leave, so each has heard it before the world's going could tell it the
        world is lost (liveliness changes through a router are not ordered among themselves).
        Data arriving meanwhile is dropped."""
        self.ended = True
        self.bus.declare_token(topics.RUN_OVER)
        wait_until(self.bus, lambda: not any(n.startswith(waited_for) for n in self.alive), timeout)

    def drained(self) -> bool:
        """Lock-step, once the run is over: whether all this process hears of the run's last tick
        has arrived (role-specific; :meth:`exit_with_world` waits up to ``DRAIN_S`` for it)."""
        return True

    @property
    def exit_status(self) -> int:
        """0, or 1 if this process gave up on a lost world."""
        return 1 if self.stop_reason == "world lost" else 0

    # --- the node ---------------------------------------------------------------------------

    def attach(self, node) -> None:
        """Subscribe to the node's topics (all through :meth:`deliver`), then say we are alive."""
        self.node = node
        self.core = unwrap(node)
        for pattern in node.subscriptions():
            self.bus.subscribe(pattern, self.deliver, reader=self.reader_for(pattern))
        if self.lockstep and hasattr(self.core, "said_again"):
            self.bus.subscribe(topics.RESYNC, self._asked_again)
        self.bus.declare_alive(self.role, self.ident)

    def _asked_again(self, topic: str, msg: Message) -> None:
        """The world asks again for its tick after a router outage: say again what was said for it.
        Past the fault filters on purpose: a repeat of what was already sent (or lost on the way)."""
        if not self.ended and not getattr(self.node, "silenced", False):  # a planned kill's silence holds
            self.publish(self.core.said_again(msg.tick))

    def reader_for(self, pattern: str):
        """How this process reads the payloads on ``pattern`` (role-specific; default: all of it)."""
        return decode

    def deliver(self, topic: str, msg: Message) -> None:
        """The one way in: count staleness, hand ``msg`` to the node, publish what it returns."""
        if self.ended:
            return
        if not self.lockstep:
            if msg.role == "world":
                self.clock.observe(msg.t)
            if self.clock.is_stale(msg.t):
                self.bus.counters.stale += 1
        elif self.is_late(msg):
            self.bus.counters.stale += 1
        out = self.node.handle(topic, msg)
        if out:
            self.bus.publish_all(self.in_send_order(out))
        if self.after_deliver is not None:
            self.after_deliver()

    def is_late(self, msg: Message) -> bool:
        """Lock-step: a message for a tick the receiver has already left (role-specific)."""
        return False

    def publish(self, out) -> None:
        """Send one ``(topic, msg)`` or a list of them."""
        if out:
            self.bus.publish_all([out] if isinstance(out[0], str) else self.in_send_order(out))

    def in_send_order(self, out: list) -> list:
        """The order to send a batch in (role-specific: what others wait for goes first)."""
        return out

    # --- exit --------------------------------------------------------------------------------

    def counters(self) -> dict:
        c = self.bus.counters.as_dict()
        c["stop_reason"] = self.stop_reason or "done"
        c["router_outages"] = self.connectivity.report()
        c.update(process_counters(self.node))  # per-link fault counts, if a fault filter is in
        if getattr(self.core, "tolerate", 0):  # an agent with W-MSR: the values it discarded
            c["discarded"] = self.core.discarded
        return c

    def write_counters(self, extra: dict | None = None) -> None:
        """Write OUT/processes/<role>-<id>.json; a failure is said, never raised (it runs on the
        way out, and must not keep the session from being closed)."""
        if not self.args.out:
            return
        folder = Path(self.args.out) / "processes"
        data = {"role": self.role, "id": self.ident, "pid": os.getpid(), **self.counters(), **(extra or {})}
        try:
            folder.mkdir(parents=True, exist_ok=True)
            write_atomic(folder / f"{self.role}-{self.ident}.json", json.dumps(data, indent=2) + "\n")
        except OSError as exc:
            print(f"fxswarm {self.role}: could not write its counters to {folder}: {exc}", file=sys.stderr)

    def close(self) -> None:
        self.connectivity.close()  # first: the session's own closing is no outage
        self.bus.close()

    def finish(self, extra: dict | None = None) -> None:
        """On the way out: write the counters, then close the session whatever happened (an open
        session keeps the process from exiting)."""
        try:
            self.write_counters(extra)
        finally:
            self.close()


def run_event_loop(proc: RoleProcess, on_idle=None, step: float = 0.1) -> None:
    """Deliver messages until stopped; ``on_idle()`` runs at least every ``step`` s and after
    every liveliness change.

    The node's work happens in its handlers, so while no peer is gone the handlers run on
    Zenoh's callback threads (``poll(stay=True)``): the loop is not woken per message.
    """
    while not proc.stopping:
        proc.bus.poll(step, stay=not proc.gone)
        if on_idle is not None:
            on_idle()
        proc.check_parent()
        proc.exit_with_world()


def run_periodic_loop(proc: RoleProcess, pacer: Pacer, act, act_early=None, act_keeps_time: bool = False) -> None:
    """Real time: call ``act()`` whenever ``pacer`` says it is due, delivering messages in between.

    The decisions are the pacer's (:class:`~fxswarm.core.pacing.Pacer`: deadlines, no burst
    after a late act, ``patience`` after an early one); this loop only waits for its next
    deadline, feeds messages and publishes. Zero-order hold: ``act`` works on whatever the
    node holds. ``act_early()`` (checked after each delivered message) lets fresh data
    trigger the act at once (e.g. an agent's new sensing). ``act_keeps_time``: ``act()``
    records itself on ``pacer`` (the world's :meth:`~fxswarm.world.node.RealTimeWorld.tick`
    chooses between an act on time and a hold), so the loop must not record it a second
    time: that would push every deadline one more period away and halve the rate.

    Unless a fault filter must release delayed messages between batches, Zenoh's
    callback threads run the handlers as messages arrive (``poll(stay=True)``),
    ``act_early`` checked after each: the world takes a command the moment it
    lands, an agent answers fresh sensing on the thread that received it,
    neither waits for its main thread to wake.
    """
    stay = not hasattr(proc.node, "poll")

    def act_if_early() -> bool:
        if act_early is None or not act_early():
            return False
        act()
        pacer.acted_early()
        return True

    if act_early is not None:
        proc.after_deliver = act_if_early  # after every delivered message, on whichever thread
    while not proc.stopping:
        left = pacer.wait_s()
        proc.bus.poll(min(left, 0.1), stay=stay and not proc.gone)
        proc.publish(getattr(proc.node, "poll", lambda: [])())  # delayed messages now due (faults)
        # act_if_early again: messages a fault filter released just now bypassed deliver.
        if not act_if_early() and pacer.due():
            if not act_keeps_time:
                pacer.on_time()
            act()
        proc.check_parent()
        proc.exit_with_world()
