"""One place where runners put a scenario's faults around the nodes they build.

The in-memory simulator and the role processes both call
:meth:`SwarmFaults.world` / :meth:`SwarmFaults.agent` when they construct a
node, so the same filters (and, in one process, the same stand-ins for
process faults) sit in front of the same nodes on either bus.
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from fxswarm.core.scenario import Scenario
from fxswarm.faults.inbox import FaultyInbox, link_counts, wrap
from fxswarm.faults.plan import plan_of
from fxswarm.faults.process import Mortal
from fxswarm.faults.report import fault_summary


class SwarmFaults:
    """The faults of ``scenario`` for one runner.

    lockstep: lock-step (delays in ticks) or real time (delays in seconds of
    ``clock``). ``mortal``: stand in for process faults in this process (the
    simulator; a role process whose launcher also sends real signals).
    """

    def __init__(self, scenario: Scenario, lockstep: bool = True,
                 clock: Callable[[], float] = time.monotonic, mortal: bool = True) -> None:
        self.sc = scenario
        self.plan = plan_of(scenario)
        self.lockstep = lockstep
        self.clock = clock
        self.mortal = mortal
        self.built: list = []

    def world(self, node):
        """The world node behind its inbox filter (or itself when nothing can reach it)."""
        out = wrap(node, "world", 0, self.plan, self.sc.dt, self.lockstep, self.clock)
        self.built.append(out)
        return out

    def agent(self, robot_id: int, build: Callable[[], object]):
        """Robot ``robot_id``'s node, built by ``build()`` (again at each restart), filtered."""
        def make():
            return wrap(build(), "agent", robot_id, self.plan, self.sc.dt, self.lockstep, self.clock)

        mine = [p for p in self.plan.processes if p.target == f"agent:{robot_id}"]
        out = Mortal(make, mine) if mine and self.mortal else make()
        self.built.append(out)
        return out

    def poll(self) -> list:
        """Real time: messages whose delay is over, handed to their nodes; returns what they send."""
        out = []
        for node in self.built:
            inbox = node.node if isinstance(node, Mortal) else node
            if isinstance(inbox, FaultyInbox):
                out += inbox.poll()
        return out

    def link_counts(self) -> dict[str, dict[str, int]]:
        inboxes = [g for node in self.built for g in getattr(node, "generations", [node])]
        return link_counts(inboxes)

    def restarts(self) -> dict[str, int]:
        return {f"agent:{getattr(n, 'id', '?')}": n.restarts for n in self.built if getattr(n, "restarts", 0)}

    def summary(self, traj: dict[str, np.ndarray], world) -> dict:
        """The summary additions (faults, degraded modes, recoveries) for this runner's nodes."""
        return fault_summary(self.sc, self.plan, traj, world, self.link_counts(), self.restarts())


def wrap_for_process(node, role: str, ident: int, scenario: Scenario, args) -> object:
    """A role process's node behind the scenario's faults (with its ``--fault`` overrides).

    Real time: delays are in simulation seconds on a clock running ``--speed``
    times wall time. Process faults are the launcher's (real signals) here.
    """
    from fxswarm.faults.plan import with_cli_faults

    sc = with_cli_faults(scenario, getattr(args, "fault", None))
    plan = plan_of(sc)
    speed = float(getattr(args, "speed", 1.0) or 1.0)
    lockstep = getattr(args, "clock", "lockstep") == "lockstep"
    return wrap(node, role, ident, plan, sc.dt, lockstep, lambda: time.monotonic() * speed)


def process_counters(node) -> dict:
    """What a role process adds to its counters file: its inbox's per-link counts."""
    while node is not None and not isinstance(node, FaultyInbox):
        node = getattr(node, "inner", None) if not isinstance(node, Mortal) else node.node
    return {"links": {k: dict(v.__dict__) for k, v in node.links.items()}} if node is not None else {}


def merge_process_links(summary: dict, schedule=None) -> None:
    """Launcher: sum the processes' per-link counts into ``summary["faults"]["links"]``, and
    list the process faults it sent (``faults.process_events``) from its ``schedule``."""
    merged: dict[str, dict[str, int]] = {}
    for counters in (summary.get("processes") or {}).values():
        for key, c in (counters.get("links") or {}).items():
            m = merged.setdefault(key, {"delivered": 0, "dropped": 0, "delayed": 0, "duplicated": 0})
            for name in m:
                m[name] += int(c.get(name, 0))
    if "faults" in summary or merged:
        summary.setdefault("faults", {})["links"] = dict(sorted(merged.items()))
    if schedule is not None and schedule.log:
        summary.setdefault("faults", {})["process_events"] = list(schedule.log)


def world_process_summary(scenario: Scenario, args, traj: dict[str, np.ndarray], world) -> dict:
    """The world process's summary additions (links are merged in later by the launcher)."""
    from fxswarm.faults.plan import with_cli_faults

    sc = with_cli_faults(scenario, getattr(args, "fault", None))
    return fault_summary(sc, plan_of(sc), traj, world, {}, {})
