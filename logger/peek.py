"""Reading only a message's header off the wire: what the logger needs from most messages.

The logger logs only one world state in several (the log rate): for the
others it needs only the time. :func:`fxswarm.core.messages.decode` validates every field
in Python, which for a ``WorldState`` costs tens of times what msgpack's C
unpacker takes to read the map; so the logger unpacks, checks the header as
strictly as ``decode`` would, and decodes fully only what it will draw.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import msgpack

from fxswarm.core.messages import KINDS, MAX_MAGNITUDE, ROLES, SCHEMA_VERSION

#: The wire's envelope and header keys (``encode`` writes them first). The tests peek at
#: ``encode``'s own output, so a change of the wire shows up as a failing test, not a misread.
_HEADER = ("schema", "kind", "role", "sender", "seq", "tick", "t")


class Header(NamedTuple):
    kind: str  # "estimate", "leader", "state", ...
    role: str
    sender: int
    seq: int
    tick: int
    t: float  # s


def _count(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool) and 0 <= x <= 2**53


def peek_header(payload: bytes) -> Header | None:
    """The header of a wire message, validated; None if it is not a well-formed one."""
    try:
        raw = msgpack.unpackb(payload, raw=False, strict_map_key=True)
    except Exception:  # msgpack raises several unrelated types on garbage
        return None
    if not isinstance(raw, dict):
        return None
    v, kind, role, sender, seq, tick, t = (raw.get(k) for k in _HEADER)
    if v != SCHEMA_VERSION or not isinstance(kind, str) or kind not in KINDS or role not in ROLES:
        return None
    if not (_count(sender) and _count(seq) and _count(tick)):
        return None
    if not (isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t) and abs(t) <= MAX_MAGNITUDE):
        return None
    return Header(kind, role, sender, seq, tick, float(t))
