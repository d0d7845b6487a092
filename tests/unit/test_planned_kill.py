"""A planned kill in lock-step over processes (fxswarm.faults.process.PlannedKill and the
launcher's schedule): the process falls silent at its kill's tick exactly where fxswarm sim's
stand-in (Mortal) does, and its restart is sent a tick ahead for the world to hold that tick."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from fxswarm.core.messages import Estimate, Sense
from fxswarm.faults.plan import ProcessFault
from fxswarm.faults.process import Mortal, PlannedKill, ProcessSchedule

DT = 0.01
KILL = ProcessFault("agent:2", "kill", 0.4, 1.4)


class Echo:
    """A node that answers every message with its tick, and counts what it handled."""

    def __init__(self) -> None:
        self.heard: list[tuple[str, int]] = []

    def subscriptions(self) -> list[str]:
        return []

    def handle(self, topic, msg):
        self.heard.append((type(msg).__name__, msg.tick))
        return [("out", msg.tick)]


def sense(k: int) -> Sense:
    return Sense("world", 0, k, k, k * DT, 2, np.zeros(3), None, None)


def estimate(k: int) -> Estimate:
    return Estimate("agent", 1, k, k, k * DT, 1, np.zeros(3))


def inputs(first: int, last: int):
    """Per tick, a neighbour's estimate pipelined for the next tick, then the tick's sensing."""
    for k in range(first, last):
        yield "est", estimate(k + 1)
        yield "sense", sense(k)


def test_the_process_falls_silent_where_the_simulator_s_stand_in_does():
    killed, sim = PlannedKill(Echo(), [KILL]), Mortal(Echo, [KILL])
    said = {"process": [], "sim": []}
    for topic, msg in inputs(0, 100):
        said["process"] += killed.handle(topic, msg)
        said["sim"] += sim.handle(topic, msg)
    # The sim's stand-in comes back at 1.4 s; up to there both said the same, the last at tick 39.
    assert said["process"] == [o for o in said["sim"] if o[1] < 40]
    assert max(o[1] for o in said["process"]) == 39 and ("out", 40) not in said["process"]
    assert killed.silenced
    # Silent for good: its restart is a new process.
    assert [killed.handle(t, m) for t, m in inputs(140, 142)] == [[]] * 4


def test_the_restarted_process_is_not_silenced_by_the_kill_it_restarts_from():
    new = PlannedKill(Echo(), [KILL])
    said = [o for t, m in inputs(140, 143) for o in new.handle(t, m)]
    assert said and not new.silenced and ("out", 142) in said


def test_a_restart_is_due_a_tick_ahead_in_lock_step_and_a_kill_at_its_time():
    schedule = ProcessSchedule((KILL,))
    assert schedule.due(0.39, restart_lead=DT) == []
    assert schedule.due(0.40, restart_lead=DT) == [("kill", "agent:2")]
    assert schedule.due(1.38, restart_lead=DT) == []
    assert schedule.due(1.39, restart_lead=DT) == [("restart", "agent:2")]
    real_time = ProcessSchedule((KILL,))
    assert real_time.due(1.39) == [("kill", "agent:2")] and real_time.due(1.40) == [("restart", "agent:2")]


def test_the_launcher_s_schedule_leads_restarts_by_a_tick_only_in_lock_step():
    class Swarm:
        children: dict = {}

        def __init__(self, clock: str, t: float) -> None:
            self.clock, self.scenario, self.t = clock, SimpleNamespace(dt=DT), t

        def sim_time(self) -> float:
            return self.t

    lockstep = ProcessSchedule((ProcessFault("agent:2", "kill", 0.4, 1.4),))
    lockstep.due(0.5)  # the kill, done
    assert [e["action"] for e in lockstep.run(Swarm("lockstep", 1.39))] == ["restart"]
    realtime = ProcessSchedule((ProcessFault("agent:2", "kill", 0.4, 1.4),))
    realtime.due(0.5)
    assert realtime.run(Swarm("realtime", 1.39)) == []



def test_a_receiver_waits_for_what_a_killed_sender_sent_the_tick_before_its_kill():
    """The leader's state and an estimate for the kill's own tick left the sender a tick early,
    while it was up: the simulator always hears them, so a process waits for them too (else it
    is a race whether they beat the next sensing). A command for that tick was never sent."""
    from fxswarm.faults.inbox import FaultyInbox
    from fxswarm.faults.plan import FaultPlan

    plan = FaultPlan(processes=(ProcessFault("leader", "kill", 3.0), KILL))
    agent, world = FaultyInbox(Echo(), "agent:1", plan, DT), FaultyInbox(Echo(), "world", plan, DT)
    assert agent.expects("leader", 299) and agent.expects("leader", 300)  # sent at tick 299
    assert not agent.expects("leader", 301)
    assert agent.expects("agent:2", 40) and not agent.expects("agent:2", 41)  # estimate: pipelined
    assert not world.expects("agent:2", 40) and world.expects("agent:2", 39)  # command: its own tick
    assert not agent.expects("agent:2", 139) and agent.expects("agent:2", 140)  # restarted at 1.4 s
