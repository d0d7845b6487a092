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
from fxswarm.core.laws import BatchUnsupported
from fxswarm.core.metrics import estimate_errors, formation_errors
from fxswarm.core.scenario import Scenario
from fxswarm.faults.apply import SwarmFaults
from fxswarm.faults.plan import FaultPlan, plan_of
from fxswarm.faults.summary import build_summary
from fxswarm.launch.batch import PATHS, BatchRun, batch_plan
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
    path: ``"per-robot"`` (an agent node per robot on the bus), ``"auto"`` (the batch path,
    fxswarm.launch.batch, when it takes the run; ``path_reason`` says why not) or ``"batch"``
    (that, or :class:`~fxswarm.core.laws.BatchUnsupported`); the trajectories are the same.
    record_every: the world records every K-th tick.
    """

    scenario: Scenario
    plan: FaultPlan | None = None
    bus: InMemoryBus = field(default_factory=InMemoryBus)
    path: str = "per-robot"  # "auto": the batch path when it takes the run (fxswarm sim); "batch": it or an error
    record_every: int = 1  # trajectory.npz keeps every K-th tick

    def __post_init__(self) -> None:
        sc = self.scenario
        if self.plan is None:
            self.plan = plan_of(sc)
        if self.path not in PATHS:
            raise ValueError(f"path {self.path!r}: expected one of {', '.join(PATHS)}")
        self.path_reason = None  # why the per-robot path, when the batch path was not taken
        self.batch_law = None
        if self.path != "per-robot":
            try:
                self.batch_law = batch_plan(sc, self.plan)
            except BatchUnsupported as exc:
                self.path_reason = str(exc)
                if self.path == "batch":
                    raise
        if self.batch_law is not None:
            self.world = WorldNode(sc, limits=self.plan.limits, record_every=self.record_every)
            self.agents = []
            return
        self._build_per_robot()

    def _build_per_robot(self) -> None:
        sc = self.scenario
        limits = self.plan.limits
        self.world = WorldNode(sc, limits=limits, record_every=self.record_every)
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
        if self.batch_law is not None:
            try:
                return self._run_batch(progress)
            except BatchUnsupported as exc:  # never a silently different result: start again per robot
                self.path_reason = f"the batch path stopped: {exc}"
                sys.stderr.write(f"\nfxswarm sim: {self.path_reason}; running again per robot\n")
                self.batch_law = None
                self._build_per_robot()
        start = time.perf_counter()
        last_report = start
        self.bus.publish_all(self.world.start())
        while not self.world.done:
            if self.bus.pump() == 0:
                # Nothing left to deliver yet the tick did not complete: a node is waiting
                # on a message that will never come (only faults cause this in-process).
                # A robot holding a later tick's sensing stops waiting first; else the world.
                held = self.faults.stop_waiting()
                self.bus.publish_all(held if held else self.world.timeout())
            now = time.perf_counter()
            if progress is not None and now - last_report > 0.5:
                progress(self.world, self.world.tick / (now - start))
                last_report = now
        wall = time.perf_counter() - start
        if progress is not None:  # the final line, also for a run shorter than one report period
            progress(self.world, self.world.tick / max(wall, 1e-9))
        runner = {"counters": {"bus": self.bus.counters.as_dict(), "missed_ticks": self.world.missed_ticks},
                  "speed_limited_ticks": sum(a.speed_limited for a in self.agents),
                  "path": "per-robot", "path_reason": self.path_reason}
        discarded = ({r.id: a.discarded for r, a in zip(self.scenario.robots, self.agents)}
                     if self.scenario.resilience != "none" else None)
        return self._ticks_run(build_summary(self.scenario, self.world.trajectory(), self.plan, wall_s=wall,
                                             world=self.world, links=self.faults.link_counts(),
                                             restarts=self.faults.restarts(), runner=runner, discarded=discarded))

    def _ticks_run(self, summary: dict) -> dict:
        """With ``--record-every K`` the trajectory holds every K-th tick: the summary counts the ticks run."""
        if self.record_every > 1:
            summary["ticks"] = int(self.world.tick)
            summary["duration_s"] = float(self.world.tick * self.scenario.dt)
            summary["record_every"] = self.record_every
        return summary

    def _run_batch(self, progress) -> dict:
        """The batch path (fxswarm.launch.batch): the same world, every robot's law in one call a tick."""
        stepper = BatchRun(self.scenario, self.world, self.batch_law)
        wall = stepper.run(progress)
        runner = {"counters": {"bus": {}, "missed_ticks": self.world.missed_ticks},
                  "speed_limited_ticks": stepper.speed_limited, "path": "batch", "path_reason": None}
        return self._ticks_run(build_summary(self.scenario, self.world.trajectory(), self.plan, wall_s=wall,
                                             world=self.world, links={}, restarts={}, runner=runner))

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
