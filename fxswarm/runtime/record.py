"""The world's own record of a run, served over Zenoh to whoever needs the run folder from afar.

The live stream (``world/state``) drops under load, so a run folder rebuilt from it can miss
ticks. Once the run has ended the world answers queries on ``world/record``
(:data:`fxswarm.core.bus.WORLD_RECORD`) with the files it wrote itself:

* ``world/record``: a JSON manifest, ``{"version", "ticks", "size", "sha256", "chunk_bytes",
  "parts", "summary"}``: the world's ``summary.json`` and what its ``trajectory.npz`` is;
* ``world/record?part=i``: the i-th ``chunk_bytes`` slice of that ``trajectory.npz``.

:func:`fetch_record` asks for both and checks them (size, SHA-256, and the number of ticks in the
arrays against the manifest's and the summary's) before anything is written.
"""

from __future__ import annotations

import hashlib
import io
import json
from dataclasses import dataclass
from typing import Callable

import numpy as np
import zenoh

VERSION = 1
CHUNK_BYTES = 1 << 20  # a reply each; Zenoh fragments larger ones too, but one lost fragment costs the whole
GET_TIMEOUT_S = 10.0


class RecordError(RuntimeError):
    """No record, or one that fails its checks (the message says which)."""


@dataclass(frozen=True)
class Record:
    """The world's ``summary.json`` (parsed) and its ``trajectory.npz`` (the file's bytes)."""

    summary: dict
    trajectory: bytes


class RecordServer:
    """Answers ``<root>/world/record`` queries on ``session`` with ``record`` until :meth:`close`.

    :attr:`served`: how many times the last part was sent (a whole record fetched)."""

    def __init__(self, session: zenoh.Session, key: str, record: Record, chunk_bytes: int = CHUNK_BYTES) -> None:
        blob = record.trajectory
        self._parts = [blob[i:i + chunk_bytes] for i in range(0, len(blob), chunk_bytes)] or [b""]
        self._manifest = json.dumps({
            "version": VERSION, "ticks": record.summary.get("ticks"), "size": len(blob),
            "sha256": hashlib.sha256(blob).hexdigest(), "chunk_bytes": chunk_bytes, "parts": len(self._parts),
            "summary": record.summary}).encode()
        self.served = 0
        self._queryable = session.declare_queryable(key, self._on_query)

    def _on_query(self, query: zenoh.Query) -> None:  # a Zenoh thread
        part = query.parameters.get("part")
        if part is None:
            query.reply(query.key_expr, self._manifest)
            return
        try:
            i = int(part)
            payload = self._parts[i]
        except (ValueError, IndexError):
            query.reply_err(f"no part {part!r}: 0 to {len(self._parts) - 1}".encode())
            return
        query.reply(query.key_expr, payload)
        if i == len(self._parts) - 1:
            self.served += 1

    def close(self) -> None:
        try:
            self._queryable.undeclare()
        except zenoh.ZError:
            pass


def _ask(session: zenoh.Session, selector: str, timeout: float) -> bytes | None:
    """The first good reply's payload, or None (no queryable, an error reply, or the timeout)."""
    for reply in session.get(selector, timeout=timeout):
        if reply.ok is not None:
            return reply.ok.payload.to_bytes()
    return None


def fetch_record(session: zenoh.Session, key: str, give_up: Callable[[], str | None],
                 wait: Callable[[float], object], timeout: float = GET_TIMEOUT_S) -> Record:
    """Ask ``key`` for the record until it answers (the world serves it once it has written it),
    then for each part; check it. Between attempts ``wait(s)`` (e.g. the bus's poll, so the
    caller's liveliness keeps flowing); ``give_up()`` returns a reason to stop (e.g. the world has
    left), or None. Raises :class:`RecordError`."""
    while (raw := _ask(session, key, timeout)) is None:
        reason = give_up()
        if reason is not None:
            raise RecordError(f"no record at {key}: {reason}")
        wait(0.2)
    try:
        manifest = json.loads(raw)
        size, digest, parts, ticks = manifest["size"], manifest["sha256"], manifest["parts"], manifest["ticks"]
        summary = manifest["summary"]
    except (ValueError, KeyError, TypeError) as exc:
        raise RecordError(f"the record's manifest at {key} is not one: {exc}") from None
    chunks = []
    for i in range(parts):
        chunk = None
        for _attempt in range(3):  # a part lost on a loaded link is asked for again
            chunk = _ask(session, f"{key}?part={i}", timeout)
            if chunk is not None:
                break
        if chunk is None:
            raise RecordError(f"part {i} of {parts} of the record at {key} never came")
        chunks.append(chunk)
    blob = b"".join(chunks)
    if len(blob) != size or hashlib.sha256(blob).hexdigest() != digest:
        raise RecordError(f"the record at {key} is damaged: {len(blob)} bytes (expected {size}), digest mismatch")
    try:
        with np.load(io.BytesIO(blob)) as data:
            got = len(data["t"])
    except (ValueError, KeyError, OSError) as exc:
        raise RecordError(f"the record's trajectory at {key} does not load: {exc}") from None
    if got != ticks or summary.get("ticks") != ticks:
        raise RecordError(f"the record at {key} holds {got} ticks; its manifest says {ticks}, "
                          f"its summary {summary.get('ticks')}")
    return Record(summary, blob)
