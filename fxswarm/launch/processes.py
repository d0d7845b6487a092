"""The processes a run owns: started here, signalled here, stopped here; nothing else is touched.

:class:`Processes` is a context manager (trio's rule: every start has a matching stop): leaving
it stops every process it started that still runs. :meth:`Processes.deaths` only looks: it
reports each unplanned end once and starts nothing again (restarting is the caller's choice,
:meth:`Processes.restart`).
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from fxswarm.launch.orphans import die_with_parent
from fxswarm.launch.plan import ChildSpec
from fxswarm.runtime.process import PARENT_ENV

# Zenoh's runtimes in each child: one worker thread each for app, rx and tx (by default app and
# rx have two). Fewer threads to wake per message: lock-step paper-fast ran faster in 6 of 8
# interleaved rounds (medians 282 -> 309 and 276 -> 295 ticks/s, ~7 % less CPU per tick);
# neutral for 24 robots and for real-time latency (docs/design.md "Transport cost").
# A ZENOH_RUNTIME already in the environment wins.
ZENOH_RUNTIME = "(app: (worker_threads: 1), rx: (worker_threads: 1), tx: (worker_threads: 1))"
STOP_BUDGET_S = 4.5  # Ctrl-C to nothing left: the issue promises 5 s


@dataclass
class Child:
    """One process the launcher started: its command, its log file, how it ended."""

    name: str  # e.g. "agent-3"
    role: str
    ident: int
    argv: list[str]
    log_path: Path
    popen: subprocess.Popen | None = None
    stopped_by: str | None = None  # the signal we sent, if we ended it
    reported: bool = False  # its death has been reported

    @classmethod
    def of(cls, spec: ChildSpec) -> Child:
        return cls(spec.name, spec.role, spec.ident, list(spec.argv), spec.log_path)

    @property
    def token(self) -> str:
        return f"{self.role}/{self.ident}"

    @property
    def pid(self) -> int | None:
        return self.popen.pid if self.popen else None

    def running(self) -> bool:
        return self.popen is not None and self.popen.poll() is None

    def tail(self, lines: int = 12) -> list[str]:
        """The last lines of its stderr/stdout."""
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return []
        return text.strip("\n\r").splitlines()[-lines:]


@dataclass
class Death:
    child: Child
    code: int
    restarted: bool = False  # a router the launcher has started again (supervision)
    pid: int | None = None  # the one that died (a restarted child has a new one)

    def __post_init__(self) -> None:
        if self.pid is None:
            self.pid = self.child.pid

    def describe(self, then: str = "") -> str:
        """``NAME (pid N) died: HOW``, ``; then`` (what the launcher did about it), then its last
        output, which goes last: its lines (zenohd logs as it starts) must not split the sentence."""
        how = f"killed by {signal.Signals(-self.code).name}" if self.code < 0 else f"exit code {self.code}"
        tail = self.child.tail()
        text = f"{self.child.name} (pid {self.pid}) died: {how}" + (f"; {then}" if then else "")
        if tail:
            text += "; its last output:\n" + "\n".join("    " + line for line in tail)
        return text


def child_environment(secure: bool) -> dict[str, str]:
    env = {"ZENOH_RUNTIME": ZENOH_RUNTIME, **os.environ, "PYTHONUNBUFFERED": "1", PARENT_ENV: str(os.getpid())}
    if not secure:
        env.pop("FXSWARM_SECURE", None)  # a plain run's children must not turn secure from the environment
    return env


class Processes:
    """The run's children by name, each started by :meth:`start` (see the module docstring)."""

    def __init__(self, secure: bool = False) -> None:
        self.children: dict[str, Child] = {}
        self.secure = secure

    def __enter__(self) -> Processes:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def add(self, child: Child) -> Child:
        """Own ``child`` (not started yet). A log is appended to within a run (a restarted
        process), never across runs: what a death reports as its last output must be this run's."""
        self.children[child.name] = child
        child.log_path.unlink(missing_ok=True)
        return child

    def start(self, child: Child) -> None:
        """Start (or start again) an owned child, in a session of its own: Ctrl-C reaches the
        launcher only, which stops its children in order."""
        assert self.children.get(child.name) is child, f"{child.name}: not one of this run's processes"
        child.log_path.parent.mkdir(parents=True, exist_ok=True)
        # The kernel ends each child if the launcher dies, SIGKILLed too (zenohd watches no parent):
        # a router outright (it keeps nothing, and a close can hang on dying links), the roles by
        # SIGTERM so they stop cleanly.
        sig = signal.SIGKILL if child.role == "router" else signal.SIGTERM
        with open(child.log_path, "ab") as log:
            child.popen = subprocess.Popen(child.argv, stdin=subprocess.DEVNULL, stdout=log, stderr=log,
                                           env=child_environment(self.secure), start_new_session=True,
                                           preexec_fn=die_with_parent(sig))
        child.stopped_by, child.reported = None, False

    def ended(self) -> list[tuple[Child, int]]:
        """Children that ended since last asked, not by our hand: ``(child, exit status)``,
        each once."""
        out = []
        for child in self.children.values():
            if child.popen is None or child.reported or child.stopped_by:
                continue
            code = child.popen.poll()
            if code is not None:
                child.reported = True
                out.append((child, code))
        return out

    def signal(self, name: str, sig: int) -> None:
        """Send ``sig``; a SIGKILL or SIGTERM is planned: its end is not reported as a death."""
        child = self.children[name]
        if sig in (signal.SIGKILL, signal.SIGTERM):
            child.stopped_by = signal.Signals(sig).name
        child.popen.send_signal(sig)
        if sig == signal.SIGTERM:
            child.popen.send_signal(signal.SIGCONT)  # a frozen process must wake to handle it

    def stop_child(self, child: Child, budget: float = 3.0) -> str:
        """End one child: SIGTERM, then SIGKILL after ``budget`` s; say which (``exited``: it had)."""
        return self.stop_all([child], budget)[child.name] if child.running() else "exited"

    def stop_all(self, children: list[Child], budget: float) -> dict[str, str]:
        """SIGTERM to each of ``children`` still running, then SIGKILL to any left after ``budget``
        s; return ``{name: how}`` for those that were running."""
        how: dict[str, str] = {}
        for c in children:
            if c.running():
                self.signal(c.name, signal.SIGTERM)
                how[c.name] = "SIGTERM"
        deadline = time.monotonic() + budget
        for c in children:
            if c.name not in how:
                continue
            try:
                c.popen.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                c.stopped_by = "SIGKILL"
                c.popen.kill()
                c.popen.wait()
                how[c.name] = "SIGKILL"
        return how

    def stop(self, budget: float = STOP_BUDGET_S, last: tuple[str, ...] = ("router",),
             between: Callable[[], object] = lambda: None) -> dict[str, str]:
        """End every child within ``budget`` s, the roles in ``last`` after all others (the
        routers: the others' sessions close cleanly through them), ``between`` called in between;
        return ``{name: how}``, with ``exited`` for those that had ended."""
        first = [c for c in self.children.values() if c.role not in last]
        then = [c for c in self.children.values() if c.role in last]
        how = {c.name: "exited" for c in self.children.values() if c.popen is not None}
        how.update(self.stop_all(first, max(0.0, budget - 1.0)))
        between()
        how.update(self.stop_all(then, 0.8))
        return how
