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
import signal
import sys
import time

from fxswarm.core.bus import WORLD_STATE
from fxswarm.core.messages import Message
from fxswarm.core.pacing import Deadline, WallClock
from fxswarm.core.scenario import Scenario
from fxswarm.faults.plan import FaultPlan
from fxswarm.faults.summary import build_summary
from fxswarm.runtime.numbers import non_negative_int, positive
from fxswarm.runtime.output import read_process_counters, write_run
from fxswarm.runtime.process import RoleProcess, add_process_arguments, run_periodic_loop, wrap_node
from fxswarm.runtime.config import load_or_exit
from fxswarm.world.node import RealTimeWorld, TickTimer, WorldNode


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
    p.add_argument("--wait-for", action="append", default=[], metavar="ROLE/ID",
                   help="also wait for this process's liveliness before the clock starts (repeatable), e.g. "
                        "logger/0 where no orchestrator orders the start, or observer/0 for `fxswarm attach`")


def build_node(scenario: Scenario, args: argparse.Namespace, plan: FaultPlan,
               clock: WallClock = time.monotonic):
    """The world's node as this process runs it (one place, so wrappers apply here)."""
    node = WorldNode(scenario, limits=plan.limits)
    if args.clock == "realtime":
        node = RealTimeWorld(node, scenario.dt / args.speed, clock, args.max_lag, args.tick_timeout,
                             cut_off=plan.cut_off_from_world)
    return wrap_node(node, "world", 0, plan, scenario, args)


class WorldProcess(RoleProcess):
    def deliver(self, topic: str, msg: Message) -> None:
        super().deliver(topic, msg)
        if self.lockstep and self.core.done:
            self.bus.wake()  # the loop may be sleeping in poll(stay=True): the run is over now

    def is_late(self, msg: Message) -> bool:
        return self.core.is_late(msg)

    def in_send_order(self, out: list) -> list:
        # Sensing first: the next tick waits on it; the state (for loggers) can follow.
        return sorted(out, key=lambda o: o[0] == WORLD_STATE) if len(out) > 1 else out


def wait_for_everyone(proc: RoleProcess, timeout: float, also: tuple[str, ...] = ()) -> list[str]:
    """Wait until the leader, every agent and ``also`` (``role/id`` names) are alive; return
    those still missing."""
    needed = ["leader/0"] + [f"agent/{r.id}" for r in proc.sc.robots] + list(also)
    deadline = Deadline(timeout, proc.wall_clock)
    while not proc.stopping and not deadline.passed():
        missing = [n for n in needed if n not in proc.alive]
        if not missing:
            return []
        proc.bus.poll(min(0.1, deadline.wait_s()))
        proc.check_parent()
    return [n for n in needed if n not in proc.alive]


def run_lockstep(proc: RoleProcess, tick_timeout: float) -> None:
    """The tick protocol runs in the handlers; this loop only wakes for the tick's deadline
    and departures (:class:`~fxswarm.world.node.TickTimer` decides; 0.1 s late at most to
    see a new tick: a deadline is never early)."""
    world: WorldNode = proc.core
    proc.publish(world.start())
    timer = TickTimer(world, tick_timeout, proc.wall_clock)  # tick 0's deadline starts now
    while not world.done and not proc.stopping:
        proc.bus.poll(min(0.1, timer.wait_s()), stay=not proc.gone)
        if world.done:
            break
        proc.publish(timer.check(gone_robots(proc)))
        proc.check_parent()


def gone_robots(proc: RoleProcess) -> set[int]:
    """Ids of the robots whose agent process has left."""
    return {int(name.split("/")[1]) for name in proc.gone if name.startswith("agent/")}


def run_realtime(proc: RoleProcess, world_rt: RealTimeWorld) -> dict:
    """Tick when ``world_rt``'s pacer says so (:class:`~fxswarm.world.node.RealTimeWorld`
    decides: late ticks, holds for lagging robots); stop when the run is done. Returns its
    report (``late_ticks``, ``held_ticks``, ``sensing_sent_again``, ``achieved_speed``, ``sense_to_command``)."""
    world: WorldNode = proc.core
    robots = [r.id for r in proc.sc.robots]
    proc.clock.start_now()
    proc.publish(world_rt.start())

    def tick() -> None:
        proc.publish(world_rt.tick([r for r in robots if f"agent/{r}" in proc.alive]))
        proc.clock.observe(world.t)
        if world.done:
            proc.stop("done")

    run_periodic_loop(proc, world_rt.pacer, tick, act_keeps_time=True)  # tick() holds or records the act
    return world_rt.report()


def main(args: argparse.Namespace) -> int:
    sc = load_or_exit(args.config)
    args.out = args.out or f"runs/{sc.name}-run"
    began = time.time()  # counters files older than this are an earlier run's
    proc = WorldProcess("world", 0, sc, args)
    extra: dict = {}
    code = 0
    crashed = False
    summary_of = None  # builds summary.json once the others have left (their counters are in)
    try:
        node = build_node(sc, args, proc.plan, proc.wall_clock)
        proc.watch(["leader/0", "agent/*", *args.wait_for])
        proc.attach(node)
        start = time.perf_counter()
        missing = wait_for_everyone(proc, args.wait_timeout, tuple(args.wait_for))
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
            extra.update(run_realtime(proc, unwrap_realtime(node)))
        world: WorldNode = proc.core
        wall = time.perf_counter() - started
        extra.update(missed_ticks_world=world.missed_ticks, ticks=world.tick, wall_s=wall,
                     ticks_per_s=world.tick / wall if wall > 0 else None)
        proc.bus.counters.missed_ticks = world.missed_ticks
        if world.tick > 0:
            runner = dict(clock=args.clock, speed=args.speed if not proc.lockstep else None,
                          complete=world.done, missed_ticks=world.missed_ticks,
                          missed_ticks_per_robot={str(r.id): int(m) for r, m in zip(sc.robots, world.misses)})
            runner.update({k: extra[k] for k in ("sense_to_command", "late_ticks", "held_ticks", "sensing_sent_again",
                                                 "achieved_speed", "longest_silence_s") if k in extra})

            def summarise(processes: dict) -> dict:
                return build_summary(sc, world.trajectory(), proc.plan, wall_s=wall, world=world, runner=runner,
                                     processes=processes)

            summary_of = summarise
        if not world.done:  # a run cut short is not a success: stopped by a signal, say which (128 + n)
            signalled = proc.stop_reason in ("SIGTERM", "SIGINT")
            code = 128 + signal.Signals[proc.stop_reason].value if signalled else 1
    except BaseException:
        crashed = True
        raise
    finally:
        try:
            proc.write_counters(extra)
            if not crashed:  # the others wait for a world that is gone without having said so
                proc.end_run()
            if summary_of is not None and not crashed:
                # After end_run: the processes that left have written their counters (a launcher,
                # if any, merges them again once every process has stopped).
                write_run(args.out, summary_of(read_process_counters(args.out, since=began)), proc.core.trajectory())
        finally:
            proc.close()  # always: an open session hangs the exit
    return code


def unwrap_realtime(node) -> RealTimeWorld:
    """The :class:`RealTimeWorld` under any inbox filters."""
    while not isinstance(node, RealTimeWorld):
        node = node.inner
    return node
