"""The wire and the bus's settings without a session: sender checks, decoding every malformed
vector, Zenoh options from scenario and command line, the launcher's choice of topology."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest

from fxswarm.core.messages import Clock, Estimate, LeaderState, Sense, WireError, decode, encode
from fxswarm.core.scenario import load
from fxswarm.runtime.zenoh_bus import check_sender

from support import CONFIGS, PAPER_FAST, V, estimate


def test_check_sender_accepts_a_message_on_its_own_key():
    check_sender("agent/3/estimate", estimate(3))
    check_sender("world/sense/2", Sense("world", 0, 1, 0, 0.0, 2, V, None, None))
    check_sender("clock", Clock("world", 0, 1, 0, 0.0))


@pytest.mark.parametrize("topic,msg", [
    ("agent/3/estimate", estimate(4)),  # a stranger's robot id on robot 3's key
    ("agent/3/estimate", estimate(3, sender=4)),  # signed by someone else
    ("agent/3/cmd", LeaderState("leader", 0, 1, 0, 0.0, V)),  # wrong kind for the key
    ("agent/3/cmd", estimate(3, sender=4)),  # a first estimate on a command key, signed by someone else
    ("world/sense/2", Sense("world", 0, 1, 0, 0.0, 3, V, None, None)),
    ("clock", Clock("agent", 1, 1, 0, 0.0)),  # only the world keeps the clock
])
def test_check_sender_rejects_a_message_that_does_not_belong(topic, msg):
    with pytest.raises(WireError):
        check_sender(topic, msg)


def test_zenoh_options_come_from_the_scenario_table_and_the_command_line_wins():
    import argparse

    from fxswarm.runtime.zenoh_bus import add_zenoh_arguments, options_from_args

    p = argparse.ArgumentParser()
    add_zenoh_arguments(p)
    table = {"swarm": "lab", "mode": "client", "connect": ["tcp/10.0.0.1:7447"], "lease_ms": 2000}
    swarm, opts = options_from_args(p.parse_args([]), table)
    assert swarm == "lab" and opts.mode == "client" and opts.connect == ("tcp/10.0.0.1:7447",)
    assert not opts.multicast and opts.lease_ms == 2000
    swarm, opts = options_from_args(p.parse_args(["--swarm", "x", "--mode", "peer", "--multicast"]), table)
    assert swarm == "x" and opts.mode == "peer" and opts.multicast


@pytest.mark.parametrize("bad", [[math.nan, 0.0, 0.0], [0.0, math.inf, 0.0], [0.0, 0.0, -math.inf],
                                 [2e9, 0.0, 0.0], [0.0, -2e9, 0.0], [True, 0.0, 0.0], ["1", 0.0, 0.0],
                                 [0.0, 0.0], [0.0, 0.0, 0.0, 0.0], None, 3.0])
def test_decode_rejects_every_malformed_vector(bad):
    raw = msgpack.unpackb(encode(Estimate("agent", 3, 1, 7, 0.07, 3, np.zeros(3))))
    with pytest.raises(WireError, match="'ph'"):
        decode(msgpack.packb({**raw, "ph": bad}))


def test_decode_takes_integer_and_float_vectors_alike():
    raw = msgpack.unpackb(encode(Estimate("agent", 3, 1, 7, 0.07, 3, np.zeros(3))))
    for ph in ([1, -2, 3], [1.0, -2.0, 3.0], [1, -2.0, 3]):
        got = decode(msgpack.packb({**raw, "ph": ph})).ph
        assert got.dtype == float and got.tolist() == [1.0, -2.0, 3.0]


def test_the_launchers_topology_comes_from_the_command_line_else_the_scenario_else_auto(tmp_path, capsys):
    from fxswarm.launch.launcher import MESH_MAX_ROBOTS, Swarm
    from fxswarm.testing import scenario_with

    six, many = PAPER_FAST, CONFIGS / "large.toml"
    assert load(six).n <= MESH_MAX_ROBOTS < load(many).n
    assert Swarm(str(six), tmp_path).options.mode == "peer"  # auto: a mesh of 6
    assert Swarm(str(many), tmp_path).options.mode == "client"  # auto: 24 go through the router
    # auto: routed when a process is to be frozen (a mesh link can stay split after a freeze
    # past the lease), whether the scenario or the command line plans it.
    assert Swarm(str(six), tmp_path, faults=("freeze agent:2 at=1 thaw=3",)).topology == "routed"
    assert Swarm(str(six), tmp_path, faults=("kill agent:2 at=1 restart=3",)).topology == "mesh"
    routed = scenario_with(six, tmp_path, **{"zenoh.topology": "routed"})
    assert Swarm(str(routed), tmp_path).topology == "routed"
    assert Swarm(str(routed), tmp_path, topology="mesh").topology == "mesh"  # the command line wins
    bad = scenario_with(six, tmp_path, **{"zenoh.topology": "star"})
    with pytest.raises(SystemExit) as exc:
        Swarm(str(bad), tmp_path)
    assert exc.value.code == 2
    assert f"{bad}: zenoh.topology: expected one of 'auto', 'mesh', 'routed'" in capsys.readouterr().err


def test_a_command_carries_its_estimate_exactly_and_all_or_nothing_of_it():
    from fxswarm.core.messages import Command
    from fxswarm.core.messages import _decode_fast  # the one-pass path must agree with the full one

    cmd = Command("agent", 3, 7, 4, 0.04, 3, V, V, False, 0, (0, 0), (0, 0), None, 5, 0.05, V * 3, None)
    back = decode(encode(cmd))
    est = back.carried_estimate()
    assert (est.robot, est.seq, est.tick, est.t) == (3, 7, 5, 0.05) and np.array_equal(est.ph, V * 3)
    assert decode(encode(Command("agent", 3, 7, 4, 0.04, 3, V, V, False))).carried_estimate() is None
    raw = msgpack.unpackb(encode(cmd))
    for missing in ("est_tick", "est_t", "est_ph"):
        half = dict(raw)
        del half[missing]
        assert _decode_fast(msgpack.packb(half)) is None
        with pytest.raises(WireError, match="carried estimate"):
            decode(msgpack.packb(half))
    for bad in ({"est_t": float("nan")}, {"est_tick": -1}, {"est_ph": [1.0, 2.0]}):
        with pytest.raises(WireError):
            decode(msgpack.packb({**raw, **bad}))


@pytest.mark.parametrize("command", [
    ["run", str(PAPER_FAST)], ["world", str(PAPER_FAST)], ["agent", str(PAPER_FAST), "--id", "1"],
    ["router"], ["health", "world"], ["attach", "tcp/127.0.0.1:7447", "--out", "OUT"],
    ["stack", str(PAPER_FAST), "--out", "OUT"], ["k8s", str(PAPER_FAST), "--out", "OUT"],
])
@pytest.mark.parametrize("bad", ["x*y", "a/b", "", "q?"])
def test_every_command_refuses_a_swarm_name_that_is_not_one_key_chunk(command, bad, capsys, tmp_path):
    """The swarm name is one chunk of every key expression: `fxswarm run --swarm 'x*y'` used to
    start every process and die in a Zenoh traceback (invalid key expression)."""
    from fxswarm.cli import main as fxswarm_main

    with pytest.raises(SystemExit) as exc:
        fxswarm_main([*(str(tmp_path / "out") if a == "OUT" else a for a in command), "--swarm", bad])
    assert exc.value.code == 2
    assert f"argument --swarm: expected a swarm name (not empty, without / * $ ? or #), got {bad!r}" \
        in capsys.readouterr().err
