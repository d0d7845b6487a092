"""fetch_record checks what it is sent: size, digest and tick count, before anything is written."""

from __future__ import annotations

import hashlib
import io
import json
from types import SimpleNamespace

import numpy as np
import pytest

from fxswarm.runtime.record import RecordError, fetch_record


def npz(ticks: int) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, t=np.arange(ticks) * 0.01)
    return buf.getvalue()


class FakeSession:
    """Answers ``get`` as a world's RecordServer would, from ``manifest`` and ``parts``."""

    def __init__(self, manifest: dict, parts: list[bytes]) -> None:
        self.manifest, self.parts = manifest, parts

    def get(self, selector: str, timeout: float):
        _, _, query = selector.partition("?")
        payload = json.dumps(self.manifest).encode() if not query else self.parts[int(query.split("=")[1])]
        return [SimpleNamespace(ok=SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: payload)))]


def manifest_for(blob: bytes, ticks: int, parts: int, summary_ticks: int | None = None) -> dict:
    return {"version": 1, "ticks": ticks, "size": len(blob), "sha256": hashlib.sha256(blob).hexdigest(),
            "chunk_bytes": len(blob) // parts + 1, "parts": parts,
            "summary": {"ticks": ticks if summary_ticks is None else summary_ticks}}


def halves(blob: bytes) -> list[bytes]:
    return [blob[: len(blob) // 2], blob[len(blob) // 2:]]


def fetch(session):
    return fetch_record(session, "fxswarm/s/world/record", lambda: "gave up", lambda s: None)


def test_a_whole_record_comes_back_byte_for_byte():
    blob = npz(300)
    record = fetch(FakeSession(manifest_for(blob, 300, 2), halves(blob)))
    assert record.trajectory == blob and record.summary == {"ticks": 300}


def test_a_damaged_part_is_refused():
    blob = npz(300)
    parts = halves(blob)
    parts[1] = parts[1][:-1] + bytes([parts[1][-1] ^ 1])
    with pytest.raises(RecordError, match="damaged"):
        fetch(FakeSession(manifest_for(blob, 300, 2), parts))


def test_a_record_with_fewer_ticks_than_its_summary_says_is_refused():
    blob = npz(299)
    with pytest.raises(RecordError, match="holds 299 ticks"):
        fetch(FakeSession(manifest_for(blob, 299, 2, summary_ticks=300), halves(blob)))


def test_no_answer_gives_up_with_the_callers_reason():
    class Nobody:
        def get(self, selector, timeout):
            return []

    with pytest.raises(RecordError, match="gave up"):
        fetch(Nobody())
