"""``fxswarm agent CONFIG --id I``: one robot as its own process on Zenoh.

It hears only its own sensing, its graph neighbours' estimates and, if
pinned, the leader (the node's ``subscriptions()``): locality, as in the paper.

Lock-step: event-driven on its inbox (the node answers ``Sense(k)`` with its
estimate and, once every neighbour's estimate for ``k`` is in, its command).
A neighbour (or the leader) whose process is gone is not waited for: the
robot acts on what it last heard from it. Real time: it acts at once on
fresh sensing, and otherwise on its own beat (every 1.5 control periods,
``dt / speed`` wall s each), on the latest data held (zero-order hold),
integrating ``dt`` = the world's time elapsed since its last act
(:meth:`~fxswarm.agents.node.AgentNode.act_realtime`). Exits when
the world ends the run, on SIGINT/SIGTERM, or (status 1) when a world gone
without ending it has not come back within ``--world-timeout`` s
(:meth:`~fxswarm.runtime.process.RoleProcess.exit_with_world`).
"""

from __future__ import annotations

import argparse
import sys

from fxswarm.agents.node import AgentNode
from fxswarm.core import bus as topics
from fxswarm.core.messages import Message, decode_carried
from fxswarm.core.pacing import Deadline, Pacer
from fxswarm.core.scenario import Scenario
from fxswarm.faults.plan import FaultPlan
from fxswarm.runtime.process import RoleProcess, add_process_arguments, run_event_loop, run_periodic_loop, wrap_node
from fxswarm.runtime.config import load_or_exit
from fxswarm.runtime.liveness import REJOIN_S


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_process_arguments(p)
    p.add_argument("--id", type=int, required=True, help="robot id (1-based, as in the scenario)")


def build_node(scenario: Scenario, robot_id: int, args: argparse.Namespace, plan: FaultPlan):
    node = AgentNode(scenario, robot_id, lockstep=args.clock == "lockstep", limits=plan.limits,
                     lie=plan.lie_of(robot_id), seed=plan.seed)
    return wrap_node(node, "agent", robot_id, plan, scenario, args)


class AgentProcess(RoleProcess):
    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.last_tick: dict[tuple[str, int], int] = {}  # (role, sender) -> newest tick arrived
        self.neighbour_commands = {topics.command_topic(j) for j in self.sc.neighbours(self.ident)}
        self.waiting_since: dict[tuple[str, int], Deadline] = {}  # (target, restarts due): for restarting()

    def deliver(self, topic: str, msg: Message) -> None:
        key = (msg.role, msg.sender)
        if msg.tick > self.last_tick.get(key, -1):
            self.last_tick[key] = msg.tick
        super().deliver(topic, msg)

    def drained(self) -> bool:
        """Lock-step: each neighbour's estimate for the last tick (and, pinned, the leader's
        last state) has arrived, or that process is gone. Each sends in order on one key, so
        nothing the robot reads from it is still on its way, lost or delayed by a fault filter
        or not: all of it has been counted. (A neighbour's last command carries no estimate:
        the robot reads nothing from it, and may leave before it lands.)"""
        last = self.sc.ticks - 1
        senders = [("agent", j) for j in self.sc.neighbours(self.ident)]
        if self.sc.is_pinned(self.ident):
            senders.append(("leader", 0))
        return all(self.last_tick.get(s, -1) >= last or f"{s[0]}/{s[1]}" in self.gone for s in senders)

    def is_late(self, msg: Message) -> bool:
        return self.core.is_late(msg)

    def reader_for(self, pattern: str):
        """A neighbour's command key: only the estimate it carries, which is all the robot uses."""
        if pattern in self.neighbour_commands:
            return decode_carried
        return super().reader_for(pattern)

    def act_past_the_gone(self) -> None:
        """Lock-step: act now if all the robot still waits for are processes that are gone. A
        sender whose planned restart is due by the current tick is waited for (as in ``fxswarm
        sim``, where it is back at that tick) until its new process is up, at most ``REJOIN_S``."""
        gone = {"leader" if n == "leader/0" else n.replace("/", ":") for n in self.gone}
        sense = self.core.sense
        if gone and sense is not None:
            gone -= self.restarting(sense.tick * self.sc.dt)
        # Through the node's wrappers: an inbox filter starts the tick it held while the robot waited.
        self.publish(self.node.act_past_the_gone(gone))

    def restarting(self, t: float) -> set[str]:
        """Plan targets (``agent:<id>``, ``leader``) restarted by time ``t`` whose new process is
        not up yet (its token has come up fewer times than its start and those restarts), and not
        waited for longer than ``REJOIN_S`` already."""
        due: dict[str, int] = {}
        for f in self.plan.processes:
            if f.action == "kill" and f.restart is not None and f.restart <= t + 1e-9:
                due[f.target] = due.get(f.target, 0) + 1
        out = set()
        for target, restarts in due.items():
            name = "leader/0" if target == "leader" else target.replace(":", "/")
            if self.liveness.ups.get(name, 0) >= 1 + restarts:
                continue
            since = self.waiting_since.setdefault((target, restarts), Deadline(REJOIN_S, self.wall_clock))
            if not since.passed():
                out.add(target)
        return out


def main(args: argparse.Namespace) -> int:
    sc = load_or_exit(args.config)
    if not 1 <= args.id <= sc.n:
        print(f"fxswarm agent: --id: expected a robot id in 1..{sc.n} of {args.config}, got {args.id}",
              file=sys.stderr)
        return 2
    proc = AgentProcess("agent", args.id, sc, args)
    try:
        node = build_node(sc, args.id, args, proc.plan)
        watched = ["world/0"] + [f"agent/{j}" for j in sc.neighbours(args.id)]
        if sc.is_pinned(args.id):
            watched.append("leader/0")
        proc.watch(watched)
        proc.attach(node)
        agent: AgentNode = proc.core
        if proc.lockstep:
            run_event_loop(proc, on_idle=proc.act_past_the_gone)
        else:
            def act() -> None:
                if proc.clock.known:
                    proc.publish(agent.act_realtime(proc.clock.now()))

            # Fresh sensing is acted on at once; the timer fires only when it is 1.5 periods late.
            pacer = Pacer(sc.dt / args.speed, proc.wall_clock, patience=1.5)
            run_periodic_loop(proc, pacer, act, act_early=agent.fresh_sensing)
    finally:
        proc.finish()
    return proc.exit_status
