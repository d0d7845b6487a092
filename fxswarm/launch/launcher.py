"""``fxswarm run CONFIG``: a scenario as one OS process per role, on one machine.

The command line over :class:`~fxswarm.launch.swarm.Swarm`, which carries out a pure
:class:`~fxswarm.launch.plan.LaunchPlan` (topology, ports, every child's command line, the
router config) with a :class:`~fxswarm.launch.processes.Processes` owner. It starts
``fxswarm router`` on a free port, then the logger (if installed), the leader and every agent,
which meet at that router: as peers that then link to each other directly (``mesh``, the
default for small swarms) or as its clients, every message through it (``routed``); it waits on
their liveliness tokens (no fixed sleeps), starts the world last (so nobody misses tick 0),
shows a progress line from ``world/state``, and at the end merges every process's counters
into ``summary.json``.

Deaths: the world or leader dying unplanned ends the run with a non-zero exit that names the
process and shows its last stderr lines; a router that dies is started again on its endpoint
(with its keys and rules), every process reconnects, and lock-step asks again for what the
outage swallowed (``--routers N`` runs N meshed routers, each process failing over among
them); an agent dying is reported and the swarm runs on (``--fail-fast`` ends it); Ctrl-C (or
SIGTERM) stops everything within 5 s and says what it stopped.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time
from pathlib import Path

import numpy as np

from fxswarm.core.scenario import RUN_TOPOLOGIES
from fxswarm.faults.plan import CLI_HELP as FAULT_HELP
# The launcher's parts, by their former home's names (tests and benchmarks import them from here).
from fxswarm.launch.plan import MESH_MAX_ROBOTS, auto_topology, free_port, topology_options  # noqa: F401
from fxswarm.launch.processes import ZENOH_RUNTIME, Child, Death  # noqa: F401
from fxswarm.launch.swarm import MAX_ROUTER_RESTARTS, Swarm
from fxswarm.launch.watch import StartError
from fxswarm.runtime.config import load_or_exit, plan_or_exit
from fxswarm.runtime.numbers import non_negative_int, port, positive, positive_int, swarm_name
from fxswarm.runtime.output import prepare_run_folder
from fxswarm.runtime.process import CLOCKS


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="scenario file (TOML)")
    p.add_argument("--out", default=None, help="run folder (default: runs/<scenario name>)")
    p.add_argument("--clock", choices=CLOCKS, default=None,
                   help="lockstep (bit-identical to `fxswarm sim`; the default) or realtime (the default with --world ros2)")
    p.add_argument("--world", choices=("sim", "ros2"), default="sim",
                   help="sim: the simulated world; ros2: a gateway to ROS 2 robots (real time; fxswarm[ros2]; docs/ros2.md)")
    p.add_argument("--ros2", action="store_true",
                   help="also publish the swarm to ROS 2 (robot and leader poses, estimates, obstacles as markers) "
                        "for RViz, Foxglove and rosbag2 (fxswarm[ros2]; docs/ros2.md)")
    p.add_argument("--speed", type=positive, default=None,
                   help="real time: simulation seconds per wall second (default 1)")
    p.add_argument("--swarm", type=swarm_name, default=None,
                   help="key prefix (default: the scenario's [zenoh] swarm, else <scenario name>-<launcher pid>)")
    p.add_argument("--port", type=port, default=None, help="router port on 127.0.0.1 (default: a free one)")
    p.add_argument("--tick-timeout", type=positive, default=1.0, metavar="S",
                   help="lock-step: a tick waits at most S s for its commands (default 1)")
    p.add_argument("--topology", choices=RUN_TOPOLOGIES, default=None,
                   help="mesh: peers on direct links, the router only where they meet; routed: every "
                        f"message through the router; auto: mesh up to {MESH_MAX_ROBOTS} robots unless a process "
                        "is to be frozen (default: "
                        "the scenario's [zenoh] topology, else auto)")
    p.add_argument("--routers", type=positive_int, default=1, metavar="N",
                   help="start N routers meshed with each other; every process lists them all and fails over "
                        "to another when its router is lost (default 1; a router that dies is started again)")
    p.add_argument("--lease-ms", type=positive_int, default=None, help="zenoh lease (how fast a frozen process is seen gone)")
    p.add_argument("--max-lag", type=non_negative_int, default=None, metavar="TICKS",
                   help="real time: the world holds its clock while a robot or the leader is more than TICKS ticks behind "
                        "(default 10; 0: never)")
    p.add_argument("--no-logger", action="store_true", help="do not start the Rerun logger process")
    p.add_argument("--rerun", default=None, metavar="OUTPUTS",
                   help="the logger's outputs, as in `fxswarm logger --rerun`: file[=PATH], grpc[=URL] (a "
                        "running viewer), spawn (a local viewer), web[=PORT] (default: file, OUT/recording.rrd); "
                        "e.g. file,spawn to watch the run live and keep the recording")
    p.add_argument("--fail-fast", action="store_true", help="end the run when any agent dies")
    p.add_argument("--start-timeout", type=positive, default=60.0, help="seconds to wait for every process to be up")
    p.add_argument("--quiet", action="store_true", help="no start, fault, progress or summary lines; warnings and errors are still written")
    p.add_argument("--fault", action="append", default=None, metavar="SPEC", help=FAULT_HELP)
    g = p.add_argument_group("secure mode (docs/security.md)")
    g.add_argument("--secure", default=None, metavar="KEYS",
                   help="keys folder from `fxswarm keys KEYS CONFIG`: mutual TLS on every link (tls/127.0.0.1:PORT, "
                        "nothing in plaintext) and per-process rights enforced by the router and, in a mesh, by every "
                        "peer on its own links; same topology as a plain run")
    g.add_argument("--audit", action="store_true",
                   help="secure: the router logs each message its rules refuse (logs/router.log); makes the run routed")



def _progress(swarm: Swarm, t0: float, stream=sys.stderr) -> None:
    s = swarm.state
    if s is None:
        return
    sc = swarm.scenario
    p0 = sc.leader.position(s.t)
    offsets = np.array([r.offset.position(s.t) for r in sc.robots])
    f_err = float(np.linalg.norm(s.p - p0 - offsets, axis=1).max())
    rate = s.tick / max(time.monotonic() - t0, 1e-9)
    up = sum(1 for c in swarm.children.values() if c.running())
    line = (f"  t = {s.t:7.2f} / {sc.duration:g} s   {rate:7.0f} ticks/s   "
            f"max formation error {f_err:8.3f} m   processes up {up}/{len(swarm.children)} ")
    # On a terminal the line overwrites itself; in a log file each update is a line of its own.
    stream.write("\r" + line if stream.isatty() else line + "\n")
    stream.flush()


def _raise_interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def _fail(text: str) -> int:
    print(f"fxswarm run: {text}", file=sys.stderr)
    return 2


def _options_error(args: argparse.Namespace) -> str | None:
    """What is wrong with options that do not go together (None: nothing); sets the clock."""
    ros2 = args.world == "ros2"
    if ros2 and (args.clock == "lockstep" or args.speed not in (None, 1.0)):
        return "--world ros2 flies real robots: real time (--clock realtime) at --speed 1 only"
    args.clock = args.clock or ("realtime" if ros2 else "lockstep")
    given = [f"--{name.replace('_', '-')}" for name in ("speed", "max_lag") if getattr(args, name) is not None]
    if given and args.clock != "realtime":  # lock-step runs as fast as it can and never lags
        return f"{' and '.join(given)} set real time's pace: add --clock realtime"
    if args.rerun is not None and args.no_logger:
        return "--rerun sets the logger's outputs; it cannot go with --no-logger"
    if args.audit and not args.secure:
        return "--audit needs --secure KEYS (the rules go by certificate)"
    return None


def _recording(args: argparse.Namespace, out: Path) -> Path | None:
    """Where the logger writes its file, if it does (a bad --rerun: exit 2)."""
    if args.rerun is None:
        return out / "recording.rrd"
    from fxswarm.logger.sinks import OutputError, parse_outputs  # loads Rerun: only when asked

    try:
        return parse_outputs(args.rerun, out).file
    except OutputError as exc:
        raise SystemExit(_fail(str(exc))) from None


def _ros2_view(args: argparse.Namespace, sc):
    """The ROS 2 checks, before anything starts; the ``--ros2`` view (None without)."""
    if args.world == "ros2":
        from fxswarm.world.process import ros2_or_exit

        ros2_or_exit(sc, "fxswarm run")  # the extra, ROS_DOMAIN_ID and a speed limit
    if not args.ros2:
        return None
    from fxswarm.world.process import ros2_module_or_exit

    ros2 = ros2_module_or_exit("fxswarm run")  # the extra and ROS_DOMAIN_ID, checked
    from fxswarm.launch.ros2_view import Ros2View

    return Ros2View(sc, ros2.domain_id())


def _swarm(args: argparse.Namespace, sc, out: Path, plan, view) -> Swarm:
    """The run's swarm: planned, nothing started."""
    world_args = (("--max-lag", str(args.max_lag)) if args.max_lag is not None else ()) \
        + (("--ros2",) if args.world == "ros2" else ())
    try:
        return Swarm(args.config, out, clock=args.clock, speed=args.speed or 1.0, swarm=args.swarm, port=args.port,
                     logger=not args.no_logger, tick_timeout=args.tick_timeout, lease_ms=args.lease_ms,
                     scenario=sc, topology=args.topology, faults=tuple(args.fault or ()), plan=plan,
                     secure=args.secure, audit=args.audit, routers=args.routers, world_args=world_args,
                     logger_args=("--rerun", args.rerun) if args.rerun is not None else (),
                     state_listener=view.publish if view is not None else None)
    except ValueError as exc:  # options that do not go together (e.g. --audit with --topology mesh)
        raise SystemExit(_fail(str(exc))) from None


class _Outcome:
    """What the run loop saw: the exit code and the deaths the summary reports."""

    def __init__(self) -> None:
        self.code = 0
        self.agent_deaths: list[str] = []
        self.logger_death: str | None = None  # a run whose recording stopped must not look whole


def _on_death(d: Death, swarm: Swarm, args: argparse.Namespace, seen: _Outcome) -> None:
    def warn(text: str) -> None:
        print(text, file=sys.stderr)

    if d.child.role == "agent":
        seen.agent_deaths.append(d.child.name)
        warn(f"\nfxswarm run: {d.describe()}")
        if args.fail_fast:
            warn("fxswarm run: --fail-fast: ending the run")
            seen.code = 1
    elif d.child.role == "logger":
        seen.logger_death = f"{d.describe()} at t = {swarm.sim_time():.2f} s"
        warn(f"\nfxswarm run: warning: {d.describe('the swarm runs on without it')}")
    elif d.restarted:
        warn("\nfxswarm run: warning: " + d.describe(f"started it again (restart {swarm.router_restarts} of at "
                                                     f"most {MAX_ROUTER_RESTARTS}): every process reconnects"))
    elif d.child.role == "router" and swarm.topology == "mesh":
        warn("\nfxswarm run: warning: " + d.describe("the swarm runs on over its direct links (a process that "
                                                     "starts from now on cannot join it)"))
    else:
        warn(f"\nfxswarm run: {d.describe()}")
        seen.code = 1


def _fly(swarm: Swarm, args: argparse.Namespace, say, seen: _Outcome) -> None:
    """Start the swarm and tend it until the world ends (or a death ends the run)."""
    took = swarm.start(timeout=args.start_timeout)
    say(f"fxswarm run: {len(swarm.children)} processes up in {took:.1f} s "
        f"(swarm {swarm.swarm!r}, router {swarm.endpoint}, {swarm.topology}, clock {args.clock})")
    t0, last = time.monotonic(), 0.0
    world = swarm.children["world"]
    while True:
        deaths, events = swarm.tend(0.1)
        for event in events:
            done = event["done_t_s"]
            later = f", done at t = {done:.2f} s" if done is not None and done > event["t_s"] else ""
            say(f"\nfxswarm run: fault: {event['action']} {event['target']} at t = {event['t_s']:.2f} s{later}")
        for d in deaths:
            _on_death(d, swarm, args, seen)
        if seen.code or not world.running():
            break
        now = time.monotonic()
        if not args.quiet and now - last > (0.5 if sys.stderr.isatty() else 5.0):
            _progress(swarm, t0)
            last = now
    if not args.quiet:
        _progress(swarm, t0)
        if sys.stderr.isatty():
            sys.stderr.write("\n")
    if world.popen.returncode not in (None, 0) and seen.code == 0:
        print(f"fxswarm run: {Death(world, world.popen.returncode).describe()}", file=sys.stderr)
        seen.code = 1


def _say_stopped(swarm: Swarm, args: argparse.Namespace, code: int) -> None:
    stopped = {k: v for k, v in swarm.stopped.items() if v != "exited"}
    if stopped and (code or not args.quiet):
        print("fxswarm run: stopped " + ", ".join(f"{k} ({v})" for k, v in stopped.items()), file=sys.stderr)


def _report(swarm: Swarm, args: argparse.Namespace, seen: _Outcome, recording: Path | None, started: float) -> None:
    summary = swarm.merge_summary({"launcher": {"swarm": swarm.swarm, "router": swarm.endpoint,
                                                "routers": list(swarm.endpoints),
                                                "router_restarts": swarm.router_restarts,
                                                "topology": swarm.topology,
                                                "secure": bool(args.secure),
                                                "agent_deaths": seen.agent_deaths, "logger_death": seen.logger_death,
                                                "exit_code": seen.code}})
    if summary is None or seen.code != 0 or args.quiet:
        return
    keys = ("robots", "ticks", "wall_s", "min_object_distance_m", "formation_error_final_m",
            "estimate_error_final_m", "formation_settle_s", "missed_ticks")
    print(json.dumps({k: summary.get(k) for k in keys}, indent=2))
    print(f"wrote {swarm.out}/summary.json and {swarm.out}/trajectory.npz")
    if recording is not None and recording.exists() and recording.stat().st_mtime >= started:  # not a stale one
        print(f"wrote {recording} (view it: rerun {recording}; figures: fxswarm report {swarm.out})")


def main(args: argparse.Namespace) -> int:
    error = _options_error(args)
    if error is not None:
        return _fail(error)
    sc = load_or_exit(args.config)
    view = _ros2_view(args, sc)
    plan = plan_or_exit(sc, args.fault)  # resolved once here: every child receives this plan
    out = prepare_run_folder(args.out or f"runs/{sc.name}", "fxswarm run")
    recording = _recording(args, out)
    started = time.time()
    swarm = _swarm(args, sc, out, plan, view)
    # SIGINT and SIGTERM both stop the run cleanly, even where SIGINT came in ignored (a background job).
    signal.signal(signal.SIGTERM, _raise_interrupt)
    signal.signal(signal.SIGINT, _raise_interrupt)
    # --quiet hides the chatter (start, planned faults, progress, the summary), never a warning.
    say = (lambda *a: None) if args.quiet else (lambda text: print(text, file=sys.stderr))
    seen = _Outcome()
    with swarm:  # leaving it stops every process the run started
        try:
            _fly(swarm, args, say, seen)
        except StartError as exc:
            print(f"fxswarm run: the swarm did not start: {exc}", file=sys.stderr)
            seen.code = 1
        except KeyboardInterrupt:
            seen.code = 130
            print("\nfxswarm run: interrupted", file=sys.stderr)
        finally:
            for sig in (signal.SIGINT, signal.SIGTERM):  # a second Ctrl-C must not cut the clean-up short
                signal.signal(sig, signal.SIG_IGN)
    _say_stopped(swarm, args, seen.code)
    _report(swarm, args, seen, recording, started)
    return seen.code
