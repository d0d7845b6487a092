"""``fxswarm agent CONFIG --id I``: one robot as its own process on Zenoh.

It hears only its own sensing, its graph neighbours' estimates and, if
pinned, the leader (the node's ``subscriptions()``): locality, as in the paper.

Lock-step: event-driven on its inbox (the node answers ``Sense(k)`` with its
estimate and, once every neighbour's estimate for ``k`` is in, its command).
A neighbour (or the leader) whose process is gone is not waited for: the
robot acts on what it last heard from it. Real time: it acts at once on
fresh sensing, and otherwise on its own beat (every 1.5 control periods,
``dt / speed`` wall s each), on the latest data held (zero-order hold),
integrating ``dt`` = the world's time elapsed since its last act. Exits when
the world ends the run, on SIGINT/SIGTERM, or (status 1) when a world gone
without ending it has not come back within ``--world-timeout`` s
(:meth:`~fxswarm.runtime.process.RoleProcess.exit_with_world`).
"""

from __future__ import annotations

import argparse
import sys

from fxswarm.agent.node import AgentNode
from fxswarm.core.messages import Estimate, LeaderState, Message, Sense
from fxswarm.core.scenario import Scenario
from fxswarm.runtime.process import RoleProcess, add_process_arguments, run_event_loop, run_periodic_loop, wrap_node
from fxswarm.runtime.sim_cli import load_or_exit


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_process_arguments(p)
    p.add_argument("--id", type=int, required=True, help="robot id (1-based, as in the scenario)")


def build_node(scenario: Scenario, robot_id: int, args: argparse.Namespace):
    node = AgentNode(scenario, robot_id, lockstep=args.clock == "lockstep")
    return wrap_node(node, "agent", robot_id, scenario, args)


class AgentProcess(RoleProcess):
    def is_late(self, msg: Message) -> bool:
        sense = self.core.sense
        return sense is not None and isinstance(msg, (Sense, Estimate, LeaderState)) and msg.tick < sense.tick

    def act_past_the_gone(self) -> None:
        """Lock-step: if all the robot still waits for are processes that are gone, act now."""
        agent: AgentNode = self.core
        s = agent.sense
        if s is None or agent.acted_tick >= s.tick:
            return
        missing = agent.waiting_for(s.tick)
        names = ["leader/0" if m == "leader" else "agent/" + m.split(":")[1] for m in missing]
        if names and all(n in self.gone for n in names):
            self.publish(agent.act_tick())


def main(args: argparse.Namespace) -> int:
    sc = load_or_exit(args.config)
    if not 1 <= args.id <= sc.n:
        print(f"fxswarm agent: --id: expected a robot id in 1..{sc.n} of {args.config}, got {args.id}",
              file=sys.stderr)
        return 2
    proc = AgentProcess("agent", args.id, sc, args)
    try:
        node = build_node(sc, args.id, args)
        watched = ["world/0"] + [f"agent/{j}" for j in sc.neighbours(args.id)]
        if sc.is_pinned(args.id):
            watched.append("leader/0")
        proc.watch(watched)
        proc.attach(node)
        agent: AgentNode = proc.core
        if proc.lockstep:
            run_event_loop(proc, on_idle=proc.act_past_the_gone)
        else:
            last = None

            def act() -> None:
                nonlocal last
                if agent.sense is None or not proc.clock.known:
                    return
                now = proc.clock.now()
                if last is not None and now <= last:
                    return  # the world's time has not moved: nothing to integrate
                dt = sc.dt if last is None else now - last
                last = now
                proc.publish(agent.act(dt))
                proc.publish(agent.estimate_message(agent.sense.tick, now))

            run_periodic_loop(proc, sc.dt / args.speed, act,
                              act_early=lambda: agent.sense is not None and agent.sense.tick > agent.acted_tick)
    finally:
        proc.finish()
    return proc.exit_status
