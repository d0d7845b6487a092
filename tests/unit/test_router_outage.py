"""A router outage, sans I/O: who went with the router, the world holding and asking again, and
what agents and leader say again (docs/routers.md)."""

from __future__ import annotations

import numpy as np
import pytest

from fxswarm.agents.node import AgentNode
from fxswarm.core import bus as topics
from fxswarm.core.messages import Clock, Command, Estimate, Sense
from fxswarm.core.scenario import load
from fxswarm.leader.node import LeaderNode
from fxswarm.runtime.liveness import Liveness
from fxswarm.world.node import TickTimer, WorldNode


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture(scope="module")
def sc():
    return load("configs/paper-fast.toml")


def test_departures_with_a_router_are_expected_back_others_are_deaths():
    clock = FakeClock()
    live = Liveness(clock, settle_s=0.3, rejoin_s=10.0)
    for name in ("router/0", "agent/1", "agent/2", "agent/3"):
        live.change(name, True)
    # agent/1 goes a moment before the router, agent/2 a moment after: both went with it.
    live.change("agent/1", False)
    clock.t += 0.05
    live.change("router/0", False)
    clock.t += 0.05
    live.change("agent/2", False)
    clock.t += 1.0
    live.settle()
    assert live.gone == set() and live.unsure() == {"agent/1", "agent/2"}
    # agent/3 goes long after: a death, judged once SETTLE_S has passed (unsure until then).
    live.change("agent/3", False)
    assert live.unsure() == {"agent/1", "agent/2", "agent/3"} and live.gone == set()
    clock.t += 0.4
    live.settle()
    assert live.gone == {"agent/3"}
    # Back: the outage is over once everyone who went with the router is.
    live.change("agent/1", True)
    assert live.rejoined == 0
    live.change("agent/2", True)
    assert live.rejoined == 1 and live.unsure() == set() and live.alive == {"agent/1", "agent/2"}


def test_a_process_lost_with_a_router_and_never_back_is_gone_after_the_rejoin_limit():
    clock = FakeClock()
    live = Liveness(clock, settle_s=0.3, rejoin_s=10.0)
    live.change("agent/4", True)
    live.change("router/link-abc", False)  # this process's own link to its router closed
    live.change("agent/4", False)
    clock.t += 9.9
    assert live.settle() == [] and live.gone == set()
    clock.t += 0.2
    assert live.settle() == ["agent/4"] and live.gone == {"agent/4"} and live.rejoined == 1


def test_the_world_holds_the_tick_while_unsure_then_asks_again_instead_of_closing(sc):
    clock = FakeClock()
    world = WorldNode(sc, record=False)
    sent = world.start()
    timer = TickTimer(world, 1.0, clock, ask_limit=5.0)
    clock.t += 3.0  # far past the tick timeout, but a robot is away with a router: held
    assert timer.check(unsure=True) == [] and world.tick == 0 and world.missed_ticks == 0
    again = timer.ask_again()
    assert again[:-1] == sent  # the tick's sensing, as sent
    topic, clock_msg = again[-1]
    assert topic == topics.RESYNC and isinstance(clock_msg, Clock) and clock_msg.tick == 0
    clock.t += 1.5  # deadline passed while asking again: ask again, do not close
    assert timer.check()[-1][0] == topics.RESYNC and world.tick == 0
    clock.t += 5.0  # past ask_limit: the tick timeout rules again
    out = timer.check()
    assert world.tick == 1 and world.missed_ticks == 1 and out


def sense(sc, robot: int, tick: int) -> Sense:
    r = sc.robots[robot - 1]
    return Sense("world", 0, tick + 1, tick, tick * sc.dt, robot, np.array(r.position, dtype=float), None, None)


def test_an_agent_says_again_its_estimate_and_command_for_the_tick_the_same_values(sc):
    agent = AgentNode(sc, 2, lockstep=True)  # neighbours 1 and 3, not pinned
    first = agent.handle(topics.sense_topic(2), sense(sc, 2, 0))
    (est0,) = [m for _, m in first]
    assert isinstance(est0, Estimate) and est0.tick == 0
    again = agent.said_again(0)
    assert [type(m) for _, m in again] == [Estimate] and again[0][1].tick == 0
    assert np.array_equal(again[0][1].ph, est0.ph) and again[0][1].seq > est0.seq
    for j in (1, 3):
        agent.handle(topics.command_topic(j), Estimate("agent", j, 1, 0, 0.0, j, np.zeros(3), None))
    assert agent.acted_tick == 0
    cmd0 = agent.last_command[1]
    again = agent.said_again(0)  # acted: its estimate for tick 0 and its command for it
    assert [type(m) for _, m in again] == [Estimate, Command]
    assert np.array_equal(again[1][1].v, cmd0.v) and again[1][1].est_tick == 1
    agent.handle(topics.sense_topic(2), sense(sc, 2, 1))
    again = agent.said_again(1)  # not acted on tick 1: its estimate for it, carried by command 0
    assert [type(m) for _, m in again] == [Estimate] and again[0][1].tick == 1
    assert np.array_equal(again[0][1].ph, cmd0.est_ph)


def test_the_leader_says_again_the_states_for_the_tick_and_the_next(sc):
    leader = LeaderNode(sc)
    sent = leader.handle(topics.sense_topic(1), sense(sc, 1, 5))
    again = leader.said_again(5)
    assert [m.tick for _, m in again] == [5, 6] == [m.tick for _, m in sent]
    assert all(np.array_equal(a.p0, b.p0) for (_, a), (_, b) in zip(again, sent))


def test_while_asking_again_the_world_asks_every_second_however_long_the_tick_timeout(sc):
    """What is said again can be lost too (right after a planned restart, estimates between the
    new process and a neighbour were): with a 60 s --tick-timeout the tick waited the minute out
    and closed as a miss. It asks again every ASK_AGAIN_S instead, while a robot is missing."""
    clock = FakeClock()
    world = WorldNode(sc, record=False)
    world.start()
    timer = TickTimer(world, 60.0, clock, ask_limit=120.0)
    assert timer.check() == []  # not asking: a 60 s deadline is a 60 s deadline
    clock.t += 5.0
    assert timer.check() == [] and world.tick == 0
    assert timer.ask_again()[-1][0] == topics.RESYNC and timer.asked == 1
    clock.t += 0.5
    assert timer.check() == []
    clock.t += 0.6
    assert timer.check()[-1][0] == topics.RESYNC and timer.asked == 2 and world.tick == 0
    for r in range(1, sc.n + 1):  # everyone answered: nothing more to ask for
        world.handle(topics.command_topic(r), Command("agent", r, 1, 0, 0.0, r, np.zeros(3), np.zeros(3), False))
    assert world.tick == 1 and world.missed_ticks == 0
    clock.t += 1.1
    assert all(t != topics.RESYNC for t, _ in timer.check()) and timer.asked == 2
