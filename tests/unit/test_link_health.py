"""Link health measured at the receiver: sequence gaps and estimate ages, from the agent's
Command through the world's WorldState (the recorder's part is in test_logger_recording)."""

from __future__ import annotations

import numpy as np
import pytest

from fxswarm.agents.links import InLinks
from fxswarm.agents.node import AgentNode
from fxswarm.core import bus as topics
from fxswarm.core.messages import Command, Estimate, LeaderState, Sense, WireError, WorldState, decode, encode
from fxswarm.core.scenario import load
from fxswarm.launch.sim import Simulation
from fxswarm.core.scenario import directed_links
from fxswarm.world.node import WorldNode

from support import PAPER_FAST, with_faults


def test_gaps_count_as_missed_late_arrivals_are_taken_back_duplicates_change_nothing():
    links = InLinks([2, 6, 0])
    for seq in (1, 2, 3, 3, 6):  # 3 twice (a duplicate), then 4 and 5 missing
        links.heard(2, seq, tick=seq - 1)
    assert links.drops[0] == 2 and links.last_seq[0] == 6
    links.heard(2, 4, tick=3)  # 4 was late, not lost
    assert links.drops[0] == 1
    links.heard(2, 4, tick=3)  # and again: a duplicate of a late one
    assert links.drops[0] == 1
    assert links.drops[1:] == [0, 0]
    links.heard(6, 3, tick=2)  # the first two of robot 6's never came
    assert links.drops == [1, 2, 0]
    links.heard(0, 1, tick=0)
    assert links.drops == [1, 2, 0]


def test_a_restarted_sender_starts_a_new_count():
    links = InLinks([1])
    for seq in range(1, 11):
        links.heard(1, seq, tick=seq - 1)
    links.heard(1, 1, tick=50)  # numbering starts again, later: a new process, not a late message
    links.heard(1, 3, tick=52)
    assert links.drops[0] == 1 and links.last_seq[0] == 3


def test_command_reports_ages_and_drops_per_in_link_in_order():
    sc = load(PAPER_FAST)
    agent = AgentNode(sc, 1)  # neighbours 2 and 6, pinned
    assert agent.neighbour_ids == [2, 6] and agent.pinned
    z = np.zeros(3)
    for k in range(4):
        agent.handle(topics.sense_topic(1), Sense("world", 0, k + 1, k, k * sc.dt, 1, z, None, None))
        if k != 2:  # robot 6's tick-2 estimate never arrives (nothing waits for it: acted below)
            agent.handle(topics.estimate_topic(6), Estimate("agent", 6, k + 1, k, k * sc.dt, 6, z))
        agent.handle(topics.LEADER_STATE, LeaderState("leader", 0, k + 1, k, k * sc.dt, z))
        out = agent.handle(topics.estimate_topic(2), Estimate("agent", 2, k + 1, k, k * sc.dt, 2, z))
        if k == 2:
            out = [agent.act(sc.dt)]
        (_, cmd), = [o for o in out if isinstance(o[1], Command)]
        if k == 2:
            assert cmd.link_age == (0, 1, 0) and cmd.link_drops == (0, 0, 0)  # the gap is not seen yet
    assert cmd.link_age == (0, 0, 0) and cmd.link_drops == (0, 1, 0)
    back = decode(encode(cmd))
    assert back.link_age == cmd.link_age and back.link_drops == cmd.link_drops


def test_wire_rejects_malformed_link_fields():
    z = np.zeros(3)
    good = Command("agent", 1, 1, 0, 0.0, 1, z, z, False, 0, (0, 1, 2), (0, 0, 5))
    assert decode(encode(good)).link_drops == (0, 0, 5)
    for age, drops in (((0, 1), (0, 0, 5)), ((0, -1, 2), (0, 0, 0)), ((0, 1.0, 2), (0, 0, 0)),
                       ((0, True, 2), (0, 0, 0)), ((0, 1, 2), (0, 0, 2**60))):
        with pytest.raises(WireError, match="link"):
            decode(encode(Command("agent", 1, 1, 0, 0.0, 1, z, z, False, 0, age, drops)))
    n = 2
    state = WorldState("world", 0, 1, 0, 0.0, np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n),
                       np.zeros(n, bool), np.zeros((0, 3)), np.array([1, 2]), np.array([3]))
    with pytest.raises(WireError, match="link"):
        decode(encode(state))


def test_world_ages_a_silent_robots_report_and_ignores_a_wrong_sized_one():
    sc = load(PAPER_FAST)
    world = WorldNode(sc, record=False)
    world.start()
    z = np.zeros(3)
    degree = world.in_degree
    for r in sc.robots:
        m = degree[r.id - 1]
        out = world.handle(topics.command_topic(r.id), Command("agent", r.id, 1, 0, 0.0, r.id, z, z, False, 0,
                                                               (1,) * m, (r.id,) * m))
    state = next(m for _, m in out if isinstance(m, WorldState))
    links = directed_links(sc)
    assert len(state.link_age) == len(links) == sum(degree)
    assert [d for d, (_, i) in zip(state.link_drops, links)] == [i for _, i in links]
    # Tick 1: robot 3 is silent and robot 4 reports one link too few: 3's links age, 4's keep tick 0's report.
    for r in sc.robots:
        if r.id == 3:
            continue
        m = degree[r.id - 1] - (r.id == 4)
        world.handle(topics.command_topic(r.id), Command("agent", r.id, 2, 1, sc.dt, r.id, z, z, False, 0,
                                                         (0,) * m, (0,) * m))
    (_, state), *_ = world.timeout()
    assert world.link_reports_invalid == 1
    by_link = dict(zip(links, zip(state.link_age.tolist(), state.link_drops.tolist())))
    assert by_link[(2, 3)] == (2, 3) and by_link[(4, 3)] == (2, 3)  # held, one tick older
    assert by_link[(3, 4)] == (2, 4)  # robot 4's bad report was not taken: its tick-0 report, one tick older
    assert by_link[(1, 2)] == (0, 0)


def test_receiver_side_drops_reach_the_world_state_for_that_link_only():
    """A partition cutting 2 -> 3 at robot 3's inbox for 1 s: robot 3 counts exactly the
    estimates its inbox dropped, the world publishes them on link (2, 3), nowhere else."""
    sc = with_faults({"partitions": [{"start": 1.0, "end": 2.0, "links": ["agent:2->agent:3"],
                                      "kinds": ["estimate"]}]}, duration=3.0)
    sim = Simulation(sc)
    states: list[WorldState] = []
    sim.bus.subscribe(topics.WORLD_STATE, lambda topic, msg: states.append(msg))
    summary = sim.run()
    dropped = summary["faults"]["links"]["agent:2->agent:3/estimate"]["dropped"]
    assert dropped == 100
    links = directed_links(sc)
    k23 = links.index((2, 3))
    final = states[-1]
    assert final.link_drops[k23] == dropped
    assert final.link_drops.sum() == dropped
    ages = np.array([s.link_age[k23] for s in states])
    t = np.array([s.t for s in states])
    assert ages[(t > 1.5) & (t < 1.99)].min() > 40  # robot 3 holds robot 2's estimate from before 1 s
    assert ages[t < 0.99].max() == 0 and ages[t > 2.01].max() == 0
    others = np.delete(np.stack([s.link_age for s in states]), k23, axis=1)
    assert others.max() == 0
