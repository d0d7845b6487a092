"""Delay compensation: a robot carries a late neighbour estimate (or leader state) forward to its own
time at the leader velocity it estimates; current values, and ``delay_compensation = "none"``, are
used as they are (docs/design.md "Delay compensation")."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fxswarm.agents.node import AgentNode
from fxswarm.core import bus as topics
from fxswarm.core.messages import Estimate, LeaderState, Sense
from fxswarm.core.scenario import ScenarioError, load, parse

from support import PAPER_FAST


V_LEADER = np.array([0.1, -0.2, 1.0])


def holding(compensation: str, ages_ticks: dict[int, int], lockstep: bool = False) -> tuple[AgentNode, float]:
    """Robot 1 (neighbours 2 and 6, pinned) at tick 100, holding messages that many ticks old
    (key 0: the leader), having estimated the leader's velocity as ``V_LEADER``."""
    sc = dataclasses.replace(load(PAPER_FAST), delay_compensation=compensation)
    agent = AgentNode(sc, 1, lockstep=lockstep)
    agent.v_leader = V_LEADER.copy()
    k = 100
    now = k * sc.dt
    agent.handle(topics.sense_topic(1), Sense("world", 0, k, k, now, 1, np.zeros(3), None, None))
    for j, age in ages_ticks.items():
        tick = k - age
        if j == 0:
            agent.handle(topics.LEADER_STATE,
                         LeaderState("leader", 0, tick, tick, tick * sc.dt, np.array([0.0, 0, j])))
        else:
            agent.handle(topics.estimate_topic(j),
                         Estimate("agent", j, tick, tick, tick * sc.dt, j, np.array([0.0, 0, j])))
    return agent, now


def test_late_values_are_carried_forward_at_the_estimated_leader_velocity():
    agent, now = holding("leader-velocity", {2: 3, 6: 0, 0: 5})
    rows, weights = agent.held_estimates(now=now)
    dt = agent.sc.dt
    np.testing.assert_allclose(rows[0], [0, 0, 2] + 3 * dt * V_LEADER)  # robot 2, 3 ticks late
    np.testing.assert_array_equal(rows[1], [0, 0, 6])  # robot 6, current: as it is
    np.testing.assert_allclose(rows[2], [0, 0, 0] + 5 * dt * V_LEADER)  # the leader, 5 ticks late
    np.testing.assert_array_equal(weights, [1.0, 1.0, 1.0])


def test_without_compensation_late_values_are_used_as_held():
    agent, now = holding("none", {2: 3, 6: 0, 0: 5})
    rows, _ = agent.held_estimates(now=now)
    np.testing.assert_array_equal(rows, [[0, 0, 2], [0, 0, 6], [0, 0, 0]])


def test_the_command_is_the_one_the_carried_values_would_give_if_current():
    late, _ = holding("leader-velocity", {2: 4, 6: 4, 0: 4})
    current, now = holding("none", {2: 0, 6: 0, 0: 0})
    carried, _ = late.held_estimates(now=now)
    held_by_id = sorted(current.estimates.items())  # robots 2, 6: rows 0, 1; the leader: row 2
    current.estimates = {j: dataclasses.replace(e, ph=carried[i]) for i, (j, e) in enumerate(held_by_id)}
    current.leader = dataclasses.replace(current.leader, p0=carried[2])
    (_, cmd_late), (_, cmd_current) = late.act(late.sc.dt), current.act(current.sc.dt)
    np.testing.assert_allclose(cmd_late.v, cmd_current.v)
    np.testing.assert_allclose(late.ph, current.ph)
    held, _ = holding("none", {2: 4, 6: 4, 0: 4})
    _, cmd_held = held.act(held.sc.dt)
    assert not np.allclose(cmd_held.v, cmd_late.v)


def test_lock_step_without_faults_holds_only_current_values_so_nothing_changes():
    on, _ = holding("leader-velocity", {2: 0, 6: 0, 0: 0}, lockstep=True)
    off, _ = holding("none", {2: 0, 6: 0, 0: 0}, lockstep=True)
    [(_, cmd_on)] = on.act_tick()
    [(_, cmd_off)] = off.act_tick()
    est_on, est_off = cmd_on.carried_estimate(), cmd_off.carried_estimate()
    assert np.array_equal(cmd_on.v, cmd_off.v) and np.array_equal(est_on.ph, est_off.ph)


def test_an_unknown_compensation_names_the_field_and_the_choices():
    import tomllib
    data = tomllib.loads(PAPER_FAST.read_text())
    data.setdefault("controller", {})["delay_compensation"] = "psychic"
    with pytest.raises(ScenarioError, match=r"controller\.delay_compensation.*leader-velocity.*none"):
        parse(data, "x.toml")
