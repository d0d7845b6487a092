"""The in-process simulator: every node on one in-memory bus, in lock-step.

The same node classes as the multi-process runtime; only the bus differs.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

import numpy as np

from fxswarm.agents.node import AgentNode
from fxswarm.core.bus import InMemoryBus
from fxswarm.core.metrics import estimate_errors, formation_errors
from fxswarm.core.scenario import Scenario
from fxswarm.faults.apply import SwarmFaults
from fxswarm.faults.plan import FaultPlan, plan_of
from fxswarm.faults.summary import build_summary
from fxswarm.leader.node import LeaderNode
from fxswarm.world.node import WorldNode


def attach(bus: InMemoryBus, node) -> None:
    """Subscribe ``node`` to its topics on ``bus``; what it returns is published."""

    def deliver(topic, msg, node=node):
        out = node.handle(topic, msg)
        if out:
            bus.publish_all(out)

    for pattern in node.subscriptions():
        bus.subscribe(pattern, deliver)


@dataclass
class Simulation:
    """A lock-step swarm in one process. ``run()`` returns the summary.

    plan: the run's resolved fault plan (default: the scenario's ``[faults]`` alone).
    """

    scenario: Scenario
    plan: FaultPlan | None = None
    bus: InMemoryBus = field(default_factory=InMemoryBus)

    def __post_init__(self) -> None:
        sc = self.scenario
        if self.plan is None:
            self.plan = plan_of(sc)
        limits = self.plan.limits
        self.world = WorldNode(sc, limits=limits)
        self.faults = SwarmFaults(sc, self.plan)  # the plan's faults, if any, on each receiver's inbox
        self.leader = self.faults.leader(lambda: LeaderNode(sc))
        plan = self.plan
        self.agents = [self.faults.agent(r.id, lambda i=r.id: AgentNode(sc, i, limits=limits, lie=plan.lie_of(i),
                                                                        seed=plan.seed)) for r in sc.robots]
        for node in (self.faults.world(self.world), self.leader, *self.agents):
            attach(self.bus, node)

    def run(self, progress=None) -> dict:
        """Run to the end; ``progress(world, ticks_per_s)`` is called about twice a second, and
        once at the end."""
        start = time.perf_counter()
        last_report = start
        self.bus.publish_all(self.world.start())
        while not self.world.done:
            if self.bus.pump() == 0:
                # Nothing left to deliver yet the tick did not complete: a node is waiting
                # on a message that will never come (only faults cause this in-process).
                self.bus.publish_all(self.world.timeout())
            now = time.perf_counter()
            if progress is not None and now - last_report > 0.5:
                progress(self.world, self.world.tick / (now - start))
                last_report = now
        wall = time.perf_counter() - start
        if progress is not None:  # the final line, also for a run shorter than one report period
            progress(self.world, self.world.tick / max(wall, 1e-9))
        runner = {"counters": {"bus": self.bus.counters.as_dict(), "missed_ticks": self.world.missed_ticks},
                  "speed_limited_ticks": sum(a.speed_limited for a in self.agents)}
        return build_summary(self.scenario, self.world.trajectory(), self.plan, wall_s=wall, world=self.world,
                             links=self.faults.link_counts(), restarts=self.faults.restarts(), runner=runner,
                             discarded={r.id: a.discarded for r, a in zip(self.scenario.robots, self.agents)}
                             if self.scenario.resilience != "none" else None)

    def trajectory(self) -> dict[str, np.ndarray]:
        return self.world.trajectory()


def progress_line(world: WorldNode, ticks_per_s: float, stream=sys.stderr) -> None:
    """One overwriting line: sim time, ticks/s, current max formation and estimate error."""
    k = max(world.tick - 1, 0)
    sc = world.sc
    t = k * sc.dt
    p0 = sc.leader.position(t)
    offsets = np.array([r.offset.position(t) for r in sc.robots])
    f_err = np.linalg.norm(world.p - p0 - offsets, axis=1).max()
    e_err = np.linalg.norm(world.ph - p0, axis=1).max()
    stream.write(f"\r  t = {t:7.2f} / {sc.duration:g} s   {ticks_per_s:8.0f} ticks/s   "
                 f"max formation error {f_err:8.3f} m   max estimate error {e_err:8.3f} m ")
    stream.flush()


__all__ = ["Simulation", "attach", "progress_line", "formation_errors", "estimate_errors"]
