"""The bounded ring buffer between the bus's delivery threads and the logger.

The bus must never wait on the logger: a delivery callback only appends
here (O(1), no lock held beyond the GIL) and returns. When the logger falls
behind, the *oldest* entries are overwritten, so the live view stays
current, and every overwritten entry is counted in :attr:`Inbox.dropped`.
"""

from __future__ import annotations

from collections import deque
from typing import Any, Iterator


class Inbox:
    """A ring of at most ``capacity`` items; :meth:`put` from any thread, :meth:`drain` from one."""

    def __init__(self, capacity: int = 4096) -> None:
        if capacity < 1:
            raise ValueError(f"inbox capacity: expected a positive integer, got {capacity}")
        self.capacity = capacity
        self._ring: deque = deque(maxlen=capacity)
        self.dropped = 0
        self.accepted = 0

    def put(self, item: Any) -> None:
        # deque.append with maxlen is atomic; the length check may race with drain() by
        # one item, which can only under-count a drop that did not quite happen.
        if len(self._ring) >= self.capacity:
            self.dropped += 1
        self._ring.append(item)
        self.accepted += 1

    def drain(self, limit: int | None = None) -> Iterator[Any]:
        """Yield queued items, oldest first (at most ``limit``)."""
        pop = self._ring.popleft
        k = 0
        while self._ring and (limit is None or k < limit):
            try:
                yield pop()
            except IndexError:
                return
            k += 1

    def __len__(self) -> int:
        return len(self._ring)
