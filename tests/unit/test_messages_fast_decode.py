"""decode's fast path accepts and builds exactly what its full path does (fxswarm.core.messages)."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest

from fxswarm.core import messages as m

V = np.array([0.5, -1.25, 3.0])
VALID = [
    m.Clock("world", 0, 3, 3, 0.03),
    m.Sense("world", 0, 3, 3, 0.03, 2, V, V, V),
    m.Sense("world", 0, 3, 3, 0.03, 2, V, None, None),
    m.LeaderState("leader", 0, 1, 4, 0.04, V),
    m.Estimate("agent", 2, 7, 3, 0.03, 2, V),
    m.Command("agent", 2, 7, 3, 0.03, 2, V, V, True, 5, (0, 2), (1, 0)),
]


def full_path(payload: bytes, monkeypatch) -> object:
    with monkeypatch.context() as mp:
        mp.setattr(m, "_decode_fast", lambda raw: None)
        try:
            return m.decode(payload)
        except m.WireError as exc:
            return ("error", str(exc))


def both(payload: bytes, monkeypatch):
    try:
        fast = m.decode(payload)
    except m.WireError as exc:
        fast = ("error", str(exc))
    return fast, full_path(payload, monkeypatch)


def same(a, b) -> bool:
    return type(a) is type(b) and repr(a) == repr(b)


@pytest.mark.parametrize("msg", VALID, ids=lambda x: type(x).__name__)
def test_valid_messages_decode_alike_and_fast(msg, monkeypatch):
    payload = m.encode(msg)
    raw = msgpack.unpackb(payload)
    assert m._decode_fast(raw) is not None  # the usual message does take the fast path
    fast, full = both(payload, monkeypatch)
    assert same(fast, full) and same(fast, msg)


MUTATIONS = [
    ("t", 3), ("t", math.nan), ("t", math.inf), ("t", 2e9), ("t", "x"), ("t", True),
    ("tick", -1), ("tick", 1.0), ("tick", True), ("tick", 2**60), ("seq", None), ("sender", "2"),
    ("role", "stranger"), ("role", ["agent"]), ("schema", 1), ("kind", ["sense"]), ("kind", "nope"),
    ("robot", -2), ("robot", False), ("p", [1.0, 2.0]), ("p", [1.0, 2.0, math.nan]), ("p", [1, 2, 3]),
    ("p", [1.0, 2.0, 1e10]), ("p", None), ("po", None), ("po", "x"), ("ph", (1.0, 2.0, 3.0)),
    ("v", [True, 0.0, 0.0]), ("avoid_active", 1), ("flags", -1), ("flags", None), ("link_age", [0]),
    ("link_age", [0, -1]), ("link_age", [0, 1.0]), ("link_drops", "ab"), ("p0", [0.0, 0.0]),
]


@pytest.mark.parametrize("msg", VALID, ids=lambda x: type(x).__name__)
@pytest.mark.parametrize("field,value", MUTATIONS)
def test_altered_messages_decode_alike(msg, field, value, monkeypatch):
    raw = msgpack.unpackb(m.encode(msg))
    raw[field] = value
    fast, full = both(msgpack.packb(raw), monkeypatch)
    assert same(fast, full), (fast, full)


@pytest.mark.parametrize("msg", VALID, ids=lambda x: type(x).__name__)
def test_missing_fields_decode_alike(msg, monkeypatch):
    for field in msgpack.unpackb(m.encode(msg)):
        raw = msgpack.unpackb(m.encode(msg))
        del raw[field]
        fast, full = both(msgpack.packb(raw), monkeypatch)
        assert same(fast, full), (field, fast, full)


def test_a_refused_message_is_refused_by_the_fast_path_too():
    raw = msgpack.unpackb(m.encode(VALID[1]))
    raw["p"] = [0.0, math.nan, 0.0]
    assert m._decode_fast(raw) is None
    with pytest.raises(m.WireError, match="'p'"):
        m.decode(msgpack.packb(raw))


# --- decode_carried: what a graph neighbour reads off a robot's command key -------------------

CARRYING = [
    m.Command("agent", 2, 7, 3, 0.03, 2, V, V, True, 5, (0, 2), (1, 0), None, 4, 0.04, V, None),
    m.Command("agent", 2, 7, 3, 0.03, 2, V, V, False, 0, (0,), (0,), V, 4, 0.04, V, 2 * V),  # feedforward
]
ON_A_COMMAND_KEY = CARRYING + [
    m.Command("agent", 2, 7, 3, 0.03, 2, V, V, True, 5, (0, 2), (1, 0)),  # the last tick: carries none
    m.Estimate("agent", 2, 1, 0, 0.0, 2, V),  # a robot's first estimate, sent alone
]


def as_a_neighbour_sees_it(read):
    """A reader's outcome as the robot's node takes it: the estimate a command carries (a node
    unwraps a Command itself), or the error."""
    try:
        msg = read()
    except m.WireError as exc:
        return ("error", str(exc))
    return msg.carried_estimate() if type(msg) is m.Command else msg


@pytest.mark.parametrize("msg", ON_A_COMMAND_KEY, ids=lambda x: f"{type(x).__name__}-{x.est_tick if type(x) is m.Command else ''}")
def test_a_neighbour_reads_what_the_full_decode_gives_it(msg):
    payload = m.encode(msg)
    lean = as_a_neighbour_sees_it(lambda: m.decode_carried(payload))
    assert same(lean, as_a_neighbour_sees_it(lambda: m.decode(payload)))
    assert lean is None if type(msg) is m.Command and msg.est_ph is None else lean is not None


def test_a_carried_estimate_is_built_without_the_full_decode(monkeypatch):
    payload = m.encode(CARRYING[1])
    monkeypatch.setattr(m, "decode", lambda p: pytest.fail("took the full path"))
    est = m.decode_carried(payload)
    assert type(est) is m.Estimate and (est.tick, est.t, est.seq, est.robot) == (4, 0.04, 7, 2)
    assert est.ph.tolist() == V.tolist() and est.vh.tolist() == (2 * V).tolist()


READ = [("t", math.nan), ("t", "x"), ("tick", -1), ("seq", None), ("sender", "2"), ("role", "stranger"),
        ("schema", 1), ("robot", -2), ("robot", False), ("est_tick", -1), ("est_tick", 1.5), ("est_t", math.inf),
        ("est_t", None), ("est_ph", [1.0, 2.0]), ("est_ph", [1.0, math.nan, 0.0]), ("est_ph", [1.0, 2.0, 1e10]),
        ("est_ph", None), ("est_vh", [0.0, 0.0]), ("est_vh", "x"), ("est_t", 3)]


@pytest.mark.parametrize("field,value", READ)
def test_what_a_neighbour_reads_is_checked_as_the_full_decode_checks_it(field, value):
    raw = msgpack.unpackb(m.encode(CARRYING[0]))
    raw[field] = value
    payload = msgpack.packb(raw)
    assert same(as_a_neighbour_sees_it(lambda: m.decode_carried(payload)),
                as_a_neighbour_sees_it(lambda: m.decode(payload)))


@pytest.mark.parametrize("field,value", [("v", [1.0, 2.0]), ("ph", [math.nan, 0.0, 0.0]), ("avoid_active", 1),
                                         ("flags", -1), ("link_age", [0]), ("link_drops", "ab"), ("vh", "x")])
def test_what_only_the_world_reads_is_left_to_the_world(field, value):
    """A neighbour does not check the fields it does not use; the world, which reads them, refuses."""
    raw = msgpack.unpackb(m.encode(CARRYING[0]))
    raw[field] = value
    payload = msgpack.packb(raw)
    with pytest.raises(m.WireError):
        m.decode(payload)
    assert same(m.decode_carried(payload), CARRYING[0].carried_estimate())
