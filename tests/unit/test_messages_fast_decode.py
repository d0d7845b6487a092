"""decode's fast path accepts and builds exactly what its full path does (fxswarm.core.messages)."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

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
# Commands that carry the robot's next estimate (neighbours read it: decode_carried).
CARRYING = [
    m.Command("agent", 2, 7, 3, 0.03, 2, V, V, True, 5, (0, 2), (1, 0), None, 4, 0.04, V, None),
    m.Command("agent", 2, 7, 3, 0.03, 2, V, V, False, 0, (0,), (0,), V, 4, 0.04, V, 2 * V),  # feedforward
]


def full_path(payload: bytes, monkeypatch) -> object:
    with monkeypatch.context() as mp:
        mp.setattr(m, "_decode_fast", lambda payload: None)
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
    assert m._decode_fast(payload) is not None  # the usual message does take the fast path
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
    ("link_age", [0, 2**60]), ("link_drops", [True, 0]), ("est_tick", -1), ("est_tick", 2**60), ("est_tick", 4.0),
    ("est_t", math.nan), ("est_t", 2), ("est_ph", [1.0, 2.0]), ("est_vh", [1, 2, 3]), ("vh", [0.0, 0.0, 2e9]),
]


@pytest.mark.parametrize("msg", VALID + CARRYING, ids=lambda x: type(x).__name__)
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
    assert m._decode_fast(msgpack.packb(raw)) is None
    with pytest.raises(m.WireError, match="'p'"):
        m.decode(msgpack.packb(raw))


# --- decode_carried: what a graph neighbour reads off a robot's command key -------------------

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


# --- the wire as msgspec reads it: what a dict of the payload cannot show ----------------------

def packed_map(items) -> bytes:
    """A msgpack map of ``items`` in order, repeated keys kept (msgpack.packb of a dict cannot)."""
    return b"\xde" + len(items).to_bytes(2, "big") + b"".join(msgpack.packb(k) + msgpack.packb(v) for k, v in items)


UNREAD = {"v": [0.0, 0.0, 0.0], "ph": [0.0, 0.0, 0.0], "avoid_active": False, "flags": 0, "link_age": [],
          "link_drops": [], "vh": None}  # a command's fields a neighbour leaves to the world, valid


def carried_reference(payload: bytes):
    """What a neighbour must read off ``payload``, by the full path: a command's carried estimate,
    whatever the fields it does not read hold (the world checks those); else decode's outcome."""
    try:
        raw = msgpack.unpackb(payload, strict_map_key=True)
    except Exception:
        raw = None
    if type(raw) is dict and raw.get("kind") == "command":
        try:
            cmd = m.decode(msgpack.packb({**raw, **UNREAD}))
        except m.WireError:
            cmd = None
        if type(cmd) is m.Command and cmd.carried_estimate() is not None:
            return cmd.carried_estimate()
    return as_a_neighbour_sees_it(lambda: m.decode(payload))


def outcomes(payload: bytes, monkeypatch):
    """decode's and decode_carried's outcomes, each beside its reference by the full path."""
    fast, full = both(payload, monkeypatch)
    lean = as_a_neighbour_sees_it(lambda: m.decode_carried(payload))
    return (fast, full), (lean, carried_reference(payload))


@pytest.mark.parametrize("msg", VALID + CARRYING, ids=lambda x: type(x).__name__)
@pytest.mark.parametrize("change", ["repeat-last", "repeat-first", "kind-twice", "no-kind", "extra-key",
                                    "int-key", "bin-key", "schema-float", "schema-float-bad-unread", "float32"])
def test_wire_forms_decode_alike(msg, change, monkeypatch):
    items = list(msgpack.unpackb(m.encode(msg)).items())
    if change == "repeat-last":  # the last value of a repeated key is read, as msgpack keeps it
        items.append(("tick", 99))
    elif change == "repeat-first":
        items.insert(0, ("tick", -5))
    elif change == "kind-twice":
        items.insert(0, ("kind", "clock"))
    elif change == "no-kind":
        items = [(k, v) for k, v in items if k != "kind"]
    elif change == "extra-key":
        items.append(("unheard_of", [float("nan"), b"\x00"]))
    elif change == "int-key":
        items.append((7, 1.0))
    elif change == "bin-key":
        items.append((b"tick", 3))
    elif change == "schema-float":
        items = [(k, float(v) if k == "schema" else v) for k, v in items]
    elif change == "schema-float-bad-unread":  # a neighbour takes the estimate; the world refuses the command
        items = [(k, 2.0 if k == "schema" else None if k == "avoid_active" else v) for k, v in items]
    if change == "float32":  # every float as msgpack float32
        payload = msgpack.packb({**dict(items), "t": 0.5}, use_single_float=True)
    else:
        payload = packed_map(items)
    for got, reference in outcomes(payload, monkeypatch):
        assert same(got, reference), (got, reference)


# Values a field may be given, weighted to the edges of decode's shapes: vectors of 2 to 4
# mostly valid numbers, integers at and beyond the bounds, floats as integers and integers as
# floats, booleans for numbers and numbers for booleans, nothing, text and bytes.
NUMBER = st.one_of(st.floats(-1e9, 1e9), st.integers(-3, 3),
                   st.sampled_from([math.nan, math.inf, -math.inf, 1e9 + 1, -2e9, True, None, "1"]))
ANY_VALUE = st.one_of(
    st.lists(NUMBER, min_size=2, max_size=4), st.lists(st.floats(-1e9, 1e9), min_size=3, max_size=3),
    st.lists(st.integers(-1, 3), max_size=3), st.lists(st.booleans(), max_size=2),
    st.integers(-3, 3), st.sampled_from([-1, 2**53, 2**53 + 1, 2**63, 2**64 - 1, -2**63]),
    NUMBER, st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([2.0, 0.0, -0.0, 1e9]),
    st.booleans(), st.none(), st.text(max_size=3), st.binary(max_size=3),
    st.sampled_from(list(m.KINDS) + list(m.ROLES) + ["nope"]),
)
FIELDS = ["schema", "kind", "role", "sender", "seq", "tick", "t", "robot", "p", "po", "vo", "p0", "v0", "ph", "vh",
          "v", "avoid_active", "flags", "link_age", "link_drops", "est_tick", "est_t", "est_ph", "est_vh"]


def packable(i: int) -> int:
    """``i`` held to msgpack's integers (-2**63 .. 2**64 - 1), so that a near value can be sent."""
    return max(-2**63, min(i, 2**64 - 1))


def near(valid) -> st.SearchStrategy:
    """A value near a field's valid one: an element replaced, one more or fewer, or another type."""
    if type(valid) is list:
        edited = st.tuples(st.integers(0, max(len(valid) - 1, 0)), st.one_of(NUMBER, ANY_VALUE)).map(
            lambda e: [e[1] if i == e[0] else x for i, x in enumerate(valid)] or [e[1]])
        return st.one_of(edited, st.just(valid + valid[:1]), st.just(valid[1:]), ANY_VALUE)
    if type(valid) is bool:
        return st.one_of(st.sampled_from([0, 1, None, "true", 1.0]), ANY_VALUE)
    if type(valid) is int:
        return st.one_of(st.sampled_from([packable(valid + 1), -1, 2**53, 2**53 + 1, float(valid), True, None]),
                         ANY_VALUE)
    if type(valid) is float:
        return st.one_of(st.sampled_from([math.nan, math.inf, 1e9 + 1, packable(round(valid)) if math.isfinite(valid) else 0,
                                          True, None, "x"]), ANY_VALUE)
    return ANY_VALUE


def altered_message_decodes_alike(msg, data):
    """msgspec's checks (the fast path) accept exactly what the full path accepts, and build the same:
    one field, then perhaps another, given a value near its own or any other; perhaps one dropped."""
    raw = msgpack.unpackb(m.encode(msg))
    for _ in range(data.draw(st.integers(1, 2))):
        field = data.draw(st.sampled_from(sorted(raw)) | st.sampled_from(FIELDS))
        raw[field] = data.draw(near(raw[field]) if field in raw else ANY_VALUE)
    if data.draw(st.booleans()):
        raw.pop(data.draw(st.sampled_from(sorted(raw))))
    payload = msgpack.packb(raw)
    with pytest.MonkeyPatch.context() as mp:
        for got, reference in outcomes(payload, mp):
            assert same(got, reference), (got, reference)


def altered_messages(examples: int):
    """The search above as a test of ``examples`` examples (a new test object each call)."""
    return settings(max_examples=examples, deadline=None)(
        given(msg=st.sampled_from(VALID + CARRYING), data=st.data())(altered_message_decodes_alike))


# 300 examples in the quick layer (0.8 s of CPU); the deep search, 1500 (4 s), runs with the slow
# tests (make test, CI): a bug that only a rare pair of fields shows is found there.
test_any_altered_message_decodes_alike = altered_messages(300)
test_any_altered_message_decodes_alike_deeply = pytest.mark.slow(altered_messages(1500))


# --- encode: the bytes it always wrote ----------------------------------------------------------

def reference_bytes(msg) -> bytes:
    """The wire form as msgpack writes it: envelope, then the fields in order (arrays as lists,
    numpy scalars as numbers), optional ones left out when None."""
    out = {"schema": m.SCHEMA_VERSION, "kind": m._KIND_OF[type(msg)]}
    for f in m.fields(msg):
        value = getattr(msg, f.name)
        if value is None and f.name in m._OPTIONAL:
            continue
        out[f.name] = value.tolist() if isinstance(value, (np.ndarray, np.generic)) else value
    return msgpack.packb(out, use_bin_type=True)


STATE = m.WorldState("world", 0, 9, 9, 0.09, np.ones((2, 3)), np.zeros((2, 3)), np.ones((2, 3)) / 3,
                     np.array([1.5, 2.5]), np.array([True, False]), np.zeros((0, 3)),
                     np.array([0, 3], dtype=np.int64), np.array([1, 0], dtype=np.int64))
SCALARS = m.Command("agent", 2, 7, 3, np.float64(0.03), 2, V, V, np.bool_(True), np.int64(5), (0, 2), (1, 0),
                    None, np.int64(4), np.float64(0.04), V, None)


@pytest.mark.parametrize("msg", VALID + CARRYING + [STATE, SCALARS], ids=lambda x: type(x).__name__)
def test_encode_writes_the_bytes_msgpack_writes(msg):
    assert m.encode(msg) == reference_bytes(msg)


def test_encode_refuses_what_has_no_wire_form():
    with pytest.raises(TypeError):
        m.encode(m.Estimate("agent", 2, 1, 0, 0.0, 2, object()))
