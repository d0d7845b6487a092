"""``fxswarm leader CONFIG``: the virtual leader as its own process on Zenoh.

Lock-step: answers the world's tick ``k`` (the sensing of the first robot) with
``LeaderState(k + 1)`` (event-driven). Real time: publishes ``p0(t)`` every control
period (``dt / speed`` wall seconds) at the simulation time learnt from the world's
messages. Exits when the
world ends the run, on SIGINT/SIGTERM, or (status 1) when a world gone without
ending it has not come back within ``--world-timeout`` s.
"""

from __future__ import annotations

import argparse

from fxswarm.core.messages import Message
from fxswarm.core.pacing import Pacer
from fxswarm.core.scenario import Scenario
from fxswarm.faults.plan import FaultPlan
from fxswarm.leader.node import LeaderNode
from fxswarm.runtime.process import RoleProcess, add_process_arguments, run_event_loop, run_periodic_loop, wrap_node
from fxswarm.runtime.config import load_or_exit


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_process_arguments(p)


class ClockOnly:
    """Real time: the world's messages only set the process's simulation time; the leader speaks on its own beat."""

    def __init__(self, leader: LeaderNode) -> None:
        self.inner = leader

    def subscriptions(self) -> list[str]:
        return self.inner.subscriptions()

    def handle(self, topic: str, msg: Message) -> list:
        return []


def build_node(scenario: Scenario, args: argparse.Namespace, plan: FaultPlan):
    node = LeaderNode(scenario)
    if args.clock == "realtime":
        node = ClockOnly(node)
    return wrap_node(node, "leader", 0, plan, scenario, args)


class LeaderProcess(RoleProcess):
    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.heard_tick = -1  # the newest tick of the world's (robot 1's) sensing arrived

    def deliver(self, topic: str, msg: Message) -> None:
        self.heard_tick = max(self.heard_tick, msg.tick)
        super().deliver(topic, msg)

    def drained(self) -> bool:
        """Lock-step: the last tick's sensing has arrived (or the world is gone). It asks for
        nothing (that tick's state went with the one before), so the world may end the run
        before it lands; waiting for it keeps this process's counters whole (the received
        count was one short in 1 run of 7 at load 18)."""
        return self.heard_tick >= self.sc.ticks - 1 or "world/0" in self.gone


def main(args: argparse.Namespace) -> int:
    sc = load_or_exit(args.config)
    proc = LeaderProcess("leader", 0, sc, args)
    try:
        proc.watch(["world/0"])
        proc.attach(build_node(sc, args, proc.plan))
        if proc.lockstep:
            run_event_loop(proc)
        else:
            leader: LeaderNode = proc.core

            def act() -> None:
                if proc.clock.known:
                    proc.publish(leader.act_realtime(proc.clock.now()))

            run_periodic_loop(proc, Pacer(sc.dt / args.speed, proc.wall_clock), act)
    finally:
        proc.finish()
    return proc.exit_status
