"""The inbox filter: a node wrapper that applies a :class:`FaultPlan` to what its node hears.

:class:`FaultyInbox` has the node's interface (``subscriptions()``,
``handle(topic, msg) -> outgoing``) so the in-memory bus and the Zenoh
process loops drive it exactly as they drive a bare node.

Lock-step: a message's fate is known in advance (it is a pure function of
the plan, the link and the tick), so the node is told, through its
``expects(sender, tick)`` hook, which senders' tick-``k`` messages will come
on time; it does not wait for the others. A message delayed by ``D`` ticks
(its delay rounded to the control period) is held here and handed to the
node just before the node's tick ``k + D`` starts; if it has not physically
arrived by then (possible over Zenoh), the tick's sensing message is held
back until it has, so every process sees the same inputs at the same tick.
A lost sensing message still starts the tick (the world's clock reached the
robot) but carries the robot's last sensed content, marked as a replay.
When the plan loses a robot's command to the world, the world moves on
without it, and over Zenoh that next sensing can overtake a neighbour's
estimate the robot still waits for (each subscription has its own callback
thread): it is held, in tick order, until the robot has acted on the tick
before, as in ``fxswarm sim``. A world that moved on for any other reason
(its tick timeout, a robot that is down) is followed at once, as before.

Real time: delays are real time; held messages are released by
:meth:`FaultyInbox.poll`, which the process loop calls every iteration;
fates are indexed by the sender's sequence number instead of its tick.
"""

from __future__ import annotations

import heapq
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable

from fxswarm.core import bus as topics
from fxswarm.core.messages import KINDS, Command, Estimate, Message, Sense
from fxswarm.faults.plan import FAULTABLE_KINDS, FaultPlan
from fxswarm.faults.wrapper import NodeWrapper

KIND_OF: dict[type, str] = {cls: name for name, cls in KINDS.items()}


@dataclass(frozen=True)
class ReplayedSense(Sense):
    """A tick whose sensing was lost: the robot's last sensed content under the new tick."""

    replayed = True  # class attribute, not a field: the agent reads it to age its sensing


def endpoint(msg: Message) -> str:
    """The sender's endpoint name as link patterns use it: ``world``, ``leader``, ``agent:<id>``."""
    return f"agent:{msg.sender}" if msg.role == "agent" else msg.role


@dataclass
class LinkCounts:
    delivered: int = 0
    dropped: int = 0
    delayed: int = 0
    duplicated: int = 0


def _upstream(subscriptions: list[str]) -> list[tuple[str, str]]:
    """(sender, kind) pairs a node's subscriptions name, for the lock-step due check."""
    out = []
    for topic in subscriptions:
        parts = topic.split("/")
        if topic == topics.LEADER_STATE:
            out.append(("leader", "leader"))
        elif len(parts) == 3 and parts[0] == "agent" and parts[2] in ("estimate", "cmd") and parts[1].isdigit():
            out.append((f"agent:{parts[1]}", "estimate"))  # a neighbour's estimate rides on its command
    return out


class FaultyInbox(NodeWrapper):
    """``node`` as ``receiver`` (``agent:<id>`` or ``world``) hears it through ``plan``.

    dt: control period, s (lock-step delays are rounded to it); clock: real
    time's "now", s (monotonic by default). Attributes not defined here are
    the node's, so runners may keep treating the wrapper as the node.
    """

    def __init__(self, node, receiver: str, plan: FaultPlan, dt: float, lockstep: bool = True,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.node = node
        self.receiver = receiver
        self.plan = plan
        self.dt = dt
        self.lockstep = lockstep
        self.clock = clock
        self.links: dict[str, LinkCounts] = {}
        # Only estimates and the leader's state can be late, and only agents hear them.
        self.max_delay_ticks = plan.max_delay_ticks(receiver, dt) if receiver != "world" else 0
        self.upstream = _upstream(node.subscriptions())
        self.held: list[tuple] = []  # heap of (release tick or time, order, topic, msg)
        self.order = 0
        self.seen: set[tuple[str, str, int]] = set()  # (sender, kind, tick) arrived, for the due check
        self.last_sense: Sense | None = None
        # Sensing held until its tick may start, in tick order: (topic, msg, wait for the node to
        # act on the tick before: the world moved on without this robot's lost command).
        self.pending: deque[tuple[str, Sense, bool]] = deque()
        self.commands_lost = receiver != "world" and plan.may_lose(receiver, "world", "command")
        self.tick = -1  # the receiver's current tick (lock-step)
        self.late = 0  # delayed messages that arrived after their release tick (gave up waiting)
        self._fates: dict[tuple, object] = {}  # memo: a fate is asked for several times per tick
        self.install(node)

    def install(self, node) -> None:
        """Attach (or re-attach, after a restart) the node this inbox feeds; the node under any
        other wrapper (``.inner``) gets the ``expects`` hook. (Its degraded limits it took from
        the same plan when it was built: every runner passes ``limits=plan.limits``.)"""
        self.node = node
        core = node
        while hasattr(core, "inner"):
            core = core.inner
        self.core = core
        if hasattr(core, "expects"):
            core.expects = self.expects

    # --- what the node should wait for -------------------------------------------------

    def expects(self, sender: str, tick: int) -> bool:
        """Lock-step: whether ``sender``'s tick-``tick`` message reaches this node at tick ``tick``."""
        t = tick * self.dt
        kind = "leader" if sender == "leader" else ("command" if self.receiver == "world" else "estimate")
        if self.plan.processes and self.plan.down(sender, t):
            # The leader's state and an estimate are sent a tick early (lock-step pipelining): one
            # for a kill's or a freeze's own tick left its sender the tick before, while it was up,
            # and in the simulator it is always heard. So it is waited for here too, else whether
            # it is used depends on whether it beats the next sensing (a race over processes).
            if kind == "command" or self.plan.down(sender, t - self.dt):
                return False
        fate = self._fate(sender, kind, tick, t)
        return not fate.lost and self._ticks(fate.delay) == 0

    def _fate(self, sender: str, kind: str, tick: int, t: float):
        key = (sender, kind, tick, t)
        fate = self._fates.get(key)
        if fate is None:
            if len(self._fates) > 20_000:
                self._fates.clear()
            fate = self._fates[key] = self.plan.fate(sender, self.receiver, kind, tick, t)
        return fate

    def _ticks(self, delay: float) -> int:
        return int(round(delay / self.dt)) if delay > 0 else 0

    def _count(self, sender: str, kind: str) -> LinkCounts:
        key = f"{sender}->{self.receiver}/{kind}"
        c = self.links.get(key)
        if c is None:
            c = self.links[key] = LinkCounts()
        return c

    # --- delivery ------------------------------------------------------------------------

    def handle(self, topic: str, msg: Message) -> list[topics.Outgoing]:
        if type(msg) is Command and self.receiver != "world":
            # A neighbour's command, heard for the estimate it carries: that is what a link
            # fault acts on (kind "estimate", its tick), as on an estimate sent alone.
            msg = msg.carried_estimate()
            if msg is None:
                return []
        elif type(msg) is Estimate and self.receiver == "world":
            return self.node.handle(topic, msg)  # a robot's first estimate, on its command key: not the world's
        kind = KIND_OF.get(type(msg))
        if kind not in FAULTABLE_KINDS:
            out = self.node.handle(topic, msg)
            return out + self._start_pending_tick() if self.lockstep and self.pending else out
        sender = endpoint(msg)
        # Lock-step: fates by tick (known in advance). Real time: by the sender's sequence
        # number, since a real-time sender may send several messages in one tick.
        fate = self._fate(sender, kind, msg.tick if self.lockstep else msg.seq, msg.t)
        counts = self._count(sender, kind)
        if fate.lost:
            counts.dropped += 1
        if kind == "sense" and isinstance(msg, Sense):
            return self._sensing(topic, msg, fate.lost)
        if fate.lost:
            return []
        out: list[topics.Outgoing] = []
        if fate.copies > 1:
            counts.duplicated += fate.copies - 1
        if self.lockstep:
            if self.max_delay_ticks:
                self.seen.add((sender, kind, msg.tick))
            d = self._ticks(fate.delay)
            if d > 0 and msg.tick + d > self.tick:
                counts.delayed += 1
                self._hold(msg.tick + d, topic, msg, fate.copies)
                return self._start_pending_tick()
            if d > 0:
                self.late += 1
        elif fate.delay > 0:
            counts.delayed += 1
            self._hold(self.clock() + fate.delay, topic, msg, fate.copies)
            return out
        counts.delivered += 1
        for _ in range(fate.copies):
            out += self.node.handle(topic, msg)
        if self.lockstep and self.pending:
            out += self._start_pending_tick()
        return out

    def _hold(self, release: float, topic: str, msg: Message, copies: int) -> None:
        for _ in range(copies):
            self.order += 1
            heapq.heappush(self.held, (release, self.order, topic, msg))

    def _release(self, upto: float) -> list[topics.Outgoing]:
        out: list[topics.Outgoing] = []
        while self.held and self.held[0][0] <= upto:
            _, _, topic, msg = heapq.heappop(self.held)
            self._count(endpoint(msg), KIND_OF[type(msg)]).delivered += 1
            out += self.node.handle(topic, msg)
        return out

    def poll(self) -> list[topics.Outgoing]:
        """Real time: hand the node every held message whose release time has come."""
        if self.lockstep or not self.held:
            return []
        return self._release(self.clock())

    # --- lock-step ticks -------------------------------------------------------------

    def _sensing(self, topic: str, msg: Sense, lost: bool) -> list[topics.Outgoing]:
        if not self.lockstep:
            if lost:
                return []
            self._count("world", "sense").delivered += 1
            return self.node.handle(topic, msg)
        if lost:
            base = self.last_sense if self.last_sense is not None else msg
            msg = ReplayedSense(msg.role, msg.sender, msg.seq, msg.tick, msg.t, msg.robot,
                                base.p, base.po, base.vo)
        else:
            self._count("world", "sense").delivered += 1
            self.last_sense = msg
        pending = self.pending
        if pending and msg.tick <= pending[-1][1].tick:
            if msg.tick == pending[-1][1].tick:  # the same tick said again: the newer word on it
                pending[-1] = (topic, msg, pending[-1][2])
            return []  # (an older tick's: overtaken by the one held)
        waits = self.commands_lost and self._moved_on_without_me(msg.tick)
        out: list[topics.Outgoing] = []
        if pending and not waits:
            out += self._start_pending_tick(force=True)  # the world gave up waiting: stop waiting too
        pending.append((topic, msg, waits))
        return out + self._start_pending_tick()

    def _moved_on_without_me(self, k: int) -> bool:
        """Whether the world reached tick ``k`` without this robot's commands because the plan lost
        each one since the oldest tick the robot has not acted on (so in ``fxswarm sim`` it acts on
        each of those ticks in turn), not because it gave up waiting or the robot was down."""
        if self._acting():
            first = self.core.sense.tick
        elif self.pending:
            first = self.pending[0][1].tick
        else:
            return False
        plan, me = self.plan, self.receiver
        return first < k and all(
            not (plan.processes and plan.down(me, j * self.dt)) and plan.fate(me, "world", "command", j, j * self.dt).lost
            for j in range(first, k))

    def _acting(self) -> bool:
        """Whether the node holds a tick's sensing it has not acted on yet."""
        sense = getattr(self.core, "sense", None)
        return sense is not None and self.core.acted_tick < sense.tick

    def _due_missing(self, k: int) -> bool:
        """Whether a message delayed into tick ``k`` has not arrived yet."""
        for sender, kind in self.upstream:
            for k2 in range(max(0, k - self.max_delay_ticks), k):
                if (sender, kind, k2) in self.seen or (self.plan.processes and self.plan.down(sender, k2 * self.dt)):
                    continue
                fate = self._fate(sender, kind, k2, k2 * self.dt)
                if not fate.lost and fate.delay > 0 and k2 + self._ticks(fate.delay) == k:
                    return True
        return False

    def _start_pending_tick(self, force: bool = False) -> list[topics.Outgoing]:
        """Start each held tick, in order, once the messages delayed into it have arrived and, if
        it waits for that, the node has acted on the tick before (``force``: at once, all)."""
        out: list[topics.Outgoing] = []
        pending = self.pending
        while pending:
            topic, sense, waits = pending[0]
            k = sense.tick
            if not force and ((waits and self._acting()) or (self.max_delay_ticks and self._due_missing(k))):
                break
            pending.popleft()
            self.tick = k
            if self.max_delay_ticks and k % 64 == 0:
                self.seen = {s for s in self.seen if s[2] >= k - self.max_delay_ticks - 1}
            out += self._release(k) + self.node.handle(topic, sense)
        return out

    def act_past_the_gone(self, gone) -> list[topics.Outgoing]:
        """Lock-step: the node acts past senders that are gone (``AgentNode.act_past_the_gone``),
        then the held ticks that may start now do."""
        out = self.core.act_past_the_gone(gone)
        if out and self.lockstep and self.pending:
            out += self._start_pending_tick()
        return out

    def stop_waiting(self) -> list[topics.Outgoing]:
        """Lock-step: start every held tick now if one waits for the node to act (the simulator,
        when nothing is left to deliver: what the node waits for will never come). A tick held
        only for delayed messages is left to the world's timeout, as it always was."""
        if self.lockstep and any(waits for _, _, waits in self.pending):
            return self._start_pending_tick(force=True)
        return []


def link_counts(inboxes) -> dict[str, dict[str, int]]:
    """Per-link counts of several inboxes, merged, sorted by link name."""
    merged: dict[str, dict[str, int]] = {}
    for inbox in inboxes:
        for key, c in getattr(inbox, "links", {}).items():
            m = merged.setdefault(key, {"delivered": 0, "dropped": 0, "delayed": 0, "duplicated": 0})
            for field_name, value in c.__dict__.items():
                m[field_name] += value
    return dict(sorted(merged.items()))


def receiver_name(role: str, ident: int | str = 0) -> str:
    return f"agent:{ident}" if role == "agent" else role


def wrap(node, role: str, ident: int | str, plan: FaultPlan, dt: float, lockstep: bool = True,
         clock: Callable[[], float] = time.monotonic):
    """The node behind its fault filter, or the node itself when no link fault can reach it.

    The one call every runner makes when it builds a node (in-memory simulator
    and role processes alike), so both see the same faults.
    """
    receiver = receiver_name(role, ident)
    if role not in ("agent", "world"):
        return node
    # A robot whose commands the plan may lose needs one too: the world moves on without it.
    if not (plan.touches(receiver) or (role == "agent" and plan.may_lose(receiver, "world", "command"))):
        return node
    return FaultyInbox(node, receiver, plan, dt, lockstep, clock)


__all__ = ["FaultyInbox", "ReplayedSense", "LinkCounts", "endpoint", "link_counts", "wrap"]
