"""One place where runners put a scenario's faults around the nodes they build.

The in-memory simulator and the role processes both call
:meth:`SwarmFaults.world` / :meth:`SwarmFaults.agent` when they construct a
node, so the same filters (and, in one process, the same stand-ins for
process faults) sit in front of the same nodes on either bus.
"""

from __future__ import annotations

import time
from typing import Callable

from fxswarm.core.scenario import Scenario
from fxswarm.faults.inbox import FaultyInbox, link_counts, wrap
from fxswarm.faults.plan import FaultPlan, plan_of
from fxswarm.faults.process import Mortal


class SwarmFaults:
    """The faults of ``plan`` (default: the scenario's ``[faults]``) for one runner.

    lockstep: lock-step (delays in ticks) or real time (delays in seconds of
    ``clock``). ``mortal``: stand in for process faults in this process (the
    simulator; a role process whose launcher also sends real signals).
    """

    def __init__(self, scenario: Scenario, plan: FaultPlan | None = None, lockstep: bool = True,
                 clock: Callable[[], float] = time.monotonic, mortal: bool = True) -> None:
        self.sc = scenario
        self.plan = plan if plan is not None else plan_of(scenario)
        self.lockstep = lockstep
        self.clock = clock
        self.mortal = mortal
        self.built: list = []
        self.mortals: dict[str, Mortal] = {}  # plan target -> its stand-in

    def world(self, node):
        """The world node behind its inbox filter (or itself when nothing can reach it)."""
        out = wrap(node, "world", 0, self.plan, self.sc.dt, self.lockstep, self.clock)
        self.built.append(out)
        return out

    def agent(self, robot_id: int, build: Callable[[], object]):
        """Robot ``robot_id``'s node, built by ``build()`` (again at each restart), filtered."""
        return self._node("agent", robot_id, f"agent:{robot_id}", build)

    def leader(self, build: Callable[[], object]):
        """The leader's node, built by ``build()`` (again at each restart), filtered: a plan may
        kill or freeze the leader as it may a robot."""
        return self._node("leader", 0, "leader", build)

    def _node(self, role: str, ident: int, target: str, build: Callable[[], object]):
        def make():
            return wrap(build(), role, ident, self.plan, self.sc.dt, self.lockstep, self.clock)

        mine = [p for p in self.plan.processes if p.target == target]
        out = Mortal(make, mine) if mine and self.mortal else make()
        self.built.append(out)
        if isinstance(out, Mortal):
            self.mortals[target] = out
        return out

    def poll(self) -> list:
        """Real time: messages whose delay is over, handed to their nodes; returns what they send."""
        return [out for inbox in self._inboxes() for out in inbox.poll()]

    def stop_waiting(self) -> list:
        """Lock-step, nothing left to deliver: every inbox starts the ticks it holds (what their
        nodes wait for will never come); returns what that sends."""
        return [out for inbox in self._inboxes() for out in inbox.stop_waiting()]

    def _inboxes(self) -> list[FaultyInbox]:
        return [inbox for inbox in map(inbox_of, self.built) if inbox is not None]

    def link_counts(self) -> dict[str, dict[str, int]]:
        inboxes = [g for node in self.built for g in getattr(node, "generations", [node])]
        return link_counts(inboxes)

    def restarts(self) -> dict[str, int]:
        return {target: n.restarts for target, n in self.mortals.items() if n.restarts}


def wrap_for_process(node, role: str, ident: int, plan: FaultPlan, dt: float, lockstep: bool, speed: float):
    """A role process's node behind ``plan``'s inbox filter (itself when nothing reaches it).

    Real time: delays are in simulation seconds on a clock running ``speed`` times wall
    time. Process faults are the launcher's (real signals) here.
    """
    return wrap(node, role, ident, plan, dt, lockstep, lambda: time.monotonic() * speed)


def inbox_of(node) -> FaultyInbox | None:
    """The inbox filter among ``node``'s wrappers, if it has one."""
    while node is not None and not isinstance(node, FaultyInbox):
        node = getattr(node, "inner", None) if not isinstance(node, Mortal) else node.node
    return node


def process_counters(node) -> dict:
    """What a role process adds to its counters file: its inbox's per-link counts."""
    inbox = inbox_of(node)
    return {"links": {k: dict(v.__dict__) for k, v in inbox.links.items()}} if inbox is not None else {}
