"""The fault plan: what the scenario's ``[faults]`` table says, and each message's fate.

A message's fate (lost, delayed, duplicated) is a pure function of the
plan's seed, the link (sender -> receiver), the message kind, its tick and
its time: a counter-based hash, never a shared random stream. So the fate
does not depend on arrival order or on which process computes it, and the
in-memory simulator and a multi-process run agree message for message.
Bursty loss (Gilbert-Elliott) is a two-state chain per link and kind,
advanced once per sender tick; each step draws from the same hash, so the
chain too is the same wherever it is evaluated.

Endpoints are named ``world``, ``leader``, ``agent:<id>``; link patterns are
``SRC->DST`` with shell wildcards (``agent:*->agent:4``, ``leader->*``).
Kinds are the wire kinds of :mod:`fxswarm.core.messages`: ``estimate``,
``leader``, ``sense``, ``command`` (``clock`` and ``state`` drive the
lock-step and the loggers and are never faulted).
"""

from __future__ import annotations

import hashlib
import json
import math
import struct
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from pathlib import Path

from fxswarm.core.scenario import Scenario, ScenarioError, _Fields

#: Kinds a link rule may touch; delays, duplication and reordering apply to the
#: first two only: sensing and actuation are the world's physics here, and
#: their loss is modelled (stale sensing, a held command), their lateness is not.
FAULTABLE_KINDS = ("estimate", "leader", "sense", "command")
LATE_KINDS = ("estimate", "leader")
#: What a partition or an isolation cuts unless told: the robots' radio, not physics.
CUT_KINDS_DEFAULT = ("estimate", "leader")
#: The leader, where a robot id is asked for (:meth:`FaultPlan.cut_off_from_world`; the real-time
#: world waits for it as for a robot). Robot ids start at 1.
LEADER = 0


@dataclass(frozen=True)
class Burst:
    """Gilbert-Elliott loss: per-tick transition probabilities and loss in each state."""

    p_good_bad: float
    p_bad_good: float
    loss_good: float = 0.0
    loss_bad: float = 1.0


@dataclass(frozen=True)
class LinkRule:
    """Faults on every link matching ``src->dst`` for the given kinds.

    drop: iid loss probability; burst: Gilbert-Elliott loss (both may be
    set: either loses the message); delay: fixed latency, s; jitter: extra
    latency drawn uniformly in [0, jitter), s; duplicate: probability of a
    second copy; reorder: probability of an extra ``reorder_delay`` s, so
    the message is overtaken by later ones.
    """

    src: str
    dst: str
    kinds: tuple[str, ...] = FAULTABLE_KINDS
    drop: float = 0.0
    burst: Burst | None = None
    delay: float = 0.0
    jitter: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    reorder_delay: float = 0.02

    def matches(self, sender: str, receiver: str, kind: str) -> bool:
        return kind in self.kinds and fnmatchcase(sender, self.src) and fnmatchcase(receiver, self.dst)

    @property
    def loses_all(self) -> bool:
        """Whether every message this rule matches is lost, whatever its tick."""
        return self.drop >= 1.0 or (self.burst is not None and min(self.burst.loss_good, self.burst.loss_bad) >= 1.0)

    @property
    def max_latency(self) -> float:
        return self.delay + self.jitter + (self.reorder_delay if self.reorder > 0 else 0.0)


@dataclass(frozen=True)
class Cut:
    """A time window ``[start, end)`` (s, message time) in which some links carry nothing.

    links: ``(src, dst)`` patterns; isolate: robot ids cut from every other
    robot and from the leader (both directions); label: how the summary names it.
    """

    start: float
    end: float
    links: tuple[tuple[str, str], ...] = ()
    isolate: tuple[int, ...] = ()
    kinds: tuple[str, ...] = CUT_KINDS_DEFAULT
    label: str = "partition"

    def cuts(self, sender: str, receiver: str, kind: str, t: float) -> bool:
        return self.start <= t < self.end and self.reaches(sender, receiver, kind)

    def reaches(self, sender: str, receiver: str, kind: str) -> bool:
        """Whether this cut, while it lasts, cuts ``sender``'s ``kind`` messages to ``receiver``."""
        if kind not in self.kinds:
            return False
        for r in self.isolate:
            me = f"agent:{r}"
            if (sender == me and receiver != me and receiver.startswith("agent:")) or (
                    receiver == me and sender != me and (sender.startswith("agent:") or sender == "leader")):
                return True
        return any(fnmatchcase(sender, s) and fnmatchcase(receiver, d) for s, d in self.links)

    def robots(self, n: int) -> list[int]:
        """Robots this cut silences or deafens (for recovery measurement); all when unknown."""
        if self.isolate and not self.links:
            return sorted(self.isolate)
        return list(range(1, n + 1))


@dataclass(frozen=True)
class ProcessFault:
    """Kill (SIGKILL) a process at ``at`` s and restart it at ``restart`` s (None: never),
    or freeze it (SIGSTOP) at ``at`` and thaw it (SIGCONT) at ``restart``."""

    target: str  # "agent:<id>" or "leader"
    action: str  # "kill" | "freeze"
    at: float
    restart: float | None = None

    @property
    def label(self) -> str:
        return f"{self.action} {self.target}"


@dataclass(frozen=True)
class Lie:
    """Robot ``robot`` is compromised from ``at`` s (until ``until`` s, None: to the end): the
    estimate it sends its neighbours is false (docs/resilience.md "The fault").

    What it sends at time t (the estimate's own time stamp): ``base + offset + drift (t - at) +
    noise``, where ``base`` is its true estimate, or with ``freeze`` the true estimate it held
    when it began to lie; ``noise`` is ``sigma`` times a standard normal per axis, drawn from
    the plan's seed, the robot and the tick (the same in one process and over Zenoh). It flies
    its *true* estimate (its own slot): the lie is in what it says, not in where it flies, and
    the velocity estimate it sends (``vh``, feedforward) stays true.
    """

    robot: int
    at: float
    until: float | None = None
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    drift: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m/s
    noise: float = 0.0  # m, standard deviation per axis
    freeze: bool = False

    @property
    def label(self) -> str:
        parts = [f"lie agent:{self.robot} at={self.at:g}"]
        if self.until is not None:
            parts.append(f"until={self.until:g}")
        for name in ("offset", "drift"):
            v = getattr(self, name)
            if any(v):
                parts.append(f"{name}={','.join(f'{x:g}' for x in v)}")
        if self.noise:
            parts.append(f"noise={self.noise:g}")
        if self.freeze:
            parts.append("freeze")
        return " ".join(parts)

    def active(self, t: float) -> bool:
        return self.at <= t + 1e-9 and (self.until is None or t + 1e-9 < self.until)

    def told(self, true_ph: list[float], frozen: list[float] | None, t: float, tick: int, seed: int) -> list[float]:
        """The false estimate for time ``t`` (s), tick ``tick``: from ``true_ph`` (or ``frozen``
        when freezing: the caller keeps the first true estimate it lied about)."""
        base = frozen if self.freeze and frozen is not None else true_ph
        age = t - self.at
        out = [base[c] + self.offset[c] + self.drift[c] * age for c in range(3)]
        if self.noise > 0:
            for c in range(3):
                out[c] += self.noise * _normal(seed, self.robot, tick, c)
        return out


def _normal(seed: int, robot: int, tick: int, axis: int) -> float:
    """A standard normal number from the seed and the key alone (Box-Muller on two hashed uniforms)."""
    digest = hashlib.blake2b(repr((seed, "lie", robot, tick, axis)).encode(), digest_size=16).digest()
    u1, u2 = struct.unpack("<QQ", digest)
    u1 = (u1 + 1) / (2.0**64 + 1)  # in (0, 1): log is finite
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2 / 2.0**64)


@dataclass(frozen=True)
class DegradedLimits:
    """How long an agent or the world trusts silence (s).

    staleness: a neighbour's (or the leader's) estimate older than this
    leaves the agent's sums; sense_timeout: an agent without sensing for
    longer commands zero velocity; silent_hold: the world holds a robot whose
    agent has been silent longer at zero velocity (before that, its last command).
    """

    staleness: float = 0.5
    sense_timeout: float = 0.5
    silent_hold: float = 0.5


@dataclass(frozen=True)
class Fate:
    lost: bool
    cause: str = ""  # "drop", "burst", "cut" or "" when delivered
    delay: float = 0.0  # s
    copies: int = 1


DELIVERED = Fate(False)


@dataclass(frozen=True)
class FaultPlan:
    """Every fault of a run. Empty plan => no wrapper, no cost, the clean run exactly."""

    seed: int = 0
    rules: tuple[LinkRule, ...] = ()
    cuts: tuple[Cut, ...] = ()
    processes: tuple[ProcessFault, ...] = ()
    limits: DegradedLimits = field(default_factory=DegradedLimits)
    lies: tuple[Lie, ...] = ()  # compromised robots: what they send (agents/node.py), not how links carry it
    _burst: dict = field(default_factory=dict, compare=False, repr=False)  # chain states per link
    _rules_of: dict = field(default_factory=dict, compare=False, repr=False)  # link -> matching rules

    def touches(self, receiver: str) -> bool:
        """Whether any link rule, cut or process fault can reach ``receiver`` (else it needs no
        inbox filter): a dead agent or leader concerns every receiver that would wait for it."""
        if self.cuts or self.processes:
            return True
        return any(fnmatchcase(receiver, r.dst) for r in self.rules)

    def may_lose(self, sender: str, receiver: str, kind: str) -> bool:
        """Whether a link rule or a cut may lose some of ``sender``'s ``kind`` messages to
        ``receiver`` (whatever their tick)."""
        return any(c.reaches(sender, receiver, kind) for c in self.cuts) or any(
            r.matches(sender, receiver, kind) and (r.drop > 0 or r.burst is not None) for r in self.rules)

    def lie_of(self, robot: int) -> Lie | None:
        """Robot ``robot``'s lie, if the plan makes it a liar (at most one per robot)."""
        return next((x for x in self.lies if x.robot == robot), None)

    def down(self, process: str, t: float) -> bool:
        """Whether ``process`` (``agent:<id>``, ...) is killed or frozen at time ``t`` (s)."""
        return any(p.target == process and p.at <= t + 1e-9 and (p.restart is None or t + 1e-9 < p.restart)
                   for p in self.processes)

    def max_delay_ticks(self, receiver: str, dt: float) -> int:
        worst = max((r.max_latency for r in self.rules if fnmatchcase(receiver, r.dst)), default=0.0)
        return int(math.ceil(worst / dt - 1e-9)) + 1 if worst > 0 else 0

    def cut(self, sender: str, receiver: str, kind: str, t: float) -> bool:
        """Whether a partition cuts ``sender``'s messages of ``kind`` to ``receiver`` at time ``t`` (s)."""
        return any(c.cuts(sender, receiver, kind, t) for c in self.cuts)

    def cut_off_from_world(self, robot: int, t: float) -> bool:
        """Whether the plan keeps robot ``robot`` (``LEADER``: the leader) and the world from answering
        each other at time ``t`` (s): the process killed or frozen, its sensing or its commands
        cut by a partition, or lost, every one, by a link rule (the real-time world does not
        wait for it). The leader keeps time by the sensing it hears, and the world hears its
        states past the fault filters (:meth:`~fxswarm.world.node.RealTimeWorld.heard_leader`),
        so only the sensing counts for it."""
        if robot == LEADER:
            return (self.down("leader", t) or self.cut("world", "leader", "sense", t)
                    or self.loses_all("world", "leader", "sense"))
        me = f"agent:{robot}"
        return (self.down(me, t) or self.cut("world", me, "sense", t) or self.cut(me, "world", "command", t)
                or self.loses_all("world", me, "sense") or self.loses_all(me, "world", "command"))

    def loses_all(self, sender: str, receiver: str, kind: str) -> bool:
        """Whether a link rule drops every message of ``kind`` from ``sender`` to ``receiver``."""
        return any(r.loses_all and r.matches(sender, receiver, kind) for r in self.rules)

    def fate(self, sender: str, receiver: str, kind: str, tick: int, t: float) -> Fate:
        """The fate of ``sender``'s tick-``tick`` message of ``kind`` at ``receiver`` (pure)."""
        if self.cut(sender, receiver, kind, t):
            return Fate(True, "cut")
        if kind not in FAULTABLE_KINDS:
            return DELIVERED
        link = (sender, receiver, kind)
        matching = self._rules_of.get(link)
        if matching is None:
            matching = self._rules_of[link] = [(n, r) for n, r in enumerate(self.rules) if r.matches(*link)]
        if not matching:
            return DELIVERED
        delay, copies = 0.0, 1
        for n, rule in matching:
            key = (n, sender, receiver, kind, tick)
            if rule.drop > 0 and self.uniform("drop", *key) < rule.drop:
                return Fate(True, "drop")
            if rule.burst is not None and self._burst_loses(n, rule.burst, sender, receiver, kind, tick):
                return Fate(True, "burst")
            if kind in LATE_KINDS:
                delay += rule.delay
                if rule.jitter > 0:
                    delay += rule.jitter * self.uniform("jitter", *key)
                if rule.reorder > 0 and self.uniform("reorder", *key) < rule.reorder:
                    delay += rule.reorder_delay
                if rule.duplicate > 0 and self.uniform("dup", *key) < rule.duplicate:
                    copies = 2
        if delay == 0.0 and copies == 1:
            return DELIVERED
        return Fate(False, "", delay, copies)

    def uniform(self, purpose: str, *key) -> float:
        """A uniform number in [0, 1) that depends only on the seed and ``key``."""
        digest = hashlib.blake2b(repr((self.seed, purpose) + key).encode(), digest_size=8).digest()
        return struct.unpack("<Q", digest)[0] / 2.0**64

    def _burst_loses(self, n: int, b: Burst, sender: str, receiver: str, kind: str, tick: int) -> bool:
        bad = self._burst_state(n, b, sender, receiver, kind, tick)
        return self.uniform("burst-loss", n, sender, receiver, kind, tick) < (b.loss_bad if bad else b.loss_good)

    def _burst_state(self, n: int, b: Burst, sender: str, receiver: str, kind: str, tick: int) -> bool:
        """Chain state at ``tick`` (True = bad), starting good at tick 0; cached per link."""
        cache = self._burst.setdefault((n, sender, receiver, kind), [False])
        while len(cache) <= tick:
            k = len(cache)
            u = self.uniform("burst-step", n, sender, receiver, kind, k)
            cache.append(u >= b.p_bad_good if cache[-1] else u < b.p_good_bad)
        return cache[tick]


# --- parsing ----------------------------------------------------------------------


def _fraction(f: _Fields, key: str, required: bool = False) -> float:
    if required and not f.has(key):
        f.fail(key, "a number (a probability in [0, 1])", show_got=False)
    value = f.number(key, 0.0, nonnegative=True)
    if value > 1.0:
        f.fail(key, "a probability in [0, 1]", value)
    return value


def _kinds(f: _Fields, key: str, default: tuple[str, ...]) -> tuple[str, ...]:
    if key not in f.table:
        return default
    value = f.table[key]
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not value or not all(v in FAULTABLE_KINDS for v in value):
        f.fail(key, f"a list of message kinds from {', '.join(FAULTABLE_KINDS)}", value)
    return tuple(value)


def _endpoint_ok(name: str) -> bool:
    return name == "*" or name in ("world", "leader") or (
        name.startswith("agent:") and (name[6:] == "*" or name[6:].isdigit() or any(c in name[6:] for c in "*?[")))


def _link(f: _Fields, key: str | int, text, n: int) -> tuple[str, str]:
    if not isinstance(text, str) or text.count("->") != 1:
        f.fail(key, "a link 'SRC->DST' such as 'agent:*->agent:4', 'leader->*' or 'world->agent:5'", text)
    src, dst = (s.strip() for s in text.split("->"))
    for end in (src, dst):
        if not _endpoint_ok(end):
            f.fail(key, "endpoints 'world', 'leader', 'agent:<id>', 'agent:*' or '*'", text)
        if end[6:].isdigit() and not 1 <= int(end[6:]) <= n:  # a robot the scenario does not have
            f.fail(key, f"endpoints 'agent:<id>' with id in 1..{n} (the scenario's robots)", text)
    return src, dst


def _links(f: _Fields, n: int) -> list[tuple[str, str]]:
    if f.has("link") == f.has("links") and f.has("link"):
        f.fail("link", "either 'link' or 'links', not both", show_got=False)
    if f.has("link"):
        return [_link(f, "link", f.table["link"], n)]
    raw = f.table.get("links", [])
    if not isinstance(raw, list):
        f.fail("links", "a list of 'SRC->DST' links", raw)
    lf = _Fields(f.source, {}, f.sub_path("links"))
    return [_link(lf, k, x, n) for k, x in enumerate(raw)]


def _window(f: _Fields, duration: float | None) -> tuple[float, float]:
    start = f.number("start", nonnegative=True)
    end = f.number("end", positive=True)
    if end <= start:
        f.fail("end", f"an end after start ({start:g} s)", end)
    return start, end


def _rule(f: _Fields, n: int) -> list[LinkRule]:
    f.check_known({"link", "links", "kinds", "drop", "burst", "delay", "jitter", "duplicate", "reorder",
                   "reorder_delay"})
    links = _links(f, n)
    if not links:
        f.fail("link", "a link 'SRC->DST'", show_got=False)
    burst = None
    if f.has("burst"):
        bf = f.table_at("burst")
        bf.check_known({"p_good_bad", "p_bad_good", "loss_good", "loss_bad"})
        burst = Burst(_fraction(bf, "p_good_bad", True), _fraction(bf, "p_bad_good", True),
                      _fraction(bf, "loss_good"), bf.number("loss_bad", 1.0, nonnegative=True))
        if burst.loss_bad > 1:
            bf.fail("loss_bad", "a probability in [0, 1]", burst.loss_bad)
    common = dict(
        kinds=_kinds(f, "kinds", FAULTABLE_KINDS), drop=_fraction(f, "drop"), burst=burst,
        delay=f.number("delay", 0.0, nonnegative=True), jitter=f.number("jitter", 0.0, nonnegative=True),
        duplicate=_fraction(f, "duplicate"), reorder=_fraction(f, "reorder"),
        reorder_delay=f.number("reorder_delay", 0.02, nonnegative=True),
    )
    return [LinkRule(src, dst, **common) for src, dst in links]


def _robot_ids(f: _Fields, key: str, n: int) -> tuple[int, ...]:
    raw = f.table.get(key, [])
    if isinstance(raw, int) and not isinstance(raw, bool):
        raw = [raw]
    if not isinstance(raw, list) or not all(isinstance(x, int) and not isinstance(x, bool) and 1 <= x <= n
                                            for x in raw):
        f.fail(key, f"a list of robot ids in 1..{n}", raw)
    return tuple(raw)


def _target(f: _Fields, n: int) -> str:
    target = f.string("target")
    # Not the world: it is the simulation itself; killing it ends the run.
    ok = target == "leader" or (target.startswith("agent:") and target[6:].isdigit() and 1 <= int(target[6:]) <= n)
    if not ok:
        f.fail("target", f"'leader' or 'agent:<id>' with id in 1..{n}", target)
    return target


def parse_faults(table: dict | None, scenario_seed: int, n: int, source: str = "<scenario>") -> FaultPlan:
    """Validate a ``[faults]`` table (as parsed TOML) into a :class:`FaultPlan`."""
    if table is None:
        return FaultPlan(seed=scenario_seed)
    top = _Fields(source, {"faults": table})
    f = top.table_at("faults")
    f.check_known({"seed", "staleness", "sense_timeout", "silent_hold", "links", "partitions",
                   "leader_outages", "processes", "lies"})
    limits = DegradedLimits(
        staleness=f.number("staleness", DegradedLimits.staleness, positive=True),
        sense_timeout=f.number("sense_timeout", DegradedLimits.sense_timeout, positive=True),
        silent_hold=f.number("silent_hold", DegradedLimits.silent_hold, positive=True),
    )
    rules: list[LinkRule] = []
    for rf in f.tables("links"):
        rules += _rule(rf, n)
    cuts: list[Cut] = []
    for pf in f.tables("partitions"):
        pf.check_known({"start", "end", "link", "links", "isolate", "kinds"})
        start, end = _window(pf, None)
        isolate = _robot_ids(pf, "isolate", n)
        links = tuple(_links(pf, n))
        if not isolate and not links:
            pf.fail("isolate", "robots to isolate or 'links' to cut", show_got=False)
        what = (f"isolate {','.join(map(str, isolate))}" if isolate else "") + \
               (" " if isolate and links else "") + " ".join(f"{s}->{d}" for s, d in links)
        cuts.append(Cut(start, end, links, isolate, _kinds(pf, "kinds", CUT_KINDS_DEFAULT),
                        label=f"partition {what} {start:g}-{end:g} s"))
    for of in f.tables("leader_outages"):
        of.check_known({"start", "end"})
        start, end = _window(of, None)
        cuts.append(Cut(start, end, (("leader", "*"),), (), ("leader",), label=f"leader outage {start:g}-{end:g} s"))
    processes = []
    for pf in f.tables("processes"):
        pf.check_known({"target", "kill", "restart", "freeze", "thaw"})
        target = _target(pf, n)
        if pf.has("kill") == pf.has("freeze"):
            pf.fail("kill", "exactly one of 'kill' (with optional 'restart') or 'freeze' (with 'thaw')",
                    show_got=False)
        action = "kill" if pf.has("kill") else "freeze"
        at = pf.number(action, nonnegative=True)
        back_key = "restart" if action == "kill" else "thaw"
        other = "thaw" if action == "kill" else "restart"
        if pf.has(other):
            pf.fail(other, f"'{back_key}' with '{action}'", show_got=False)
        back = pf.optional_number(back_key)
        if back is not None and back <= at:
            pf.fail(back_key, f"a time after {action} ({at:g} s)", back)
        processes.append(ProcessFault(target, action, at, back))
    lies: list[Lie] = []
    for lf in f.tables("lies"):
        lies.append(_lie(lf, n))
        if sum(x.robot == lies[-1].robot for x in lies) > 1:
            lf.fail("target", "one lie per robot (robot agent:%d lies twice)" % lies[-1].robot, show_got=False)
    seed = f.integer("seed", scenario_seed)
    return FaultPlan(seed, tuple(rules), tuple(cuts), tuple(processes), limits, tuple(lies))


def _lie(f: _Fields, n: int) -> Lie:
    f.check_known({"target", "at", "until", "offset", "drift", "noise", "freeze"})
    target = _target(f, n)
    if target == "leader":
        f.fail("target", f"'agent:<id>' with id in 1..{n} (the leader is trusted: it is the reference)", target)
    at = f.number("at", nonnegative=True)
    until = f.optional_number("until")
    if until is not None and until <= at:
        f.fail("until", f"a time after at ({at:g} s)", until)
    zero = (0.0, 0.0, 0.0)
    lie = Lie(int(target[6:]), at, until, f.vector("offset", zero), f.vector("drift", zero),
              f.number("noise", 0.0, nonnegative=True), f.boolean("freeze") if f.has("freeze") else False)
    if not (any(lie.offset) or any(lie.drift) or lie.noise or lie.freeze):
        f.fail("offset", "at least one of offset, drift, noise or freeze (a lie that says the truth is none)",
               show_got=False)
    return lie


def plan_of(scenario: Scenario) -> FaultPlan:
    """The scenario's fault plan (validated; raises :class:`ScenarioError` naming file and field)."""
    return parse_faults(scenario.raw.get("faults"), scenario.seed, scenario.n, scenario.source)


def degraded_limits(scenario: Scenario) -> DegradedLimits:
    return plan_of(scenario).limits


# --- resolution: the scenario's table, then --fault flags, then FXSWARM_FAULTS -----------

#: Where the compose writer (``fxswarm compose``) reads extra fault specs, ``;``-separated.
FAULTS_ENV = "FXSWARM_FAULTS"
#: Where a role process finds its resolved plan when no ``--fault-plan`` is given (compose).
PLAN_ENV = "FXSWARM_FAULT_PLAN"
#: The serialised plan's format tag: a reader refuses any other.
PLAN_FORMAT = "fxswarm-fault-plan/1"

CLI_HELP = (
    "add a fault (repeatable): 'SRC->DST key=value ...' with keys drop, delay, jitter, duplicate, "
    "reorder, reorder_delay, kinds (comma list), burst=p_gb,p_bg[,loss_good,loss_bad]; "
    "'partition START-END isolate=3[,4]' or 'partition START-END links=a->b[,c->d]'; "
    "'leader-outage START-END'; 'kill agent:2 at=10 [restart=12]'; 'freeze agent:2 at=10 [thaw=12]'; "
    "'lie agent:3 at=5 [until=T] [offset=x,y,z] [drift=x,y,z] [noise=SIGMA] [freeze]'; "
    "'seed=N'; 'staleness=S', 'sense_timeout=S', 'silent_hold=S'"
)


def resolve(scenario: Scenario, flags: list[str] | tuple[str, ...] | None = (),
            env: dict[str, str] | None = None) -> FaultPlan:
    """The run's one fault plan: the scenario's ``[faults]``, then each ``--fault`` spec of
    ``flags``, then each ``;``-separated spec of ``env[FXSWARM_FAULTS]`` (when ``env`` is given).

    Rules keep that order (a rule's index is part of its fates' hash); a later ``key=value``
    (``seed=``, ``staleness=``, ...) wins. Raises :class:`ScenarioError` naming the file and
    field, or the flag or variable and the spec, and what was expected.
    """
    table = _copy_table(scenario.raw.get("faults") or {})
    parse_faults(table, scenario.seed, scenario.n, scenario.source)  # the file's own errors name the file
    specs = [("--fault", s) for s in (flags or ())]
    if env is not None:
        specs += [(FAULTS_ENV, s.strip()) for s in env.get(FAULTS_ENV, "").split(";") if s.strip()]
    for origin, spec in specs:
        where = f"{origin} {spec!r}"
        fragment = _spec_table(spec, where)
        parse_faults(fragment, scenario.seed, scenario.n, where)  # its errors name this spec
        for key, value in fragment.items():
            if isinstance(value, list):
                table.setdefault(key, []).extend(value)
            else:
                table[key] = value
    origins = sorted({o for o, _ in specs})
    source = scenario.source + (f" with {' and '.join(origins)}" if origins else "")
    return parse_faults(table, scenario.seed, scenario.n, source)


def _cli_value(text: str):
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def _spec_table(spec: str, where: str) -> dict:
    """One ``--fault`` spec as the ``[faults]`` table that says the same (not yet validated)."""
    words = spec.split()
    if not words:
        raise ScenarioError(f"{where}: expected a fault, got nothing")
    head, rest = words[0], words[1:]
    if "->" in head:
        entry: dict = {"link": head}
        for key, value in _pairs(where, head, rest).items():
            if key == "kinds":
                entry[key] = value.split(",")
            elif key == "burst":
                try:
                    parts = [float(x) for x in value.split(",")]
                except ValueError:
                    raise ScenarioError(f"{where}: expected burst=p_gb,p_bg[,loss_good,loss_bad] (numbers), "
                                        f"got {value!r}") from None
                entry[key] = dict(zip(("p_good_bad", "p_bad_good", "loss_good", "loss_bad"), parts))
            else:
                entry[key] = _cli_value(value)
        return {"links": [entry]}
    if head in ("partition", "leader-outage"):
        if not rest or "-" not in rest[0] or "=" in rest[0]:
            raise ScenarioError(f"{where}: expected '{head} START-END ...' (seconds)")
        a, b = rest[0].split("-", 1)
        try:
            entry = {"start": float(a), "end": float(b)}
        except ValueError:
            raise ScenarioError(f"{where}: expected START-END in seconds, got {rest[0]!r}") from None
        pairs = _pairs(where, head, rest[1:])
        if head == "leader-outage":
            return {"leader_outages": [entry | pairs]}
        try:
            if "isolate" in pairs:
                entry["isolate"] = [int(x) for x in pairs.pop("isolate").split(",")]
        except ValueError:
            raise ScenarioError(f"{where}: expected isolate=ID[,ID...] (robot ids)") from None
        for key in ("links", "kinds"):
            if key in pairs:
                entry[key] = pairs.pop(key).split(",")
        return {"partitions": [entry | pairs]}
    if head in ("kill", "freeze"):
        if not rest:
            raise ScenarioError(f"{where}: expected '{head} TARGET at=SECONDS'")
        pairs = _pairs(where, head, rest[1:])
        if "at" not in pairs:
            raise ScenarioError(f"{where}: expected at=SECONDS")
        entry = {"target": rest[0], head: _cli_value(pairs.pop("at"))}
        return {"processes": [entry | {key: _cli_value(v) for key, v in pairs.items()}]}
    if head == "lie":
        if not rest:
            raise ScenarioError(f"{where}: expected 'lie agent:ID at=SECONDS ...'")
        words = rest[1:]
        freeze = "freeze" in words
        pairs = _pairs(where, head, [w for w in words if w != "freeze"])
        if "at" not in pairs:
            raise ScenarioError(f"{where}: expected at=SECONDS")
        entry = {"target": rest[0]} | ({"freeze": True} if freeze else {})
        for key, value in pairs.items():
            if key == "freeze":  # 'freeze' alone, or freeze=true/false as in the table
                entry[key] = {"true": True, "false": False}.get(value.lower(), value)
            elif key in ("offset", "drift"):
                try:
                    entry[key] = [float(x) for x in value.split(",")]
                except ValueError:
                    raise ScenarioError(f"{where}: expected {key}=x,y,z (numbers, m{'/s' * (key == 'drift')}), "
                                        f"got {value!r}") from None
            else:
                entry[key] = _cli_value(value)
        return {"lies": [entry]}
    if "=" in head and not rest:
        key, value = head.split("=", 1)
        return {key: _cli_value(value)}
    raise ScenarioError(f"{where}: expected 'SRC->DST ...', 'partition', 'leader-outage', 'kill', "
                        f"'freeze', 'lie' or key=value")


def _pairs(where: str, head: str, words: list[str]) -> dict[str, str]:
    if not all("=" in w for w in words):
        raise ScenarioError(f"{where}: expected key=value words after {head!r}")
    return dict(w.split("=", 1) for w in words)


def _copy_table(value):
    if isinstance(value, dict):
        return {k: _copy_table(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_copy_table(v) for v in value]
    return value


# --- the serialised plan: what the edge hands every process ----------------------------


def to_table(plan: FaultPlan) -> dict:
    """The ``[faults]`` table that :func:`parse_faults` turns back into ``plan`` (every field
    explicit), so a received plan is checked by the same validator as a scenario file."""
    links = []
    for r in plan.rules:
        entry = {"link": f"{r.src}->{r.dst}", "kinds": list(r.kinds), "drop": r.drop, "delay": r.delay,
                 "jitter": r.jitter, "duplicate": r.duplicate, "reorder": r.reorder,
                 "reorder_delay": r.reorder_delay}
        if r.burst is not None:
            entry["burst"] = {"p_good_bad": r.burst.p_good_bad, "p_bad_good": r.burst.p_bad_good,
                              "loss_good": r.burst.loss_good, "loss_bad": r.burst.loss_bad}
        links.append(entry)
    partitions, outages = [], []
    for c in plan.cuts:
        if c.label.startswith("leader outage"):
            outages.append({"start": c.start, "end": c.end})
            continue
        entry = {"start": c.start, "end": c.end, "kinds": list(c.kinds)}
        if c.isolate:
            entry["isolate"] = list(c.isolate)
        if c.links:
            entry["links"] = [f"{s}->{d}" for s, d in c.links]
        partitions.append(entry)
    processes = []
    for p in plan.processes:
        entry = {"target": p.target, p.action: p.at}
        if p.restart is not None:
            entry["restart" if p.action == "kill" else "thaw"] = p.restart
        processes.append(entry)
    lies = []
    for x in plan.lies:
        entry = {"target": f"agent:{x.robot}", "at": x.at, "offset": list(x.offset), "drift": list(x.drift),
                 "noise": x.noise, "freeze": x.freeze}
        if x.until is not None:
            entry["until"] = x.until
        lies.append(entry)
    table: dict = {"seed": plan.seed, "staleness": plan.limits.staleness,
                   "sense_timeout": plan.limits.sense_timeout, "silent_hold": plan.limits.silent_hold}
    for key, value in (("links", links), ("partitions", partitions), ("leader_outages", outages),
                       ("processes", processes), ("lies", lies)):
        if value:
            table[key] = value
    return table


def _origin(scenario: Scenario) -> str:
    """What a plan depends on in its scenario besides the robot count: the seed and the
    ``[faults]`` table (a digest): another scenario file with the same ones takes the same plan."""
    text = json.dumps([scenario.seed, scenario.raw.get("faults") or {}], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def dumps(plan: FaultPlan, scenario: Scenario) -> str:
    """``plan`` as JSON (one line), tagged with its format and the scenario it was resolved from."""
    return json.dumps({"format": PLAN_FORMAT, "scenario": scenario.name, "robots": scenario.n,
                       "origin": _origin(scenario), "faults": to_table(plan)}, separators=(",", ":"))


def loads(text: str, scenario: Scenario, source: str) -> FaultPlan:
    """A plan serialised by :func:`dumps`, checked against ``scenario`` (which it must have been
    resolved for) and validated; errors name ``source`` (e.g. ``--fault-plan FILE``)."""
    try:
        data = json.loads(text)
    except ValueError as exc:
        raise ScenarioError(f"{source}: expected a fault plan in JSON, got invalid JSON ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != PLAN_FORMAT:
        got = data.get("format") if isinstance(data, dict) else type(data).__name__
        raise ScenarioError(f"{source}: format: expected {PLAN_FORMAT!r}, got {got!r}")
    if data.get("robots") != scenario.n or data.get("origin") != _origin(scenario):
        raise ScenarioError(
            f"{source}: scenario: expected a plan resolved from {scenario.source} ({scenario.n} robots, its seed "
            f"and [faults]), got one from {data.get('scenario')!r} ({data.get('robots')} robots, other seed or "
            f"[faults]); resolve it again from this file")
    faults = data.get("faults")
    if not isinstance(faults, dict):
        raise ScenarioError(f"{source}: faults: expected a table, got {faults!r}")
    return parse_faults(faults, scenario.seed, scenario.n, source)


def load_plan(value: str, scenario: Scenario, source: str) -> FaultPlan:
    """``--fault-plan JSON|FILE``: inline JSON (it starts with ``{``) or a file that holds it."""
    if value.lstrip().startswith("{"):
        return loads(value, scenario, source)
    try:
        text = Path(value).read_text()
    except OSError as exc:
        raise ScenarioError(f"{source}: expected a fault plan file, cannot read it: "
                            f"{exc.strerror or exc}") from None
    return loads(text, scenario, source)
