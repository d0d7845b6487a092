"""Who is up, who is gone, and who went with a router: liveliness judged, sans I/O.

A process hears liveliness tokens come and go (``role/id``), and routers go: their own token
(``router/<id>``, ``fxswarm router``) or its own link to one (``router/link-<zid>``, any router,
``zenohd`` too). A router's clients' tokens go with it, at once, and come back when they have
reconnected to it or to another router; so a departure within ``SETTLE_S`` of a router's (before
or after: the order of the two is not given) is that router's outage and is expected back, for
up to ``REJOIN_S``; any other departure is a death, judged ``SETTLE_S`` after it. Until judged,
a departure is *unsure*: lock-step waits rather than act past it, since acting on what was last
heard from a process that is only away would part from ``fxswarm sim``.
"""

from __future__ import annotations

from collections.abc import Callable

#: A departure this close (s) to a router's is that router's outage, not the process's death.
SETTLE_S = 0.3
#: How long (s) a process lost with a router is waited for before it counts as gone.
REJOIN_S = 60.0


class Liveness:
    """``alive``, ``gone``, and the departures not judged yet, on the wall clock ``clock``."""

    def __init__(self, clock: Callable[[], float], settle_s: float = SETTLE_S, rejoin_s: float = REJOIN_S) -> None:
        self.clock = clock
        self.settle_s, self.rejoin_s = settle_s, rejoin_s
        self.alive: set[str] = set()  # tokens up now (role/id)
        self.gone: set[str] = set()  # tokens seen up, then down, and judged gone
        self.departed: dict[str, float] = {}  # down, not judged yet: name -> when
        self.rejoining: dict[str, float] = {}  # went with a router, expected back: name -> when
        self.routers: set[str] = set()  # routers up now (their tokens, this process's links)
        self.router_lost_at = -float("inf")  # when a router last went
        self.rejoined = 0  # outages over: everyone who went with a router is back (or judged gone)
        self.ups: dict[str, int] = {}  # times each token came up (a restarted process: once more)

    def change(self, name: str, up: bool) -> None:
        """A token (or, ``router/...``, a router) came up or went."""
        now = self.clock()
        if name.startswith("router/"):
            if up:
                self.routers.add(name)
                return
            self.routers.discard(name)
            self.router_lost_at = now
            for other, when in list(self.departed.items()):  # they went with it, just before it
                if now - when <= self.settle_s:
                    del self.departed[other]
                    self.rejoining[other] = when
            return
        if up:
            if name not in self.alive:
                self.ups[name] = self.ups.get(name, 0) + 1
            self.alive.add(name)
            self.gone.discard(name)
            self.departed.pop(name, None)
            if self.rejoining.pop(name, None) is not None and not self.rejoining:
                self.rejoined += 1
        elif name in self.alive:
            self.alive.discard(name)
            (self.rejoining if now - self.router_lost_at <= self.settle_s else self.departed)[name] = now

    def settle(self) -> list[str]:
        """Judge what is due: a departure unexplained for ``settle_s`` is gone, one expected back
        for ``rejoin_s`` too. Returns the names given up on after a router outage."""
        if not (self.departed or self.rejoining):
            return []
        now = self.clock()
        for name, when in list(self.departed.items()):
            if now - when > self.settle_s:
                del self.departed[name]
                self.gone.add(name)
        lost = [name for name, when in self.rejoining.items() if now - when > self.rejoin_s]
        for name in lost:
            del self.rejoining[name]
            self.gone.add(name)
        if lost and not self.rejoining:
            self.rejoined += 1
        return lost

    def unsure(self) -> set[str]:
        """Departures not judged yet, and those expected back after a router outage."""
        return set(self.departed) | set(self.rejoining)
