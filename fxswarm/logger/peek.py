"""Reading only a message's header off the wire: what the logger needs from most messages.

The logger uses an estimate or a leader state only for its sender, sequence
number and tick (link health), and logs only one world state in several
(the log rate). Decoding and validating a whole ``WorldState`` costs about
forty times as much as reading its first keys, so the logger reads the
header first, checks it as strictly as :func:`fxswarm.core.messages.decode`
would, and decodes fully only what it will draw.

Keys are read in whatever order they come, skipping (not decoding) the
others, and reading stops as soon as the header is complete; ``encode``
writes the header first, so that is after seven keys. The envelope keys
(``schema``, ``kind``) are the wire's; the tests peek at ``encode``'s output,
so a change there shows up as a failing test, not as a misread.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import msgpack

from fxswarm.core.messages import KINDS, MAX_MAGNITUDE, ROLES, SCHEMA_VERSION

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
        unpacker = msgpack.Unpacker(raw=False, strict_map_key=True)
        unpacker.feed(payload)
        found: dict = {}
        for _ in range(unpacker.read_map_header()):
            key = unpacker.unpack()
            if key in _HEADER and key not in found:
                found[key] = unpacker.unpack()
                if len(found) == len(_HEADER):
                    break
            else:
                unpacker.skip()
        else:
            return None  # the map ended before the header was complete
    except Exception:  # msgpack raises several unrelated types on garbage
        return None
    v, kind, role, sender, seq, tick, t = (found[k] for k in _HEADER)
    if v != SCHEMA_VERSION or kind not in KINDS or role not in ROLES:
        return None
    if not (_count(sender) and _count(seq) and _count(tick)):
        return None
    if not (isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t) and abs(t) <= MAX_MAGNITUDE):
        return None
    return Header(kind, role, sender, seq, tick, float(t))
