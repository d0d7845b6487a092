"""Real-time decisions of the sans-I/O nodes on a fake clock: no process, no Zenoh, no sleep.

The pacer (ticks on time, a late tick counted, no burst, patience after an early act), the
deadlines, staleness, the world's zero-order hold of a silent robot's command, its lock-step
tick timer and real-time hold for a lagging robot, the agent's staleness, extrapolation and
stop without sensing, the leader's once-per-time state.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from fxswarm.agents.node import FLAG_EXTRAPOLATING, FLAG_NO_LEADER, FLAG_NO_SENSING, FLAG_STALE_NEIGHBOUR, AgentNode
from fxswarm.core import bus as topics
from fxswarm.core.messages import Command, Estimate, LeaderState, Sense
from fxswarm.core.pacing import Deadline, Pacer, SimClock
from fxswarm.core.scenario import load
from fxswarm.faults.plan import ProcessFault, parse_faults
from fxswarm.leader.node import LeaderNode
from fxswarm.runtime.liveness import Liveness
from fxswarm.world.node import RealTimeWorld, RestartHold, TickTimer, WorldNode

PAPER_FAST = Path(__file__).resolve().parents[2] / "configs" / "paper-fast.toml"


class FakeClock:
    """A clock the test moves by hand, s."""

    def __init__(self, t: float = 100.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t

    def advance(self, s: float) -> None:
        self.t += s


@pytest.fixture(scope="module")
def sc():
    return load(PAPER_FAST)


# --- the pacer ------------------------------------------------------------------------------


def test_pacer_ticks_on_time_and_jitter_does_not_shift_the_schedule():
    clock = FakeClock(100.0)
    pacer = Pacer(0.1, clock)
    jitter = [0.0, 0.03, 0.09, 0.0, 0.05] * 10  # each act starts up to 90 ms after its deadline
    for k, late_by in enumerate(jitter):
        clock.t = 100.0 + k * 0.1 - 0.001
        assert not pacer.due() or k == 0
        clock.t = 100.0 + k * 0.1 + late_by
        assert pacer.due()
        assert pacer.on_time() == pytest.approx(late_by, abs=1e-9)
        assert pacer.next_due == pytest.approx(100.0 + (k + 1) * 0.1)  # deadlines stay at k * period
    assert pacer.late == 0


def test_pacer_waits_exactly_until_the_deadline():
    clock = FakeClock()
    pacer = Pacer(0.25, clock, start=clock() + 0.25)
    assert not pacer.due() and pacer.wait_s() == pytest.approx(0.25)
    clock.advance(0.2)
    assert not pacer.due() and pacer.wait_s() == pytest.approx(0.05)
    clock.advance(0.05)
    assert pacer.due() and pacer.wait_s() == 0.0
    assert pacer.on_time() == pytest.approx(0.0)
    assert pacer.next_due == pytest.approx(clock() + 0.25)


def test_a_late_tick_is_counted_and_the_schedule_slips_without_a_burst():
    clock = FakeClock()
    pacer = Pacer(0.1, clock)
    pacer.on_time()  # t = 0: on time; next due at 0.1
    clock.advance(0.35)  # stalled: the act due at 0.1 starts 0.25 s late
    assert pacer.due()
    assert pacer.on_time() == pytest.approx(0.25)
    assert pacer.late == 1
    clock.advance(0.001)
    assert not pacer.due()  # one act, not three to catch up
    assert pacer.next_due == pytest.approx(100.45)
    clock.advance(0.099)
    assert pacer.due() and pacer.on_time() == pytest.approx(0.0) and pacer.late == 1


def test_an_act_less_than_a_period_late_is_not_counted():
    clock = FakeClock()
    pacer = Pacer(0.1, clock)
    clock.advance(0.09)
    pacer.on_time()
    assert pacer.late == 0 and pacer.next_due == pytest.approx(100.1)


def test_an_early_act_on_fresh_data_pushes_the_timer_patience_periods_away():
    clock = FakeClock()
    pacer = Pacer(0.1, clock, patience=1.5)
    pacer.on_time()
    clock.advance(0.04)
    pacer.acted_early()
    clock.advance(0.1)
    assert not pacer.due()  # the timer would have fired at 0.1
    clock.advance(0.051)
    assert pacer.due()


def test_hold_skips_a_due_act_and_counts_it():
    clock = FakeClock()
    pacer = Pacer(0.1, clock)
    pacer.hold()
    assert pacer.held == 1 and not pacer.due()
    clock.advance(0.1)
    assert pacer.due()


def test_deadline_passes_after_its_timeout_and_restarts():
    clock = FakeClock()
    d = Deadline(1.0, clock)
    clock.advance(0.999)
    assert not d.passed() and d.wait_s() == pytest.approx(0.001)
    clock.advance(0.001)
    assert d.passed()
    d.restart()
    assert not d.passed() and d.wait_s() == pytest.approx(1.0)
    forever = Deadline(0.0, clock)
    clock.advance(1e9)
    assert not forever.passed() and forever.wait_s() == float("inf")


def test_a_message_is_stale_after_the_limit_of_world_time():
    clock = SimClock(speed=1.0, stale_after=5 * 0.01)  # 5 control periods
    assert not clock.is_stale(0.0)  # world time not known yet: nothing is judged stale
    clock.observe(0.05)
    assert not clock.is_stale(0.0)
    clock.observe(0.0500001)
    assert clock.is_stale(0.0) and not clock.is_stale(0.01)
    clock.observe(0.02)  # an old world message does not take time back
    assert clock.now() == 0.0500001


# --- the world --------------------------------------------------------------------------------


def command(robot: int, tick: int, t: float, v) -> Command:
    return Command("agent", robot, tick + 1, tick, t, robot, np.asarray(v, dtype=float), np.zeros(3), False)


def test_lockstep_tick_timer_closes_a_tick_only_after_its_deadline_and_counts_the_miss(sc):
    clock = FakeClock()
    world = WorldNode(sc, record=False)
    timer = TickTimer(world, 1.0, clock)
    world.start()
    for r in range(1, sc.n + 1):  # tick 0: everyone answers
        world.handle(topics.command_topic(r), command(r, 0, 0.0, [r, 0, 0]))
    assert world.tick == 1
    assert timer.check() == [] and timer.wait_s() == pytest.approx(1.0)  # a new tick restarts the deadline
    for r in range(1, sc.n):  # tick 1: robot n is silent
        world.handle(topics.command_topic(r), command(r, 1, sc.dt, [0, r, 0]))
    clock.advance(0.999)
    assert timer.check() == [] and world.tick == 1
    clock.advance(0.001)
    out = timer.check()
    assert out and world.tick == 2 and world.missed_ticks == 1 and world.misses.tolist() == [0] * (sc.n - 1) + [1]
    np.testing.assert_array_equal(world.v[sc.n - 1], [sc.n, 0, 0])  # its last command held
    np.testing.assert_array_equal(world.v[0], [0, 1, 0])
    assert timer.wait_s() == pytest.approx(1.0)


def test_lockstep_tick_timer_does_not_wait_for_a_robot_that_is_gone(sc):
    clock = FakeClock()
    world = WorldNode(sc, record=False)
    timer = TickTimer(world, 60.0, clock)
    world.start()
    for r in range(2, sc.n + 1):
        world.handle(topics.command_topic(r), command(r, 0, 0.0, [0, 0, 0]))
    assert timer.check(gone={3}) == [] and world.tick == 0  # robot 1 is silent but not gone
    assert timer.check(gone={1}) and world.tick == 1 and world.missed_ticks == 1


def test_a_planned_restart_holds_its_tick_until_the_new_process_is_up_then_asks_again():
    """Agent 2 killed at 1 s and restarted at 2 s (dt 0.01): the restart's own tick (200, at 2.00
    s, where fxswarm sim restarts it) is held until agent 2's token is up a second time; a token
    up all along (the kill not done yet) does not release it; the hold gives up after its limit."""
    clock = FakeClock()
    live = Liveness(clock)
    for name in ("agent/1", "agent/2"):
        live.change(name, True)
    plan = (ProcessFault("agent:2", "kill", 1.0, 2.0), ProcessFault("agent:1", "freeze", 0.5, 0.6),
            ProcessFault("agent:1", "kill", 3.0))  # neither a freeze nor a kill for good is held
    hold = RestartHold(plan, live.ups, 0.01, clock, limit_s=60.0)
    assert hold.check(199) == (False, [])  # at 1.99 s: not due yet
    assert hold.check(200) == (True, [])  # at 2.00 s: restart due, agent 2 still its old process
    live.change("agent/2", False)
    clock.advance(30.0)
    assert hold.check(200) == (True, [])
    live.change("agent/2", True)  # the new process
    assert hold.check(200) == (False, ["agent/2"]) and not hold.pending
    assert hold.check(201) == (False, [])

    late = RestartHold(plan[:1], {"agent/2": 1}, 0.01, clock, limit_s=60.0)
    assert late.check(200) == (True, [])
    clock.advance(59.9)
    assert late.check(200) == (True, [])
    clock.advance(0.1)
    assert late.check(200) == (False, []) and late.given_up == ["agent/2"] and not late.pending


def test_liveness_counts_each_time_a_token_comes_up_not_each_repeat():
    live = Liveness(FakeClock())
    live.change("agent/2", True)
    live.change("agent/2", True)  # heard twice (history, then the change): the same process
    live.change("agent/2", False)
    live.change("agent/2", True)
    assert live.ups == {"agent/2": 2}


def realtime_world(sc, clock, **kw) -> RealTimeWorld:
    rt = RealTimeWorld(WorldNode(sc, record=False), 0.01, clock, **kw)
    rt.start()
    return rt


def test_realtime_world_ticks_on_time_and_measures_latency(sc):
    clock = FakeClock()
    rt = realtime_world(sc, clock)
    robots = range(1, sc.n + 1)
    for k in range(20):
        clock.advance(0.004)
        for r in robots:
            rt.handle(topics.command_topic(r), command(r, k, k * sc.dt, [0, 0, 1]))
        clock.advance(0.006)
        assert rt.pacer.due()
        out = rt.tick(robots)
        assert out and rt.inner.tick == k + 1
        assert not rt.pacer.due()
    report = rt.report()
    assert report["late_ticks"] == 0 and report["held_ticks"] == 0
    assert report["achieved_speed"] == pytest.approx(1.0)
    assert report["sense_to_command"]["n"] == 20 * sc.n
    assert report["sense_to_command"]["p50_ms"] == pytest.approx(4.0)


def test_realtime_world_reports_each_robots_longest_silence(sc):
    """Robot 2 goes 0.5 s without a new command (a duplicate of an old one does not count), the
    others answer every 10 ms: the world's record says so, per robot."""
    clock = FakeClock()
    rt = realtime_world(sc, clock, max_lag=0)
    for k in range(100):
        clock.advance(0.01)
        for r in range(1, sc.n + 1):
            if r != 2 or not 20 <= k < 70:
                rt.handle(topics.command_topic(r), command(r, k, k * sc.dt, [0, 0, 1]))
            elif k == 40:  # robot 2's old command again, late
                rt.handle(topics.command_topic(r), command(r, 19, 19 * sc.dt, [0, 0, 1]))
        rt.tick(range(1, sc.n + 1))
    silence = rt.report()["longest_silence_s"]
    assert sorted(silence) == [str(r) for r in range(1, sc.n + 1)]
    assert silence["2"] == pytest.approx(0.51)
    assert all(silence[str(r)] == pytest.approx(0.01) for r in range(1, sc.n + 1) if r != 2)


def test_realtime_world_counts_a_late_tick(sc):
    clock = FakeClock()
    rt = realtime_world(sc, clock)
    clock.advance(0.035)  # the machine stalled: tick 1 was due at 0.01
    rt.tick()
    assert rt.report()["late_ticks"] == 1 and rt.inner.tick == 1
    assert not rt.pacer.due()


def test_realtime_world_holds_the_clock_for_a_lagging_robot_up_to_the_limit(sc):
    clock = FakeClock()
    rt = realtime_world(sc, clock, max_lag=3, hold_limit=0.045)
    alive = range(1, sc.n + 1)
    for k in range(3):  # robots 1..n-1 answer every tick; robot n never does
        for r in range(1, sc.n):
            rt.handle(topics.command_topic(r), command(r, k, k * sc.dt, [0, 0, 0]))
        clock.advance(0.01)
        rt.tick(alive)
    assert rt.inner.tick == 3 and rt.pacer.held == 0  # robot n no more than 3 ticks behind: no hold
    for r in range(1, sc.n):
        rt.handle(topics.command_topic(r), command(r, 3, 3 * sc.dt, [0, 0, 0]))
    held_for = 0.0
    while rt.inner.tick == 3:
        clock.advance(0.01)
        held_for += 0.01
        rt.tick(alive)
    assert rt.pacer.held == 5 and held_for == pytest.approx(0.06)  # held 0.05 s, then went on
    clock.advance(0.01)  # a robot whose process is gone is not waited for
    before = rt.inner.tick
    rt.tick(alive=[])
    assert rt.inner.tick == before + 1


def test_a_holding_world_asks_the_lagging_robot_again_each_period_and_goes_on_once_it_answers(sc):
    """Robot n's answers are lost: while the clock is held, the world sends it (and only it) its
    sensing of the current tick again, once a period, instead of waiting out the hold limit."""
    clock = FakeClock()
    rt = realtime_world(sc, clock, max_lag=3, hold_limit=1.0)
    alive = range(1, sc.n + 1)
    for k in range(4):  # robots 1..n-1 answer ticks 0..3; robot n's answers never arrive
        for r in range(1, sc.n):
            rt.handle(topics.command_topic(r), command(r, k, k * sc.dt, [0, 0, 0]))
        if k < 3:
            clock.advance(0.01)
            rt.tick(alive)
    sent_at_3 = dict(rt.sent)
    for held in (1, 2):
        clock.advance(0.01)
        out = rt.tick(alive)
        assert rt.inner.tick == 3 and rt.pacer.held == held
        assert [topic for topic, _ in out] == [topics.sense_topic(sc.n)]  # the lagging robot's, no one else's
        assert out[0][1] is sent_at_3[topics.sense_topic(sc.n)]  # tick 3's sensing, as first sent
    rt.handle(topics.command_topic(sc.n), command(sc.n, 3, 3 * sc.dt, [0, 0, 0]))  # asked again, it answers
    clock.advance(0.01)
    out = rt.tick(alive)
    assert rt.inner.tick == 4 and rt.pacer.held == 2
    assert sum(type(m) is Sense for _, m in out) == sc.n  # tick 4 for everyone
    assert rt.report()["sensing_sent_again"] == 2


def test_a_real_time_world_does_not_hold_for_a_robot_a_fault_plan_cuts_off(sc):
    """Robot n's commands to the world are cut from 0.03 s to 0.08 s: its silence is the
    experiment, so the clock goes on through the cut; once the cut is over, it holds again."""
    plan = parse_faults({"partitions": [{"start": 0.03, "end": 0.08, "links": [f"agent:{sc.n}->world"],
                                       "kinds": ["command"]}]}, 7, sc.n)
    assert plan.cut_off_from_world(sc.n, 0.05) and not plan.cut_off_from_world(sc.n, 0.08)
    assert not plan.cut_off_from_world(1, 0.05)
    clock = FakeClock()
    rt = realtime_world(sc, clock, max_lag=3, hold_limit=1.0, cut_off=plan.cut_off_from_world)
    alive = range(1, sc.n + 1)
    for k in range(8):  # robot n is silent throughout; the others answer every tick
        for r in range(1, sc.n):
            rt.handle(topics.command_topic(r), command(r, k, k * sc.dt, [0, 0, 0]))
        clock.advance(0.01)
        rt.tick(alive)
    assert rt.inner.tick == 8 and rt.pacer.held == 0  # 3 ticks behind from t = 0.03, but cut off until 0.08
    for r in range(1, sc.n):
        rt.handle(topics.command_topic(r), command(r, 8, 8 * sc.dt, [0, 0, 0]))
    clock.advance(0.01)
    assert rt.tick(alive) == [m for m in rt.sent if m[0] == topics.sense_topic(sc.n)]  # t = 0.08: held, asked
    assert rt.inner.tick == 8 and rt.pacer.held == 1


@pytest.mark.parametrize("rule, lost", [
    ({"drop": 1.0}, True),
    ({"burst": {"p_good_bad": 0.1, "p_bad_good": 0.5, "loss_good": 1.0}}, True),
    ({"drop": 0.99}, False),  # some get through: asking again is what helps
    ({"burst": {"p_good_bad": 0.1, "p_bad_good": 0.5}}, False),
])
def test_a_real_time_world_does_not_hold_for_a_robot_whose_link_rule_loses_every_command(sc, rule, lost):
    """A link rule that loses all of robot n's commands to the world cuts it off for the whole
    run, like a partition that never ends: the world does not hold a second a tick for it."""
    plan = parse_faults({"links": [{"link": f"agent:{sc.n}->world", "kinds": ["command"], **rule}]}, 7, sc.n)
    assert plan.cut_off_from_world(sc.n, 0.0) is lost and plan.cut_off_from_world(sc.n, 9.0) is lost
    assert not plan.cut_off_from_world(1, 0.0)
    clock = FakeClock()
    rt = realtime_world(sc, clock, max_lag=3, hold_limit=1.0, cut_off=plan.cut_off_from_world)
    alive = range(1, sc.n + 1)
    for k in range(6):  # robot n is never heard from
        for r in range(1, sc.n):
            rt.handle(topics.command_topic(r), command(r, k, k * sc.dt, [0, 0, 0]))
        clock.advance(0.01)
        rt.tick(alive)
    assert (rt.inner.tick, rt.pacer.held) == ((6, 0) if lost else (3, 3))  # held from tick 3


def leader_state(sc, t: float) -> tuple[str, LeaderState]:
    return topics.LEADER_STATE, LeaderState("leader", 0, 1, 0, t, sc.leader.position(t), None)


def all_robots_answer(rt, sc, ticks: int, clock: FakeClock, alive, leader_alive: bool = True, leader_upto: float = -1.0):
    """Every robot answers each of ``ticks`` more ticks; the leader's states get as far as
    ``leader_upto`` s of the world's time."""
    for _ in range(ticks):
        k = rt.inner.tick
        for r in range(1, sc.n + 1):
            rt.handle(topics.command_topic(r), command(r, k, k * sc.dt, [0, 0, 0]))
        if k * sc.dt <= leader_upto + 1e-9:
            rt.heard_leader(*leader_state(sc, k * sc.dt))
        clock.advance(0.01)
        rt.tick(alive, leader_alive)


def test_a_real_time_world_holds_the_clock_for_a_lagging_leader_and_asks_it_again(sc):
    """The leader's states stop at 0.02 s (its process starved of CPU; they are stamped with the
    world's time as the leader last heard it): more than max_lag ticks on, the world holds its
    clock and sends again the sensing the leader keeps time by, as for a lagging robot, and goes
    on once a state of the current time arrives. Without it, the pinned robots dropped the
    leader's stale states and the swarm flew on without its anchor (docs/design.md "Real time")."""
    assert RealTimeWorld(WorldNode(sc, record=False), 0.01, FakeClock()).leader_clock \
        == LeaderNode(sc).subscriptions()[0]
    clock = FakeClock()
    rt = realtime_world(sc, clock, max_lag=3, hold_limit=1.0)
    alive = range(1, sc.n + 1)
    all_robots_answer(rt, sc, 7, clock, alive, leader_upto=0.02)
    assert rt.inner.tick == 6 and rt.pacer.held == 1  # 3 ticks behind (tick 5) is no lag; 4 (tick 6) is
    for held in (2, 3):
        clock.advance(0.01)
        out = rt.tick(alive, True)
        assert rt.inner.tick == 6 and rt.pacer.held == held
        assert [topic for topic, _ in out] == [rt.leader_clock]
        assert out[0][1] is dict(rt.sent)[rt.leader_clock]  # tick 6's sensing, as first sent
    rt.heard_leader(*leader_state(sc, 6 * sc.dt))
    clock.advance(0.01)
    out = rt.tick(alive, True)
    assert rt.inner.tick == 7 and sum(type(m) is Sense for _, m in out) == sc.n
    assert rt.report()["held_for"] == {"leader": 3} and rt.report()["sensing_sent_again"] == 3


@pytest.mark.parametrize("case", ["never heard", "process gone", "frozen by the plan", "its sensing cut"])
def test_a_real_time_world_does_not_hold_for_a_leader_it_cannot_or_should_not_wait_for(sc, case):
    """Not waited for: a leader never heard (a world that may not hear it, under an access policy
    from before it did, would otherwise hold every tick), one whose process is gone, one the
    plan freezes, one whose clock source the plan cuts."""
    faults = {"frozen by the plan": {"processes": [{"target": "leader", "freeze": 0.0, "thaw": 9.0}]},
              "its sensing cut": {"partitions": [{"start": 0.0, "end": 9.0, "links": ["world->leader"],
                                                  "kinds": ["sense"]}]}}.get(case, {})
    plan = parse_faults(faults, 7, sc.n)
    assert plan.cut_off_from_world(0, 0.05) is bool(faults) and not plan.cut_off_from_world(1, 0.05)
    clock = FakeClock()
    rt = realtime_world(sc, clock, max_lag=3, hold_limit=1.0, cut_off=plan.cut_off_from_world)
    all_robots_answer(rt, sc, 10, clock, range(1, sc.n + 1), leader_alive=case != "process gone",
                      leader_upto=-1.0 if case == "never heard" else 0.0)
    assert rt.inner.tick == 10 and rt.pacer.held == 0 and rt.report()["held_for"] == {}


def test_a_plan_that_freezes_a_robot_cuts_it_off_from_the_world_while_frozen(sc):
    plan = parse_faults({"processes": [{"target": "agent:2", "freeze": 1.0, "thaw": 2.0},
                                       {"target": "agent:3", "kill": 1.0}]}, 7, sc.n)
    assert [plan.cut_off_from_world(2, t) for t in (0.5, 1.0, 1.99, 2.0)] == [False, True, True, False]
    assert plan.cut_off_from_world(3, 5.0) and not plan.cut_off_from_world(0, 1.5)


def test_the_world_holds_a_silent_robots_last_command_then_stops_it(sc):
    clock = FakeClock()
    rt = realtime_world(sc, clock)
    world = rt.inner
    for r in range(1, sc.n + 1):
        rt.handle(topics.command_topic(r), command(r, 0, 0.0, [0.5, 0, 0]))
    limit_ticks = round(world.limits.silent_hold / sc.dt)  # 0.5 s: 50 ticks
    p_before = world.p[0].copy()
    for k in range(limit_ticks + 5):
        if k:  # robot 1 falls silent after tick 0; the others go on
            for r in range(2, sc.n + 1):
                rt.handle(topics.command_topic(r), command(r, k, k * sc.dt, [0.5, 0, 0]))
        clock.advance(0.01)
        rt.tick()
        if k < limit_ticks:
            np.testing.assert_array_equal(world.v[0], [0.5, 0, 0])  # zero-order hold
    np.testing.assert_array_equal(world.v[0], [0, 0, 0])  # silent longer than the limit: held at zero
    assert world.held_at_zero[0] > 0 and world.held_at_zero[1:].sum() == 0
    assert world.p[0][0] - p_before[0] == pytest.approx(limit_ticks * sc.dt * 0.5, abs=sc.dt * 0.5)


# --- the agent --------------------------------------------------------------------------------


def sense(sc, k: int) -> Sense:
    return Sense("world", 0, k + 1, k, k * sc.dt, 1, np.array([0.0, 0.0, 0.0]), None, None)


def test_agent_integrates_the_world_time_since_its_last_act_and_not_twice(sc):
    agent = AgentNode(sc, 1, lockstep=False)
    assert agent.act_realtime(0.0) == []  # nothing before sensing
    agent.handle(topics.sense_topic(1), sense(sc, 0))
    assert agent.fresh_sensing()
    out = agent.act_realtime(0.0)
    assert [topic for topic, _ in out] == [topics.command_topic(1)]  # the new estimate rides on it
    assert out[0][1].carried_estimate().t == 0.0 and np.array_equal(out[0][1].est_ph, agent.ph)
    assert not agent.fresh_sensing()
    assert agent.act_realtime(0.0) == []  # world time has not moved: nothing to integrate
    ph = agent.ph.copy()
    agent.handle(topics.sense_topic(1), sense(sc, 3))  # missed two ticks: integrates all three
    _, cmd = agent.act_realtime(3 * sc.dt)[0]
    rate = (agent.ph - ph) / (3 * sc.dt)
    assert np.all(np.isfinite(rate)) and agent.since_sense_s == pytest.approx(3 * sc.dt)


def test_a_real_time_agent_asked_again_for_a_tick_sends_its_answer_again_numbered_anew(sc):
    """The world holding its clock sends a robot the sensing it already acted on: the robot's
    answer was lost, so it sends that command again (a new transmission: a new number), without
    acting again (time has not moved). In lock-step a repeated sensing gets no answer."""
    agent = AgentNode(sc, 1, lockstep=False)
    agent.handle(topics.sense_topic(1), sense(sc, 0))
    [(topic, first)] = agent.act_realtime(0.0)
    ph, acted_t = agent.ph.copy(), agent.acted_t
    seqs = []
    for _ in range(2):
        [(again_topic, again)] = agent.handle(topics.sense_topic(1), sense(sc, 0))
        assert again_topic == topic == topics.command_topic(1)
        assert dataclasses.replace(again, seq=first.seq) == first  # the same command, field for field
        seqs.append(again.seq)
    assert seqs == [first.seq + 1, first.seq + 2]
    np.testing.assert_array_equal(agent.ph, ph)
    assert agent.acted_t == acted_t and not agent.fresh_sensing()
    assert agent.handle(topics.sense_topic(1), sense(sc, 1)) == [] and agent.fresh_sensing()  # a new tick: act

    lockstep = AgentNode(sc, 3, lockstep=True)  # robot 3 is not pinned: its neighbours 2 and 4
    lockstep.handle(topics.sense_topic(3), dataclasses.replace(sense(sc, 0), robot=3))
    for j in sc.neighbours(3):
        lockstep.handle(topics.estimate_topic(j), Estimate("agent", j, 1, 0, 0.0, j, np.zeros(3)))
    assert lockstep.acted_tick == 0
    assert lockstep.handle(topics.sense_topic(3), dataclasses.replace(sense(sc, 0), robot=3)) == []


def test_agent_holds_a_silent_neighbour_until_stale_then_extrapolates(sc):
    """Robot 1 (neighbours 2 and 6, pinned) hears them once at t = 0, then only its sensing:
    it uses the held values for the staleness limit (50 periods), then leaves them out and,
    hearing nobody, carries its estimate forward in a straight line."""
    agent = AgentNode(sc, 1, lockstep=False)
    agent.handle(topics.sense_topic(1), sense(sc, 0))
    for j in (2, 6):
        agent.handle(topics.estimate_topic(j), Estimate("agent", j, 1, 0, 0.0, j, np.array([0.0, 0.0, 1.0])))
    agent.handle(topics.LEADER_STATE, LeaderState("leader", 0, 1, 0, 0.0, np.array([0.0, 0.0, 0.5])))
    limit = round(agent.limits.staleness / sc.dt)  # 0.5 s: 50 control periods
    flags, ph = [], []
    for k in range(limit + 10):
        agent.handle(topics.sense_topic(1), sense(sc, k))
        [(_, cmd)] = agent.act_realtime(k * sc.dt)
        flags.append(cmd.flags)
        ph.append(agent.ph.copy())
    assert all(f == 0 for f in flags[:limit + 1]), flags[:limit + 1]  # held, not stale, up to the limit
    stale = FLAG_STALE_NEIGHBOUR | FLAG_NO_LEADER | FLAG_EXTRAPOLATING
    assert all(f == stale for f in flags[limit + 1:]), flags[limit + 1:]
    assert agent.degraded_ticks["extrapolating"] == 9
    steps = np.diff(np.array(ph[limit + 1:]), axis=0)  # extrapolating: equal steps of dt * velocity
    np.testing.assert_allclose(steps, np.tile(sc.dt * agent.v_extrapolate, (len(steps), 1)), atol=1e-15)
    assert np.linalg.norm(agent.v_extrapolate) > 0


def test_agent_without_sensing_past_the_limit_commands_zero(sc):
    agent = AgentNode(sc, 1, lockstep=False)
    agent.handle(topics.sense_topic(1), sense(sc, 0))
    agent.handle(topics.estimate_topic(2), Estimate("agent", 2, 1, 0, 0.0, 2, np.array([3.0, 0.0, 0.0])))
    limit = round(agent.limits.sense_timeout / sc.dt)
    cmds = [agent.act_realtime(k * sc.dt)[0][1] for k in range(limit + 3)]  # time moves, no new sensing
    assert all(not c.flags & FLAG_NO_SENSING and np.any(c.v) for c in cmds[:limit + 1])
    assert all(c.flags & FLAG_NO_SENSING and not np.any(c.v) for c in cmds[limit + 1:])


# --- the leader -------------------------------------------------------------------------------


def test_leader_says_p0_once_per_world_time(sc):
    leader = LeaderNode(sc)
    (topic, first), = leader.act_realtime(0.5)
    assert topic == topics.LEADER_STATE and first.t == 0.5
    np.testing.assert_array_equal(first.p0, sc.leader.position(0.5))
    assert leader.act_realtime(0.5) == []  # p0 only moves with the world's time
    (_, second), = leader.act_realtime(0.51)
    assert (first.tick, second.tick) == (0, 1) and second.seq == first.seq + 1


def test_lockstep_agent_acts_past_a_gone_neighbour_only(sc):
    """Robot 1 holds tick 0's sensing, robot 2's estimate and the leader's state; robot 6 is
    missing. It waits while 6's process is alive, and acts on what it holds once 6 is gone."""
    agent = AgentNode(sc, 1, lockstep=True)
    agent.handle(topics.sense_topic(1), sense(sc, 0))
    agent.handle(topics.estimate_topic(2), Estimate("agent", 2, 1, 0, 0.0, 2, np.array([0.0, 0.0, 1.0])))
    agent.handle(topics.LEADER_STATE, LeaderState("leader", 0, 1, 0, 0.0, np.array([0.0, 0.0, 0.5])))
    assert agent.waiting_for(0) == ["agent:6"]
    assert agent.act_past_the_gone({"agent:2", "leader"}) == []
    out = agent.act_past_the_gone({"agent:6"})
    assert [topic for topic, _ in out][:1] == [topics.command_topic(1)] and agent.acted_tick == 0
    assert agent.act_past_the_gone({"agent:6"}) == []  # acted once on this tick


def test_lockstep_messages_for_a_tick_already_left_are_late(sc):
    agent = AgentNode(sc, 1, lockstep=True)
    agent.handle(topics.sense_topic(1), sense(sc, 5))
    old = Estimate("agent", 2, 1, 4, 4 * sc.dt, 2, np.zeros(3))
    current = Estimate("agent", 2, 2, 5, 5 * sc.dt, 2, np.zeros(3))
    assert agent.is_late(old) and not agent.is_late(current)
    world = WorldNode(sc, record=False)
    world.start()
    world.tick = 3
    assert world.is_late(command(1, 2, 0.02, [0, 0, 0])) and not world.is_late(command(1, 3, 0.03, [0, 0, 0]))
