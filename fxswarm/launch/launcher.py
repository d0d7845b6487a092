"""``fxswarm run CONFIG``: a scenario as one OS process per role, on one machine.

The launcher owns every process it starts (trio's rule: every start has a
matching stop). It starts ``fxswarm router`` on a free port, then the logger
(if installed), the leader and every agent, which meet at that router: as
peers that then link to each other directly (``mesh``, the default for small
swarms) or as its clients, every message through it (``routed``); it
waits on their liveliness tokens (no fixed sleeps), starts the world last
(so nobody misses tick 0), shows a progress line from ``world/state``, and
at the end merges every process's counters into ``summary.json``.

Deaths: the world or leader dying unplanned ends the run with a non-zero exit that names the
process and shows its last stderr lines; a router that dies is started again on its endpoint
(with its keys and rules), every process reconnects, and lock-step asks again for what the
outage swallowed (``--routers N`` runs N meshed routers, each process failing over among them); an
agent dying is reported and the swarm runs on (``--fail-fast`` ends it);
Ctrl-C (or SIGTERM) stops everything within 5 s and says what it stopped.

:class:`Swarm` holds the building blocks (start, wait, kill, freeze,
restart, stop); :mod:`fxswarm.testing` drives the same class from tests.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import os
import shlex
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from fxswarm.core import bus as topics
from fxswarm.core.messages import WireError, WorldState, decode
from fxswarm.core.scenario import RUN_TOPOLOGIES, Scenario
from fxswarm.faults.plan import CLI_HELP as FAULT_HELP
from fxswarm.faults.plan import FaultPlan, dumps, plan_of, resolve
from fxswarm.faults.process import ProcessSchedule
from fxswarm.faults.summary import add_processes
from fxswarm.launch.orphans import die_with_parent
from fxswarm.runtime.numbers import non_negative_int, port, positive, positive_int, swarm_name
from fxswarm.runtime.output import prepare_run_folder, read_process_counters, write_summary
from fxswarm.runtime.process import CLOCKS, PARENT_ENV
from fxswarm.runtime.config import load_or_exit, plan_or_exit
from fxswarm.runtime.zenoh_bus import ConnectError, ZenohBus, ZenohOptions, check_sender

# "auto" meshes swarms up to this many robots. Measured (docs/design.md "Topology";
# docs/benchmarks.md "Topology: mesh against routed"): with 6 robots a mesh takes the router's
# hop out of every message (4-24 % more lock-step ticks/s, real-time p50 at speed 4 halved),
# with 8 a little (177-180 against 166-174 ticks/s); with 12 the mesh's
# links already cost more than the hop (104-114 against 106-120), with 24 (351 links) clearly.
MESH_MAX_ROBOTS = 8
# Zenoh's runtimes in each child: one worker thread each for app, rx and tx (by default app and
# rx have two). Fewer threads to wake per message: lock-step paper-fast ran faster in 6 of 8
# interleaved rounds (medians 282 -> 309 and 276 -> 295 ticks/s, ~7 % less CPU per tick);
# neutral for 24 robots and for real-time latency (docs/design.md "Transport cost").
# A ZENOH_RUNTIME already in the environment wins.
ZENOH_RUNTIME = "(app: (worker_threads: 1), rx: (worker_threads: 1), tx: (worker_threads: 1))"
STOP_BUDGET_S = 4.5  # Ctrl-C to nothing left: the issue promises 5 s
LOGGER_GRACE_S = 15.0
#: Supervision: a router that dies is started again, at most this many times in a run (one that
#: keeps dying, e.g. its port taken, ends a routed run as before).
MAX_ROUTER_RESTARTS = 10
#: The official router's binary (a command line) to start instead of `fxswarm router`, as
#: ``ZENOHD -c FILE`` (`make test-zenohd` sets it).
ZENOHD_ENV = "FXSWARM_ZENOHD"  # at the end of a run, time for the logger to close its recording by itself


def free_port() -> int:
    """A TCP port that was free a moment ago (bind port 0 and let the kernel choose)."""
    return free_ports(1)[0]


def free_ports(n: int) -> list[int]:
    """``n`` distinct TCP ports that were free a moment ago: all held open together while the
    kernel chooses, so that it cannot hand the same port out twice."""
    with contextlib.ExitStack() as stack:
        socks = [stack.enter_context(socket.socket(socket.AF_INET, socket.SOCK_STREAM)) for _ in range(n)]
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]


def auto_topology(scenario: Scenario, plan: FaultPlan | None = None) -> str:
    """What ``--topology auto`` picks: a mesh up to :data:`MESH_MAX_ROBOTS` robots, else routed;
    and routed whenever the fault ``plan`` (default: the scenario's ``[faults]``) freezes a
    process. A freeze longer than the Zenoh lease (in lock-step, a frozen robot's ticks close at
    ``--tick-timeout`` each, so most are) can leave a mesh link that expired on one side only
    split for good: some peers never see the thawed process's token again
    (eclipse-zenoh/zenoh#2806; docs/design.md "Topology")."""
    if scenario.n > MESH_MAX_ROBOTS:
        return "routed"
    if any(f.action == "freeze" for f in (plan if plan is not None else plan_of(scenario)).processes):
        return "routed"
    return "mesh"


def topology_options(topology: str, router: str | tuple[str, ...], lease_ms: int | None = None,
                     secure: bool = False) -> ZenohOptions:
    """How a process on this machine joins a ``mesh`` or ``routed`` swarm whose router listens at
    ``router`` (or routers: the first that answers, the others if it is lost): a mesh peer meets the others there (gossip) and then talks to them over direct
    links, each on a port of its own, so the router carries no data once the links are up; a
    routed client sends everything through it. Multicast scouting off either way; ``secure``: the
    peers' own links are TLS too."""
    routers = (router,) if isinstance(router, str) else tuple(router)
    if topology == "mesh":
        return ZenohOptions("peer", routers, (f"{'tls' if secure else 'tcp'}/127.0.0.1:0",), False, lease_ms)
    if topology == "routed":
        return ZenohOptions("client", routers, (), False, lease_ms)
    raise ValueError(f"topology: expected mesh or routed, got {topology!r}")


def secure_topology(topology: str, audit: bool) -> str:
    """The topology of a secure run: the one asked for (``auto`` as for a plain run), routed with
    ``--audit``. A mesh peer enforces the swarm's rules on its own direct links, as the router does
    on its own (docs/security.md "Topology"); refusals are logged only where ``--audit`` asks, at
    the router, so an audited run sends everything through it."""
    if audit:
        if topology == "mesh":
            raise ValueError("--audit: the router logs the refusals, so an audited run is routed; "
                             "leave --topology out or say routed")
        return "routed"
    return topology


def secure_files_or_exit(keys: str, scenario: Scenario, mesh: bool = False):
    """Check every process's key files in ``keys`` before anything starts; the launcher's own files.

    A missing, unreadable, expired or wrong-CA file is one line naming it, and exit 2.
    """
    from fxswarm.runtime.tls import KeyFileError, checked
    from fxswarm.security.policy import process_names

    try:
        for name in process_names(scenario):
            checked(keys, name, server=mesh and name != "router")  # a mesh peer serves its links
        return checked(keys, "observer", server=mesh)
    except KeyFileError as exc:
        print(f"fxswarm run: --secure: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


def logger_available() -> bool:
    try:
        return importlib.util.find_spec("fxswarm.logger.process") is not None
    except ModuleNotFoundError:
        return False


@dataclass
class Child:
    """One process the launcher started: its command, its log file, how it ended."""

    name: str  # e.g. "agent-3"
    role: str
    ident: int
    argv: list[str]
    log_path: Path
    popen: subprocess.Popen | None = None
    stopped_by: str | None = None  # the signal we sent, if we ended it
    reported: bool = False  # its death has been reported

    @property
    def token(self) -> str:
        return f"{self.role}/{self.ident}"

    @property
    def pid(self) -> int | None:
        return self.popen.pid if self.popen else None

    def running(self) -> bool:
        return self.popen is not None and self.popen.poll() is None

    def tail(self, lines: int = 12) -> list[str]:
        """The last lines of its stderr/stdout."""
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return []
        return text.strip("\n\r").splitlines()[-lines:]


@dataclass
class Death:
    child: Child
    code: int
    restarted: bool = False  # a router the launcher has started again (supervision)
    pid: int | None = None  # the one that died (a restarted child has a new one)

    def __post_init__(self) -> None:
        if self.pid is None:
            self.pid = self.child.pid

    def describe(self) -> str:
        how = f"killed by {signal.Signals(-self.code).name}" if self.code < 0 else f"exit code {self.code}"
        tail = self.child.tail()
        text = f"{self.child.name} (pid {self.pid}) died: {how}"
        if tail:
            text += "; its last output:\n" + "\n".join("    " + line for line in tail)
        return text


class StartError(RuntimeError):
    """The swarm did not come up; the message says who is missing or who died."""


@dataclass
class Swarm:
    """A scenario's processes on one machine: router, logger, leader, agents, world.

    ``start()`` brings them up (waiting on liveliness), ``poll()`` pumps the
    launcher's own session and reports deaths, ``stop()`` always ends every
    process (SIGTERM, then SIGKILL) and returns what it did.
    """

    config: str
    out: Path
    clock: str = "lockstep"
    speed: float = 1.0
    swarm: str | None = None
    port: int | None = None
    logger: bool = True
    tick_timeout: float = 1.0
    lease_ms: int | None = None
    topology: str | None = None  # mesh | routed | auto (mesh up to MESH_MAX_ROBOTS robots); None: the
    # scenario's [zenoh] topology, else auto
    world_args: tuple[str, ...] = ()
    logger_args: tuple[str, ...] = ()  # e.g. ("--rerun", "file,spawn")
    faults: tuple[str, ...] = ()  # --fault specs, resolved with the scenario's [faults] into plan
    plan: FaultPlan | None = None  # the run's resolved fault plan, handed to every role process
    secure: str | None = None  # keys folder (`fxswarm keys`): mutual TLS + access rules (docs/security.md)
    audit: bool = False  # secure: the router logs each refusal by the rules (costs: docs/security.md)
    routers: int = 1  # routers meshed with each other; each process lists them all (its own first in turn)
    # The official Zenoh router instead of `fxswarm router` (docs/routers.md): its path, default $FXSWARM_ZENOHD.
    zenohd: str | None = field(default_factory=lambda: os.environ.get(ZENOHD_ENV) or None)
    python: str = sys.executable
    scenario: Scenario | None = None
    children: dict[str, Child] = field(default_factory=dict)
    _state_bytes: bytes | None = None  # the latest world/state heard, decoded only when asked
    _state: WorldState | None = None
    alive: set[str] = field(default_factory=set)
    bus: ZenohBus | None = None
    state_listener: Callable[[WorldState], object] | None = None  # each valid world state heard (`run --ros2`)

    def __post_init__(self) -> None:
        self.out = Path(self.out)
        if self.scenario is None:
            self.scenario = load_or_exit(self.config)
        if self.plan is None:
            self.plan = resolve(self.scenario, self.faults)  # ScenarioError names a wrong spec
        self.plan_path = self.out / "fault-plan.json"
        zen = self.scenario.zenoh
        self.swarm = self.swarm or zen.get("swarm") or f"{self.scenario.name}-{os.getpid()}"
        ports = free_ports(self.routers + 1)  # one spare: the given --port may be among the kernel's choices
        self.port = self.port or ports.pop()
        scheme = "tls" if self.secure else "tcp"
        self.endpoints = tuple(f"{scheme}/127.0.0.1:{p}"
                               for p in [self.port, *[p for p in ports if p != self.port][:self.routers - 1]])
        self.endpoint = self.endpoints[0]
        self.router_restarts = 0
        self.topology = self.topology or zen.get("topology") or "auto"
        if self.topology not in RUN_TOPOLOGIES:
            raise ValueError(f"topology: expected one of {', '.join(RUN_TOPOLOGIES)}, got {self.topology!r}")
        if self.secure:
            self.topology = secure_topology(self.topology, self.audit)
        if self.topology == "auto":
            self.topology = auto_topology(self.scenario, self.plan)
        self.options = topology_options(self.topology, self.endpoints, self.lease_ms, secure=bool(self.secure))
        if self.secure:
            mesh = self.topology == "mesh"
            self.options = replace(self.options, tls=secure_files_or_exit(self.secure, self.scenario, mesh),
                                   access=self.out / "access.json" if mesh else None)

    # --- commands --------------------------------------------------------------------------

    def _zenoh_args(self, turn: int = 0) -> list[str]:
        """``turn``: with several routers, the process's place in turn: it lists them from router
        ``turn mod n`` on, so the processes spread over the routers and fail over to the next."""
        k = turn % len(self.endpoints)
        options = replace(self.options, connect=self.endpoints[k:] + self.endpoints[:k])
        return ["--swarm", self.swarm, *options.as_args()]

    def _role_argv(self, role: str, extra: list[str], turn: int = 0) -> list[str]:
        argv = [self.python, "-m", "fxswarm.cli", role, self.config, *self._zenoh_args(turn), "--out", str(self.out)]
        if role in ("world", "leader", "agent"):
            argv += ["--clock", self.clock, "--speed", repr(self.speed), "--fault-plan", str(self.plan_path)]
        return argv + extra

    def _router_secure_args(self) -> list[str]:
        """Secure: the router's keys, and rules for this scenario and swarm, written fresh into the run."""
        if not self.secure:
            return []
        from fxswarm.security.keys import write_access

        self.out.mkdir(parents=True, exist_ok=True)
        access = write_access(self.out / "access.json", self.scenario, self.swarm)
        return ["--secure", str(self.secure), "--access", str(access), *(["--audit"] if self.audit else [])]

    def _zenohd_config(self, name: str, endpoint: str) -> Path:
        """The official router's configuration for router ``name`` (docs/routers.md): the same
        endpoint, mesh, keys and rules as `fxswarm router` would take."""
        conf: dict = {"mode": "router", "listen": {"endpoints": [endpoint]},
                      "connect": {"endpoints": [e for e in self.endpoints if e != endpoint],
                                  "timeout_ms": -1, "exit_on_failure": False,
                                  "retry": {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2}},
                      "scouting": {"multicast": {"enabled": False}}}
        if self.secure:
            from fxswarm.runtime.tls import checked

            conf["transport"] = {"link": {"tls": checked(self.secure, "router").zenoh_tls(listen=True)}}
            conf["access_control"] = json.loads((self.out / "access.json").read_text())
        path = self.out / f"{name}.zenohd.json5"
        path.write_text(json.dumps(conf, indent=2) + "\n")  # JSON is JSON5
        return path

    def planned(self) -> list[Child]:
        """Every process of the run, in start order (the world last)."""
        logs = self.out / "logs"
        secure = self._router_secure_args()
        out = []
        for i, endpoint in enumerate(self.endpoints):
            name = "router" if i == 0 else f"router-{i}"
            others = [a for e in self.endpoints if e != endpoint for a in ("--connect", e)]  # meshed
            argv = [self.python, "-m", "fxswarm.cli", "router", "--listen", endpoint, "--id", str(i), *others,
                    "--swarm", self.swarm, "--scenario", self.config,  # for `fxswarm attach`
                    *secure]
            if self.zenohd:
                argv = [*shlex.split(self.zenohd), "-c", str(self._zenohd_config(name, endpoint))]
            out.append(Child(name, "router", i, argv, logs / f"{name}.log"))
        if self.logger and logger_available():
            out.append(Child("logger", "logger", 0, self._role_argv("logger", list(self.logger_args)),
                             logs / "logger.log"))
        out.append(Child("leader", "leader", 0, self._role_argv("leader", []), logs / "leader.log"))
        for r in self.scenario.robots:
            out.append(Child(f"agent-{r.id}", "agent", r.id, self._role_argv("agent", ["--id", str(r.id)], r.id),
                             logs / f"agent-{r.id}.log"))
        world_extra = ["--tick-timeout", repr(self.tick_timeout), *self.world_args]
        if self.clock == "lockstep" and any(f.restart is not None for f in self.plan.processes):
            world_extra.append("--hold-restarts")  # this launcher does the restarts: at their ticks
        out.append(Child("world", "world", 0, self._role_argv("world", world_extra), logs / "world.log"))
        return out

    def _spawn(self, child: Child) -> None:
        child.log_path.parent.mkdir(parents=True, exist_ok=True)
        env = {"ZENOH_RUNTIME": ZENOH_RUNTIME, **os.environ, "PYTHONUNBUFFERED": "1",
               PARENT_ENV: str(os.getpid())}
        if not self.secure:
            env.pop("FXSWARM_SECURE", None)  # a plain run's children must not turn secure from the environment
        with open(child.log_path, "ab") as log:
            # A new session: Ctrl-C reaches the launcher only, which stops children in order. The
            # kernel ends each child if the launcher dies, SIGKILLed too: zenohd watches no parent.
            # A router is killed outright (it keeps nothing, and a close can hang on dying links);
            # the roles get SIGTERM and stop cleanly.
            sig = signal.SIGKILL if child.role == "router" else signal.SIGTERM
            child.popen = subprocess.Popen(child.argv, stdin=subprocess.DEVNULL, stdout=log, stderr=log,
                                           env=env, start_new_session=True, preexec_fn=die_with_parent(sig))
        child.stopped_by, child.reported = None, False

    # --- start -----------------------------------------------------------------------------

    def start(self, timeout: float = 60.0, logger_timeout: float = 20.0) -> float:
        """Start everything and wait until all are alive; return the seconds it took.

        Raises :class:`StartError` naming who did not come up (or died) in time.
        """
        t0 = time.monotonic()
        self.out.mkdir(parents=True, exist_ok=True)
        for stale in (self.out / "processes").glob("*.json"):
            stale.unlink()  # a previous run's counters must not be merged into this one
        # The plan every role process receives (and a record of it beside the run's results).
        self.plan_path.write_text(dumps(self.plan, self.scenario) + "\n")
        planned = self.planned()
        for child in planned:
            self.children[child.name] = child
            # A log is appended to within a run (a restarted process), never across runs: what
            # a death reports as its last output must be this run's.
            child.log_path.unlink(missing_ok=True)
        world = self.children.pop("world")
        for child in self.children.values():
            self._spawn(child)
        self.bus = self._open_bus(t0 + timeout)
        self.bus.watch_alive("**", self._on_alive)
        self.bus.watch_router_links(self._on_alive)  # zenohd declares no token: a link to it tells
        self.bus.subscribe(topics.WORLD_STATE, self._on_state, raw=True)
        required = [c for c in self.children.values() if c.role != "logger"]
        self._wait_alive(required, t0 + timeout)
        logger = self.children.get("logger")
        if logger is not None:
            try:
                self._wait_alive([logger], time.monotonic() + logger_timeout)
            except StartError as exc:
                print(f"fxswarm run: warning: the logger did not come up, running without it: {exc}",
                      file=sys.stderr)
                self.stop_child(logger)
        self.children["world"] = world
        self._spawn(world)
        self._wait_alive([world], t0 + timeout + 5.0)
        return time.monotonic() - t0

    def _open_bus(self, deadline: float) -> ZenohBus:
        """The launcher's own session. A client (routed) waits for the router it has just started,
        which takes a moment to come up or may die (its port taken): then say why it died rather
        than wait out the connect timeout."""
        routers = [c for c in self.children.values() if c.role == "router"]

        def router_still_up() -> None:  # between two attempts to reach it
            for router in routers:
                code = router.popen.poll()
                if code is not None:
                    raise StartError(Death(router, code).describe())

        wait_ms = max(1000, int((deadline - time.monotonic()) * 1000))
        try:
            return ZenohBus(self.swarm, replace(self.options, connect_timeout_ms=wait_ms), validate=True,
                            who="fxswarm run", on_wait=router_still_up)
        except ConnectError as exc:
            raise StartError(str(exc)) from None

    def _on_alive(self, name: str, up: bool) -> None:
        (self.alive.add if up else self.alive.discard)(name)

    def _on_state(self, topic: str, payload: bytes) -> None:
        self._state_bytes = payload  # decoded only when read: most states are never looked at
        if self.state_listener is not None:
            state = self.state
            if state is not None:
                self.state_listener(state)

    @property
    def state(self) -> WorldState | None:
        """The latest valid world state heard (None before the first). An invalid one (a
        stranger's, or garbage) is counted and leaves the last valid one in place."""
        payload, self._state_bytes = self._state_bytes, None
        if payload is not None:
            try:
                msg = decode(payload)
                check_sender(topics.WORLD_STATE, msg)
                self._state = msg
            except WireError:
                self.bus.counters.invalid += 1
        return self._state

    def _up(self, child: Child) -> bool:
        if child.role == "router" and self.zenohd:  # no token of its own: the launcher linked to a router
            return any(name.startswith("router/link-") for name in self.alive)
        return child.token in self.alive

    def _wait_alive(self, children: list[Child], deadline: float) -> None:
        while True:
            missing = [c for c in children if not self._up(c)]
            if not missing:
                return
            for c in missing:
                code = c.popen.poll() if c.popen else None
                if code is not None:
                    raise StartError(Death(c, code).describe())
            if time.monotonic() > deadline:
                raise StartError("not alive in time: " + ", ".join(c.name for c in missing))
            self.bus.poll(0.05)

    # --- while running -------------------------------------------------------------------------

    def poll(self, timeout: float = 0.1) -> list[Death]:
        """Pump the launcher's session for up to ``timeout`` s; return deaths not yet reported.
        A router that died unplanned is started again here (supervision: ``restarted``)."""
        if self.bus is not None:
            self.bus.poll(timeout)
        deaths = []
        world = self.children.get("world")
        # Once the world has finished (or gone), the others leave by themselves with code 0: planned.
        run_over = world is not None and world.popen is not None and (
            world.popen.poll() == 0 or world.token not in self.alive)
        for child in self.children.values():
            if child.popen is None or child.reported or child.stopped_by:
                continue
            code = child.popen.poll()
            if code is not None:
                child.reported = True
                world_on = world is None or world.popen is None or world.popen.poll() is None
                if child.role == "router" and world_on and self.router_restarts < MAX_ROUTER_RESTARTS:
                    deaths.append(Death(child, code, restarted=True))
                    self.restart_router(child)
                elif not (code == 0 and (run_over or self._left_at_run_over(child))):
                    deaths.append(Death(child, code))
        return deaths

    def _left_at_run_over(self, child: Child) -> bool:
        """Whether ``child`` wrote, before it exited, that it left because the world ended the run
        (the world waits for its processes to leave before it exits itself)."""
        try:
            counters = json.loads((self.out / "processes" / f"{child.role}-{child.ident}.json").read_text())
        except (OSError, ValueError):
            return False
        return counters.get("stop_reason") == "run over"

    def wait_alive(self, name: str, timeout: float = 30.0) -> None:
        self._wait_alive([self.children[name]], time.monotonic() + timeout)

    def wait_gone(self, name: str, timeout: float = 10.0) -> None:
        child = self.children[name]
        end = time.monotonic() + timeout
        while child.token in self.alive:
            if time.monotonic() > end:
                raise TimeoutError(f"{name} still alive after {timeout:g} s")
            self.bus.poll(0.05)

    def run_process_faults(self) -> list[dict]:
        """Send the scenario's process faults (kill, restart, freeze, thaw) whose time has come."""
        if getattr(self, "_process_faults", None) is None:
            self._process_faults = ProcessSchedule(self.plan.processes)
        return self._process_faults.run(self)

    def sim_time(self) -> float:
        """Simulation time of the latest world state heard (s); -1 before any."""
        return self.state.t if self.state is not None else -1.0

    def kill(self, name: str, sig: int = signal.SIGKILL, timeout: float = 10.0) -> None:
        """End a process (planned: not reported as a death) and wait until the swarm has seen it go."""
        child = self.children[name]
        child.stopped_by = signal.Signals(sig).name
        child.popen.send_signal(sig)
        if sig == signal.SIGTERM:
            child.popen.send_signal(signal.SIGCONT)  # a frozen process must wake to handle it
        child.popen.wait(timeout=5)
        # Its liveliness token outlives it by a moment: a restart must not mistake it for the new one.
        self.wait_gone(name, timeout)

    def freeze(self, name: str) -> None:
        self.children[name].popen.send_signal(signal.SIGSTOP)

    def thaw(self, name: str) -> None:
        self.children[name].popen.send_signal(signal.SIGCONT)

    def restart(self, name: str, timeout: float = 30.0) -> None:
        """Start a stopped or dead process again with a fresh state; wait until it is alive."""
        child = self.children[name]
        if child.running():
            self.kill(name)
        self._spawn(child)
        self.wait_alive(name, timeout)

    def restart_router(self, child: Child) -> None:
        """Supervision: start a router that died again, on its endpoint with its keys and rules
        (the same command); every process reconnects by itself (Zenoh retries its routers)."""
        self.router_restarts += 1
        self._spawn(child)

    # --- stop -------------------------------------------------------------------------------

    def stop_child(self, child: Child, budget: float = 3.0) -> str:
        if not child.running():
            return "exited"
        child.stopped_by = "SIGTERM"
        child.popen.send_signal(signal.SIGTERM)
        child.popen.send_signal(signal.SIGCONT)  # a frozen process must wake to handle SIGTERM
        try:
            child.popen.wait(timeout=budget)
            return "SIGTERM"
        except subprocess.TimeoutExpired:
            child.stopped_by = "SIGKILL"
            child.popen.kill()
            child.popen.wait()
            return "SIGKILL"

    def stop(self, budget: float = STOP_BUDGET_S, grace: float = 0.0) -> dict[str, str]:
        """End every process within ``budget`` s; return ``{name: how}``.

        ``grace``: first let processes that are ending by themselves (agents
        and leader once the world has gone) finish for up to that long; the
        logger, which then closes its recording, for up to ``LOGGER_GRACE_S``.
        """
        start = time.monotonic()
        while grace:
            waited = time.monotonic() - start
            leaving = [c for c in self.children.values() if c.running() and (
                (c.role in ("agent", "leader") and waited < grace)
                or (c.role == "logger" and waited < max(grace, LOGGER_GRACE_S)))]
            if not leaving:
                break
            self.poll(0.05)
        how: dict[str, str] = {}
        routers = [c for c in self.children.values() if c.role == "router"]
        others = [c for c in self.children.values() if c.role != "router"]
        for c in others:
            if c.running():
                c.stopped_by = "SIGTERM"
                c.popen.send_signal(signal.SIGTERM)
                c.popen.send_signal(signal.SIGCONT)
                how[c.name] = "SIGTERM"
        deadline = time.monotonic() + budget - 1.0
        for c in others:
            if c.popen is None:
                continue
            try:
                c.popen.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                c.stopped_by = "SIGKILL"
                c.popen.kill()
                c.popen.wait()
                how[c.name] = "SIGKILL"
        if self.bus is not None:
            self.bus.close()
            self.bus = None
        for router in routers:
            if router.popen is not None:
                how[router.name] = self.stop_child(router, budget=0.8)
        return how

    # --- results -----------------------------------------------------------------------------

    def process_counters(self) -> dict[str, dict]:
        return read_process_counters(self.out)

    def merge_summary(self, extra: dict | None = None) -> dict | None:
        """The world's ``summary.json`` with every process's counters (the world's builder's
        :func:`~fxswarm.faults.summary.add_processes`, now that all have stopped), the process
        faults sent and ``extra`` (the launcher's own facts); written back and returned."""
        path = self.out / "summary.json"
        if not path.exists():
            return None
        summary = json.loads(path.read_text())
        schedule = getattr(self, "_process_faults", None)
        add_processes(summary, self.process_counters(), schedule.log if schedule is not None else None)
        summary.update(extra or {})
        write_summary(self.out, summary)
        return summary

    def summary(self) -> dict | None:
        path = self.out / "summary.json"
        return json.loads(path.read_text()) if path.exists() else None


# --- the command -------------------------------------------------------------------------------


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
                   help="real time: the world holds its clock while a robot is more than TICKS ticks behind "
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


def main(args: argparse.Namespace) -> int:
    ros2 = args.world == "ros2"
    if ros2 and (args.clock == "lockstep" or args.speed not in (None, 1.0)):
        print("fxswarm run: --world ros2 flies real robots: real time (--clock realtime) at --speed 1 only",
              file=sys.stderr)
        return 2
    args.clock = args.clock or ("realtime" if ros2 else "lockstep")
    given = [f"--{name.replace('_', '-')}" for name in ("speed", "max_lag") if getattr(args, name) is not None]
    if given and args.clock != "realtime":  # lock-step runs as fast as it can and never lags
        print(f"fxswarm run: {' and '.join(given)} set real time's pace: add --clock realtime", file=sys.stderr)
        return 2
    sc = load_or_exit(args.config)
    if ros2:
        from fxswarm.world.process import ros2_or_exit

        ros2_or_exit(sc, "fxswarm run")  # the extra, ROS_DOMAIN_ID and a speed limit, before anything starts
    view = None
    if args.ros2:
        from fxswarm.world.process import ros2_module_or_exit

        ros2_view = ros2_module_or_exit("fxswarm run")
        view = ros2_view.Ros2View(sc, ros2_view.domain_id())
    plan = plan_or_exit(sc, args.fault)  # resolved once here: every child receives this plan
    out = prepare_run_folder(args.out or f"runs/{sc.name}", "fxswarm run")
    recording: Path | None = out / "recording.rrd"  # where the logger writes its file, if it does
    if args.rerun is not None:
        if args.no_logger:
            print("fxswarm run: --rerun sets the logger's outputs; it cannot go with --no-logger", file=sys.stderr)
            return 2
        from fxswarm.logger.sinks import OutputError, parse_outputs  # loads Rerun: only when asked

        try:
            recording = parse_outputs(args.rerun, out).file
        except OutputError as exc:
            print(f"fxswarm run: {exc}", file=sys.stderr)
            return 2
    if args.audit and not args.secure:
        print("fxswarm run: --audit needs --secure KEYS (the rules go by certificate)", file=sys.stderr)
        return 2
    started = time.time()
    try:
        swarm = Swarm(args.config, out, clock=args.clock, speed=args.speed or 1.0, swarm=args.swarm, port=args.port,
                      logger=not args.no_logger, tick_timeout=args.tick_timeout, lease_ms=args.lease_ms,
                      scenario=sc, topology=args.topology, faults=tuple(args.fault or ()), plan=plan,
                      secure=args.secure, audit=args.audit, routers=args.routers,
                      world_args=(("--max-lag", str(args.max_lag)) if args.max_lag is not None else ())
                      + (("--ros2",) if ros2 else ()),
                      logger_args=("--rerun", args.rerun) if args.rerun is not None else (),
                      state_listener=view.publish if view is not None else None)
    except ValueError as exc:  # options that do not go together (e.g. --audit with --topology mesh)
        print(f"fxswarm run: {exc}", file=sys.stderr)
        return 2
    # SIGINT and SIGTERM both stop the run cleanly, even where SIGINT came in ignored (a background job).
    signal.signal(signal.SIGTERM, _raise_interrupt)
    signal.signal(signal.SIGINT, _raise_interrupt)
    # --quiet hides the chatter (start, planned faults, progress, the summary), never a warning.
    def warn(text: str) -> None:
        print(text, file=sys.stderr)

    say = (lambda *a: None) if args.quiet else warn
    code = 0
    agent_deaths: list[str] = []
    logger_death: str | None = None  # the summary says so: a run whose recording stopped must not look whole
    try:
        took = swarm.start(timeout=args.start_timeout)
        say(f"fxswarm run: {len(swarm.children)} processes up in {took:.1f} s "
            f"(swarm {swarm.swarm!r}, router {swarm.endpoint}, {swarm.topology}, clock {args.clock})")
        t0, last = time.monotonic(), 0.0
        world = swarm.children["world"]
        while True:
            deaths = swarm.poll(0.1)
            for event in swarm.run_process_faults():
                done = event["done_t_s"]
                later = f", done at t = {done:.2f} s" if done is not None and done > event["t_s"] else ""
                say(f"\nfxswarm run: fault: {event['action']} {event['target']} at t = {event['t_s']:.2f} s{later}")
            for d in deaths:
                if d.child.role == "agent":
                    agent_deaths.append(d.child.name)
                    warn(f"\nfxswarm run: {d.describe()}")
                    if args.fail_fast:
                        warn("fxswarm run: --fail-fast: ending the run")
                        code = 1
                elif d.child.role == "logger":
                    logger_death = f"{d.describe()} at t = {swarm.sim_time():.2f} s"
                    warn(f"\nfxswarm run: warning: {d.describe()}; the swarm runs on without it")
                elif d.restarted:
                    warn(f"\nfxswarm run: warning: {d.describe()}; started it again (restart "
                         f"{swarm.router_restarts} of at most {MAX_ROUTER_RESTARTS}): every process reconnects")
                elif d.child.role == "router" and swarm.topology == "mesh":
                    warn(f"\nfxswarm run: warning: {d.describe()}; the swarm runs on over its direct links "
                        f"(a process that starts from now on cannot join it)")
                else:
                    print(f"\nfxswarm run: {d.describe()}", file=sys.stderr)
                    code = 1
            if code or not world.running():
                break
            now = time.monotonic()
            if not args.quiet and now - last > (0.5 if sys.stderr.isatty() else 5.0):
                _progress(swarm, t0)
                last = now
        if not args.quiet:
            _progress(swarm, t0)
            if sys.stderr.isatty():
                sys.stderr.write("\n")
        if world.popen.returncode not in (None, 0) and code == 0:
            print(f"fxswarm run: {Death(world, world.popen.returncode).describe()}", file=sys.stderr)
            code = 1
    except StartError as exc:
        print(f"fxswarm run: the swarm did not start: {exc}", file=sys.stderr)
        code = 1
    except KeyboardInterrupt:
        code = 130
        warn("\nfxswarm run: interrupted")
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):  # a second Ctrl-C must not cut the clean-up short
            signal.signal(sig, signal.SIG_IGN)
        finished = "world" in swarm.children and swarm.children["world"].popen is not None \
            and swarm.children["world"].popen.returncode == 0
        how = swarm.stop(grace=3.0 if finished else 0.0)
        stopped = {k: v for k, v in how.items() if v != "exited"}
        if stopped and (code or not args.quiet):
            warn("fxswarm run: stopped " + ", ".join(f"{k} ({v})" for k, v in stopped.items()))
    summary = swarm.merge_summary({"launcher": {"swarm": swarm.swarm, "router": swarm.endpoint,
                                                "routers": list(swarm.endpoints),
                                                "router_restarts": swarm.router_restarts,
                                                "topology": swarm.topology,
                                                "secure": bool(args.secure),
                                                "agent_deaths": agent_deaths, "logger_death": logger_death,
                                                "exit_code": code}})
    if summary is not None and code == 0 and not args.quiet:
        keys = ("robots", "ticks", "wall_s", "min_object_distance_m", "formation_error_final_m",
                "estimate_error_final_m", "formation_settle_s", "missed_ticks")
        print(json.dumps({k: summary.get(k) for k in keys}, indent=2))
        print(f"wrote {out}/summary.json and {out}/trajectory.npz")
        if recording is not None and recording.exists() and recording.stat().st_mtime >= started:  # not a stale one
            print(f"wrote {recording} (view it: rerun {recording}; figures: fxswarm report {out})")
    return code
