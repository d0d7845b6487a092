"""The logger's ring buffer: the bus never waits, a slow logger drops the oldest and counts."""

from __future__ import annotations

import threading

import pytest

from fxswarm.logger.inbox import Inbox


def test_overflow_drops_oldest_and_counts():
    box = Inbox(3)
    for k in range(5):
        box.put(k)
    assert box.dropped == 2 and box.accepted == 5
    assert list(box.drain()) == [2, 3, 4]
    assert len(box) == 0


def test_drain_limit_keeps_the_rest():
    box = Inbox(10)
    for k in range(6):
        box.put(k)
    assert list(box.drain(limit=4)) == [0, 1, 2, 3]
    assert list(box.drain()) == [4, 5]


def test_producer_thread_never_blocks_on_a_consumer_that_never_drains():
    box = Inbox(100)
    done = threading.Event()

    def produce():
        for k in range(10_000):
            box.put(k)
        done.set()

    thread = threading.Thread(target=produce)
    thread.start()
    assert done.wait(5.0), "put() blocked"
    thread.join()
    assert box.dropped == 10_000 - 100 and list(box.drain())[0] == 9_900


def test_capacity_must_be_positive():
    with pytest.raises(ValueError, match="capacity"):
        Inbox(0)


def test_peek_header_reads_what_decode_would_accept():
    import msgpack
    import numpy as np

    from fxswarm.core.messages import SCHEMA_VERSION, Estimate, WorldState, encode
    from fxswarm.logger.peek import peek_header

    h = peek_header(encode(Estimate("agent", 3, 7, 6, 0.06, 3, np.ones(3))))
    assert h == ("estimate", "agent", 3, 7, 6, 0.06)
    state = WorldState("world", 0, 9, 8, 0.08, np.ones((2, 3)), np.ones((2, 3)), np.ones((2, 3)), np.ones(2),
                       np.zeros(2, bool), np.zeros((0, 3)))
    assert peek_header(encode(state)).kind == "state"
    reordered = msgpack.packb({"t": 0.5, "p": [[1.0, 2.0, 3.0]], "tick": 2, "seq": 3, "sender": 0, "role": "world",
                               "kind": "state", "schema": SCHEMA_VERSION})
    assert peek_header(reordered) == ("state", "world", 0, 3, 2, 0.5)
    for junk in (b"", b"\xc1", msgpack.packb([1, 2]), msgpack.packb({"schema": SCHEMA_VERSION, "kind": "estimate"}),
                 msgpack.packb({"schema": SCHEMA_VERSION, "kind": "estimate", "role": "agent", "sender": -1, "seq": 1,
                                "tick": 1, "t": 0.0}),
                 msgpack.packb({"schema": SCHEMA_VERSION - 1, "kind": "estimate", "role": "agent", "sender": 1, "seq": 1,
                                "tick": 1, "t": 0.0}),
                 msgpack.packb({"schema": SCHEMA_VERSION, "kind": "estimate", "role": "agent", "sender": 1, "seq": 1,
                                "tick": 1, "t": float("nan")})):
        assert peek_header(junk) is None
