"""The bus: publish, subscribe, liveliness; and its in-memory implementation.

Topics are relative key expressions such as ``world/sense/3``; a bus puts
them under its swarm prefix (``fxswarm/<swarm>/``) so two swarms never
cross-talk. Patterns use Zenoh's wildcards: ``*`` one chunk, ``**`` any.

Two implementations share this interface: :class:`InMemoryBus` (one
process, deterministic, synchronous delivery in publication order) and the
Zenoh bus in :mod:`fxswarm.runtime.zenoh_bus`.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Callable, Protocol

from fxswarm.core.messages import Message

Handler = Callable[[str, Message], None]
Outgoing = tuple[str, Message]  # (topic, message) a node asks to send

# Topics of the wire (ARCHITECTURE.md "Key expressions"), relative to the swarm prefix.
CLOCK = "clock"
WORLD_STATE = "world/state"
LEADER_STATE = "leader/state"
#: A liveliness token the world declares once its run has ended (done, stopped, or given up),
#: never on a crash: the others tell "the run is over" from "the world is lost" (a network cut
#: longer than the Zenoh lease, a frozen or killed world) by it.
RUN_OVER = "run/over"
#: Lock-step, after a router outage: the world asks everyone again for its current tick (a
#: ``Clock``); each answers with what it has already said for that tick (messages put while a
#: router was down are lost, and receivers hold by tick, so a repeat changes nothing).
RESYNC = "world/again"
#: The scenario file's text, answered by the router (``fxswarm router --scenario``) to observers.
SCENARIO = "scenario"
#: The world's own record of the run (summary and trajectory), answered by the world once the run
#: has ended, to observers that need the whole run folder (``fxswarm attach``; fxswarm.runtime.record).
WORLD_RECORD = "world/record"


def sense_topic(robot: int) -> str:
    return f"world/sense/{robot}"


def leader_clock_topic(first_robot: int) -> str:
    """What the leader keeps time by: the first robot's sensing (the leader hears nothing else
    of the world's). The leader subscribes to it; a real-time world asks a lagging leader again
    on it."""
    return sense_topic(first_robot)


def estimate_topic(robot: int) -> str:
    return f"agent/{robot}/estimate"


def command_topic(robot: int) -> str:
    return f"agent/{robot}/cmd"


def alive_topic(role: str, ident: int | str) -> str:
    return f"alive/{role}/{ident}"


def prefix(swarm: str) -> str:
    return f"fxswarm/{swarm}"


#: What a swarm name must be, said to a user who gave another.
SWARM_NAME_RULE = "not empty, without / * $ ? or #"


def is_swarm_name(name: str) -> bool:
    """Whether ``name`` can name a swarm: it is one chunk of every key expression
    (``fxswarm/<swarm>/...``), so Zenoh's separator and wildcards cannot be in it."""
    return bool(name) and not any(c in name for c in "/*$?#")


def matches(pattern: str, topic: str) -> bool:
    """Whether ``topic`` matches ``pattern`` (``*``: one chunk, ``**``: zero or more)."""
    return _match(pattern.split("/"), topic.split("/"))


def _match(p: list[str], t: list[str]) -> bool:
    if not p:
        return not t
    if p[0] == "**":
        return any(_match(p[1:], t[k:]) for k in range(len(t) + 1))
    if not t:
        return False
    return (p[0] == "*" or p[0] == t[0]) and _match(p[1:], t[1:])


@dataclass
class Counters:
    """Per-process message counters, reported in the summary."""

    sent: int = 0
    received: int = 0
    invalid: int = 0
    stale: int = 0
    missed_ticks: int = 0
    dropped: int = 0  # frames a receiver chose to drop (e.g. a slow logger)

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


class Bus(Protocol):
    counters: Counters

    def publish(self, topic: str, msg: Message) -> None: ...

    def subscribe(self, pattern: str, handler: Handler) -> None: ...

    def declare_alive(self, role: str, ident: int | str) -> None: ...

    def close(self) -> None: ...


@dataclass
class InMemoryBus:
    """One-process bus: every publication is queued and delivered in order by :meth:`pump`.

    Delivery is synchronous and deterministic; handlers may publish more,
    which joins the end of the queue. Liveliness is a set of names.
    """

    counters: Counters = field(default_factory=Counters)
    _subs: list[tuple[str, Handler]] = field(default_factory=list)
    _exact: dict[str, list[Handler]] = field(default_factory=dict)
    _queue: deque = field(default_factory=deque)
    alive: set[str] = field(default_factory=set)

    def publish(self, topic: str, msg: Message) -> None:
        self.counters.sent += 1
        self._queue.append((topic, msg))

    def publish_all(self, outgoing: list[Outgoing]) -> None:
        # What publish() does, for a whole batch at once (the simulator's per-message hot path).
        queue = self._queue
        before = len(queue)
        queue.extend(outgoing)
        self.counters.sent += len(queue) - before

    def subscribe(self, pattern: str, handler: Handler) -> None:
        if "*" in pattern:
            self._subs.append((pattern, handler))
        else:
            self._exact.setdefault(pattern, []).append(handler)

    def declare_alive(self, role: str, ident: int | str) -> None:
        self.alive.add(alive_topic(role, ident))

    def pump(self) -> int:
        """Deliver queued messages (and what they cause) until the queue is empty."""
        delivered = 0
        queue, exact, subs = self._queue, self._exact, self._subs
        while queue:
            topic, msg = queue.popleft()
            for handler in exact.get(topic, ()):
                handler(topic, msg)
                delivered += 1
            for pattern, handler in subs:
                if matches(pattern, topic):
                    handler(topic, msg)
                    delivered += 1
        self.counters.received += delivered
        return delivered

    def close(self) -> None:
        self._queue.clear()
