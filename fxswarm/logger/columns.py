"""Frames buffered as columns and sent with ``rr.send_columns``, many rows per call.

One ``rr.log`` per entity per frame costs tens of microseconds of Python
each (notes/rerun.md); a column batch of 25 frames costs about the same as
one. Every entity keeps its own rows and times, so entities logged at
different rates (trails) share the mechanism.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import rerun as rr

from fxswarm.logger.style import TICK_TIMELINE, TIMELINE


@dataclass
class EntityColumns:
    """The buffered rows of one entity of archetype ``archetype`` (e.g. ``rr.Points3D``).

    Each row gives, per component (a keyword of ``archetype.columns``), an array
    of ``length`` instances; all components of a row have the same length.
    """

    path: str
    archetype: type
    times: list[float] = field(default_factory=list)
    ticks: list[int] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)
    rows: dict[str, list] = field(default_factory=dict)

    def add(self, t: float, tick: int, **components) -> None:
        length = None
        for name, value in components.items():
            if length is None:
                length = len(value)
            self.rows.setdefault(name, []).append(value)
        self.times.append(t)
        self.ticks.append(tick)
        self.lengths.append(int(length or 0))

    def __len__(self) -> int:
        return len(self.times)

    def send(self, rec: rr.RecordingStream) -> None:
        if not self.times:
            return
        parts = {}
        for name, rows in self.rows.items():
            first = rows[0]
            if isinstance(first, list):  # e.g. line strips: a list of (k, 3) arrays per row
                parts[name] = [strip for row in rows for strip in row]
            else:
                parts[name] = np.concatenate(rows)
        rec.send_columns(
            self.path,
            indexes=[rr.TimeColumn(TIMELINE, duration=np.asarray(self.times)),
                     rr.TimeColumn(TICK_TIMELINE, sequence=np.asarray(self.ticks))],
            columns=self.archetype.columns(**parts).partition(self.lengths),
        )
        self.times, self.ticks, self.lengths, self.rows = [], [], [], {}
