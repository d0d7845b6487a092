"""The Zenoh bus over real sessions (a router and clients in this process): delivery, validation,
swarm isolation, liveliness, ``poll(stay=True)``. The pure parts (sender checks, decoding, options)
are in tests/unit/test_runtime_wire.py."""

from __future__ import annotations

import numpy as np
import pytest

from fxswarm.core.messages import Clock, Command, encode
from fxswarm.runtime.zenoh_bus import ZenohBus, wait_until

from support import V, estimate


@pytest.mark.zenoh
def test_valid_messages_arrive_exactly_and_invalid_ones_are_counted_and_warned_once(zenoh_client, capsys):
    a, b = zenoh_client("iso-a"), zenoh_client("iso-a")
    try:
        got = []
        a.subscribe("agent/*/cmd", lambda topic, msg: got.append((topic, msg)))
        b.declare_alive("agent", 3)
        alive = []
        a.watch_alive("**", lambda name, up: alive.append((name, up)))
        assert wait_until(a, lambda: ("agent/3", True) in alive, 10)  # b's subscriptions are in place too
        cmd = Command("agent", 3, 1, 7, 0.07, 3, np.array([0.1, 1 / 3, -2e-17]), V, True)
        b.publish("agent/3/cmd", cmd)
        for bad in (b"\x00garbage", encode(Command("agent", 4, 1, 7, 0.07, 4, V, V, False)),
                    encode(Clock("world", 0, 1, 0, 0.0))):
            b.publish_bytes("agent/3/cmd", bad)
        b.publish("agent/5/cmd", Command("agent", 5, 1, 7, 0.07, 5, V, V, False))
        assert wait_until(a, lambda: len(got) == 2 and a.counters.invalid == 3, 10), (got, a.counters)
        topic, msg = got[0]
        assert topic == "agent/3/cmd" and msg.tick == 7 and msg.avoid_active
        assert np.array_equal(msg.v, cmd.v)  # float64 bit for bit
        warnings = capsys.readouterr().err
        assert warnings.count("agent/3/cmd") == 1  # once per key, the rest only counted
        assert a.counters.received == 2
    finally:
        a.close()
        b.close()


@pytest.mark.zenoh
def test_two_swarms_on_one_router_never_cross_talk(zenoh_client):
    a, b, a2 = zenoh_client("iso-a"), zenoh_client("iso-b"), zenoh_client("iso-a")
    try:
        heard_a, heard_b = [], []
        a.subscribe("**", lambda t, m: heard_a.append(t))
        b.subscribe("**", lambda t, m: heard_b.append(t))
        alive_b = []
        b.watch_alive("**", lambda name, up: alive_b.append(name))
        a2.declare_alive("agent", 1)
        alive_a = []
        a.watch_alive("**", lambda name, up: alive_a.append(name))
        assert wait_until(a, lambda: alive_a, 10)
        a2.publish("agent/1/estimate", estimate(1))
        assert wait_until(a, lambda: heard_a, 10)
        b.poll(0.3)
        assert heard_a == ["agent/1/estimate"] and heard_b == [] and alive_b == []
    finally:
        for bus in (a, b, a2):
            bus.close()


def wait_for(done, timeout: float) -> bool:
    """Wait (without a bus) until ``done()``, checking every millisecond."""
    import time

    end = time.monotonic() + timeout
    while not done() and time.monotonic() < end:
        time.sleep(0.001)
    return done()


def stay_until(bus: ZenohBus, done, timeout: float) -> bool:
    """Like :func:`wait_until`, polling with ``stay=True``."""
    import time

    end = time.monotonic() + timeout
    while not done() and time.monotonic() < end:
        bus.poll(0.05, stay=True)
    return done()


@pytest.mark.zenoh
def test_poll_stay_runs_handlers_off_the_polling_thread_only_while_polling_and_still_validates(zenoh_client):
    import threading

    a, b = zenoh_client("stay"), zenoh_client("stay")
    try:
        where, alive = [], []
        a.subscribe("agent/*/estimate", lambda topic, msg: where.append((msg.tick, threading.get_ident())))
        b.declare_alive("agent", 3)
        a.watch_alive("**", lambda name, up: alive.append(name))
        assert wait_until(a, lambda: "agent/3" in alive, 10)
        main = threading.get_ident()
        b.publish("agent/3/estimate", estimate(3, tick=1))
        assert wait_until(a, lambda: where, 10)  # plain poll: on the polling thread
        assert where == [(1, main)]
        b.publish("agent/3/estimate", estimate(3, tick=2))
        b.publish_bytes("agent/3/estimate", b"\x00garbage")
        b.publish("agent/3/estimate", estimate(3, tick=3))
        assert stay_until(a, lambda: len(where) == 3 and a.counters.invalid == 1, 10), (where, a.counters)
        assert [t for t, _ in where] == [1, 2, 3]  # one key's order kept
        # Delivered on a Zenoh callback thread (one that lands between two polls is queued and
        # handled on the polling thread instead: send more until one lands inside a poll).
        tick = 3
        while all(ident == main for _, ident in where[1:]) and tick < 50:
            tick += 1
            b.publish("agent/3/estimate", estimate(3, tick=tick))
            assert stay_until(a, lambda: len(where) == tick, 10)
        assert any(ident != main for _, ident in where[1:]), where
        # Between polls no handler runs: what arrives waits for the next poll.
        b.publish("agent/3/estimate", estimate(3, tick=tick + 1))
        b.publish("agent/3/estimate", estimate(3, tick=tick + 2))
        assert wait_for(lambda: a._inbox.qsize() == 2, 10)  # noqa: SLF001 - queued, not handled
        assert len(where) == tick
        assert a.poll(0) == 2 and where[tick:] == [(tick + 1, main), (tick + 2, main)]
    finally:
        a.close()
        b.close()


@pytest.mark.zenoh
def test_poll_stay_returns_on_wake_from_a_handler_and_reraises_a_handlers_error(zenoh_client):
    a, b = zenoh_client("stay-err"), zenoh_client("stay-err")
    try:
        def handler(topic, msg):
            if msg.tick == 1:
                a.wake()  # e.g. the world's last tick: the loop must see it now
            else:
                raise RuntimeError(f"handler failed at tick {msg.tick}")

        a.subscribe("agent/*/estimate", handler)
        alive = []
        a.watch_alive("**", lambda name, up: alive.append(name))
        b.declare_alive("agent", 3)
        assert wait_until(a, lambda: "agent/3" in alive, 10)
        b.publish("agent/3/estimate", estimate(3, tick=1))
        assert a.poll(30, stay=True) == 1  # returned on wake(), long before the timeout
        b.publish("agent/3/estimate", estimate(3, tick=2))
        with pytest.raises(RuntimeError, match="tick 2"):
            for _ in range(200):
                a.poll(0.05, stay=True)
    finally:
        a.close()
        b.close()
