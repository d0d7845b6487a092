"""The fault plan: parsing with named errors, pure seeded fates, burst statistics, the inbox filter."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from fxswarm.agents.node import AgentNode
from fxswarm.core.messages import Clock, Command, Estimate, LeaderState, Sense
from fxswarm.core.scenario import ScenarioError, load, parse
from fxswarm.faults.inbox import FaultyInbox, ReplayedSense, wrap
from fxswarm.faults.plan import FAULTABLE_KINDS, Cut, FaultPlan, LinkRule, ProcessFault, parse_faults, plan_of, resolve
from fxswarm.faults.process import Mortal, ProcessSchedule

from support import PAPER_FAST


def plan(table: dict, n: int = 6) -> FaultPlan:
    return parse_faults(table, 1, n, "x.toml")


@pytest.mark.parametrize("table, message", [
    ({"links": [{"link": "agent:1-agent:2", "drop": 0.1}]}, "x.toml: faults.links[0].link: expected a link 'SRC->DST'"),
    ({"links": [{"link": "agent:x->*"}]}, "faults.links[0].link: expected endpoints"),
    ({"links": [{"link": "agent:9->world", "drop": 0.1}]},
     "faults.links[0].link: expected endpoints 'agent:<id>' with id in 1..6 (the scenario's robots), got 'agent:9->world'"),
    ({"partitions": [{"start": 1, "end": 2, "isolate": [1], "links": ["world->agent:0"]}]},
     "faults.partitions[0].links[0]: expected endpoints 'agent:<id>' with id in 1..6"),
    ({"links": [{"link": "*->*", "drop": 1.5}]}, "faults.links[0].drop: expected a probability in [0, 1], got 1.5"),
    ({"links": [{"link": "*->*", "delay": -1}]}, "faults.links[0].delay: expected a number >= 0"),
    ({"links": [{"link": "*->*", "kinds": ["clock"]}]}, "faults.links[0].kinds: expected a list of message kinds"),
    ({"links": [{"link": "*->*", "burst": {"p_good_bad": 0.1}}]}, "faults.links[0].burst.p_bad_good: expected a number"),
    ({"links": [{"link": "*->*", "loss": 0.1}]}, "faults.links[0].loss: expected no such field here"),
    ({"partitions": [{"start": 1, "end": 2}]}, "faults.partitions[0].isolate: expected robots to isolate"),
    ({"partitions": [{"start": 3, "end": 2, "isolate": [1]}]}, "faults.partitions[0].end: expected an end after"),
    ({"partitions": [{"start": 1, "end": 2, "isolate": [9]}]}, "faults.partitions[0].isolate: expected a list of robot ids in 1..6"),
    ({"processes": [{"target": "agent:2", "kill": 1, "freeze": 2}]}, "faults.processes[0].kill: expected exactly one"),
    ({"processes": [{"target": "agent:7", "kill": 1}]}, "faults.processes[0].target: expected 'leader' or 'agent:<id>'"),
    ({"processes": [{"target": "agent:2", "kill": 3, "restart": 2}]}, "faults.processes[0].restart: expected a time after"),
    ({"processes": [{"target": "agent:2", "kill": 3, "thaw": 4}]}, "faults.processes[0].thaw: expected 'restart' with 'kill'"),
    ({"staleness": 0}, "faults.staleness: expected a number > 0"),
    ({"lossy": True}, "faults.lossy: expected no such field here"),
])
def test_every_bad_faults_table_is_refused_naming_file_field_and_expected_form(table, message):
    with pytest.raises(ScenarioError) as exc:
        plan(table)
    assert message in str(exc.value)


def test_scenario_file_faults_are_checked_through_the_scenario_and_cli_specs_equal_the_toml_form():
    data = tomllib.loads(PAPER_FAST.read_text())
    sc = parse(data, "paper-fast.toml")
    specs = ["agent:*->agent:4 drop=0.2 delay=0.05 kinds=estimate", "leader->* burst=0.1,0.3",
             "partition 10-15 isolate=3", "leader-outage 5-8", "kill agent:2 at=10 restart=12", "seed=5",
             "staleness=0.3"]
    from_cli = resolve(sc, specs)
    data["faults"] = {
        "seed": 5, "staleness": 0.3,
        "links": [{"link": "agent:*->agent:4", "drop": 0.2, "delay": 0.05, "kinds": ["estimate"]},
                  {"link": "leader->*", "burst": {"p_good_bad": 0.1, "p_bad_good": 0.3}}],
        "partitions": [{"start": 10, "end": 15, "isolate": [3]}],
        "leader_outages": [{"start": 5, "end": 8}],
        "processes": [{"target": "agent:2", "kill": 10.0, "restart": 12}],
    }
    from_toml = plan_of(parse(data, "paper-fast.toml"))
    assert from_cli == from_toml
    clean = load(PAPER_FAST)
    with pytest.raises(ScenarioError, match=r"--fault 'partition 10': expected 'partition START-END"):
        resolve(clean, ["partition 10"])
    with pytest.raises(ScenarioError, match=r"--fault '\*->\* drop=3': faults.links\[0\].drop: expected a probability"):
        resolve(clean, ["*->* drop=3"])


def test_fates_are_pure_functions_of_seed_link_kind_and_tick():
    a = plan({"seed": 3, "links": [{"link": "agent:*->agent:*", "drop": 0.3, "delay": 0.02, "jitter": 0.05,
                                    "duplicate": 0.1}]})
    b = plan({"seed": 3, "links": [{"link": "agent:*->agent:*", "drop": 0.3, "delay": 0.02, "jitter": 0.05,
                                    "duplicate": 0.1}]})
    other = plan({"seed": 4, "links": [{"link": "agent:*->agent:*", "drop": 0.3}]})
    ticks = range(4000)
    fa = [a.fate("agent:1", "agent:2", "estimate", k, k * 0.01) for k in ticks]
    assert fa == [b.fate("agent:1", "agent:2", "estimate", k, k * 0.01) for k in reversed(ticks)][::-1]
    lost = np.array([f.lost for f in fa])
    assert 0.26 < lost.mean() < 0.34  # iid loss at 0.3 (4000 draws: +-4 sigma)
    lost_other = np.array([other.fate("agent:1", "agent:2", "estimate", k, 0.0).lost for k in ticks])
    assert (lost != lost_other).mean() > 0.3  # another seed, another pattern
    lost_reverse = np.array([a.fate("agent:2", "agent:1", "estimate", k, 0.0).lost for k in ticks])
    assert (lost != lost_reverse).mean() > 0.3  # each direction of a link has its own fate
    delays = np.array([f.delay for f in fa if not f.lost])
    assert delays.min() >= 0.02 and delays.max() < 0.07 and delays.std() > 0.01
    assert 0.07 < np.mean([f.copies == 2 for f in fa if not f.lost]) < 0.13
    # A rule without `kinds` applies to every kind: each is lost at the rule's rate on its own draws.
    for kind in FAULTABLE_KINDS:
        lost_kind = np.array([a.fate("agent:1", "agent:2", kind, k, 0.0).lost for k in ticks])
        assert 0.26 < lost_kind.mean() < 0.34, kind
    # ... and one that names its kinds spares the others.
    only = plan({"seed": 3, "links": [{"link": "agent:*->agent:*", "drop": 0.3, "kinds": ["estimate"]}]})
    assert not any(only.fate("agent:1", "agent:2", "sense", k, 0.0).lost for k in ticks)
    assert a.fate("leader", "agent:1", "leader", 5, 0.05).lost is False  # no rule for the leader


def test_gilbert_elliott_loss_has_its_stationary_rate_and_burst_length():
    p_gb, p_bg, loss_bad = 0.05, 0.25, 0.9
    p = plan({"links": [{"link": "*->*", "burst": {"p_good_bad": p_gb, "p_bad_good": p_bg, "loss_bad": loss_bad}}]})
    lost = np.array([p.fate("agent:1", "agent:2", "estimate", k, 0.0).lost for k in range(40_000)])
    bad_share = p_gb / (p_gb + p_bg)
    assert abs(lost.mean() - bad_share * loss_bad) < 0.02
    runs = np.diff(np.flatnonzero(np.diff(np.concatenate([[0], lost.astype(int), [0]]))))[::2]
    assert runs.mean() > 2.5  # bursty: iid loss at the same rate would give runs of ~1.2
    # Asked out of order (as another process might), the chain gives the same answer.
    q = plan({"links": [{"link": "*->*", "burst": {"p_good_bad": p_gb, "p_bad_good": p_bg, "loss_bad": loss_bad}}]})
    assert [q.fate("agent:1", "agent:2", "estimate", k, 0.0).lost for k in (9000, 5, 300)] == \
        [bool(lost[9000]), bool(lost[5]), bool(lost[300])]


def test_partitions_and_outages_cut_radio_links_only_inside_their_window():
    cut = Cut(1.0, 2.0, isolate=(3,))
    assert cut.cuts("agent:2", "agent:3", "estimate", 1.5) and cut.cuts("agent:3", "agent:4", "estimate", 1.0)
    assert cut.cuts("leader", "agent:3", "leader", 1.5)
    assert not cut.cuts("agent:2", "agent:3", "estimate", 2.0) and not cut.cuts("agent:2", "agent:3", "estimate", 0.9)
    assert not cut.cuts("world", "agent:3", "sense", 1.5)  # sensing is physics, not radio
    assert not cut.cuts("agent:3", "world", "command", 1.5)
    assert not cut.cuts("agent:1", "agent:2", "estimate", 1.5)
    outage = plan({"leader_outages": [{"start": 5, "end": 6}]})
    assert outage.fate("leader", "agent:1", "leader", 550, 5.5).cause == "cut"
    assert not outage.fate("leader", "agent:1", "leader", 650, 6.5).lost


def _estimate(j: int, k: int, ph=(0.0, 0.0, 0.0)) -> Estimate:
    return Estimate("agent", j, k + 1, k, k * 0.01, j, np.array(ph, dtype=float))


def test_the_agent_does_not_wait_for_what_its_filter_declared_lost_or_delayed():
    sc = load(PAPER_FAST)  # robot 3: neighbours 2 and 4, not pinned
    p = FaultPlan(seed=1, rules=(LinkRule("agent:2", "agent:3", ("estimate",), drop=0.5),
                                 LinkRule("agent:4", "agent:3", ("estimate",), delay=0.02)))
    inbox = FaultyInbox(AgentNode(sc, 3), "agent:3", p, sc.dt)
    agent = inbox.node
    commands = 0
    for k in range(50):
        sense = Sense("world", 0, k + 1, k, k * 0.01, 3, np.zeros(3), None, None)
        out = inbox.handle("world/sense/3", sense)
        out += inbox.handle("agent/2/estimate", _estimate(2, k))
        out += inbox.handle("agent/4/estimate", _estimate(4, k))
        cmds = [m for t, m in out if isinstance(m, Command)]  # (its first estimate goes on the same key)
        assert len(cmds) == 1 and cmds[0].tick == k, k  # acted once per tick, never stuck
        commands += 1
        held4 = agent.estimates.get(4)
        assert held4 is None or held4.tick == k - 2  # two ticks late, exactly
    counts = inbox.links
    assert counts["agent:2->agent:3/estimate"].dropped > 10
    assert counts["agent:4->agent:3/estimate"].delayed == 50


def test_a_lost_sensing_message_still_starts_the_tick_but_replays_old_content_then_stops_the_robot():
    sc = load(PAPER_FAST)
    p = FaultPlan(seed=1, cuts=(Cut(0.05, 10.0, (("world", "agent:3"),), (), ("sense",)),))
    inbox = FaultyInbox(AgentNode(sc, 3), "agent:3", p, sc.dt)
    speeds = []
    for k in range(100):
        sense = Sense("world", 0, k + 1, k, k * 0.01, 3, np.array([k * 1.0, 0, 0]), None, None)
        out = inbox.handle("world/sense/3", sense)
        out += inbox.handle("agent/2/estimate", _estimate(2, k))
        out += inbox.handle("agent/4/estimate", _estimate(4, k))
        (cmd,) = [m for t, m in out if isinstance(m, Command)]
        speeds.append(np.linalg.norm(cmd.v))
        if k >= 5:
            assert isinstance(inbox.node.sense, ReplayedSense) and inbox.node.sense.p[0] == 4.0
    # Last sensed at tick 4 (0.04 s); the limit is 0.5 s: zero velocity from tick 55 on, flagged.
    assert min(speeds[:55]) > 0 and max(speeds[55:]) == 0.0
    assert inbox.node.degraded_ticks["no_sensing"] == 45


def test_mortal_node_dies_restarts_fresh_and_a_frozen_one_gets_its_backlog():
    sc = load(PAPER_FAST)
    built = []

    def build():
        built.append(AgentNode(sc, 1))
        return built[-1]

    # The node's time is its own sensing's (a leader state, like an estimate, is sent a tick
    # early in lock-step, so one past a kill or restart waits for the node's time to get there).
    def sense(k: int, t: float) -> tuple[str, Sense]:
        return "world/sense/1", Sense("world", 0, k, k, t, 1, np.zeros(3), None, None)

    m = Mortal(build, [ProcessFault("agent:1", "kill", 0.1, 0.2)])
    assert m.handle("clock", Clock("world", 0, 1, 5, 0.05)) == []
    assert m.handle(*sense(15, 0.15)) == []
    assert m.handle("leader/state", LeaderState("leader", 0, 1, 15, 0.15, np.ones(3))) == []
    assert built[0].leader is None and built[0].sense is None  # dead: heard nothing
    m.handle(*sense(25, 0.25))
    m.handle("leader/state", LeaderState("leader", 0, 1, 25, 0.25, np.ones(3)))
    assert len(built) == 2 and m.restarts == 1 and built[1].leader.tick == 25

    f = Mortal(lambda: AgentNode(sc, 1), [ProcessFault("agent:1", "freeze", 0.1, 0.2)])
    f.handle(*sense(15, 0.15))
    f.handle("leader/state", LeaderState("leader", 0, 1, 15, 0.15, np.ones(3)))
    assert f.node.leader is None and len(f.backlog) == 2
    f.handle(*sense(21, 0.21))
    f.handle("leader/state", LeaderState("leader", 0, 1, 21, 0.21, np.ones(3)))
    assert f.node.leader.tick == 21 and not f.backlog


def test_process_schedule_fires_each_signal_once_when_its_time_comes():
    s = ProcessSchedule((ProcessFault("agent:2", "kill", 10.0, 12.0), ProcessFault("leader", "freeze", 5.0, 6.0)))
    assert s.due(4.0) == []
    assert s.due(5.5) == [("freeze", "leader")]
    assert s.due(11.0) == [("thaw", "leader"), ("kill", "agent:2")]
    assert s.due(12.0) == [("restart", "agent:2")] and s.due(20.0) == []


def test_the_schedule_logs_when_each_process_fault_was_sent_and_when_it_took_effect():
    """A restart returns once the new process is alive, seconds of wall time later; the world
    went on meanwhile, so the summary's event says both times."""

    class Swarm:  # the launcher's side of it: a clock the world drives, and the signals
        children = {"agent-2": object()}
        t = 10.0

        def sim_time(self) -> float:
            return self.t

        def kill(self, name: str) -> None:
            pass

        def restart(self, name: str) -> None:
            self.t += 3.5  # the world went on while the new process started

    s, swarm = ProcessSchedule((ProcessFault("agent:2", "kill", 10.0, 12.0),)), Swarm()
    assert s.run(swarm) == [{"action": "kill", "target": "agent:2", "t_s": 10.0, "done_t_s": 10.0}]
    swarm.t = 12.25
    assert s.run(swarm) == [{"action": "restart", "target": "agent:2", "t_s": 12.25, "done_t_s": 15.75}]
    assert [e["done_t_s"] for e in s.log] == [10.0, 15.75]


def _commands_of(arrival_seed: int | None, ticks: int = 60) -> list[tuple]:
    """Robot 3 behind a lossy, slow, duplicating filter, fed one tick at a time. With a seed, each
    tick's messages arrive shuffled, and each delayed estimate physically arrives at a random
    moment between its sending and its release tick (as over a network); None: in order."""
    import random

    sc = load(PAPER_FAST)
    p = FaultPlan(seed=2, rules=(LinkRule("agent:2", "agent:3", ("estimate",), drop=0.3, duplicate=0.2),
                                 LinkRule("agent:4", "agent:3", ("estimate",), delay=0.02, jitter=0.03)))
    inbox = FaultyInbox(AgentNode(sc, 3), "agent:3", p, sc.dt)
    rng = random.Random(arrival_seed)
    in_flight: dict[int, list] = {}
    commands = []
    for k in range(ticks):
        ph2, ph4 = np.array([0.1 * k, 1.0, 2.0]), np.array([0.0, 0.2 * k, -1.0])
        sense = Sense("world", 0, k + 1, k, k * 0.01, 3, np.array([1.0, 2.0, 0.1 * k]), None, None)
        pool = [("world/sense/3", sense)]
        for j, ph in ((2, ph2), (4, ph4)):
            msg = _estimate(j, k, ph)
            fate = p.fate(f"agent:{j}", "agent:3", "estimate", k, k * 0.01)
            late = int(round(fate.delay / sc.dt))
            arrive = k if arrival_seed is None or late == 0 else rng.randint(k, k + late)
            in_flight.setdefault(arrive, []).append((f"agent/{j}/estimate", msg))
        pool += in_flight.pop(k, [])
        if arrival_seed is not None:
            rng.shuffle(pool)
        for topic, msg in pool:
            for t, m in inbox.handle(topic, msg):
                if isinstance(m, Command):
                    commands.append((m.tick, tuple(m.v), tuple(m.ph), m.flags))
    return commands


def test_the_filtered_agent_acts_the_same_whatever_the_arrival_order():
    canonical = _commands_of(None)
    assert [c[0] for c in canonical] == list(range(60))  # one command per tick, none stuck
    # (without the filter holding a tick back until its delayed messages arrived, all differ)
    for seed in range(6):
        assert _commands_of(seed) == canonical, seed


def _sense(robot: int, k: int) -> Sense:
    return Sense("world", 0, k + 1, k, k * 0.01, robot, np.zeros(3), None, None)


def _commands(out) -> list[int]:
    return [m.tick for _, m in out if isinstance(m, Command)]


def _robot_3_losing_commands() -> tuple[FaultyInbox, int, int]:
    """Robot 3 (neighbours 2 and 4) behind its inbox, half its commands to the world lost: the
    inbox, a tick whose command the plan loses and one it keeps (both after 2)."""
    sc = load(PAPER_FAST)
    p = FaultPlan(seed=3, rules=(LinkRule("agent:3", "world", ("command",), drop=0.5),))
    fates = [(k, p.fate("agent:3", "world", "command", k, k * 0.01).lost) for k in range(2, 200)]
    lost, kept = next(k for k, gone in fates if gone), next(k for k, gone in fates if not gone)
    return FaultyInbox(AgentNode(sc, 3), "agent:3", p, sc.dt), lost, kept


def test_a_robot_whose_command_was_lost_acts_on_its_tick_before_the_next_sensing_that_overtook_an_estimate():
    """Over Zenoh each subscription has its own thread: when the world moved on without robot 3
    (its command lost), its next sensing can come before the estimate it still waits for. The
    robot must act on its tick with that estimate, then on the next one, as ``fxswarm sim`` does."""
    inbox, lost, _ = _robot_3_losing_commands()
    for k in range(lost):
        out = inbox.handle("world/sense/3", _sense(3, k))
        out += inbox.handle("agent/2/estimate", _estimate(2, k)) + inbox.handle("agent/4/estimate", _estimate(4, k))
        assert _commands(out) == [k]
    out = inbox.handle("world/sense/3", _sense(3, lost)) + inbox.handle("agent/2/estimate", _estimate(2, lost))
    assert _commands(out) == []  # waits for robot 4's estimate
    out = inbox.handle("world/sense/3", _sense(3, lost + 1))  # the world went on: this command was lost
    assert _commands(out) == [] and inbox.node.sense.tick == lost  # held, not started over the tick
    out = inbox.handle("agent/4/estimate", _estimate(4, lost))
    assert _commands(out) == [lost]  # then the held tick starts and waits for its own estimates
    out = inbox.handle("agent/2/estimate", _estimate(2, lost + 1)) + inbox.handle("agent/4/estimate", _estimate(4, lost + 1))
    assert _commands(out) == [lost + 1]


def test_a_robot_follows_a_world_that_gave_up_waiting_for_it():
    """A world that closes a tick on its timeout (the command was not lost by the plan) sends the
    next sensing all the same: the robot follows at once, skipping the tick, as before."""
    inbox, _, kept = _robot_3_losing_commands()
    inbox.handle("world/sense/3", _sense(3, kept))
    inbox.handle("agent/2/estimate", _estimate(2, kept))
    inbox.handle("world/sense/3", _sense(3, kept + 1))  # robot 4's estimate for `kept` never came
    assert inbox.node.sense.tick == kept + 1 and not inbox.pending
    out = inbox.handle("agent/2/estimate", _estimate(2, kept + 1)) + inbox.handle("agent/4/estimate", _estimate(4, kept + 1))
    assert _commands(out) == [kept + 1]
    # A sensing said again for the tick the robot is on (a world asking again) reaches it, too.
    again = inbox.handle("world/sense/3", _sense(3, kept + 1))
    assert _commands(again) == [] and inbox.node.sense.tick == kept + 1


def test_a_robot_held_past_a_gone_neighbour_resumes_and_the_simulator_stops_waiting():
    inbox, lost, _ = _robot_3_losing_commands()
    inbox.handle("world/sense/3", _sense(3, lost))
    inbox.handle("agent/2/estimate", _estimate(2, lost))
    inbox.handle("world/sense/3", _sense(3, lost + 1))
    assert inbox.act_past_the_gone(set()) == [] and inbox.pending  # still waiting for robot 4
    assert _commands(inbox.act_past_the_gone({"agent:4"})) == [lost]
    assert inbox.node.sense.tick == lost + 1 and not inbox.pending  # the held tick started
    inbox.handle("world/sense/3", _sense(3, lost + 2))
    if inbox.pending:  # held (the command for lost + 1 lost, too): the simulator's empty bus starts it
        inbox.stop_waiting()
    assert inbox.node.sense.tick == lost + 2 and not inbox.pending


def test_a_robot_whose_only_fault_is_a_lost_command_gets_an_inbox():
    sc = load(PAPER_FAST)
    p = FaultPlan(seed=3, rules=(LinkRule("agent:6", "world", ("command",), drop=0.1),))
    assert isinstance(wrap(AgentNode(sc, 6), "agent", 6, p, sc.dt), FaultyInbox)
    assert isinstance(wrap(AgentNode(sc, 5), "agent", 5, p, sc.dt), AgentNode)  # nothing reaches robot 5
    delayed = FaultPlan(seed=3, rules=(LinkRule("agent:6", "world", ("command",), delay=0.01),))
    assert isinstance(wrap(AgentNode(sc, 6), "agent", 6, delayed, sc.dt), AgentNode)  # never lost
    isolated = FaultPlan(seed=3, cuts=(Cut(0.1, 0.5, (), (3,)),))
    assert not isolated.may_lose("agent:3", "world", "command")  # cut off from robots, not from the world
    assert FaultPlan(cuts=(Cut(0.1, 0.5, (("agent:*", "world"),), (), ("command",)),)).may_lose("agent:3", "world", "command")
