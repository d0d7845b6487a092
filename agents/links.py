"""Link health at the receiver: what a robot knows about each link into it.

Per in-link (a graph neighbour's estimates, or the leader's state if the
robot is pinned): the sequence numbers heard, and from them how many of the
sender's messages this robot missed. It is measured here, after the
robot's inbox (and any fault filter in front of it), so the count is what
the robot really lost, not what the network carried to someone else.

A gap in the numbers counts as missed at once; a message that arrives late
(a delay, not a loss) is taken off the count when it comes. A repeated
number (a duplicate) changes nothing. A sender whose numbers start again
(a restarted process: a lower number for a newer tick) starts a new count
from its new first number.
"""

from __future__ import annotations

#: Missed sequence numbers remembered per link, so that a late arrival can be told from a duplicate.
MAX_REMEMBERED = 1024


class InLinks:
    """Sequence-gap counters for the links into one robot, indexed by position in ``senders``."""

    def __init__(self, senders: list[int]) -> None:
        self.senders = list(senders)  # robot ids, 0 for the leader, in report order
        self.index = {s: k for k, s in enumerate(self.senders)}
        m = len(self.senders)
        self.last_seq = [0] * m
        self.last_tick = [-1] * m
        self.drops = [0] * m
        self._missing: list[set[int] | None] = [None] * m

    def heard(self, sender: int, seq: int, tick: int) -> None:
        """A message of ``sender`` (robot id, 0: the leader) numbered ``seq`` (tick ``tick``) arrived."""
        k = self.index[sender]
        last = self.last_seq[k]
        if seq == last + 1:  # the usual case, for every message: keep it short
            self.last_seq[k] = seq
            if tick > self.last_tick[k]:
                self.last_tick[k] = tick
            return
        if seq > last:
            if seq > last + 1:
                self._missed(k, last + 1, seq)
            self.last_seq[k] = seq
        elif seq < last:
            missing = self._missing[k]
            if missing is not None and seq in missing:
                missing.discard(seq)  # late, not lost
                self.drops[k] -= 1
            elif tick > self.last_tick[k]:  # numbering started again: a restarted sender
                self._missing[k] = None
                self.last_seq[k] = seq
                if seq > 1:
                    self._missed(k, 1, seq)
        if tick > self.last_tick[k]:
            self.last_tick[k] = tick

    def _missed(self, k: int, first: int, end: int) -> None:
        """Numbers ``first .. end - 1`` on link ``k`` did not arrive (yet)."""
        self.drops[k] += end - first
        missing = self._missing[k]
        if missing is None:
            missing = self._missing[k] = set()
        missing.update(range(max(first, end - MAX_REMEMBERED), end))
        if len(missing) > 2 * MAX_REMEMBERED:  # forget the oldest: they stay counted as missed
            floor = end - MAX_REMEMBERED
            self._missing[k] = {s for s in missing if s >= floor}
