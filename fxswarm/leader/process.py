"""``fxswarm leader CONFIG``: the virtual leader as its own process on Zenoh.

Lock-step: answers each ``Clock(k)`` with ``LeaderState(k)`` (event-driven).
Real time: publishes ``p0(t)`` every control period (``dt / speed`` wall
seconds) at the simulation time learnt from the world's clock. Exits when the
world ends the run, on SIGINT/SIGTERM, or (status 1) when a world gone without
ending it has not come back within ``--world-timeout`` s.
"""

from __future__ import annotations

import argparse

from fxswarm.core.messages import Message
from fxswarm.core.scenario import Scenario
from fxswarm.leader.node import LeaderNode
from fxswarm.runtime.process import RoleProcess, add_process_arguments, run_event_loop, run_periodic_loop, wrap_node
from fxswarm.runtime.sim_cli import load_or_exit


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_process_arguments(p)


class ClockOnly:
    """Real time: the clock only sets the process's simulation time; the leader speaks on its own beat."""

    def __init__(self, leader: LeaderNode) -> None:
        self.inner = leader

    def subscriptions(self) -> list[str]:
        return self.inner.subscriptions()

    def handle(self, topic: str, msg: Message) -> list:
        return []


def build_node(scenario: Scenario, args: argparse.Namespace):
    node = LeaderNode(scenario)
    if args.clock == "realtime":
        node = ClockOnly(node)
    return wrap_node(node, "leader", 0, scenario, args)


def main(args: argparse.Namespace) -> int:
    sc = load_or_exit(args.config)
    proc = RoleProcess("leader", 0, sc, args)
    try:
        proc.watch(["world/0"])
        proc.attach(build_node(sc, args))
        if proc.lockstep:
            run_event_loop(proc)
        else:
            leader: LeaderNode = proc.core
            beat = 0
            said = None

            def act() -> None:
                nonlocal beat, said
                if proc.clock.known and proc.clock.now() != said:  # p0 only moves with the world's time
                    said = proc.clock.now()
                    proc.publish(leader.act(beat, said))
                    beat += 1

            run_periodic_loop(proc, sc.dt / args.speed, act)
    finally:
        proc.finish()
    return proc.exit_status
