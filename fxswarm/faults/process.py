"""Process faults: kill / restart and freeze / thaw, as the plan schedules them.

Over Zenoh the launcher sends the real signals (SIGKILL, SIGSTOP/SIGCONT)
at the scheduled simulation times (:class:`ProcessSchedule`). In one
process, :class:`Mortal` stands in for them: a killed node hears and says
nothing, and at its restart time a fresh node (new state, as a restarted
process would have) takes over; a frozen node's inbox fills, and at its
thaw time the backlog arrives all at once, in order, as a SIGCONT'd
process would read its socket.

The plan's schedule is also what lock-step peers consult (through their
inbox filter's ``expects``) so they do not wait for a dead robot, which is
what keeps a lock-step run with crashes deterministic.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from fxswarm.core import bus as topics
from fxswarm.core.messages import Command, Estimate, LeaderState, Message
from fxswarm.faults.plan import ProcessFault
from fxswarm.faults.wrapper import NodeWrapper

#: What lock-step sends a tick early (docs/design.md "Lock-step pipelining").
PIPELINED = (Estimate, LeaderState)


def active_fault(faults: list[ProcessFault] | tuple[ProcessFault, ...], t: float) -> ProcessFault | None:
    """The fault whose window ``[at, restart)`` contains time ``t`` (s), if any."""
    for f in faults:
        if f.at <= t + 1e-9 and (f.restart is None or t + 1e-9 < f.restart):
            return f
    return None


class Mortal:
    """A node that ``faults`` kill or freeze; ``build()`` makes a fresh node for a restart.

    Time is the newest message time heard (s). ``generations`` lists every
    node built, for counters; ``restarts`` counts restarts.
    """

    def __init__(self, build: Callable[[], object], faults: list[ProcessFault]) -> None:
        self.build = build
        self.faults = list(faults)
        self.node = build()
        self.generations = [self.node]
        self.state = "up"
        self.backlog: list[tuple[str, Message]] = []
        self.early: list[tuple[str, Message]] = []  # pipelined messages for a time past a kill or restart
        self.now = float("-inf")
        self.restarts = 0

    def __getattr__(self, name: str):
        return getattr(self.node, name)

    def subscriptions(self) -> list[str]:
        return self.node.subscriptions()

    def handle(self, topic: str, msg: Message) -> list[topics.Outgoing]:
        if type(msg) is Command:  # a neighbour's, heard for the estimate it carries
            msg = msg.carried_estimate()
            if msg is None:
                return []
        if isinstance(msg, PIPELINED) and msg.t > self.now and \
                active_fault(self.faults, msg.t) is not active_fault(self.faults, self.now):
            # Lock-step sends a neighbour's estimate and the leader's state a tick early: across
            # a kill or a restart it is for the node alive at its time, so it waits until this
            # node's time gets there.
            self.early.append((topic, msg))
            return []
        out = self._handle(topic, msg)
        if self.early and not isinstance(msg, PIPELINED):
            due = [(tp, m) for tp, m in self.early if m.t <= self.now]
            self.early = [(tp, m) for tp, m in self.early if m.t > self.now]
            for tp, m in due:
                out += self._handle(tp, m)
        return out

    def _handle(self, topic: str, msg: Message) -> list[topics.Outgoing]:
        self.now = max(self.now, msg.t)
        fault = active_fault(self.faults, self.now)
        out: list[topics.Outgoing] = []
        if fault is None:
            if self.state == "killed":
                self.node = self.build()
                self.generations.append(self.node)
                self.restarts += 1
            elif self.state == "frozen":
                backlog, self.backlog = self.backlog, []
                for old_topic, old_msg in backlog:
                    out += self.node.handle(old_topic, old_msg)
            self.state = "up"
            return out + self.node.handle(topic, msg)
        if fault.action == "kill":
            self.state = "killed"
            return out
        self.state = "frozen"
        self.backlog.append((topic, msg))
        return out


class PlannedKill(NodeWrapper):
    """A role process's own side of its planned kills, in lock-step: it falls silent at the kill's
    time exactly where :class:`Mortal` (``fxswarm sim``) does, by the same code on the same
    inputs, so every receiver hears its last message at the same tick as in the simulator. The
    launcher's SIGKILL follows a few ticks later (once it hears the world pass that time) and
    lands on a process that already says nothing.

    A silenced process stays silent: its restart is a new process. That new process is not
    silenced by the kill it restarts from: only kills at or after the time of the first message
    it hears apply to it.
    """

    def __init__(self, node, kills: list[ProcessFault]) -> None:
        self.node = node
        self.kills = [f for f in kills if f.action == "kill"]
        self.mortal: Mortal | None = None  # built on the first message, which says who we are

    @property
    def silenced(self) -> bool:
        return self.mortal is not None and self.mortal.state == "killed"

    def handle(self, topic: str, msg: Message) -> list[topics.Outgoing]:
        if self.mortal is None:
            mine = [f for f in self.kills if f.at + 1e-9 >= msg.t]
            self.mortal = Mortal(lambda: self.node, mine)
        if self.silenced:
            return []
        return self.mortal.handle(topic, msg)


@dataclass
class ProcessSchedule:
    """The launcher's side: which signal to send to which process, once, as sim time passes.

    ``due(t)`` returns the ``(action, target)`` pairs whose time has come and
    not been returned before; actions: ``kill``, ``restart``, ``freeze``, ``thaw``.
    """

    faults: tuple[ProcessFault, ...]  # the resolved plan's ``processes``
    _done: set = field(default_factory=set)
    log: list = field(default_factory=list)  # what run() sent: {action, target, t_s, done_t_s}, for the summary

    def due(self, t: float, restart_lead: float = 0.0) -> list[tuple[str, str]]:
        """``restart_lead``: a restart is due that many seconds before its time (lock-step: one
        tick, so the world, holding the restart's own tick, never waits for a restart not sent)."""
        out = []
        for n, f in enumerate(self.faults):
            back = "restart" if f.action == "kill" else "thaw"
            for what, when in ((f.action, f.at), (back, f.restart)):
                lead = restart_lead if what == "restart" else 0.0
                if when is not None and t + lead + 1e-9 >= when and (n, what) not in self._done:
                    self._done.add((n, what))
                    out.append((when, what, f.target))
        return [(what, target) for _, what, target in sorted(out, key=lambda e: e[0])]  # in time order

    def run(self, swarm) -> list[dict]:
        """Send what is due to ``swarm`` (a :class:`fxswarm.launch.swarm.Swarm`); return it,
        as the events logged: ``{action, target, t_s, done_t_s}`` (None: no such process).

        Process names: ``agent:3`` -> ``agent-3``. A restart waits until the new
        process is alive (it rejoins with a fresh state). Lock-step: a restart is sent once the
        world's state is one tick before it (the world holds the restart's tick until it is up:
        :class:`fxswarm.world.node.RestartHold`); a kill needs no signal on time, as the process
        has fallen silent at its tick by itself (:class:`PlannedKill`).
        """
        if not self.faults:
            return []
        now = swarm.sim_time()
        lead = swarm.scenario.dt if getattr(swarm, "clock", None) == "lockstep" else 0.0
        events = []
        for action, target in self.due(now, lead):
            event = {"action": action, "target": target, "t_s": round(now, 6), "done_t_s": None}
            self.log.append(event)
            events.append(event)
            name = target.replace(":", "-")
            if name not in swarm.children:
                continue
            if action == "kill":
                swarm.kill(name)
            elif action == "restart":
                swarm.restart(name)
            elif action == "freeze":
                swarm.freeze(name)
            elif action == "thaw":
                swarm.thaw(name)
            # The world goes on meanwhile: a restarted process is alive again only seconds later.
            event["done_t_s"] = round(swarm.sim_time(), 6)
        return events
