"""Sending many frames of one entity in one ``rr.send_columns`` call.

One ``rr.log`` per entity per frame costs tens of microseconds of Python
each (notes/rerun.md); one column batch of a hundred frames costs about the
same as one ``log``. The recorder buffers frames and sends them here.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import rerun as rr

from fxswarm.logger.style import TICK_TIMELINE, TIMELINE

_STRIP_TYPE = rr.components.LineStrip3DBatch._ARROW_DATATYPE
_POINT_FIELD = pa.field("item", pa.float32(), nullable=False)


def send_rows(rec: rr.RecordingStream, path: str, archetype, t: np.ndarray, ticks: np.ndarray,
              per_row: int | np.ndarray, **components) -> None:
    """Send ``len(t)`` rows of ``archetype`` (e.g. ``rr.Points3D``) to entity ``path``.

    t: (F,) simulation times, s; ticks: (F,); per_row: instances per row (one
    number, or (F,)); components: keyword arguments of ``archetype.columns``,
    each holding every row's instances back to back.
    """
    if len(t) == 0:
        return
    lengths = np.broadcast_to(np.asarray(per_row, dtype=np.int64), (len(t),))
    rec.send_columns(
        path,
        indexes=[rr.TimeColumn(TIMELINE, duration=np.asarray(t, dtype=float)),
                 rr.TimeColumn(TICK_TIMELINE, sequence=np.asarray(ticks, dtype=np.int64))],
        columns=archetype.columns(**components).partition(lengths),
    )


def strips_array(points: np.ndarray, lengths: np.ndarray) -> pa.Array:
    """Line strips as one Arrow list array: ``points`` (N, 3) back to back, ``lengths`` (S,) per strip.

    Built in numpy: Rerun's own conversion of a list of strips works one strip
    at a time in Python (about 60 us each).
    """
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int32)
    flat = np.ascontiguousarray(points, dtype=np.float32).reshape(-1)
    inner = pa.FixedSizeListArray.from_arrays(pa.array(flat, type=pa.float32()), type=pa.list_(_POINT_FIELD, 3))
    return pa.ListArray.from_arrays(pa.array(offsets), inner, type=_STRIP_TYPE)
