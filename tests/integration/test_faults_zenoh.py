"""Faults over real processes and real Zenoh: same trajectories as the simulator, crashes, garbage."""

from __future__ import annotations

import math
import os
import threading
import tomllib
from pathlib import Path

import msgpack
import numpy as np
import pytest

from fxswarm.core.messages import (SCHEMA_VERSION, Clock, Command, LeaderState, Message, Sense, WireError,
                                   WorldState, decode, decode_carried, encode)
from fxswarm.core.metrics import formation_errors
from fxswarm.runtime.output import load_trajectory
from fxswarm.runtime.zenoh_bus import ZenohBus, ZenohOptions, check_sender
from fxswarm.testing import dump_toml
from fxswarm.core.scenario import directed_links

from support import CONFIGS, MIXED_FAULTS, PAPER_FAST

def scenario_file(folder: Path, duration: float, faults: dict) -> Path:
    data = tomllib.loads(PAPER_FAST.read_text())
    data["scenario"]["duration"] = duration
    data["faults"] = faults
    path = folder / f"faulty-{os.getpid()}.toml"
    path.write_text(dump_toml(data))
    return path


@pytest.mark.zenoh
def test_lockstep_processes_with_faults_match_the_simulator_bit_for_bit(launch_swarm, tmp_path):
    config = scenario_file(tmp_path, 1.5, MIXED_FAULTS)
    swarm = launch_swarm(config)
    summary = swarm.wait_done(timeout=180)
    expected_summary = swarm.assert_matches_sim()
    assert summary["complete"] and summary["missed_ticks"] == 0
    # Each receiver counted its own inbound links; together they are the simulator's counts.
    assert summary["faults"]["links"] == expected_summary["faults"]["links"]
    links = summary["faults"]["links"]
    assert links["agent:2->agent:3/estimate"]["dropped"] > 0
    assert links["agent:1->agent:2/estimate"]["delayed"] > 0
    assert links["agent:1->agent:2/estimate"]["duplicated"] > 0
    assert links["world->agent:5/sense"]["dropped"] > 0
    assert summary["faults"]["degraded_ticks"] == expected_summary["faults"]["degraded_ticks"]


@pytest.mark.zenoh
def test_agent_2_killed_at_10_s_and_restarted_at_12_s_rejoins_and_converges(launch_swarm):
    """Real processes: the launcher SIGKILLs agent 2 at 10 s and starts a fresh one at 12 s. Cut
    to 25 s (of 40): robot 2 is back in formation 10.3 s after its restart (fxswarm sim), and the
    run is bit-identical to the sim, recovery included."""
    config = CONFIGS / "faults-crash.toml"
    swarm = launch_swarm(config, duration=25.0)
    summary = swarm.wait_done(timeout=300)
    swarm.assert_matches_sim()
    assert summary["complete"] and summary["ticks"] == swarm.scenario.ticks
    assert not swarm.deaths  # the planned kill is not an unplanned death; nothing else died
    err = formation_errors(load_trajectory(swarm.out))
    tol = swarm.scenario.settle_tolerance
    assert err[-1, 1] < tol, "robot 2 is not back in formation by the end"
    crash = summary["faults"]["recoveries"][0]
    assert crash["event"] == "kill agent:2" and crash["recovery_s"] is not None
    events = summary["faults"]["process_events"]
    assert [e["action"] for e in events] == ["kill", "restart"]
    # Each sent once the launcher heard the world reach its time: the restart a tick ahead, so the
    # world can hold the restart's own tick until the new process is up (RestartHold).
    dt = swarm.scenario.dt
    assert all(e["done_t_s"] >= e["t_s"] >= at - 1e-9 for e, at in zip(events, (10.0, 12.0 - dt))), events
    degraded = summary["faults"]["degraded_ticks"]
    assert degraded["world_held_at_zero"]["2"] > 0  # the world stopped the silent robot
    assert degraded["stale_neighbour"]["1"] > 0 and degraded["stale_neighbour"]["3"] > 0


@pytest.mark.zenoh
def test_the_leader_killed_for_good_leaves_the_swarm_behind_as_in_the_simulator(launch_swarm):
    """Real processes: the launcher SIGKILLs the leader at 3 s; the pinned robots (1, 4) fly on
    what they last heard, as `fxswarm sim` has them do for the same plan."""
    from fxswarm.launch.sim import Simulation

    swarm = launch_swarm(PAPER_FAST, duration=10.0, **{"faults.processes": [{"target": "leader", "kill": 3.0}]})
    summary = swarm.wait_done(timeout=300)
    assert summary["complete"] and not swarm.deaths
    held = summary["faults"]["degraded_ticks"]["no_leader"]
    assert set(held) == {"1", "4"} and all(n >= 600 for n in held.values()), held
    sim = Simulation(swarm.scenario).run()
    assert sim["estimate_error_final_m"] > 5.0
    # The leader's process falls silent at the kill's tick (PlannedKill): bit-identical to the sim.
    swarm.assert_matches_sim()
    assert summary["estimate_error_final_m"] == sim["estimate_error_final_m"]


# --- garbage on every key --------------------------------------------------------------------


def rejected(topic: str, payload: bytes) -> bool:
    """Whether every receiver drops ``payload`` on ``topic``: the wire's own checks, and on a
    command key a neighbour's too. A neighbour reads only the estimate a command carries
    (decode_carried), so a command broken elsewhere with a sound estimate is to it a sound
    estimate: a forgery, not garbage, which only secure mode refuses (test_secure_swarm.py).
    Sent as garbage, one for tick 2 landed while robots 2 and 5 were still there and the run
    parted from the sim (1 run in 3 at load 24)."""
    readers = (decode, decode_carried) if topic.endswith("/cmd") else (decode,)
    for read in readers:
        try:
            check_sender(topic, read(payload))
        except WireError:
            continue
        return False
    return True


def garbage_for(topic: str, sample: Message, rng: np.random.Generator) -> list[bytes]:
    """Malformed payloads for ``topic``, from a valid ``sample``: random bytes, wrong msgpack
    types, wrong shapes, NaN/inf, huge numbers, unknown schema versions, a stranger's id."""
    out = [bytes(rng.integers(0, 256, size=int(n), dtype=np.uint8)) for n in (0, 1, 7, 64, 300)]
    out += [msgpack.packb(x) for x in ([1, 2, 3], "hello", None, 3.5, {"schema": "x"}, 12)]
    base = msgpack.unpackb(encode(sample))
    out.append(encode(sample)[:-3])  # truncated
    bad_values = ["str", None, [1.0, 2.0], [[1.0]], [math.nan, 0.0, 0.0], [math.inf, 0.0, 0.0],
                  [1e300, 0.0, 0.0], -1, 2**60, True, {"a": 1}]
    for key in base:
        for value in bad_values:
            out.append(msgpack.packb({**base, key: value}))
        without = dict(base)
        del without[key]
        out.append(msgpack.packb(without))
    out += [msgpack.packb({**base, "schema": v}) for v in (0, SCHEMA_VERSION - 1, SCHEMA_VERSION + 1, 999, "1")]
    if "link_age" in base:  # one link too many on one side
        out.append(msgpack.packb({**base, "link_age": base["link_age"] + [0]}))
    if "robot" in base:
        out.append(msgpack.packb({**base, "robot": 99, "sender": 99}))  # a stranger's robot id
    if "sender" in base:
        out.append(msgpack.packb({**base, "role": "agent", "sender": 99}))
    return [p for p in out if rejected(topic, p)]


def samples(sc) -> dict[str, Message]:
    v = np.zeros(3)
    out: dict[str, Message] = {
        "leader/state": LeaderState("leader", 0, 1, 1, 0.01, v),
        "world/state": WorldState("world", 0, 1, 1, 0.01, np.zeros((sc.n, 3)), np.zeros((sc.n, 3)),
                                  np.zeros((sc.n, 3)), np.zeros(sc.n), np.zeros(sc.n, dtype=bool), np.zeros((4, 3)),
                                  np.zeros(len(directed_links(sc)), dtype=np.int64),
                                  np.zeros(len(directed_links(sc)), dtype=np.int64)),
        "alive/agent/1": Clock("world", 0, 1, 1, 0.01),
    }
    for r in sc.robots:
        out[f"world/sense/{r.id}"] = Sense("world", 0, 1, 1, 0.01, r.id, v, v, v)
        m = len(sc.neighbours(r.id)) + sc.is_pinned(r.id)
        # With the estimate it carries for the neighbours: garbage in those fields too.
        out[f"agent/{r.id}/cmd"] = Command("agent", r.id, 1, 1, 0.01, r.id, v, v, False, 0, (0,) * m, (0,) * m,
                                           None, 2, 0.02, v, None)
    return out


@pytest.mark.zenoh
def test_garbage_on_every_key_kills_nothing_is_counted_and_leaves_the_lockstep_run_unchanged(launch_swarm):
    # A long tick timeout: a flooded process may be slow, but lock-step must wait for it, not skip.
    # The world's clock is held (--wait-for) until every key has a subscriber the attacker knows
    # of: 500 ticks go by in seconds, and once in twenty loaded runs (load 9) the run was over
    # before the attacker's session had learnt of any subscriber.
    swarm = launch_swarm(PAPER_FAST, duration=5.0, tick_timeout=20.0, world_args=("--wait-for", "test-gate/0"))
    sc = swarm.scenario
    rng = np.random.default_rng(4)
    blasts = {topic: garbage_for(topic, msg, rng) for topic, msg in samples(sc).items()}
    assert all(len(b) > 40 for t, b in blasts.items() if not t.startswith("alive")), \
        {t: len(b) for t, b in blasts.items()}
    attacker = ZenohBus(swarm.swarm.swarm, ZenohOptions("client", (swarm.swarm.endpoint,), (), False))
    rounds = 0
    heard: list[float] = []  # the harness's simulation time after each round
    try:
        # A put is sent only to subscribers the session knows of: wait until each key has one, so no
        # early garbage is lost to discovery (nobody subscribes to puts on a liveliness key).
        waiting = {t for t in blasts if not t.startswith("alive")}
        matched = threading.Event()
        lock = threading.Lock()

        def on_match(topic: str, status) -> None:
            with lock:
                if status.matching:
                    waiting.discard(topic)
                if not waiting:
                    matched.set()

        publishers, listeners = {}, []  # listeners kept: an undeclared one stops listening
        for topic in blasts:
            pub = publishers[topic] = attacker.session.declare_publisher(f"{attacker.root}/{topic}")
            if topic in waiting:
                listeners.append(pub.declare_matching_listener(lambda st, topic=topic: on_match(topic, st)))
                on_match(topic, pub.matching_status)
        assert matched.wait(30), f"no subscriber on {sorted(waiting)}"
        assert swarm.sim_time() < 0, "the world ticked before the gate opened"
        swarm.swarm.bus.declare_alive("test-gate", 0)
        world = swarm.swarm.children["world"]
        # One payload per key in turn, so every process is hit within the first pass over the keys,
        # however soon the run ends.
        order = [(t, p) for i in range(max(map(len, blasts.values())))
                 for t, ps in blasts.items() if i < len(ps) for p in (ps[i],)]
        while world.running() and rounds < 30:
            for topic, payload in order:
                publishers[topic].put(payload)
            rounds += 1
            swarm.pump(0.05)
            heard.append(swarm.sim_time())
        summary = swarm.wait_done(timeout=180)
    finally:
        attacker.close()
    assert rounds >= 1
    # Garbage on world/state neither moves nor erases the harness's view of the run.
    assert heard == sorted(heard), heard
    assert not swarm.deaths and summary["complete"] and summary["missed_ticks"] == 0
    procs = summary["processes"]
    assert set(procs) == {"world-0", "leader-0"} | {f"agent-{r.id}" for r in sc.robots}
    for name, c in procs.items():
        assert c["invalid"] > 0, (name, c)  # every process was hit and counted it
        assert c["stop_reason"] in ("done", "run over"), (name, c)
    swarm.assert_matches_sim()
