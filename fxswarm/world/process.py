"""``fxswarm world CONFIG``: the world as its own process on Zenoh.

It waits (liveliness, no sleeps) until the leader and every agent are up,
then runs the clock:

* lock-step: :class:`~fxswarm.world.node.WorldNode`'s tick protocol; a tick
  whose commands do not all arrive within ``--tick-timeout`` s (or whose
  missing robots' processes are gone) is closed by ``timeout()``: the silent
  robots hold their last command and the miss is counted, so the run never
  deadlocks;
* real time: ticks paced at ``dt / speed`` wall seconds, integrating on the
  latest command of each robot (zero-order hold); it measures the latency
  from each sensing message to the matching command's arrival.

At the end it writes ``trajectory.npz`` and ``summary.json`` (the same as
``fxswarm sim``) into ``--out``, and its counters into ``--out/processes/``.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from fxswarm.core.bus import WORLD_STATE
from fxswarm.core.messages import Command, Message
from fxswarm.core.metrics import summarise
from fxswarm.core.scenario import Scenario
from fxswarm.faults.apply import world_process_summary
from fxswarm.runtime.numbers import non_negative_int, positive
from fxswarm.runtime.output import write_run
from fxswarm.runtime.process import RoleProcess, add_process_arguments, run_periodic_loop, wrap_node
from fxswarm.runtime.sim_cli import load_or_exit
from fxswarm.world.node import WorldNode


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_process_arguments(p)
    p.add_argument("--tick-timeout", type=positive, default=1.0, metavar="S",
                   help="lock-step: close a tick after S wall seconds without every command (default 1)")
    p.add_argument("--max-lag", type=non_negative_int, default=10, metavar="TICKS",
                   help="real time: hold the clock while a live robot's latest command is more than TICKS "
                        "ticks old (robots share this machine's CPUs; in the field each has its own), at most "
                        "--tick-timeout s at a time; 0: never hold (default 10)")
    p.add_argument("--wait-timeout", type=positive, default=120.0, metavar="S",
                   help="give up (exit 3) if the leader and all agents are not up within S s (default 120)")


class RealTimeInbox:
    """Real time: commands are held (zero-order hold) and their latency measured, not ticked.

    ``sent_at[k]`` is the wall time the world sent sensing for tick ``k``;
    the first command of each robot for tick ``k`` gives one latency sample.
    """

    def __init__(self, world: WorldNode) -> None:
        self.inner = world
        self.sent_at: dict[int, float] = {}
        self.answered: set[tuple[int, int]] = set()
        self.latencies: list[float] = []  # s
        self.last_tick: dict[int, int] = {}  # robot -> the latest tick it has answered

    def subscriptions(self) -> list[str]:
        return self.inner.subscriptions()

    def handle(self, topic: str, msg: Message) -> list:
        if isinstance(msg, Command):
            self.inner.take_command(msg)
            if msg.tick > self.last_tick.get(msg.robot, -1):
                self.last_tick[msg.robot] = msg.tick
            sent = self.sent_at.get(msg.tick)
            if sent is not None and (msg.robot, msg.tick) not in self.answered:
                self.answered.add((msg.robot, msg.tick))
                self.latencies.append(time.monotonic() - sent)
        return []

    def sent(self, tick: int) -> None:
        self.sent_at[tick] = time.monotonic()
        old = tick - 1000  # keep the maps bounded: a command later than 1000 ticks is no answer
        self.sent_at.pop(old, None)
        if len(self.answered) > 20_000:
            self.answered = {(r, k) for r, k in self.answered if k > old}


def build_node(scenario: Scenario, args: argparse.Namespace):
    """The world's node as this process runs it (one place, so wrappers apply here)."""
    node = WorldNode(scenario)
    if args.clock == "realtime":
        node = RealTimeInbox(node)
    return wrap_node(node, "world", 0, scenario, args)


class WorldProcess(RoleProcess):
    def deliver(self, topic: str, msg: Message) -> None:
        super().deliver(topic, msg)
        if self.lockstep and self.core.done:
            self.bus.wake()  # the loop may be sleeping in poll(stay=True): the run is over now

    def is_late(self, msg: Message) -> bool:
        return isinstance(msg, Command) and msg.tick < self.core.tick

    def in_send_order(self, out: list) -> list:
        # Sensing first: the next tick waits on it; the state (for loggers) can follow.
        return sorted(out, key=lambda o: o[0] == WORLD_STATE) if len(out) > 1 else out


def wait_for_everyone(proc: RoleProcess, timeout: float) -> list[str]:
    """Wait until the leader and every agent are alive; return those still missing."""
    needed = ["leader/0"] + [f"agent/{r.id}" for r in proc.sc.robots]
    end = time.monotonic() + timeout
    while not proc.stopping and time.monotonic() < end:
        missing = [n for n in needed if n not in proc.alive]
        if not missing:
            return []
        proc.bus.poll(0.1)
        proc.check_parent()
    return [n for n in needed if n not in proc.alive]


def run_lockstep(proc: RoleProcess, tick_timeout: float) -> None:
    world: WorldNode = proc.core
    proc.publish(world.start())
    deadline = time.monotonic() + tick_timeout
    tick = world.tick
    while not world.done and not proc.stopping:
        # The tick protocol runs in the handlers: the loop only wakes for deadlines and
        # departures (0.1 s late at most to see a new tick: a deadline is never early).
        proc.bus.poll(max(0.0, min(0.1, deadline - time.monotonic())), stay=not proc.gone)
        now = time.monotonic()
        if world.done:
            break
        if world.tick != tick:
            tick, deadline = world.tick, now + tick_timeout
            continue
        waiting = world.waiting_for()
        # A robot whose process is gone will not answer: close the tick now, not at the deadline.
        if now >= deadline or (waiting and all(f"agent/{r}" in proc.gone for r in waiting)):
            proc.publish(world.timeout())
            tick, deadline = world.tick, time.monotonic() + tick_timeout
        proc.check_parent()


def run_realtime(proc: RoleProcess, inbox: RealTimeInbox, max_lag: int, hold_limit: float) -> dict:
    """Tick every ``dt / speed`` wall seconds, integrating the latest commands held.

    A tick that starts more than a period late is counted in ``late_ticks``
    and the schedule slips: the simulation runs slower than asked (reported
    as ``achieved_speed``) instead of integrating missed ticks on stale
    commands, which a delayed fixed-time law does not survive. Likewise the
    clock holds (``held_ticks``) while a live robot has not answered for more
    than ``max_lag`` ticks: on a shared machine a robot starved of CPU is an
    artefact (in the field each robot has its own), so the world waits for
    it, up to ``hold_limit`` wall seconds at a time.
    """
    world: WorldNode = proc.core
    sc = proc.sc
    period = sc.dt / proc.clock.speed
    start = time.monotonic()
    proc.clock.start_now()
    proc.publish(world.start())
    inbox.sent(world.tick)
    late = held = 0
    due = start + period
    holding_since: float | None = None

    def lagging() -> bool:
        if max_lag <= 0:
            return False
        oldest = world.tick - max_lag
        return any(inbox.last_tick.get(r.id, -1) < oldest for r in sc.robots if f"agent/{r.id}" in proc.alive)

    def tick() -> None:
        nonlocal late, held, due, holding_since
        now = time.monotonic()
        if lagging():
            holding_since = holding_since if holding_since is not None else now
            if now - holding_since < hold_limit:
                held += 1
                due = now + period
                return
        holding_since = None
        if now > due + period:
            late += 1
        due = max(due + period, now)
        proc.publish(world.advance(sc.dt))
        proc.clock.observe(world.t)
        inbox.sent(world.tick)
        if world.done:
            proc.stop("done")

    # run_periodic_loop acts at once when it starts: enter it when tick 1 is due.
    while time.monotonic() < due and not proc.stopping:
        proc.bus.poll(max(0.0, due - time.monotonic()))
    run_periodic_loop(proc, period, tick)
    wall = time.monotonic() - start
    return {"late_ticks": late, "held_ticks": held,
            "achieved_speed": world.tick * sc.dt / wall if wall > 0 else None}


def latency_stats(samples: list[float]) -> dict:
    """p50/p99/max of latencies given in s, reported in ms."""
    if not samples:
        return {"n": 0}
    a = np.asarray(samples) * 1e3
    return {"n": int(a.size), "p50_ms": float(np.percentile(a, 50)), "p99_ms": float(np.percentile(a, 99)),
            "max_ms": float(a.max()), "mean_ms": float(a.mean())}


def main(args: argparse.Namespace) -> int:
    sc = load_or_exit(args.config)
    args.out = args.out or f"runs/{sc.name}-run"
    proc = WorldProcess("world", 0, sc, args)
    extra: dict = {}
    code = 0
    crashed = False
    try:
        node = build_node(sc, args)
        proc.watch(["leader/0", "agent/*"])
        proc.attach(node)
        start = time.perf_counter()
        missing = wait_for_everyone(proc, args.wait_timeout)
        if missing and not proc.stopping:
            print(f"fxswarm world: gave up after {args.wait_timeout:g} s waiting for {', '.join(missing)}",
                  file=sys.stderr)
            return 3
        if proc.stopping:
            return 0
        started = time.perf_counter()
        extra["waited_s"] = started - start
        if proc.lockstep:
            run_lockstep(proc, args.tick_timeout)
        else:
            inbox = unwrap_inbox(node)
            extra.update(run_realtime(proc, inbox, args.max_lag, args.tick_timeout))
            extra["sense_to_command"] = latency_stats(inbox.latencies)
        world: WorldNode = proc.core
        wall = time.perf_counter() - started
        extra.update(missed_ticks_world=world.missed_ticks, ticks=world.tick, wall_s=wall,
                     ticks_per_s=world.tick / wall if wall > 0 else None)
        proc.bus.counters.missed_ticks = world.missed_ticks
        if world.tick > 0:
            summary = summarise(sc, world.trajectory(), wall)
            summary.update(clock=args.clock, speed=args.speed if not proc.lockstep else None,
                           complete=world.done, missed_ticks=world.missed_ticks,
                           missed_ticks_per_robot={str(r.id): int(m) for r, m in zip(sc.robots, world.misses)})
            summary.update(world_process_summary(sc, args, world.trajectory(), world))  # faults, recoveries
            for key in ("sense_to_command", "late_ticks", "held_ticks", "achieved_speed"):
                if key in extra:
                    summary[key] = extra[key]
            write_run(args.out, summary, world.trajectory())
        if not world.done:
            code = 1 if proc.stop_reason not in ("SIGTERM", "SIGINT") else 0
    except BaseException:
        crashed = True
        raise
    finally:
        try:
            proc.write_counters(extra)
            if not crashed:  # the others wait for a world that is gone without having said so
                proc.end_run()
        finally:
            proc.close()  # always: an open session hangs the exit
    return code


def unwrap_inbox(node) -> RealTimeInbox:
    while not isinstance(node, RealTimeInbox):
        node = node.inner
    return node
