"""Messages between roles, and their wire form (msgpack maps) with validation.

Every message carries the schema version, the sender's role and id, a
sequence number, the tick and the simulation time. :func:`decode` accepts
only well-formed messages (known version and kind, every field of the right
type and shape, every number finite) and raises :class:`WireError` naming
what was wrong otherwise; a node never sees an invalid message.

Vectors travel as lists of 3 floats (msgpack keeps float64 exact, so a
lock-step run over the wire is bit-identical to the in-memory one).

Link health travels with the data it is about: each ``Command`` carries,
per link into its robot (neighbours in ascending id, then the leader if
pinned), the age in ticks of the estimate held and how many of that
sender's messages the robot missed; the world gathers them into
``WorldState`` per directed link (order: :func:`fxswarm.world.node.directed_links`).
Schema 2 added these fields.

Optional fields (``[estimator] tracking = "feedforward"``, docs/estimator.md): ``LeaderState.v0``
(the leader's velocity), ``Estimate.vh`` and ``Command.vh`` (the robot's estimate of it). Left
out of the wire form when None, so a run without them sends the same bytes as before and the
schema version stays 2; when present they are checked as every vector is (3 finite numbers).
The same holds for the drive models' ``Sense.heading``, ``Sense.velocity`` and
``WorldState.heading`` (docs/robots.md).

The estimate rides on the command: a robot's command also carries the estimate it sends its
neighbours next (``Command.est_tick``, ``est_t``, ``est_ph``, ``est_vh``; all four or none),
and neighbours read it from ``agent/<j>/cmd`` (:meth:`Command.carried_estimate`). One put per
robot per tick less; a robot with no command to send yet (its first tick) sends an
``Estimate`` on the same key.
"""

from __future__ import annotations

import math
import threading
from dataclasses import MISSING, dataclass, field, fields
from typing import Annotated, Literal, Union

import msgpack
import msgspec
import numpy as np

SCHEMA_VERSION = 2  # 2: link health (link_age, link_drops) in Command and WorldState

#: Largest magnitude accepted for a coordinate or velocity on the wire (m,
#: m/s): beyond it a value is a corruption, not a robot.
MAX_MAGNITUDE = 1e9


class WireError(ValueError):
    """A payload that is not a valid message of this schema."""


def _message(cls):
    """``@dataclass(frozen=True)`` with a quicker ``__init__``: the same signature and defaults,
    but it fills the instance's ``__dict__`` directly. A frozen dataclass's own ``__init__`` sets
    each field through ``object.__setattr__``, 4 us for a Command, and every message of the hot
    path is built once (docs/benchmarks.md "Where the CPU of a tick goes"). Assignment after
    construction still raises, as for any frozen dataclass; equality, repr and hashing read the
    same attributes. Generated from ``fields()`` as dataclasses generates its own."""
    cls = dataclass(frozen=True)(cls)
    names = [f.name for f in fields(cls)]
    ns: dict = {"_factory": {f.name: f.default_factory for f in fields(cls) if f.default_factory is not MISSING},
                "_FACTORY": _FACTORY}
    params = []
    for f in fields(cls):
        if f.default is not MISSING:
            ns[f"_d_{f.name}"] = f.default
            params.append(f"{f.name}=_d_{f.name}")
        elif f.default_factory is not MISSING:
            params.append(f"{f.name}=_FACTORY")
        else:
            params.append(f.name)
    body = ["    d = self.__dict__"]
    for name in names:
        if name in ns["_factory"]:
            body.append(f"    d[{name!r}] = _factory[{name!r}]() if {name} is _FACTORY else {name}")
        else:
            body.append(f"    d[{name!r}] = {name}")
    exec(f"def __init__(self, {', '.join(params)}):\n" + "\n".join(body) + "\n", ns)
    init = ns["__init__"]
    init.__qualname__ = f"{cls.__qualname__}.__init__"
    init.__doc__ = cls.__init__.__doc__
    cls.__init__ = init
    return cls


_FACTORY = object()  # a field left to its default_factory


@_message
class Message:
    role: str  # sender's role: "world", "leader", "agent"
    sender: int  # sender's id (robot id for agents, 0 otherwise)
    seq: int  # sender's sequence number for this kind of message
    tick: int  # lock-step tick (real time: the sender's loop count)
    t: float  # simulation time of the content, s


@_message
class Clock(Message):
    """The world's tick: everyone may act for ``tick`` at time ``t``."""


@_message
class Sense(Message):
    """What the world tells robot ``robot`` alone: its position and nearest object."""

    robot: int
    p: np.ndarray  # (3,) its position as sensed (the truth unless [world] adds pose noise or delay), m
    po: np.ndarray | None  # (3,) nearest object (obstacle or teammate), m; None if there is none
    vo: np.ndarray | None  # (3,) that object's velocity, m/s
    # With drive models (docs/robots.md), where the robot's model has them; left out otherwise:
    heading: float | None = None  # yaw, rad (a unicycle)
    velocity: np.ndarray | None = None  # (3,) the velocity it moves at, m/s (not a single integrator)


@_message
class LeaderState(Message):
    """The virtual leader's position ``p0(t)``."""

    p0: np.ndarray  # (3,)
    v0: np.ndarray | None = None  # (3,) its velocity dp0/dt, m/s; sent only with tracking = "feedforward"


@_message
class Estimate(Message):
    """A robot's estimate ``ph_i`` of the leader, for its graph neighbours."""

    robot: int
    ph: np.ndarray  # (3,)
    vh: np.ndarray | None = None  # (3,) estimate of the leader's velocity, m/s (tracking = "feedforward")


@_message
class Command(Message):
    """A robot's velocity command, with what it reports about itself."""

    robot: int
    v: np.ndarray  # (3,) m/s
    ph: np.ndarray  # (3,) estimate the command was computed from
    avoid_active: bool
    flags: int = 0  # bit set of degraded modes (see fxswarm.agents.node)
    # Per link into this robot, neighbours in ascending id then the leader if pinned:
    link_age: tuple[int, ...] = ()  # ticks since the tick of the estimate held (none held: since tick -1)
    link_drops: tuple[int, ...] = ()  # that sender's messages missed so far (sequence gaps seen)
    vh: np.ndarray | None = None  # (3,) leader-velocity estimate used with ph, m/s (tracking = "feedforward")
    # The estimate this robot sends its neighbours next (the ``Estimate`` it would otherwise put
    # separately): its tick, time (s), ph (3,) and vh (3,) (vh with tracking = "feedforward").
    est_tick: int | None = None
    est_t: float | None = None
    est_ph: np.ndarray | None = None
    est_vh: np.ndarray | None = None
    law_error: str | None = None  # the robot's law failed this tick: why (fxswarm.core.laws)

    def carried_estimate(self) -> "Estimate | None":
        """The :class:`Estimate` this command carries (numbered as the command), or None."""
        if self.est_ph is None or self.est_tick is None or self.est_t is None:
            return None
        return Estimate(self.role, self.sender, self.seq, self.est_tick, self.est_t, self.robot, self.est_ph,
                        self.est_vh)


@_message
class WorldState(Message):
    """The world's whole state at a tick, for loggers and recorders."""

    p: np.ndarray  # (n, 3) positions
    v: np.ndarray  # (n, 3) velocities applied
    ph: np.ndarray  # (n, 3) estimates reported with the commands
    nearest: np.ndarray  # (n,) distance to the nearest object, m
    avoid: np.ndarray  # (n,) bool, avoidance active
    obstacles: np.ndarray  # (m, 3) obstacle positions
    # Per directed link j -> i (order: fxswarm.world.node.directed_links), as robot i last reported
    # it, its age grown by the ticks since that report:
    link_age: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # (L,) ticks
    link_drops: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # (L,) messages missed
    heading: np.ndarray | None = None  # (n,) yaw, rad, with a unicycle in the swarm (docs/robots.md)


KINDS: dict[str, type[Message]] = {
    "clock": Clock, "sense": Sense, "leader": LeaderState, "estimate": Estimate,
    "command": Command, "state": WorldState,
}
_KIND_OF = {cls: name for name, cls in KINDS.items()}
# Field names per message class, once: dataclasses.fields() rebuilds its tuple on every call,
# a few microseconds each on the hot path (every message encoded and decoded).
_FIELDS: dict[type, tuple[str, ...]] = {cls: tuple(f.name for f in fields(cls)) for cls in KINDS.values()}
ROLES = ("world", "leader", "agent", "logger", "test")

# Field types: "vec" (3,), "vec?" (3,) or None, "mat" (n, 3), "row" (n,), "int", "bool",
# "counts" (L,) non-negative integers as a tuple, "countrow" the same as an int64 array.
_SHAPES: dict[str, str] = {
    "p": "vec", "po": "vec?", "vo": "vec?", "p0": "vec", "ph": "vec", "v": "vec",
    "vh": "vec?", "v0": "vec?", "est_ph": "vec?", "est_vh": "vec?", "est_tick": "int?", "est_t": "float?",
    "robot": "int", "avoid_active": "bool", "flags": "int", "link_age": "counts", "link_drops": "counts",
    "law_error": "text?", "heading": "float?", "velocity": "vec?",
}
_STATE_SHAPES = {"p": "mat", "v": "mat", "ph": "mat", "nearest": "row", "avoid": "boolrow", "obstacles": "mat",
                 "link_age": "countrow", "link_drops": "countrow", "heading": "row?"}
_MAX_COUNT = 2**53
#: Fields a payload may leave out (None then); encode leaves them out when None.
_OPTIONAL = frozenset({"vh", "v0", "est_tick", "est_t", "est_ph", "est_vh", "law_error", "heading", "velocity"})
#: The longest text field (``law_error``) a message may carry, characters.
MAX_TEXT = 200


def encode(msg: Message) -> bytes:
    """The msgpack wire form of ``msg``: a map of the envelope (``schema``, ``kind``), then its
    fields in order, optional ones left out when None. Arrays and numpy scalars travel as lists
    and plain numbers (msgspec calls :func:`_plain` for them); the rest msgspec writes in C."""
    # Envelope keys must not collide with field names (Command and WorldState have a field "v").
    cls = type(msg)
    out = {"schema": SCHEMA_VERSION, "kind": _KIND_OF[cls]}
    out.update(msg.__dict__)  # exactly its fields, in order: set only by its __init__ or by decode
    for name in _LEFT_OUT[cls]:
        if out[name] is None:
            del out[name]  # absent on the wire: "paper" tracking sends the bytes it always did
    try:
        write = _local.encode
    except AttributeError:  # this thread's first message
        write = _local.encode = msgspec.msgpack.Encoder(enc_hook=_plain).encode
    return write(out)


def _plain(obj):
    """What msgspec writes for a value it does not know: an array as (nested) lists, a numpy
    scalar as a Python number."""
    if isinstance(obj, (np.ndarray, np.generic)):
        return obj.tolist()
    raise TypeError(f"cannot put a {type(obj).__name__} on the wire")


# One Encoder per thread: an Encoder keeps its output buffer between calls, and _plain runs
# Python code mid-message, where another thread could take the GIL and the same Encoder.
_local = threading.local()
#: Per message class, its fields left out of the wire form when None.
_LEFT_OUT = {cls: tuple(name for name in _FIELDS[cls] if name in _OPTIONAL) for cls in KINDS.values()}


def _finite_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and abs(x) <= MAX_MAGNITUDE


def _check(name: str, shape: str, value):
    if shape in ("int?", "float?", "vec?", "text?", "row?") and value is None:
        return None
    if shape == "text?":
        if not isinstance(value, str) or len(value) > MAX_TEXT:
            raise WireError(f"field {name!r}: expected a text of at most {MAX_TEXT} characters")
        return value
    if shape == "float?":
        if not _finite_number(value):
            raise WireError(f"field {name!r}: expected a finite number")
        return float(value)
    if shape in ("int", "int?"):
        if not isinstance(value, int) or isinstance(value, bool) or value < 0 or value > 2**53:
            raise WireError(f"field {name!r}: expected a non-negative integer")
        return value
    if shape == "bool":
        if not isinstance(value, bool):
            raise WireError(f"field {name!r}: expected a boolean")
        return value
    if shape == "vec?" and value is None:
        return None
    if shape in ("vec", "vec?"):
        # The common case first, without a generator per element (a third of decode's time):
        # three floats within bounds (NaN fails every comparison, so it takes the slow path).
        if type(value) is list and len(value) == 3:
            x, y, z = value
            if (type(x) is float and type(y) is float and type(z) is float
                    and -MAX_MAGNITUDE <= x <= MAX_MAGNITUDE and -MAX_MAGNITUDE <= y <= MAX_MAGNITUDE
                    and -MAX_MAGNITUDE <= z <= MAX_MAGNITUDE):
                return np.array(value)
        if not isinstance(value, list) or len(value) != 3 or not all(_finite_number(x) for x in value):
            raise WireError(f"field {name!r}: expected 3 finite numbers")
        return np.array(value, dtype=float)
    if shape == "mat":
        if not isinstance(value, list) or not all(
            isinstance(r, list) and len(r) == 3 and all(_finite_number(x) for x in r) for r in value
        ):
            raise WireError(f"field {name!r}: expected rows of 3 finite numbers")
        return np.array(value, dtype=float).reshape(-1, 3)
    if shape in ("row", "row?"):
        if not isinstance(value, list) or not all(_finite_number(x) for x in value):
            raise WireError(f"field {name!r}: expected a list of finite numbers")
        return np.array(value, dtype=float)
    if shape in ("counts", "countrow"):
        if not isinstance(value, list) or not all(type(x) is int and 0 <= x <= _MAX_COUNT for x in value):
            raise WireError(f"field {name!r}: expected a list of non-negative integers")
        return tuple(value) if shape == "counts" else np.array(value, dtype=np.int64)
    if shape == "boolrow":
        if not isinstance(value, list) or not all(isinstance(x, bool) for x in value):
            raise WireError(f"field {name!r}: expected a list of booleans")
        return np.array(value, dtype=bool)
    raise AssertionError(shape)


# The hot path's wire types, from _SHAPES: msgspec checks a payload's types, bounds and shapes
# in C as it parses it, where a Python check per field cost more than parsing (docs/benchmarks.md
# "Where the CPU of a tick goes"). It accepts only what decode's full path accepts; anything
# else it refuses, and the full path then decides and names the error. Per msgspec: an int is
# taken for a float (as the full path does), never a float or a bool for an int, nor an int for
# a bool; NaN and infinities fail the bounds; unknown keys are skipped, as the full path ignores
# them; a repeated key's last value is the one read, as msgpack.unpackb keeps it.
_Number = Annotated[float, msgspec.Meta(ge=-MAX_MAGNITUDE, le=MAX_MAGNITUDE)]
_Count = Annotated[int, msgspec.Meta(ge=0, le=_MAX_COUNT)]
_Vector = tuple[_Number, _Number, _Number]
# The version as the full path compares it (== SCHEMA_VERSION, so 2.0 too): decode_carried's
# read fields must be refused exactly when the full path refuses them, else its fallback to
# decode would judge the fields a neighbour does not read.
_Schema = Annotated[float, msgspec.Meta(ge=SCHEMA_VERSION, le=SCHEMA_VERSION)]
_WIRE_TYPE = {"vec": _Vector, "vec?": _Vector | None, "int": _Count, "int?": _Count | None,
              "float?": _Number | None, "bool": bool, "counts": tuple[_Count, ...],
              "text?": Annotated[str, msgspec.Meta(max_length=MAX_TEXT)] | None}
_ENVELOPE = ("role", "sender", "seq", "tick", "t")


def _wire_struct(kind: str, names: tuple[str, ...], tagged: bool = True) -> type[msgspec.Struct]:
    """The msgspec type of a payload of ``kind`` holding the envelope and the fields ``names``,
    with decode's shapes, and each field's default as on the full path (absent optional fields
    None, absent ``flags`` 0). ``kind`` is the tag of a union's member (``tagged``), else a field
    like the others: a lone tagged type would take a payload with no ``kind`` at all."""
    spec = [("schema", _Schema), ("role", Literal[ROLES]), ("sender", _Count), ("seq", _Count),
            ("tick", _Count), ("t", _Number)]
    if not tagged:
        spec.append(("kind", Literal[kind]))
    for name in names:
        typ = _WIRE_TYPE[_SHAPES[name]]
        spec.append((name, typ, None) if name in _OPTIONAL else (name, typ, 0) if name == "flags" else (name, typ))
    if tagged:
        return msgspec.defstruct(f"_{kind}_wire", spec, kw_only=True, tag_field="kind", tag=kind)
    return msgspec.defstruct(f"_{kind}_wire", spec, kw_only=True)


def _hot_types() -> dict[type, tuple[type, tuple[str, ...], tuple[str, ...]]]:
    """Per kind of the hot path (all but WorldState): its wire type -> (message class, its fields,
    those that are vectors)."""
    out = {}
    for kind, cls in KINDS.items():
        if cls is not WorldState:
            names = tuple(f for f in _FIELDS[cls] if f not in _ENVELOPE)
            out[_wire_struct(kind, names)] = (cls, _ENVELOPE + names,
                                              tuple(f for f in names if _SHAPES[f] in ("vec", "vec?")))
    return out


_HOT = _hot_types()
_HOT_DECODER = msgspec.msgpack.Decoder(Union[tuple(_HOT)])
_new = object.__new__


def _decode_fast(payload: bytes) -> Message | None:
    """The usual message, parsed and checked by msgspec and built in one pass; None for anything
    else (then :func:`decode`'s full path decides, and names the error). Builds what the full
    path builds: vectors as float arrays, counts as tuples."""
    try:
        wire = _HOT_DECODER.decode(payload)
    except (msgspec.ValidationError, msgspec.DecodeError):
        return None
    cls, names, vectors = _HOT[type(wire)]
    values = {name: getattr(wire, name) for name in names}
    for name in vectors:
        value = values[name]
        if value is not None:
            values[name] = np.array(value)
    if "link_age" in values and len(values["link_age"]) != len(values["link_drops"]):
        return None
    if "est_ph" in values and _partial_estimate(values):
        return None
    msg = _new(cls)
    msg.__dict__.update(values)  # its checked fields at once, as its __init__ would set them
    return msg


def decode(payload: bytes) -> Message:
    """Parse and validate a wire payload; raises :class:`WireError` on anything malformed."""
    msg = _decode_fast(payload)
    if msg is not None:
        return msg
    try:
        raw = msgpack.unpackb(payload, raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several unrelated types on garbage
        raise WireError(f"not msgpack: {type(exc).__name__}") from None
    if not isinstance(raw, dict):
        raise WireError("not a map")
    if raw.get("schema") != SCHEMA_VERSION:
        raise WireError(f"unknown schema version {raw.get('schema')!r}")
    kind = raw.get("kind")
    cls = KINDS.get(kind) if isinstance(kind, str) else None  # a list here is no kind (nor hashable)
    if cls is None:
        raise WireError(f"unknown message kind {raw.get('kind')!r}")
    role = raw.get("role")
    if role not in ROLES:
        raise WireError(f"unknown role {role!r}")
    t = raw.get("t")
    if not _finite_number(t):
        raise WireError("field 't': expected a finite time")
    values = {"role": role, "t": float(t)}
    for name in ("sender", "seq", "tick"):
        values[name] = _check(name, "int", raw.get(name))
    shapes = _STATE_SHAPES if cls is WorldState else _SHAPES
    for name in _FIELDS[cls]:
        if name in values:
            continue
        if name not in raw:
            if name == "flags":
                values[name] = 0
                continue
            if name in _OPTIONAL:
                values[name] = None
                continue
            raise WireError(f"missing field {name!r}")
        values[name] = _check(name, shapes[name], raw[name])
    if cls is WorldState:
        n = len(values["p"])
        if not all(len(values[k]) == n for k in ("v", "ph", "nearest", "avoid")) or (
                values["heading"] is not None and len(values["heading"]) != n):
            raise WireError("world state: arrays of different robot counts")
    if "link_age" in values and len(values["link_age"]) != len(values["link_drops"]):
        raise WireError("link_age and link_drops: different link counts")
    if "est_ph" in values and _partial_estimate(values):
        raise WireError("est_tick, est_t, est_ph: a carried estimate needs all three")
    return cls(**values)


def decode_carried(payload: bytes) -> Message:
    """What a graph neighbour reads off a robot's command key: the :class:`Estimate` a command
    carries (as :meth:`Command.carried_estimate` gives it), checked and built without the rest.

    A neighbour uses only the envelope, ``robot`` and the ``est_*`` fields: it checks those as
    :func:`decode` would and leaves the command's other fields (``v``, ``ph``, link health) to
    the world, which reads them. Anything else (a command carrying no estimate, a robot's first
    ``Estimate`` sent alone, or a payload whose read fields are not valid) goes through
    :func:`decode`, so it is returned or refused exactly as there (:class:`WireError`).
    One array is built, not three or four: in a real run every one is built with cold caches
    (docs/benchmarks.md "Where the CPU of a tick goes").
    """
    try:
        est = _CARRIED_DECODER.decode(payload)
    except (msgspec.ValidationError, msgspec.DecodeError):
        est = None
    if est is not None and est.est_tick is not None and est.est_t is not None and est.est_ph is not None:
        return Estimate(est.role, est.sender, est.seq, est.est_tick, est.est_t, est.robot, np.array(est.est_ph),
                        None if est.est_vh is None else np.array(est.est_vh))
    return decode(payload)


#: What a neighbour reads off a command (decode_carried): the envelope, ``robot`` and the carried
#: estimate, with decode's shapes; the command's other keys are skipped unread.
_CARRIED_DECODER = msgspec.msgpack.Decoder(
    _wire_struct("command", ("robot", "est_tick", "est_t", "est_ph", "est_vh"), tagged=False))


def _partial_estimate(values: dict) -> bool:
    """Whether a command's carried estimate is half there (est_vh alone may be absent)."""
    have = [values["est_tick"] is not None, values["est_t"] is not None, values["est_ph"] is not None]
    return any(have) and not all(have) or (values["est_vh"] is not None and not all(have))
