"""A scenario's processes on one machine, carried out from a :class:`~fxswarm.launch.plan.LaunchPlan`.

:class:`Swarm` holds the building blocks (start, wait, kill, freeze, restart, stop) that
``fxswarm run`` (:mod:`fxswarm.launch.launcher`) and :mod:`fxswarm.testing` drive: the plan
says what to start, :class:`~fxswarm.launch.processes.Processes` owns what is started, and
:class:`~fxswarm.launch.watch.Watch` is the launcher's own session (who is alive, the world's
state). Supervision is explicit: :meth:`Swarm.poll` only reports, :meth:`Swarm.supervise`
starts a dead router again, :meth:`Swarm.tend` does both and sends the process faults due.
"""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path

from fxswarm.core.messages import WorldState
from fxswarm.core.scenario import Scenario
from fxswarm.faults.plan import FaultPlan, resolve
from fxswarm.faults.process import ProcessSchedule
from fxswarm.launch.plan import LaunchPlan, Request, plan_launch, router_ports
from fxswarm.launch.processes import STOP_BUDGET_S, Child, Death, Processes
from fxswarm.launch.watch import StartError, Watch
from fxswarm.runtime.config import load_or_exit
from fxswarm.runtime.output import merge_summary, read_process_counters, read_summary
from fxswarm.runtime.zenoh_bus import ZenohOptions

LOGGER_GRACE_S = 15.0  # at the end of a run, time for the logger to close its recording by itself
#: Supervision: a router that dies is started again, at most this many times in a run (one that
#: keeps dying, e.g. its port taken, ends a routed run as before).
MAX_ROUTER_RESTARTS = 10
#: The official Zenoh router's binary (a command line) to start instead of `fxswarm router`, as
#: ``ZENOHD -c FILE`` (`make test-zenohd` sets it).
ZENOHD_ENV = "FXSWARM_ZENOHD"


def secure_files_or_exit(keys: str, scenario: Scenario, mesh: bool = False) -> None:
    """Check every process's key files in ``keys`` before anything starts. A missing,
    unreadable, expired or wrong-CA file is one line naming it, and exit 2."""
    from fxswarm.runtime.tls import KeyFileError, checked
    from fxswarm.security.policy import process_names

    try:
        for name in process_names(scenario):
            checked(keys, name, server=mesh and name != "router")  # a mesh peer serves its links
        checked(keys, "observer", server=mesh)  # the launcher's own
    except KeyFileError as exc:
        print(f"fxswarm run: --secure: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


def logger_available() -> bool:
    try:
        return importlib.util.find_spec("fxswarm.logger.process") is not None
    except ModuleNotFoundError:
        return False


@dataclass
class Swarm:
    """A scenario's processes on one machine: router(s), logger, leader, agents, world.

    The fields are :class:`~fxswarm.launch.plan.Request`'s, plus the run's ``faults`` (``--fault``
    specs, resolved with the scenario's ``[faults]`` into ``plan``), ``port`` and ``routers``.
    Building one plans the run (bad options: ValueError; bad keys: exit 2) and starts nothing.
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
    topology: str | None = None
    world_args: tuple[str, ...] = ()
    logger_args: tuple[str, ...] = ()  # e.g. ("--rerun", "file,spawn")
    faults: tuple[str, ...] = ()
    plan: FaultPlan | None = None  # the run's resolved fault plan, handed to every role process
    secure: str | None = None  # keys folder (`fxswarm keys`): mutual TLS + access rules (docs/security.md)
    audit: bool = False
    routers: int = 1  # routers meshed with each other; each process lists them all (its own first in turn)
    zenohd: str | None = field(default_factory=lambda: os.environ.get(ZENOHD_ENV) or None)
    python: str = sys.executable
    scenario: Scenario | None = None
    state_listener: Callable[[WorldState], object] | None = None  # each valid world state heard (`run --ros2`)

    def __post_init__(self) -> None:
        self.out = Path(self.out)
        if self.scenario is None:
            self.scenario = load_or_exit(self.config)
        if self.plan is None:
            self.plan = resolve(self.scenario, self.faults)  # ScenarioError names a wrong spec
        request = Request(**{f.name: getattr(self, f.name) for f in fields(Request)})
        self.launch: LaunchPlan = plan_launch(request, self.scenario, self.plan,
                                              router_ports(self.port, self.routers), os.getpid(),
                                              logger_available())
        self.swarm, self.topology = self.launch.swarm, self.launch.topology
        self.port = int(self.launch.endpoint.rsplit(":", 1)[1])
        if self.secure:
            secure_files_or_exit(self.secure, self.scenario, self.topology == "mesh")
        self.processes = Processes(secure=bool(self.secure))
        self.watch = Watch(self.state_listener)
        self.router_restarts = 0
        self.schedule = ProcessSchedule(self.plan.processes)
        self.stopped: dict[str, str] = {}  # what leaving `with swarm:` did, {name: how}

    # --- what the plan decided, and what is running -------------------------------------------

    @property
    def endpoints(self) -> tuple[str, ...]:
        return self.launch.endpoints

    @property
    def endpoint(self) -> str:
        return self.launch.endpoint

    @property
    def options(self) -> ZenohOptions:
        return self.launch.options

    @property
    def children(self) -> dict[str, Child]:
        return self.processes.children

    @children.setter
    def children(self, value: dict[str, Child]) -> None:
        self.processes.children = value

    @property
    def alive(self) -> set[str]:
        return self.watch.alive

    @property
    def bus(self):
        return self.watch.bus

    @property
    def state(self) -> WorldState | None:
        """The latest valid world state heard (None before the first)."""
        return self.watch.state

    def sim_time(self) -> float:
        """Simulation time of the latest world state heard (s); -1 before any."""
        return self.state.t if self.state is not None else -1.0

    def planned(self) -> list[Child]:
        """Every process of the run, in start order (the world last)."""
        return [Child.of(spec) for spec in self.launch.children]

    # --- start -------------------------------------------------------------------------------

    def start(self, timeout: float = 60.0, logger_timeout: float = 20.0) -> float:
        """Start everything and wait until all are alive; return the seconds it took.

        Raises :class:`StartError` naming who did not come up (or died) in time.
        """
        t0 = time.monotonic()
        self.out.mkdir(parents=True, exist_ok=True)
        for stale in (self.out / "processes").glob("*.json"):
            stale.unlink()  # a previous run's counters must not be merged into this one
        for path, text in self.launch.files.items():  # the fault plan every role reads, rules, configs
            path.write_text(text)
        children = [self.processes.add(child) for child in self.planned()]
        world = children.pop()
        for child in children:
            self.processes.start(child)
        routers = [c for c in children if c.role == "router"]
        wait_ms = max(1000, int((t0 + timeout - time.monotonic()) * 1000))
        self.watch.open(self.swarm, self.options, wait_ms, lambda: self._still_up(routers))
        self._wait_alive([c for c in children if c.role != "logger"], t0 + timeout)
        logger = self.children.get("logger")
        if logger is not None:
            try:
                self._wait_alive([logger], time.monotonic() + logger_timeout)
            except StartError as exc:
                print(f"fxswarm run: warning: the logger did not come up, running without it: {exc}",
                      file=sys.stderr)
                self.processes.stop_child(logger)
        self.processes.start(world)
        self._wait_alive([world], t0 + timeout + 5.0)
        return time.monotonic() - t0

    @staticmethod
    def _still_up(children: list[Child]) -> None:
        for child in children:
            code = child.popen.poll()
            if code is not None:
                raise StartError(Death(child, code).describe())

    def _up(self, child: Child) -> bool:
        if child.role == "router" and self.zenohd:  # no token of its own: the launcher linked to a router
            return any(name.startswith("router/link-") for name in self.alive)
        return child.token in self.alive

    def _wait_alive(self, children: list[Child], deadline: float) -> None:
        while True:
            missing = [c for c in children if not self._up(c)]
            if not missing:
                return
            self._still_up([c for c in missing if c.popen is not None])
            if time.monotonic() > deadline:
                raise StartError("not alive in time: " + ", ".join(c.name for c in missing))
            self.watch.pump(0.05)

    def wait_alive(self, name: str, timeout: float = 30.0) -> None:
        self._wait_alive([self.children[name]], time.monotonic() + timeout)

    def wait_gone(self, name: str, timeout: float = 10.0) -> None:
        child = self.children[name]
        end = time.monotonic() + timeout
        while child.token in self.alive:
            if time.monotonic() > end:
                raise TimeoutError(f"{name} still alive after {timeout:g} s")
            self.watch.pump(0.05)

    # --- while running -------------------------------------------------------------------------

    def _world_on(self) -> bool:
        world = self.children.get("world")
        return world is None or world.popen is None or world.popen.poll() is None

    def poll(self, timeout: float = 0.1) -> list[Death]:
        """Pump the launcher's session for up to ``timeout`` s; return the deaths not yet
        reported. Only reports: a dead router is started again by :meth:`supervise`."""
        self.watch.pump(timeout)
        world = self.children.get("world")
        # Once the world has finished (or gone), the others leave by themselves with code 0: planned.
        run_over = world is not None and world.popen is not None and (
            world.popen.poll() == 0 or world.token not in self.alive)
        world_on = self._world_on()
        deaths = []
        for child, code in self.processes.ended():
            if child.role == "router" and world_on:
                deaths.append(Death(child, code))  # never planned while the world runs
            elif not (code == 0 and (run_over or self._left_at_run_over(child))):
                deaths.append(Death(child, code))
        return deaths

    def supervise(self, deaths: list[Death]) -> list[Death]:
        """Start again each router among ``deaths`` that died while the world runs, on its
        endpoint with its keys and rules (the same command), at most :data:`MAX_ROUTER_RESTARTS`
        times a run; every process reconnects by itself (Zenoh retries its routers). Returns
        ``deaths``, those started again marked ``restarted``."""
        for d in deaths:
            if d.child.role == "router" and self._world_on() and self.router_restarts < MAX_ROUTER_RESTARTS:
                self.router_restarts += 1
                self.processes.start(d.child)
                d.restarted = True
        return deaths

    def tend(self, timeout: float = 0.1) -> tuple[list[Death], list[dict]]:
        """One round of a run: :meth:`poll`, :meth:`supervise`, then the process faults due
        (:meth:`run_process_faults`); returns the deaths and the faults sent."""
        deaths = self.supervise(self.poll(timeout))
        return deaths, self.run_process_faults()

    def _left_at_run_over(self, child: Child) -> bool:
        """Whether ``child`` wrote, before it exited, that it left because the world ended the run
        (the world waits for its processes to leave before it exits itself)."""
        try:
            counters = json.loads((self.out / "processes" / f"{child.role}-{child.ident}.json").read_text())
        except (OSError, ValueError):
            return False
        return counters.get("stop_reason") == "run over"

    def run_process_faults(self) -> list[dict]:
        """Send the scenario's process faults (kill, restart, freeze, thaw) whose time has come."""
        return self.schedule.run(self)

    def kill(self, name: str, sig: int = signal.SIGKILL, timeout: float = 10.0) -> None:
        """End a process (planned: not reported as a death) and wait until the swarm has seen it go."""
        self.processes.signal(name, sig)
        self.children[name].popen.wait(timeout=5)
        # Its liveliness token outlives it by a moment: a restart must not mistake it for the new one.
        self.wait_gone(name, timeout)

    def freeze(self, name: str) -> None:
        self.processes.signal(name, signal.SIGSTOP)

    def thaw(self, name: str) -> None:
        self.processes.signal(name, signal.SIGCONT)

    def restart(self, name: str, timeout: float = 30.0) -> None:
        """Start a stopped or dead process again with a fresh state; wait until it is alive."""
        if self.children[name].running():
            self.kill(name)
        self.processes.start(self.children[name])
        self.wait_alive(name, timeout)

    # --- stop and results ----------------------------------------------------------------------

    def __enter__(self) -> Swarm:
        return self

    def __exit__(self, *exc) -> None:
        """Leaving ``with swarm:`` stops every process it started (:meth:`stop`; a finished run's
        processes get time to leave by themselves); what it did is in :attr:`stopped`."""
        world = self.children.get("world")
        finished = world is not None and world.popen is not None and world.popen.poll() == 0
        self.stopped = self.stop(grace=3.0 if finished else 0.0)

    def stop(self, budget: float = STOP_BUDGET_S, grace: float = 0.0) -> dict[str, str]:
        """End every process within ``budget`` s; return ``{name: how}``.

        ``grace``: first let processes that are ending by themselves (agents and leader once the
        world has gone) finish for up to that long; the logger, which then closes its recording,
        for up to ``LOGGER_GRACE_S``.
        """
        start = time.monotonic()
        while grace:
            waited = time.monotonic() - start
            leaving = [c for c in self.children.values() if c.running() and (
                (c.role in ("agent", "leader") and waited < grace)
                or (c.role == "logger" and waited < max(grace, LOGGER_GRACE_S)))]
            if not leaving:
                break
            self.watch.pump(0.05) if self.watch.bus is not None else time.sleep(0.05)
        return self.processes.stop(budget, between=self.watch.close)

    def merge_summary(self, extra: dict | None = None) -> dict | None:
        """The world's ``summary.json`` with every process's counters (now that all have
        stopped), the process faults sent and ``extra`` (the launcher's own facts); written back
        and returned (None: the world wrote none)."""
        return merge_summary(self.out, self.schedule.log, extra)

    def summary(self) -> dict | None:
        return read_summary(self.out)

    def process_counters(self) -> dict[str, dict]:
        return read_process_counters(self.out)
