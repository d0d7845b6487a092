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
``fxswarm sim``) into ``--out``, and its counters into ``--out/processes/``; then it
serves that record on ``world/record`` (:mod:`fxswarm.runtime.record`) until the
observers still there (``alive/observer/*``, e.g. ``fxswarm attach``) have left, up to
``--record-wait`` s.

Saying it: it says at once when it has lost every router, and when one is back
(:class:`~fxswarm.runtime.connectivity.Connectivity`); ``summary.json`` has the outages
(``router_outages``) and the ticks it ran with robots it could not hear (``degraded``).
A run whose last ticks heard no robot at all (the world flew alone to the end: e.g. its
router gone for good) is no success: it says so and exits 1.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time

from fxswarm.core.bus import LEADER_STATE, WORLD_RECORD, WORLD_STATE
from fxswarm.core.messages import Message
from fxswarm.core.pacing import Deadline, WallClock
from fxswarm.core.scenario import Scenario
from fxswarm.faults.plan import FaultPlan
from fxswarm.faults.summary import build_summary
from fxswarm.runtime.numbers import non_negative_int, positive
from fxswarm.runtime.output import read_process_counters, write_run
from fxswarm.runtime.liveness import REJOIN_S
from fxswarm.runtime.record import Record, RecordServer
from fxswarm.runtime.process import RoleProcess, add_process_arguments, run_periodic_loop, wrap_node
from fxswarm.runtime.config import load_or_exit
from fxswarm.runtime.zenoh_bus import wait_until
from fxswarm.world.node import RealTimeWorld, RestartHold, TickTimer, WorldNode

#: Exit status of a world that heard none of its robots at the end of its run.
ALONE_EXIT = 1


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_process_arguments(p)
    p.add_argument("--tick-timeout", type=positive, default=1.0, metavar="S",
                   help="lock-step: close a tick after S wall seconds without every command (default 1)")
    p.add_argument("--max-lag", type=non_negative_int, default=10, metavar="TICKS",
                   help="real time: hold the clock while a live robot's latest command, or the leader's latest "
                        "state, is more than TICKS ticks old (they share this machine's CPUs; in the field each "
                        "robot has its own), at most --tick-timeout s at a time; 0: never hold (default 10)")
    p.add_argument("--wait-timeout", type=positive, default=120.0, metavar="S",
                   help="give up (exit 3) if the leader and all agents are not up within S s (default 120)")
    p.add_argument("--wait-for", action="append", default=[], metavar="ROLE/ID",
                   help="also wait for this process's liveliness before the clock starts (repeatable), e.g. "
                        "logger/0 where no orchestrator orders the start, or observer/0 for `fxswarm attach`")
    p.add_argument("--hold-restarts", action="store_true",
                   help="lock-step: hold the tick of each planned restart ([[faults.processes]]) until the robot's "
                        "new process is up, so it lands at its time as in `fxswarm sim` (`fxswarm run` sets it: "
                        "its launcher does the restarts)")
    p.add_argument("--finished-ok", action="store_true",
                   help="exit 0 once the run has reached its end, even one flown alone (still said on the "
                        "console and in summary.json's degraded): `fxswarm stack` sets it, as Docker Swarm "
                        "restarts a task that exits non-zero, and a finished run must not start over")
    p.add_argument("--ros2", action="store_true",
                   help="a gateway to ROS 2 robots instead of the simulation (real time; needs fxswarm[ros2]; "
                        "the scenario's [ros2] table, ROS_DOMAIN_ID and CYCLONEDDS_URI; docs/ros2.md)")
    p.add_argument("--record-wait", type=positive, default=60.0, metavar="S",
                   help="after the run, serve its record (world/record) for up to S s while an observer "
                        "(alive/observer/*, e.g. `fxswarm attach`) is still there to fetch it (default 60)")


def ros2_or_exit(sc: Scenario, who: str = "fxswarm world"):
    """The ROS 2 world's module (:mod:`fxswarm.world.ros2`), once its extra, ``ROS_DOMAIN_ID`` and a
    speed limit are there; else one line on stderr and exit 2 (before anything starts)."""
    from fxswarm.world.safety import require_speed_limit

    ros2 = ros2_module_or_exit(who)
    try:
        require_speed_limit(sc)
    except ValueError as exc:
        print(f"{who}: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    return ros2


def ros2_module_or_exit(who: str):
    """:mod:`fxswarm.world.ros2` once its extra (Cyclone DDS) and a valid ``ROS_DOMAIN_ID`` are
    there; else one line on stderr and exit 2."""
    try:
        from fxswarm.world import ros2
    except ImportError as exc:
        if not (exc.name or "").startswith("cyclonedds"):
            raise
        print(f"{who}: a ROS 2 world needs the ros2 extra (Cyclone DDS): pip install 'fxswarm[ros2]' ({exc})",
              file=sys.stderr)
        raise SystemExit(2) from None
    try:
        ros2.domain_id()
    except ValueError as exc:
        print(f"{who}: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    return ros2


def build_node(scenario: Scenario, args: argparse.Namespace, plan: FaultPlan,
               clock: WallClock = time.monotonic):
    """The world's node as this process runs it (one place, so wrappers apply here)."""
    if getattr(args, "ros2", False):
        from fxswarm.world.ros2 import GatewayWorld, PoseBoard

        node = GatewayWorld(scenario, PoseBoard(scenario.n, scenario.ros2.pose_timeout, clock), limits=plan.limits)
    else:
        node = WorldNode(scenario, limits=plan.limits)
    if args.clock == "realtime":
        # Real robots move on whether or not a robot lags: the ROS 2 world never holds its clock.
        max_lag = 0 if getattr(args, "ros2", False) else args.max_lag
        node = RealTimeWorld(node, scenario.dt / args.speed, clock, max_lag, args.tick_timeout,
                             cut_off=plan.cut_off_from_world)
    return wrap_node(node, "world", 0, plan, scenario, args)


class WorldProcess(RoleProcess):
    def deliver(self, topic: str, msg: Message) -> None:
        super().deliver(topic, msg)
        if self.lockstep and self.core.done:
            self.bus.wake()  # the loop may be sleeping in poll(stay=True): the run is over now

    def is_late(self, msg: Message) -> bool:
        return self.core.is_late(msg)

    def __init__(self, *args, **kwargs) -> None:
        self.observers: set[str] = set()  # alive/observer/* tokens up now: who may fetch the record
        super().__init__(*args, **kwargs)

    def on_observer(self, name: str, up: bool) -> None:
        (self.observers.add if up else self.observers.discard)(name)

    def sim_now(self):
        def now() -> tuple[float, int]:
            core = self.core
            return (core.t, core.tick) if core is not None else (0.0, 0)
        return now

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


def run_lockstep(proc: RoleProcess, tick_timeout: float, hold_restarts: bool = False) -> int:
    """The tick protocol runs in the handlers; this loop only wakes for the tick's deadline
    and departures (:class:`~fxswarm.world.node.TickTimer` decides; 0.1 s late at most to
    see a new tick: a deadline is never early). ``hold_restarts``: a planned restart is waited
    for at its tick (:class:`~fxswarm.world.node.RestartHold`)."""
    world: WorldNode = proc.core
    proc.publish(world.start())
    timer = TickTimer(world, tick_timeout, proc.wall_clock, REJOIN_S)  # tick 0's deadline starts now
    restarts = RestartHold(proc.plan.processes, proc.liveness.ups, proc.sc.dt, proc.wall_clock, REJOIN_S) \
        if hold_restarts else None
    outages = proc.rejoined
    while not world.done and not proc.stopping:
        proc.bus.poll(min(0.1, timer.wait_s()), stay=not proc.gone)
        if world.done:
            break
        proc.check_parent()
        if proc.rejoined != outages:  # a router outage is over: whatever it swallowed is asked for again
            outages = proc.rejoined
            proc.publish(timer.ask_again())
        holding = False
        if restarts is not None and restarts.pending:
            holding, back = restarts.check(world.tick)
            if back:  # the new process came up after this tick was sent: it hears it now
                proc.publish(timer.ask_again())
            for name in restarts.given_up:
                print(f"fxswarm world: {name}'s planned restart not up within {REJOIN_S:g} s: going on without it",
                      file=sys.stderr)
            restarts.given_up.clear()
        proc.publish(timer.check(gone_robots(proc), unsure=holding or bool(proc.unsure())))
    return timer.asked


def gone_robots(proc: RoleProcess) -> set[int]:
    """Ids of the robots whose agent process has left."""
    return {int(name.split("/")[1]) for name in proc.gone if name.startswith("agent/")}


def run_realtime(proc: RoleProcess, world_rt: RealTimeWorld, link=None) -> dict:
    """Tick when ``world_rt``'s pacer says so (:class:`~fxswarm.world.node.RealTimeWorld`
    decides: late ticks, holds for lagging robots); stop when the run is done. Returns its
    report (``late_ticks``, ``held_ticks``, ``held_for``, ``sensing_sent_again``, ``achieved_speed``,
    ``sense_to_command``).
    ``link``: the ROS 2 world's :class:`~fxswarm.world.ros2.Ros2Link`: each tick reads the robots'
    poses before and sends their commands after."""
    world: WorldNode = proc.core
    robots = [r.id for r in proc.sc.robots]
    proc.clock.start_now()
    if world_rt.max_lag > 0:  # how far the leader has got, past the fault filters (RealTimeWorld.heard_leader)
        proc.bus.subscribe(LEADER_STATE, world_rt.heard_leader)
    proc.publish(world_rt.start())

    def tick() -> None:
        if link is not None:
            link.read(world.board)
            world.gone = gone_robots(proc)
        proc.publish(world_rt.tick([r for r in robots if f"agent/{r}" in proc.alive], "leader/0" in proc.alive))
        if link is not None:
            link.send(world.velocities(), world.board.yaw)
        proc.clock.observe(world.t)
        if world.done:
            proc.stop("done")

    run_periodic_loop(proc, world_rt.pacer, tick, act_keeps_time=True)  # tick() holds or records the act
    return world_rt.report()


def wait_for_poses(proc: RoleProcess, link, board, timeout: float) -> list[int]:
    """The ROS 2 world: wait until every robot has published a pose; return those still unheard."""
    deadline = Deadline(timeout, proc.wall_clock)
    while not proc.stopping and not deadline.passed():
        link.read(board)
        if not board.unheard():
            return []
        proc.bus.poll(0.02)  # the poses' rate is the robots': look again at 50 Hz
        proc.check_parent()
    return board.unheard()


def main(args: argparse.Namespace) -> int:
    sc = load_or_exit(args.config)
    ros2 = None
    if args.ros2:
        if args.clock != "realtime" or args.speed != 1.0:
            print("fxswarm world: --ros2 flies real robots: it runs with --clock realtime at --speed 1",
                  file=sys.stderr)
            return 2
        ros2 = ros2_or_exit(sc)
    args.out = args.out or f"runs/{sc.name}-run"
    began = time.time()  # counters files older than this are an earlier run's
    proc = WorldProcess("world", 0, sc, args)
    extra: dict = {}
    code = 0
    crashed = False
    summary_of = None  # builds summary.json once the others have left (their counters are in)
    link = None  # the ROS 2 world's DDS side: every way out sends the robots zero Twists
    try:
        node = build_node(sc, args, proc.plan, proc.wall_clock)
        if ros2 is not None:
            link = ros2.Ros2Link(sc, ros2.domain_id())
        proc.watch(["leader/0", "agent/*", *args.wait_for])
        proc.bus.watch_alive("observer/*", proc.on_observer)  # not in alive/gone: observers come and go
        proc.attach(node)
        start = time.perf_counter()
        missing = wait_for_everyone(proc, args.wait_timeout, tuple(args.wait_for))
        if link is not None and not missing:
            unheard = wait_for_poses(proc, link, proc.core.board, args.wait_timeout)
            missing = [sc.ros2.topic(sc.ros2.pose_topic, r) for r in unheard]
        if missing and not proc.stopping:
            print(f"fxswarm world: gave up after {args.wait_timeout:g} s waiting for {', '.join(missing)}",
                  file=sys.stderr)
            return 3
        if proc.stopping:
            return 0
        started = time.perf_counter()
        extra["waited_s"] = started - start
        if proc.lockstep:
            extra["asked_again"] = run_lockstep(proc, args.tick_timeout, args.hold_restarts)
        else:
            extra.update(run_realtime(proc, unwrap_realtime(node), link))
        world: WorldNode = proc.core
        wall = time.perf_counter() - started
        extra.update(missed_ticks_world=world.missed_ticks, ticks=world.tick, wall_s=wall,
                     ticks_per_s=world.tick / wall if wall > 0 else None)
        proc.bus.counters.missed_ticks = world.missed_ticks
        if world.tick > 0:
            runner = dict(clock=args.clock, speed=args.speed if not proc.lockstep else None,
                          complete=world.done, missed_ticks=world.missed_ticks,
                          missed_ticks_per_robot={str(r.id): int(m) for r, m in zip(sc.robots, world.misses)})
            runner.update({k: extra[k] for k in ("sense_to_command", "late_ticks", "held_ticks", "held_for",
                                                 "sensing_sent_again", "achieved_speed", "longest_silence_s")
                           if k in extra})

            def summarise(processes: dict) -> dict:
                return build_summary(sc, world.trajectory(), proc.plan, wall_s=wall, world=world, runner=runner,
                                     processes=processes, router_outages=proc.connectivity.report())

            summary_of = summarise
        code = exit_status(world, proc.stop_reason, proc.connectivity.report(), args.finished_ok)
    except BaseException:
        crashed = True
        raise
    finally:
        try:
            if link is not None:  # first: nothing may keep moving once the world stops
                extra["ros2_zero_twists_acknowledged"] = link.stop_all()
                extra.update(link.report(), **proc.core.report())
            proc.write_counters(extra)
            if not crashed:  # the others wait for a world that is gone without having said so
                proc.end_run()
            if summary_of is not None and not crashed:
                # After end_run: the processes that left have written their counters (a launcher,
                # if any, merges them again once every process has stopped).
                summary = summary_of(read_process_counters(args.out, since=began))
                out = write_run(args.out, summary, proc.core.trajectory())
                serve_record(proc, Record(summary, (out / "trajectory.npz").read_bytes()), args.record_wait)
        finally:
            proc.close()  # always: an open session hangs the exit
    return code


def exit_status(world: WorldNode, stop_reason: str, outages: list[dict], finished_ok: bool = False) -> int:
    """The world's exit status at the end of its loop. A run cut short is not a success: stopped
    by a signal, 128 + its number, else 1. A finished run is 0, or ``ALONE_EXIT`` if the world
    flew alone at the end (said on the console either way), unless ``finished_ok``: `fxswarm stack`
    sets it, as Docker Swarm restarts a task that exits non-zero."""
    if not world.done:
        signalled = stop_reason in ("SIGTERM", "SIGINT")
        return 128 + signal.Signals[stop_reason].value if signalled else 1
    if say_degraded(world, outages, 0 if finished_ok else ALONE_EXIT):
        return 0 if finished_ok else ALONE_EXIT
    return 0


def say_degraded(world: WorldNode, outages: list[dict], status: int = ALONE_EXIT) -> bool:
    """Say on the console how the run was degraded, if it was; return whether the world heard
    none of its robots at the end (it flew alone: no success, whatever ``complete`` says)."""
    degraded = world.degraded()
    if outages:
        print(f"fxswarm world: warning: lost every router {len(outages)} time(s) during the run: "
              + ", ".join(f"t = {o['start']:.2f}-{'end' if o['end'] is None else format(o['end'], '.2f')} s "
                          f"({o['ticks']} ticks)" for o in outages), file=sys.stderr)
    if degraded["ticks"]:
        print(f"fxswarm world: warning: degraded run: {degraded['ticks']} of {world.tick} ticks ran with robots it "
              f"could not hear (held at zero velocity: robots {', '.join(map(str, degraded['robots']))}); "
              f"summary.json: degraded", file=sys.stderr)
    if world.unheard_since is None:
        return False
    print(f"fxswarm world: heard none of its {world.sc.n} robots from t = {world.unheard_since * world.sc.dt:.2f} s "
          f"to the end ({world.tick - world.unheard_since} of {world.tick} ticks flown alone"
          f"{', its router lost' if outages and outages[-1]['end'] is None else ''}): "
          f"the run is not a success; exit status {status}"
          f"{' (--finished-ok: the run reached its end)' if status == 0 else ''}", file=sys.stderr)
    return True


def serve_record(proc: WorldProcess, record: Record, wait_s: float) -> None:
    """Serve the run's record while observers are there to fetch it, up to ``wait_s`` s."""
    server = RecordServer(proc.bus.session, f"{proc.bus.root}/{WORLD_RECORD}", record)
    try:
        observers = proc.observers
        if observers:
            print(f"fxswarm world: serving the run's record to {', '.join(sorted(observers))} (up to {wait_s:g} s)",
                  file=sys.stderr)
            if not wait_until(proc.bus, lambda: not observers, wait_s):
                print(f"fxswarm world: {', '.join(sorted(observers))} still there after {wait_s:g} s; the record "
                      f"was fetched {server.served} time(s)", file=sys.stderr)
    finally:
        server.close()


def unwrap_realtime(node) -> RealTimeWorld:
    """The :class:`RealTimeWorld` under any inbox filters."""
    while not isinstance(node, RealTimeWorld):
        node = node.inner
    return node
