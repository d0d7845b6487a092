"""The leader node: publishes the virtual leader's position ``p0(t)``, sans I/O.

Lock-step: answers the sensing of tick ``k`` with ``LeaderState(k + 1)``, pipelined as the
agents' estimates are (docs/design.md "Lock-step pipelining"): ``p0`` is a
function of time alone, so the state for the next tick is final now, and a
pinned robot holds it when that tick's sensing arrives instead of waiting for
a second hop (world -> leader -> robot). The first tick heard, or one after a gap
(a restarted leader), also gets ``LeaderState(k)``.
The tick comes from the sensing of one robot (the first of the scenario), which the world
sends every tick anyway: a clock message of its own would be one more put per tick
(docs/design.md "Crossings per tick"). The leader reads only its tick and time. Pinned robots hold a
state for a later tick until they act on it, so every act sees what it saw
before. Real time: :meth:`act_realtime` publishes ``p0`` at the simulation
time it is given, once per value of that time.
Only robots with ``b_i > 0`` subscribe to it. With ``[estimator] tracking =
"feedforward"`` the state also carries the leader's velocity ``dp0/dt``, which the
pinned robots' velocity observers hear (fxswarm.core.observer).
"""

from __future__ import annotations

from fxswarm.core import bus as topics
from fxswarm.core.messages import LeaderState, Message, Sense
from fxswarm.core.scenario import Scenario


class LeaderNode:
    def __init__(self, scenario: Scenario) -> None:
        self.sc = scenario
        self.seq = 0
        self.sent_tick = -1  # lock-step: the latest tick whose state was sent
        self.publish_velocity = scenario.tracking == "feedforward"
        self.beats = 0  # real time: states sent (the tick field of a real-time LeaderState)
        self.said_t: float | None = None  # real time: the simulation time of the last state sent, s

    def subscriptions(self) -> list[str]:
        return [topics.leader_clock_topic(self.sc.robots[0].id)]  # the world's tick, as a robot hears it

    def handle(self, topic: str, msg: Message) -> list[topics.Outgoing]:
        if isinstance(msg, Sense):
            last = min(msg.tick + 1, self.sc.ticks - 1)  # no state for a tick the run never reaches
            first = max(self.sent_tick + 1, msg.tick)
            return [self.act(k, msg.t if k == msg.tick else k * self.sc.dt) for k in range(first, last + 1)]
        return []

    def said_again(self, tick: int) -> list[topics.Outgoing]:
        """Lock-step, the world asking again after a router outage: the states already sent for
        ``tick`` and the next one, the same values (``p0`` is a function of time alone)."""
        return [self.act(k, k * self.sc.dt) for k in range(tick, min(tick + 1, self.sent_tick) + 1)]

    def act(self, tick: int, t: float) -> topics.Outgoing:
        self.seq += 1
        self.sent_tick = max(self.sent_tick, tick)
        v0 = self.sc.leader.velocity(t) if self.publish_velocity else None
        return topics.LEADER_STATE, LeaderState("leader", 0, self.seq, tick, t, self.sc.leader.position(t), v0)

    def act_realtime(self, now: float) -> list[topics.Outgoing]:
        """Real time: ``p0`` at simulation time ``now`` (s), unless already said for that time
        (``p0`` moves only with the world's time)."""
        if now == self.said_t:
            return []
        self.said_t = now
        out = self.act(self.beats, now)
        self.beats += 1
        return [out]
