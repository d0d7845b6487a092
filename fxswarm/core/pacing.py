"""Real-time pacing, sans I/O: when a periodic act is due, how late it was, when a wait is over,
what is stale.

Time comes from an injectable clock: a callable returning seconds on a monotonic scale. The
process shells pass ``time.monotonic``; the tests pass a fake clock they move by hand. Nothing
here sleeps or does I/O: a shell asks :meth:`Pacer.wait_s` and waits (polling its bus) that
long itself, then tells the pacer what it did.
"""

from __future__ import annotations

from collections.abc import Callable

#: A clock: seconds on a monotonic scale (``time.monotonic`` in a process).
WallClock = Callable[[], float]


class Pacer:
    """A fixed-period schedule on ``clock``: the next act's deadline, late and held acts.

    ``period``: s of the clock between acts. The first act is due at ``start`` (default: now).
    After an act on the timer (:meth:`on_time`) the next is due one period after the last
    deadline, so a slightly late act does not shift the schedule; an act more than a period
    late is counted in :attr:`late` and the schedule slips to one period from now: a late loop
    acts once and goes on, it does not burst to catch up. :meth:`acted_early` (fresh data made
    the act happen before its deadline) moves the deadline ``patience`` periods away, so the
    timer only fires when fresh data is late. :meth:`hold` skips a due act (counted in
    :attr:`held`) and tries again a period later.
    """

    def __init__(self, period: float, clock: WallClock, patience: float = 1.5, start: float | None = None) -> None:
        if not period > 0:
            raise ValueError(f"pacer: expected a period > 0 s, got {period!r}")
        self.period = period
        self.clock = clock
        self.patience = patience
        self.next_due = clock() if start is None else start
        self.late = 0  # acts on the timer that started more than a period after their deadline
        self.held = 0  # due acts skipped by hold()

    def wait_s(self) -> float:
        """Seconds until the next deadline (0 when it has passed)."""
        return max(0.0, self.next_due - self.clock())

    def due(self) -> bool:
        """Whether the next act's deadline has come."""
        return self.clock() >= self.next_due

    def on_time(self) -> float:
        """Record an act on the timer now; return how late it started after its deadline, s."""
        now = self.clock()
        lateness = now - self.next_due
        if lateness > self.period:
            self.late += 1
            self.next_due = now + self.period  # slip: no burst of catch-up acts
        else:
            self.next_due += self.period
        return lateness

    def acted_early(self) -> None:
        """Record an act triggered by fresh data: the timer now waits ``patience`` periods."""
        self.next_due = self.clock() + self.patience * self.period

    def hold(self) -> None:
        """Skip the due act (counted in :attr:`held`); it is due again one period from now."""
        self.held += 1
        self.next_due = self.clock() + self.period


class Deadline:
    """A timeout of ``timeout`` s on ``clock``, started now and restartable; ``timeout <= 0``
    (or None) never passes."""

    def __init__(self, timeout: float | None, clock: WallClock) -> None:
        self.timeout = timeout
        self.clock = clock
        self.started = clock()

    def restart(self) -> None:
        self.started = self.clock()

    def passed(self) -> bool:
        return self.timeout is not None and self.timeout > 0 and self.clock() - self.started >= self.timeout

    def wait_s(self) -> float:
        """Seconds until it passes (inf if it never does)."""
        if self.timeout is None or self.timeout <= 0:
            return float("inf")
        return max(0.0, self.started + self.timeout - self.clock())


class SimClock:
    """Simulation time in a real-time process: the world's, as last heard (no I/O, no wall clock).

    The world's time is the simulation's: it advances one ``dt`` per tick, paced at
    ``dt / speed`` wall seconds while the machine keeps up, and slower when it cannot. Every
    other process takes the latest time stamp of the world's messages as its own time (no
    extrapolation: a process that ran its own clock between messages would run ahead of a
    world that slows down, and a leader ahead of the world pulls every estimate ahead of it).
    So an agent acting twice on one sensing integrates ``dt = 0`` the second time, and one
    that missed a tick integrates both. ``stale_after`` (simulation s): a message stamped
    longer ago than this is stale (:meth:`is_stale`).
    """

    def __init__(self, speed: float, stale_after: float = float("inf")) -> None:
        if not speed > 0:
            raise ValueError(f"--speed: expected a positive number, got {speed}")
        self.speed = speed
        self.stale_after = stale_after
        self.t: float | None = None

    def start_now(self) -> None:
        self.t = 0.0

    def observe(self, t: float) -> None:
        """The world said it is ``t`` (s); time never goes back."""
        if self.t is None or t > self.t:
            self.t = t

    @property
    def known(self) -> bool:
        return self.t is not None

    def now(self) -> float:
        """Simulation time, s; never decreases."""
        assert self.t is not None, "simulation time before the world started"
        return self.t

    def is_stale(self, t: float) -> bool:
        """Whether a message stamped ``t`` (s) is older than ``stale_after`` now (never before
        the world's time is known)."""
        return self.t is not None and self.t - t > self.stale_after
