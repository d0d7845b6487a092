"""What ``fxswarm run`` will start, decided before anything starts: a pure plan.

:func:`plan_launch` turns a scenario, its fault plan, the user's options and the router ports
into a :class:`LaunchPlan`: the swarm's name and topology, every process's command line in
start order (the world last), how the launcher's own session joins, and the files to write
first (the fault plan every role reads, the access rules, the official router's config).
It starts nothing, opens nothing and writes nothing, so a unit test can read it whole;
:class:`fxswarm.launch.swarm.Swarm` carries it out.
"""

from __future__ import annotations

import contextlib
import json
import shlex
import socket
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

from fxswarm.core.scenario import RUN_TOPOLOGIES, Scenario
from fxswarm.faults.plan import FaultPlan, dumps, plan_of
from fxswarm.runtime.router import router_settings
from fxswarm.runtime.tls import files_for
from fxswarm.runtime.zenoh_bus import ZenohOptions

# "auto" meshes swarms up to this many robots. Measured (docs/design.md "Topology";
# docs/benchmarks.md "Topology: mesh against routed"): with 6 robots a mesh takes the router's
# hop out of every message (4-24 % more lock-step ticks/s, real-time p50 at speed 4 halved),
# with 8 a little (177-180 against 166-174 ticks/s); with 12 the mesh's
# links already cost more than the hop (104-114 against 106-120), with 24 (351 links) clearly.
MESH_MAX_ROBOTS = 8


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


def router_ports(port: int | None, routers: int) -> list[int]:
    """The routers' ports: ``port`` (the user's ``--port``) first if given, the others free ones."""
    ports = free_ports(routers + 1)  # one spare: the given port may be among the kernel's choices
    first = port or ports.pop()
    return [first, *[p for p in ports if p != first][:routers - 1]]


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
    ``router`` (or routers: the first that answers, the others if it is lost): a mesh peer meets
    the others there (gossip) and then talks to them over direct links, each on a port of its
    own, so the router carries no data once the links are up; a routed client sends everything
    through it. Multicast scouting off either way; ``secure``: the peers' own links are TLS too."""
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


def resolve_topology(asked: str | None, scenario: Scenario, faults: FaultPlan, secure: bool, audit: bool) -> str:
    """mesh or routed: the command line's, else the scenario's ``[zenoh] topology``, else auto."""
    topology = asked or scenario.zenoh.get("topology") or "auto"
    if topology not in RUN_TOPOLOGIES:
        raise ValueError(f"topology: expected one of {', '.join(RUN_TOPOLOGIES)}, got {topology!r}")
    if secure:
        topology = secure_topology(topology, audit)
    return auto_topology(scenario, faults) if topology == "auto" else topology


@dataclass(frozen=True)
class Request:
    """What the user asked for: the command line's options (see :func:`add_arguments` of
    :mod:`fxswarm.launch.launcher`)."""

    config: str
    out: Path
    clock: str = "lockstep"
    speed: float = 1.0
    swarm: str | None = None
    logger: bool = True
    tick_timeout: float = 1.0
    lease_ms: int | None = None
    topology: str | None = None  # mesh | routed | auto; None: the scenario's, else auto
    world_args: tuple[str, ...] = ()
    logger_args: tuple[str, ...] = ()
    secure: str | None = None  # keys folder
    audit: bool = False
    zenohd: str | None = None  # the official router's command instead of `fxswarm router`
    python: str = sys.executable


@dataclass(frozen=True)
class ChildSpec:
    """One process to start: its name (``agent-3``), role, id, command line and log file."""

    name: str
    role: str
    ident: int
    argv: tuple[str, ...]
    log_path: Path


@dataclass(frozen=True)
class LaunchPlan:
    """Everything :func:`plan_launch` decided (see the module docstring)."""

    swarm: str
    topology: str  # mesh | routed
    endpoints: tuple[str, ...]  # the routers', the first the main one
    options: ZenohOptions  # how the launcher's own session (and each child, in turn) joins
    children: tuple[ChildSpec, ...]  # in start order, the world last
    files: dict[Path, str] = field(default_factory=dict)  # to write before anything starts

    @property
    def endpoint(self) -> str:
        return self.endpoints[0]


def plan_launch(req: Request, scenario: Scenario, faults: FaultPlan, ports: list[int], pid: int,
                logger_installed: bool = True) -> LaunchPlan:
    """The plan of a run (pure: see the module docstring). ``ports``: one per router;
    ``pid``: the launcher's, in the default swarm name; raises ValueError for options that do not
    go together (``--audit`` with ``--topology mesh``) or an unknown topology."""
    out = Path(req.out)
    swarm = req.swarm or scenario.zenoh.get("swarm") or f"{scenario.name}-{pid}"
    topology = resolve_topology(req.topology, scenario, faults, bool(req.secure), req.audit)
    scheme = "tls" if req.secure else "tcp"
    endpoints = tuple(f"{scheme}/127.0.0.1:{p}" for p in ports)
    options = topology_options(topology, endpoints, req.lease_ms, secure=bool(req.secure))
    fault_path = out / "fault-plan.json"
    files = {fault_path: dumps(faults, scenario) + "\n"}
    access = None
    if req.secure:
        from fxswarm.security.policy import access_control

        mesh = topology == "mesh"
        access = access_control(scenario, swarm)
        files[out / "access.json"] = json.dumps(access, indent=1) + "\n"
        options = replace(options, tls=files_for(req.secure, "observer"), access=out / "access.json" if mesh else None)
    children = [*_routers(req, swarm, endpoints, access, files),
                *_roles(req, scenario, faults, swarm, options, fault_path, logger_installed)]
    return LaunchPlan(swarm, topology, endpoints, options, tuple(children), files)


def _routers(req: Request, swarm: str, endpoints: tuple[str, ...], access: dict | None,
             files: dict[Path, str]) -> list[ChildSpec]:
    """The routers, meshed with each other: ``fxswarm router``, or the official one (``zenohd -c
    FILE``, its file added to ``files``) with the same endpoint, mesh, keys and rules."""
    out, logs = Path(req.out), Path(req.out) / "logs"
    specs = []
    for i, endpoint in enumerate(endpoints):
        name = "router" if i == 0 else f"router-{i}"
        others = [e for e in endpoints if e != endpoint]
        if req.zenohd:
            tls = files_for(req.secure, "router") if req.secure else None
            conf = out / f"{name}.zenohd.json5"
            files[conf] = json.dumps(router_settings([endpoint], False, tls, access, others), indent=2) + "\n"
            argv = [*shlex.split(req.zenohd), "-c", str(conf)]
        else:
            secure = ["--secure", str(req.secure), "--access", str(out / "access.json"),
                      *(["--audit"] if req.audit else [])] if req.secure else []
            argv = [req.python, "-m", "fxswarm.cli", "router", "--listen", endpoint, "--id", str(i),
                    *[a for e in others for a in ("--connect", e)],
                    "--swarm", swarm, "--scenario", req.config,  # for `fxswarm attach`
                    *secure]
        specs.append(ChildSpec(name, "router", i, tuple(argv), logs / f"{name}.log"))
    return specs


def _roles(req: Request, scenario: Scenario, faults: FaultPlan, swarm: str, options: ZenohOptions,
           fault_path: Path, logger_installed: bool) -> list[ChildSpec]:
    """The logger (if asked and installed), the leader, every agent and the world, in that order."""
    logs = Path(req.out) / "logs"
    n = len(options.connect)

    def argv(role: str, extra: list[str], turn: int = 0) -> tuple[str, ...]:
        # With several routers a process lists them from router `turn mod n` on: the processes
        # spread over the routers and each fails over to the next.
        k = turn % n
        joined = replace(options, connect=options.connect[k:] + options.connect[:k])
        out = [req.python, "-m", "fxswarm.cli", role, req.config, "--swarm", swarm, *joined.as_args(),
               "--out", str(req.out)]
        if role in ("world", "leader", "agent"):
            out += ["--clock", req.clock, "--speed", repr(req.speed), "--fault-plan", str(fault_path)]
        return tuple(out + extra)

    specs = []
    if req.logger and logger_installed:
        specs.append(ChildSpec("logger", "logger", 0, argv("logger", list(req.logger_args)), logs / "logger.log"))
    specs.append(ChildSpec("leader", "leader", 0, argv("leader", []), logs / "leader.log"))
    for r in scenario.robots:
        specs.append(ChildSpec(f"agent-{r.id}", "agent", r.id, argv("agent", ["--id", str(r.id)], r.id),
                               logs / f"agent-{r.id}.log"))
    world_extra = ["--tick-timeout", repr(req.tick_timeout), *req.world_args]
    if req.clock == "lockstep" and any(f.restart is not None for f in faults.processes):
        world_extra.append("--hold-restarts")  # the launcher does the restarts: at their ticks
    specs.append(ChildSpec("world", "world", 0, argv("world", world_extra), logs / "world.log"))
    return specs
