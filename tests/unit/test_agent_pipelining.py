"""Lock-step pipelining: an agent sends its tick-(k+1) estimate as soon as it has acted on tick k
(riding on its tick-k command), and a neighbour's estimate that comes a tick early waits until its
tick (docs/design.md "Lock-step pipelining")."""

from __future__ import annotations

import numpy as np

from fxswarm.agents.node import AgentNode
from fxswarm.core import bus as topics
from fxswarm.core.messages import Command, Estimate, LeaderState, Sense
from fxswarm.core.scenario import load

from support import PAPER_FAST


def sense(sc, k: int, p) -> tuple[str, Sense]:
    return topics.sense_topic(1), Sense("world", 0, k + 1, k, k * sc.dt, 1, np.asarray(p, float), None, None)


def estimate(sc, j: int, k: int, ph) -> tuple[str, Estimate]:
    return topics.estimate_topic(j), Estimate("agent", j, k + 1, k, k * sc.dt, j, np.asarray(ph, float))


def leader(sc, k: int) -> tuple[str, LeaderState]:
    return topics.LEADER_STATE, LeaderState("leader", 0, k + 1, k, k * sc.dt, np.array([0.1 * k, 0.0, 1.0]))


def feed(agent: AgentNode, messages) -> list:
    out = []
    for topic, msg in messages:
        out += agent.handle(topic, msg)
    return out


def test_the_next_estimate_goes_out_with_the_command_and_not_again_on_the_next_sensing():
    sc = load(PAPER_FAST)
    agent = AgentNode(sc, 1)  # neighbours 2 and 6, pinned
    out = feed(agent, [sense(sc, 0, [1, 2, 3])])
    assert [type(m) for _, m in out] == [Estimate] and out[0][1].tick == 0  # the first tick's, on its sensing
    assert out[0][0] == topics.command_topic(1)  # on its command key: neighbours hear only that
    out = feed(agent, [estimate(sc, 2, 0, [1, 0, 0]), estimate(sc, 6, 0, [0, 1, 0]), leader(sc, 0)])
    [(topic, cmd)] = out  # one message: the next estimate rides on the command
    assert topic == topics.command_topic(1) and isinstance(cmd, Command) and cmd.tick == 0
    est = cmd.carried_estimate()
    assert isinstance(est, Estimate) and (est.tick, est.t, est.seq) == (1, 1 * sc.dt, 2)
    np.testing.assert_array_equal(est.ph, agent.ph)  # the estimate after this tick's step
    assert feed(agent, [sense(sc, 1, [1, 2, 3])]) == []  # sent already: nothing new until the rest arrives


def test_a_neighbours_early_estimate_waits_for_its_tick():
    sc = load(PAPER_FAST)
    early, plain = AgentNode(sc, 1), AgentNode(sc, 1)
    tick0 = [sense(sc, 0, [1, 2, 3]), estimate(sc, 6, 0, [0, 1, 0]), leader(sc, 0)]
    feed(early, tick0)
    feed(plain, tick0)
    # Robot 2 acted on tick 0 first and sent its tick-1 estimate before its tick-0 one reached robot 1
    # (different paths through the router): robot 1 must still act on tick 0 with the tick-0 one.
    assert feed(early, [estimate(sc, 2, 1, [9, 9, 9])]) == []
    [(_, cmd_early)] = feed(early, [estimate(sc, 2, 0, [1, 0, 0])])
    [(_, cmd_plain)] = feed(plain, [estimate(sc, 2, 0, [1, 0, 0])])
    np.testing.assert_array_equal(cmd_early.v, cmd_plain.v)
    np.testing.assert_array_equal(early.ph, plain.ph)
    # On tick 1 the early one is held: robot 1 acts without waiting for robot 2 again.
    out = feed(early, [sense(sc, 1, [1, 2, 3]), estimate(sc, 6, 1, [0, 1, 0]), leader(sc, 1)])
    assert [m.tick for _, m in out if isinstance(m, Command)] == [1]
    assert early.estimates[2].tick == 1 and not early.ahead


def test_no_estimate_after_the_last_tick():
    sc = load(PAPER_FAST)
    agent = AgentNode(sc, 1)
    k = sc.ticks - 1
    agent.estimate_tick = k  # sent after the tick before
    out = feed(agent, [sense(sc, k, [1, 2, 3]), estimate(sc, 2, k, [1, 0, 0]), estimate(sc, 6, k, [0, 1, 0]),
                       leader(sc, k)])
    assert [type(m) for _, m in out] == [Command] and out[0][1].carried_estimate() is None


def test_a_neighbours_command_gives_the_estimate_it_carries():
    sc = load(PAPER_FAST)
    sender, receiver = AgentNode(sc, 2), AgentNode(sc, 1)  # neighbours
    own = (topics.sense_topic(2), Sense("world", 0, 1, 0, 0.0, 2, np.array([1.0, 2, 3]), None, None))
    out = feed(sender, [own, estimate(sc, 1, 0, [1, 0, 0]), estimate(sc, 3, 0, [0, 1, 0])])
    assert [type(m) for _, m in out] == [Estimate, Command]  # its first estimate alone, then the command
    topic, cmd = out[1]
    assert topic == topics.command_topic(2) and topic in receiver.subscriptions()
    assert topics.estimate_topic(2) not in receiver.subscriptions()
    receiver.handle(topic, cmd)
    held = receiver.ahead[2][0]  # for tick 1: waits for it
    assert (held.tick, held.seq) == (1, cmd.seq) and np.array_equal(held.ph, sender.ph)


def test_an_early_estimate_across_a_restart_reaches_the_restarted_robot():
    """In-process kill/restart (faults.process.Mortal): a neighbour's estimate for the first tick
    after the restart arrives while the robot is still dead; it is for the robot alive then."""
    from fxswarm.faults.plan import ProcessFault
    from fxswarm.faults.process import Mortal

    sc = load(PAPER_FAST)
    back = 3  # the restart tick
    mortal = Mortal(lambda: AgentNode(sc, 1), [ProcessFault("agent:1", "kill", 1 * sc.dt, back * sc.dt)])
    feed(mortal, [sense(sc, 0, [1, 2, 3]), estimate(sc, 2, 0, [1, 0, 0]), estimate(sc, 6, 0, [0, 1, 0]),
                  leader(sc, 0)])
    for k in (1, 2):  # dead: hears and says nothing
        assert feed(mortal, [sense(sc, k, [1, 2, 3]), estimate(sc, 6, k, [0, 1, 0]), leader(sc, k)]) == []
    assert feed(mortal, [estimate(sc, 2, back, [1, 0, 0]), estimate(sc, 6, back, [0, 1, 0])]) == []
    out = feed(mortal, [sense(sc, back, [1, 2, 3]), leader(sc, back)])
    assert mortal.restarts == 1
    assert [m.tick for _, m in out if isinstance(m, Command)] == [back]  # both early estimates were kept


def test_an_early_estimate_does_not_kill_the_robot_before_its_last_tick():
    """The kill at tick 1 comes after the robot's tick-0 act, even when a neighbour's tick-1
    estimate (sent a tick early) reaches it first."""
    from fxswarm.faults.plan import ProcessFault
    from fxswarm.faults.process import Mortal

    sc = load(PAPER_FAST)
    mortal = Mortal(lambda: AgentNode(sc, 1), [ProcessFault("agent:1", "kill", 1 * sc.dt, None)])
    feed(mortal, [sense(sc, 0, [1, 2, 3]), estimate(sc, 6, 0, [0, 1, 0]), leader(sc, 0)])
    assert feed(mortal, [estimate(sc, 2, 1, [1, 0, 0])]) == []
    out = feed(mortal, [estimate(sc, 2, 0, [1, 0, 0])])
    assert [m.tick for _, m in out if isinstance(m, Command)] == [0]
    assert feed(mortal, [sense(sc, 1, [1, 2, 3])]) == [] and mortal.state == "killed"


def test_the_leader_sends_the_next_ticks_state_on_each_tick_and_catches_up_after_a_gap():
    from fxswarm.leader.node import LeaderNode

    sc = load(PAPER_FAST)
    node = LeaderNode(sc)
    assert node.subscriptions() == [topics.sense_topic(1)]  # the tick, from the first robot's sensing

    def clock(k: int) -> list[int]:
        out = node.handle(*sense(sc, k, [1, 2, 3]))
        for _, m in out:
            np.testing.assert_array_equal(m.p0, sc.leader.position(m.t))
            assert m.t == m.tick * sc.dt
        return [m.tick for _, m in out]

    assert clock(0) == [0, 1]  # the first clock: its own tick's state and the next
    assert clock(1) == [2]
    assert clock(5) == [5, 6]  # after a gap (a restarted leader): this tick's too
    last = sc.ticks - 1
    assert clock(last - 1) == [last - 1, last] and clock(last) == []  # none for a tick never reached


def test_an_early_leader_state_waits_for_its_tick():
    sc = load(PAPER_FAST)
    early, plain = AgentNode(sc, 1), AgentNode(sc, 1)  # robot 1 is pinned
    tick0 = [sense(sc, 0, [1, 2, 3]), estimate(sc, 2, 0, [1, 0, 0]), estimate(sc, 6, 0, [0, 1, 0])]
    feed(early, tick0)
    feed(plain, tick0)
    assert feed(early, [leader(sc, 1)]) == []  # for tick 1: robot 1 still waits for tick 0's
    [(_, cmd_early)] = feed(early, [leader(sc, 0)])
    [(_, cmd_plain)] = feed(plain, [leader(sc, 0)])
    np.testing.assert_array_equal(cmd_early.v, cmd_plain.v)
    # On tick 1 the early state is held: robot 1 acts without waiting for the leader again.
    out = feed(early, [sense(sc, 1, [1, 2, 3]), estimate(sc, 2, 1, [1, 0, 0]), estimate(sc, 6, 1, [0, 1, 0])])
    assert [m.tick for _, m in out if isinstance(m, Command)] == [1]
    assert early.leader.tick == 1 and not early.ahead


def test_an_early_leader_state_does_not_kill_the_robot_before_its_last_tick():
    from fxswarm.faults.plan import ProcessFault
    from fxswarm.faults.process import Mortal

    sc = load(PAPER_FAST)
    mortal = Mortal(lambda: AgentNode(sc, 1), [ProcessFault("agent:1", "kill", 1 * sc.dt, None)])
    feed(mortal, [sense(sc, 0, [1, 2, 3]), estimate(sc, 2, 0, [1, 0, 0]), estimate(sc, 6, 0, [0, 1, 0])])
    assert feed(mortal, [leader(sc, 1)]) == []  # for the tick the robot dies at: it waits
    out = feed(mortal, [leader(sc, 0)])
    assert [m.tick for _, m in out if isinstance(m, Command)] == [0]
    assert feed(mortal, [sense(sc, 1, [1, 2, 3])]) == [] and mortal.state == "killed"
