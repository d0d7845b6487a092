"""The leader node: publishes the virtual leader's position ``p0(t)``, sans I/O.

Lock-step: answers ``Clock(k)`` with ``LeaderState(k + 1)``, pipelined as the
agents' estimates are (docs/DESIGN.md "Lock-step pipelining"): ``p0`` is a
function of time alone, so the state for the next tick is final now, and a
pinned robot holds it when that tick's sensing arrives instead of waiting for
a second hop (world -> leader -> robot). The first clock, or one after a gap
(a restarted leader), also gets ``LeaderState(k)``. Pinned robots hold a
state for a later tick until they act on it, so every act sees what it saw
before. Real time: :meth:`act` publishes ``p0`` at whatever time it is given.
Only robots with ``b_i > 0`` subscribe to it.
"""

from __future__ import annotations

from fxswarm.core import bus as topics
from fxswarm.core.messages import Clock, LeaderState, Message
from fxswarm.core.scenario import Scenario


class LeaderNode:
    def __init__(self, scenario: Scenario) -> None:
        self.sc = scenario
        self.seq = 0
        self.sent_tick = -1  # lock-step: the latest tick whose state was sent

    def subscriptions(self) -> list[str]:
        return [topics.CLOCK]

    def handle(self, topic: str, msg: Message) -> list[topics.Outgoing]:
        if isinstance(msg, Clock):
            last = min(msg.tick + 1, self.sc.ticks - 1)  # no state for a tick the run never reaches
            first = max(self.sent_tick + 1, msg.tick)
            return [self.act(k, msg.t if k == msg.tick else k * self.sc.dt) for k in range(first, last + 1)]
        return []

    def act(self, tick: int, t: float) -> topics.Outgoing:
        self.seq += 1
        self.sent_tick = max(self.sent_tick, tick)
        return topics.LEADER_STATE, LeaderState("leader", 0, self.seq, tick, t, self.sc.leader.position(t))
