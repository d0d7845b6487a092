"""The leader node: publishes the virtual leader's position ``p0(t)``, sans I/O.

Lock-step: answers each ``Clock(k)`` with ``LeaderState(k)``. Real time:
:meth:`act` publishes ``p0`` at whatever time it is given. Only robots with
``b_i > 0`` subscribe to it.
"""

from __future__ import annotations

from fxswarm.core import bus as topics
from fxswarm.core.messages import Clock, LeaderState, Message
from fxswarm.core.scenario import Scenario


class LeaderNode:
    def __init__(self, scenario: Scenario) -> None:
        self.sc = scenario
        self.seq = 0

    def subscriptions(self) -> list[str]:
        return [topics.CLOCK]

    def handle(self, topic: str, msg: Message) -> list[topics.Outgoing]:
        if isinstance(msg, Clock):
            return [self.act(msg.tick, msg.t)]
        return []

    def act(self, tick: int, t: float) -> topics.Outgoing:
        self.seq += 1
        return topics.LEADER_STATE, LeaderState("leader", 0, self.seq, tick, t, self.sc.leader.position(t))
