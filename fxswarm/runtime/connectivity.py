"""Whether a process still reaches the swarm: it says so at once when it has lost every router.

Zenoh reports each transport (a link to a router or a peer) opening and closing
(``SessionInfo.declare_transport_events_listener``, zenoh 1.10). A process whose
last transport closes has lost every router (a client's only links), or, in a mesh,
every peer too: nothing it publishes reaches anyone, nothing reaches it. Zenoh
reconnects by itself; the process says so again when a transport is back.

Event-driven: nothing runs per tick. The callback runs on a Zenoh thread and only
updates a set, the :attr:`Connectivity.lost` flag and the outage list, and prints a line.
Transports seen before the session ever had one (a mesh peer waiting for the others)
are not an outage.
"""

from __future__ import annotations

import sys
import threading
import time
from typing import Callable

import zenoh

#: ``() -> (simulation time s, tick)`` of the process, for the outage record; None: wall s only.
SimNow = Callable[[], tuple[float, int]]


class Connectivity:
    """Watches ``session``'s transports; ``who`` names the process in what it says.

    :attr:`lost`: no router nor peer reachable now (a flag read, for hot loops).
    :attr:`outages`: ``[{"start": t, "end": t or None, "ticks": n}]``, ``t`` the simulation time
    (``now()``, s) at the loss and at the return; ``ticks``: the process's ticks in between (to
    :meth:`report`'s call while still lost). Without ``now``: wall seconds since this watch began.
    """

    def __init__(self, session: zenoh.Session, who: str, now: SimNow | None = None,
                 say: Callable[[str], None] | None = None) -> None:
        self.who = who
        self.lost = False
        self.outages: list[dict] = []
        self._began = time.monotonic()
        self._sim = now is not None
        self._now = now or (lambda: (time.monotonic() - self._began, 0))
        self._say = say or (lambda line: print(line, file=sys.stderr, flush=True))
        self._lock = threading.Lock()
        self._links: set[str] = set()
        self._ever = False
        self._lost_at = 0.0  # monotonic, for the "after N s" of the return line
        self._spans: list[list[float | None]] = []  # [lost, back or None], monotonic s
        self._outage_tick = 0
        self._listener = session.info.declare_transport_events_listener(self._on_event, history=True)

    def _on_event(self, event) -> None:  # a Zenoh thread
        transport = event.transport
        if transport.is_multicast:
            return  # scouting, not a link that carries the swarm's traffic
        zid = str(transport.zid)
        with self._lock:
            if event.kind == zenoh.SampleKind.PUT:
                self._links.add(zid)
                self._ever = True
                if self.lost:
                    self._back()
            else:
                self._links.discard(zid)
                if not self._links and self._ever and not self.lost:
                    self._lose(str(transport.whatami).lower())

    def _lose(self, what: str) -> None:
        self.lost = True
        self._lost_at = time.monotonic()
        self._spans.append([self._lost_at, None])
        t, tick = self._now()
        self._outage_tick = tick
        self.outages.append({"start": round(t, 9), "end": None, "ticks": 0})
        self._say(f"{self.who}: lost every router{'' if what == 'router' else ' and peer'}{self._at(t)}: "
                  "nothing reaches this process nor leaves it; Zenoh reconnects by itself")

    def _back(self) -> None:
        self.lost = False
        self._spans[-1][1] = time.monotonic()
        t, tick = self._now()
        outage = self.outages[-1]
        outage.update(end=round(t, 9), ticks=tick - self._outage_tick)
        ticks = f", {outage['ticks']} ticks" if self._sim else ""
        self._say(f"{self.who}: reached the swarm again{self._at(t)}, after {time.monotonic() - self._lost_at:.1f} s "
                  f"without a router{ticks}")

    def _at(self, t: float) -> str:
        return f" at t = {t:.2f} s" if self._sim else ""

    def cut_around(self, when: float, margin_s: float = 1.0) -> bool:
        """Whether this process had lost every router at monotonic time ``when``, give or take
        ``margin_s`` (what the session saw go with the link, e.g. every liveliness token, may be
        handled a little before the transport's own event, or after it is back)."""
        with self._lock:
            now = time.monotonic()
            return any(lost - margin_s <= when <= (back if back is not None else now) + margin_s
                       for lost, back in self._spans)

    def report(self) -> list[dict]:
        """The outages so far (a copy); one still going has ``end`` None and its ticks up to now."""
        with self._lock:
            out = [dict(o) for o in self.outages]
            if self.lost and out:
                out[-1]["ticks"] = self._now()[1] - self._outage_tick
        return out

    def close(self) -> None:
        """Stop listening (before the session closes: its own closing is no outage)."""
        with self._lock:
            self._ever = False
            listener, self._listener = self._listener, None
        if listener is not None:  # once: a second close finds nothing to undeclare
            try:
                listener.undeclare()
            except zenoh.ZError:
                pass
