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
