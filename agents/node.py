"""The agent node: one robot's distributed estimator and behavioural control, sans I/O.

It takes messages (its own sensing, its graph neighbours' estimates, the
leader if pinned) and returns messages to send (its velocity command to the
world, carrying its estimate for its neighbours: they read ``agent/<j>/cmd``;
docs/design.md "Crossings per tick"). No transport, no clock, no
sleep: the runners drive it in lock-step or in real time. In real time the
runner calls :meth:`AgentNode.act_realtime` with the simulation time when
the schedule (``fxswarm.core.pacing.Pacer``) or :meth:`AgentNode.fresh_sensing`
says so; every decision on time (what to integrate, what is stale, when to
extrapolate, when to stop) is made here from the time stamps it is given.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from collections.abc import Collection

import numpy as np

from fxswarm.agents.links import InLinks
from fxswarm.core import bus as topics
from fxswarm.core.control import in_repulsive_zone
from fxswarm.core.laws import LawView, checked_vector, describe_failure, limit_speed, make_law, resolve_law
from fxswarm.core.messages import Command, Estimate, LeaderState, Message, Sense
from fxswarm.core.observer import observer_links, velocity_observer_rate
from fxswarm.core.resilience import wmsr_trim
from fxswarm.core.scenario import Scenario
from fxswarm.faults.plan import DegradedLimits, Lie, degraded_limits

# Degraded modes, reported to the world in Command.flags (bit set) and counted per robot.
FLAG_STALE_NEIGHBOUR = 1  # a neighbour silent longer than the staleness limit left the sums
FLAG_NO_LEADER = 2  # pinned, but the leader is silent: the estimator runs on neighbours alone
FLAG_EXTRAPOLATING = 4  # hears nobody: the estimate moves with the last estimated leader velocity
FLAG_NO_SENSING = 8  # no sensing for longer than the limit: commands zero velocity
FLAG_LAW_ERROR = 16  # the law raised or returned no 3 finite numbers: zero velocity, the estimate kept
FLAG_NAMES = {FLAG_STALE_NEIGHBOUR: "stale_neighbour", FLAG_NO_LEADER: "no_leader",
              FLAG_EXTRAPOLATING: "extrapolating", FLAG_NO_SENSING: "no_sensing", FLAG_LAW_ERROR: "law_error"}
_ZERO = (0.0, 0.0, 0.0)
#: Time constant (s) of the running mean of the estimate's rate used as the leader's velocity
#: when extrapolating: the sign term makes the raw rate chatter by +-K3 per axis.
LEADER_VELOCITY_TAU_S = 1.0


class AgentNode:
    """Robot ``robot_id``'s node.

    Lock-step: once it holds ``Estimate(k)`` from every neighbour and, if
    pinned, ``LeaderState(k)``, it computes ``Command(k)``, steps its estimate
    by ``dt`` (explicit Euler, SPEC section 7) and sends the command with
    ``Estimate(k + 1)`` riding on it. On a ``Sense(k)`` whose estimate it has
    not sent yet (the first tick, or after a tick it skipped) it sends
    ``Estimate(k)`` alone, on its command key.
    Real time: :meth:`act` computes on whatever it holds, whenever called.
    """

    def __init__(self, scenario: Scenario, robot_id: int, lockstep: bool = True,
                 limits: DegradedLimits | None = None, lie: Lie | None = None, seed: int = 0) -> None:
        self.sc = scenario
        self.id = robot_id
        self.lockstep = lockstep
        robot = scenario.robots[robot_id - 1]
        self.offset = robot.offset
        self.ph = np.array(robot.estimate, dtype=float)
        self.neighbour_ids = scenario.neighbours(robot_id)
        self.pinned = scenario.is_pinned(robot_id)
        # [estimator] estimator_graph = "oriented" (docs/estimator.md): eq. (11) sums over the
        # upstream neighbours only (fewer hops from a pinned robot); the others' rows weigh 0.
        ids, ws = observer_links(scenario.graph, scenario.b, scenario.estimator_graph).row(robot_id - 1)
        row = dict(zip((ids + 1).tolist(), ws.tolist()))
        weights = [row.get(j, 0.0) for j in self.neighbour_ids]
        if self.pinned:
            weights.append(scenario.b[robot_id - 1])
        self.weights = np.array(weights, dtype=float)
        self._weight_list = self.weights.tolist()
        # The scenario's law (fxswarm.core.laws; checked when the scenario was loaded), and the
        # view it is handed each tick, in the vectors it asked for.
        self.law = make_law(resolve_law(scenario.law, scenario.law_folder), scenario.law_params, robot_id, scenario)
        self.law_floats = getattr(self.law, "vectors", "numpy") == "floats"
        self.view = LawView(robot_id, scenario.d)
        self.law_error_first: str | None = None  # the first law_error's message
        self._command_topic = topics.command_topic(robot_id)
        self.sense: Sense | None = None
        self.estimates: dict[int, Estimate] = {}  # latest held per neighbour (zero-order hold)
        self.leader: LeaderState | None = None
        self.acted_tick = -1
        self.acted_t: float | None = None  # real time: the simulation time of the last act, s
        self.last_command: topics.Outgoing | None = None  # real time: sent again if the world asks again
        self.command_before: topics.Outgoing | None = None  # lock-step: the one before (said_again)
        self.estimate_said: Estimate | None = None  # lock-step: the last estimate sent alone (said_again)
        # Lock-step pipelining: a robot sends its tick-(k+1) estimate as soon as it has acted on
        # tick k (the estimate is final then), so neighbours hold it before tick k+1's sensing
        # arrives; a neighbour's estimate for a tick after the one this robot acts on next waits
        # in `ahead` until then (docs/design.md "Lock-step pipelining").
        self.estimate_tick = -1  # the newest tick whose estimate this robot has sent
        self.ahead: dict[int, list[Message]] = {}  # per neighbour (0: the leader): messages for later ticks
        self.seq_said = 0  # one numbering for all this robot puts on its command key (link gaps, faults)
        self.speed_limited = 0  # how often the optional speed limit bit
        # Degraded modes (docs/design.md "Fault model"): limits, what was last really sensed, counts.
        # The run's resolved plan's limits (its --fault overrides included); else the file's.
        self.limits = limits if limits is not None else degraded_limits(scenario)
        self.expects = None  # lock-step: expects(sender, tick) -> bool, set by a fault filter
        self.sensed_t: float | None = None  # time of the last real (not replayed) sensing, s
        self.since_sense_s = 0.0  # real time: seconds acted since the last sensing
        self.compensate = scenario.delay_compensation == "leader-velocity"  # see _held_rows
        self.v_leader = np.zeros(3)  # running mean of dph: the leader's velocity as estimated
        self.v_extrapolate: np.ndarray | None = None  # while hearing nobody: the velocity used
        # (t, ph, v_leader) of recent steps: extrapolation starts from the last step whose inputs
        # were current, not from an estimate that spent the staleness window chasing held values.
        self.history: deque = deque(maxlen=int(np.ceil(self.limits.staleness / scenario.dt)) + 8)
        self.degraded_ticks = {name: 0 for name in FLAG_NAMES.values()}
        # Link health as this robot sees it, reported in each Command (neighbours, then the leader).
        self.in_links = InLinks(list(self.neighbour_ids) + ([0] if self.pinned else []))
        # [estimator] tracking = "feedforward" (docs/estimator.md): the leader-velocity observer,
        # eq. (obs), whose estimate vh travels with ph and is fed forward in the estimator, eq. (11ff),
        # and in the formation behaviour, eq. (v2ff).
        self.feedforward = scenario.tracking == "feedforward"
        self.vh = np.zeros(3)  # estimate of the leader's velocity, m/s
        if self.feedforward:  # the neighbours eq. (obs) listens to (upstream ones, if oriented), and weights
            ids, ws = observer_links(scenario.graph, scenario.b, scenario.observer_graph).row(robot_id - 1)
            self.observer_links = list(zip((ids + 1).tolist(), ws.tolist()))
        # [estimator] resilience = "w-msr" (docs/resilience.md): F, the values discarded per axis
        # above and below its own before the law sees its rows; 0: none (the paper's, no cost).
        self.tolerate = scenario.tolerate if scenario.resilience == "w-msr" else 0
        self.discarded = 0  # neighbour values (per axis) discarded so far
        # A lie fault (fxswarm.faults.plan.Lie): this robot is compromised and sends false estimates.
        self.lie, self.lie_seed = lie, seed
        self.lie_frozen: list[float] | None = None  # freeze: the true estimate when the lie began

    # --- wiring -------------------------------------------------------------------------

    def subscriptions(self) -> list[str]:
        """The only topics this robot hears: locality is the point of the paper. A neighbour's
        estimate rides on its command (``agent/<j>/cmd``)."""
        subs = [topics.sense_topic(self.id)] + [topics.command_topic(j) for j in self.neighbour_ids]
        if self.pinned:
            subs.append(topics.LEADER_STATE)
        return subs

    def handle(self, topic: str, msg: Message) -> list[topics.Outgoing]:
        """Take one message; return what to send because of it."""
        out: list[topics.Outgoing] = []
        if type(msg) is Command:  # a neighbour's: the estimate it carries, if any
            msg = msg.carried_estimate()
            if msg is None:
                return out
        if isinstance(msg, Sense):
            if msg.robot != self.id:
                return out
            if self.sense is not None and msg.tick < self.sense.tick:
                return out  # an old sensing message overtaken by a newer one
            if not self.lockstep and msg.tick == self.acted_tick and self.last_command is not None:
                # The world holding its clock asks again (RealTimeWorld.tick): the answer it
                # lacks was lost on the way, and time has not moved, so that answer goes again,
                # numbered anew as the new transmission it is.
                self.seq_said += 1
                topic, cmd = self.last_command
                self.last_command = topic, dataclasses.replace(cmd, seq=self.seq_said)
                out.append(self.last_command)
                return out
            self.sense = msg
            if not getattr(msg, "replayed", False):
                self.sensed_t, self.since_sense_s = msg.t, 0.0
            if self.lockstep:
                if self.ahead:
                    self._take_ahead(msg.tick)
                if self.estimate_tick < msg.tick:  # not sent after the last act (first tick, or a skipped one)
                    out.append(self.estimate_message(msg.tick, msg.t))
        elif isinstance(msg, Estimate):
            if msg.robot in self.neighbour_ids and msg.robot != self.id:
                self.in_links.heard(msg.robot, msg.seq, msg.tick)
                self._take(msg.robot, msg)
        elif isinstance(msg, LeaderState):
            if self.pinned:
                self.in_links.heard(0, msg.seq, msg.tick)
                self._take(0, msg)
        if self.lockstep and self.ready():
            out += self.act_tick()
        return out

    def next_tick(self) -> int:
        """Lock-step: the tick this robot acts on next (the one after its last act, or a later
        sensing's if the world moved on without it)."""
        return max(self.acted_tick + 1, self.sense.tick if self.sense is not None else 0)

    def _take(self, j: int, msg: Estimate | LeaderState) -> None:
        """A neighbour's estimate (``j``: its id) or the leader's state (``j`` = 0): held now, or,
        in lock-step, kept in ``ahead`` if it is for a tick after the one this robot acts on next
        (sent a tick early: pipelined)."""
        if self.lockstep and msg.tick > self.next_tick():
            self.ahead.setdefault(j, []).append(msg)
        else:
            self._hold(j, msg)

    def _hold(self, j: int, msg: Estimate | LeaderState) -> None:
        """Hold ``msg`` as sender ``j``'s latest (0: the leader), unless a newer one is held."""
        held = self.leader if j == 0 else self.estimates.get(j)
        if held is None or msg.tick >= held.tick:
            if j == 0:
                self.leader = msg
            else:
                self.estimates[j] = msg

    def _take_ahead(self, upto: int) -> None:
        """Hold each neighbour's (and, key 0, the leader's) newest waiting message for a tick up
        to ``upto``."""
        for j, waiting in list(self.ahead.items()):
            due = [m for m in waiting if m.tick <= upto]
            if not due:
                continue
            self._hold(j, max(due, key=lambda m: m.tick))
            rest = [m for m in waiting if m.tick > upto]
            if rest:
                self.ahead[j] = rest
            else:
                del self.ahead[j]

    def act_tick(self) -> list[topics.Outgoing]:
        """Lock-step: act on the current tick ``k``; return the command and the tick-``k+1``
        estimate (final now: the estimator has stepped), sent at once so it is not on the next
        tick's critical path."""
        k = self.sense.tick + 1
        last = k >= self.sc.ticks  # the run's last tick: no next one to estimate for
        cmd = self.act(self.sc.dt, None if last else (k, k * self.sc.dt))
        if self.ahead:
            self._take_ahead(k)
        if not last:
            self.estimate_tick = k
        return [cmd]

    def waiting_for(self, tick: int) -> list[str]:
        """Senders whose tick-``tick`` message this agent still lacks (lock-step)."""
        missing = [f"agent:{j}" for j in self.neighbour_ids
                   if (h := self.estimates.get(j)) is None or h.tick < tick]
        if self.pinned and (self.leader is None or self.leader.tick < tick):
            missing.append("leader")
        if self.expects is not None:  # a fault filter knows these will not come this tick
            missing = [m for m in missing if self.expects(m, tick)]
        return missing

    def is_late(self, msg: Message) -> bool:
        """Lock-step: whether ``msg`` is for a tick older than the sensing held (counted stale)."""
        s = self.sense
        if type(msg) is Command:  # a neighbour's: its carried estimate's tick (none on the last tick)
            return s is not None and msg.est_tick is not None and msg.est_tick < s.tick
        return s is not None and isinstance(msg, (Sense, Estimate, LeaderState)) and msg.tick < s.tick

    def act_past_the_gone(self, gone: Collection[str]) -> list[topics.Outgoing]:
        """Lock-step: act on the current tick now if every sender it still waits for is in
        ``gone`` (names as :meth:`waiting_for` gives them: ``"agent:<id>"``, ``"leader"``) -
        their processes have left and will not answer; the robot acts on what it last heard."""
        s = self.sense
        if s is None or self.acted_tick >= s.tick:
            return []
        missing = self.waiting_for(s.tick)
        if missing and all(m in gone for m in missing):
            return self.act_tick()
        return []

    def ready(self) -> bool:
        """Lock-step: whether this robot holds everything it expects for its current tick."""
        s = self.sense
        if s is None or s.tick <= self.acted_tick:
            return False
        k = s.tick
        if self.expects is not None:
            return not self.waiting_for(k)
        for j in self.neighbour_ids:
            held = self.estimates.get(j)
            if held is None or held.tick < k:
                return False
        return not self.pinned or (self.leader is not None and self.leader.tick >= k)

    # --- messages out -------------------------------------------------------------------

    def estimate_message(self, tick: int, t: float) -> topics.Outgoing:
        """The current estimate alone, for a tick with no command to carry it (on the command key)."""
        self.seq_said += 1
        ph = self.ph.copy() if self.lie is None else self._said(self.ph, tick, t)
        msg = Estimate("agent", self.id, self.seq_said, tick, t, self.id, ph,
                       self.vh.copy() if self.feedforward else None)
        self.estimate_said = msg
        return self._command_topic, msg

    def _said(self, ph: np.ndarray, tick: int, t: float) -> np.ndarray:
        """The estimate this robot tells its neighbours for ``tick`` at ``t`` s: ``ph``, or, while
        its lie fault is on, the lie (deterministic: the plan's seed, the tick)."""
        lie = self.lie
        if not lie.active(t):
            return ph.copy()
        true = ph.tolist()
        if lie.freeze and self.lie_frozen is None:
            self.lie_frozen = true
        return np.array(lie.told(true, self.lie_frozen, t, tick, self.lie_seed))

    def said_again(self, tick: int) -> list[topics.Outgoing]:
        """Lock-step, the world asking again after a router outage: what this robot has said for
        ``tick``, the same values numbered anew: its estimate for the tick (sent alone, or carried
        by its previous command) and, if it has acted on it, its command. Receivers hold by tick,
        so a repeat changes nothing; one lost with the router arrives now."""
        out: list[topics.Outgoing] = []
        said = [self.estimate_said, *(c[1] for c in (self.command_before, self.last_command) if c is not None)]
        for m in said:
            if type(m) is Command:
                m = m if m.tick == tick else m.carried_estimate() if m.est_tick == tick else None
            if m is not None and m.tick == tick:
                self.seq_said += 1
                out.append((self._command_topic, dataclasses.replace(m, seq=self.seq_said)))
        return out

    def held_estimates(self, fresh_by: float = -np.inf, now: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The estimates this robot holds, shape (m, 3), neighbours in ascending id then the
        leader (``ph_0 := p0``), with their weights ``a_ij`` / ``b_i``, shape (m,).
        Those sent before ``fresh_by`` (s) are stale and left out; given the robot's time ``now``
        (s), older ones are carried forward to it (:meth:`_held_rows`)."""
        rows, weights, _, _ = self._held_rows(fresh_by, now)
        return np.array(rows, dtype=float).reshape(-1, 3), np.array(weights, dtype=float)

    def _held_rows(self, fresh_by: float, now: float | None) -> tuple[list[list[float]], list[float], bool, bool]:
        """:meth:`held_estimates` as lists, and whether a neighbour / the (pinned) leader is
        missing or stale: one pass over the holds (the agent's per-tick hot path).

        Delay compensation (``[controller] delay_compensation = "leader-velocity"``, the
        default): a held value stamped ``t`` < ``now`` is carried forward by ``now - t`` at the
        leader's velocity as this robot estimates it (:attr:`v_leader`). Every estimate tracks
        the leader, so that is where it has moved since it was sent. Without it, each hop adds
        its delay times the leader's speed to the lag, compounded over the graph (docs/design.md
        "Delay compensation"). Lock-step without faults holds only current values: no change.
        """
        rows: list[list[float]] = []
        weights: list[float] = []
        stale_neighbour = False
        held = self.estimates
        v = self.leader_velocity().tolist() if self.compensate and now is not None else None
        for j, w in zip(self.neighbour_ids, self._weight_list):
            h = held.get(j)
            if h is None or h.t < fresh_by:
                stale_neighbour = True
            else:
                rows.append(h.ph.tolist() if v is None or h.t >= now else _carried(h.ph, now - h.t, v))
                weights.append(w)
        no_leader = False
        if self.pinned:
            leader = self.leader
            if leader is None or leader.t < fresh_by:
                no_leader = True
            else:
                rows.append(leader.p0.tolist() if v is None or leader.t >= now
                            else _carried(leader.p0, now - leader.t, v))
                weights.append(self._weight_list[-1])
        return rows, weights, stale_neighbour, no_leader

    def act(self, dt: float, estimate_at: tuple[int, float] | None = None) -> topics.Outgoing:
        """Compute the command from what is held, step the estimate by ``dt``, return the command;
        with ``estimate_at`` = (tick, t s), it carries the stepped estimate for that tick and time."""
        s = self.sense
        assert s is not None, "act() before any sensing"
        now = s.t if self.lockstep else (self.sensed_t if self.sensed_t is not None else s.t) + self.since_sense_s
        fresh_by = now - self.limits.staleness - 1e-9  # heard before this: stale (s)
        rows, weights, stale_neighbour, no_leader = self._held_rows(fresh_by, now)
        if self.tolerate:  # W-MSR: the law (any law) sees the trimmed rows; the leader's is trusted
            rows, n = wmsr_trim(self.ph.tolist(), rows, self.tolerate, int(self.pinned and not no_leader))
            self.discarded += n
        hears = len(weights) > 0
        if not hears and self.v_extrapolate is None:
            self._start_extrapolating(now)
        p_i0, dp_i0 = self.offset.state_lists(s.t)
        p = s.p.tolist()
        po = None if s.po is None else s.po.tolist()
        view = self.view  # refreshed in place (per tick, per robot: the hot path)
        view.t, view.dt, view.heard_leader = s.t, dt, self.pinned and not no_leader
        vh = self.vh.tolist() if self.feedforward else None  # eqs. (11ff), (v2ff)
        nearest = None if po is None else (po, _ZERO if s.vo is None else s.vo.tolist())
        if s.heading is not None or s.velocity is not None:  # the robot's drive model has them
            view.heading = s.heading
            view.velocity = s.velocity if s.velocity is None or not self.law_floats else s.velocity.tolist()
        if self.law_floats:
            view.p, view.ph, view.offset, view.offset_rate = p, self.ph.tolist(), p_i0, dp_i0
            view.rows, view.weights, view.vh, view.nearest = rows, weights, vh, nearest
        else:
            self._numpy_view(p, rows, weights, p_i0, dp_i0, vh, nearest)
        law_error = None
        try:
            method = "estimate_rate"  # hearing nobody: the node extrapolates, the law only steers
            dph = checked_vector(self.law.estimate_rate(view)) if hears else self.v_extrapolate.tolist()
            method = "velocity"
            v = checked_vector(self.law.velocity(view, dph if self.law_floats else np.array(dph)))
        except Exception as exc:  # the law's failure is the robot's degraded mode, never its crash
            law_error = describe_failure(method, exc)
            v, dph = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]  # stop, and keep the estimate
            if self.law_error_first is None:
                self.law_error_first = law_error
        limited = False
        if self.sc.v_max is not None:  # not in the paper: [scenario] v_max, for every law alike
            v, limited = limit_speed(v, self.sc.v_max)
        avoid_active = po is not None and in_repulsive_zone(p, po, self.sc.d)
        flags = self._degraded_flags(stale_neighbour, no_leader, hears, now, law_error is not None)
        if hears:
            if law_error is None:
                gain = min(1.0, dt / LEADER_VELOCITY_TAU_S)
                vl = self.v_leader.tolist()
                self.v_leader = np.array([vl[0] + gain * (dph[0] - vl[0]), vl[1] + gain * (dph[1] - vl[1]),
                                          vl[2] + gain * (dph[2] - vl[2])])
            self.v_extrapolate = None
        self.history.append((now, self.ph, self.leader_velocity()))
        vh_used = self.vh
        if self.feedforward:
            self.vh = self._observer_step(fresh_by, dt)
        if flags & FLAG_NO_SENSING:
            v = [0.0, 0.0, 0.0]  # blind for too long: stop rather than fly on old sensing
        self.speed_limited += limited
        ph_used = self.ph
        ph = ph_used.tolist()
        self.ph = np.array([ph[0] + dt * dph[0], ph[1] + dt * dph[1], ph[2] + dt * dph[2]])  # explicit Euler (SPEC 7)
        self.acted_tick = s.tick
        self.seq_said += 1
        if not self.lockstep:
            self.since_sense_s += dt
        est_tick, est_t, est_ph, est_vh = None, None, None, None
        if estimate_at is not None:  # self.ph, self.vh: new arrays, never changed in place
            (est_tick, est_t), est_ph, est_vh = estimate_at, self.ph, self.vh if self.feedforward else None
            if self.lie is not None:
                est_ph = self._said(est_ph, est_tick, est_t)
        cmd = Command("agent", self.id, self.seq_said, s.tick, s.t, self.id, np.array(v), ph_used, avoid_active,
                      flags, self.link_ages(now), tuple(self.in_links.drops), vh_used if self.feedforward else None,
                      est_tick, est_t, est_ph, est_vh, law_error)
        self.command_before, self.last_command = self.last_command, (self._command_topic, cmd)
        return self.last_command

    def _numpy_view(self, p: list, rows: list, weights: list, offset: list, offset_rate: list, vh: list | None,
                    nearest: tuple | None) -> None:
        """This tick's vectors into :attr:`view` as numpy arrays (a law with ``vectors = "numpy"``)."""
        view, a = self.view, np.array
        view.p, view.ph, view.offset, view.offset_rate = a(p), self.ph.copy(), a(offset), a(offset_rate)
        view.rows, view.weights = a(rows, dtype=float).reshape(-1, 3), a(weights, dtype=float)
        view.vh = None if vh is None else a(vh)
        view.nearest = None if nearest is None else (a(nearest[0]), a(nearest[1], dtype=float))

    def fresh_sensing(self) -> bool:
        """Real time: whether sensing newer than the last act is held (act on it at once)."""
        return self.sense is not None and self.sense.tick > self.acted_tick

    def act_realtime(self, now: float) -> list[topics.Outgoing]:
        """Real time: act at simulation time ``now`` (s) on what is held (zero-order hold),
        integrating the time since the last act (one period for the first); return the command
        and the new estimate. Nothing before any sensing, or if time has not moved since the
        last act (a second act on the same sensing would integrate nothing)."""
        if self.sense is None or (self.acted_t is not None and now <= self.acted_t):
            return []
        dt = self.sc.dt if self.acted_t is None else now - self.acted_t
        self.acted_t = now
        return [self.act(dt, (self.sense.tick, now))]

    # --- tracking = "feedforward": the leader-velocity observer (fxswarm.core.observer) --------

    def leader_velocity(self) -> np.ndarray:
        """The leader's velocity as this robot knows it (m/s, (3,)): what delay compensation
        carries late values forward at and what extrapolation moves the estimate at. The
        observer's ``vh`` with feedforward (it converges to ``dp0/dt`` in fixed time); else the
        running mean of the estimate's rate (the paper's estimator has no better)."""
        return self.vh if self.feedforward else self.v_leader

    def _observer_step(self, fresh_by: float, dt: float) -> np.ndarray:
        """``vh`` after one explicit Euler step of eq. (obs) over ``dt`` (s), on the velocity
        estimates held from its observer links (upstream neighbours, if oriented) and the
        leader's velocity if pinned. Values sent before ``fresh_by`` (s) are stale and left out,
        as in the position estimator; late ones are used as they are (a velocity changes
        slowly). Hearing none of them, ``vh`` holds."""
        rows: list[list[float]] = []
        weights: list[float] = []
        for j, w in self.observer_links:
            h = self.estimates.get(j)
            if h is not None and h.t >= fresh_by and h.vh is not None:
                rows.append(h.vh.tolist())
                weights.append(w)
        leader = self.leader
        if self.pinned and leader is not None and leader.t >= fresh_by and leader.v0 is not None:
            rows.append(leader.v0.tolist())
            weights.append(self._weight_list[-1])
        vh = self.vh.tolist()
        rate = velocity_observer_rate(vh, rows, weights, self.sc.observer)
        return np.array([vh[0] + dt * rate[0], vh[1] + dt * rate[1], vh[2] + dt * rate[2]])  # eq. (obs), Euler

    def link_ages(self, now: float) -> tuple[int, ...]:
        """Per in-link (neighbours in ascending id, then the leader): how many ticks old the held
        message is at ``now`` (s); with nothing held, ticks since tick -1. Lock-step: the sensing's
        tick less the held message's (the same, in integers: every node times tick k at k * dt)."""
        held = [self.estimates.get(j) for j in self.neighbour_ids]
        if self.pinned:
            held.append(self.leader)
        if self.lockstep:  # per act, per robot: plain integer arithmetic
            k = self.sense.tick
            return tuple([k + 1 if h is None else (k - h.tick if h.tick < k else 0) for h in held])
        dt = self.sc.dt
        return tuple(round(now / dt) + 1 if h is None else max(0, round((now - h.t) / dt)) for h in held)

    def _start_extrapolating(self, now: float) -> None:
        """Hearing nobody from ``now`` (s) on: go back to the step at the newest input's time and
        carry that estimate forward at that step's estimated leader velocity."""
        inputs = [h.t for h in self.estimates.values()] + ([self.leader.t] if self.leader is not None else [])
        newest = max(inputs, default=None)
        start = None
        if newest is not None:
            start = next((e for e in reversed(self.history) if e[0] <= newest + 1e-9), None)
        if start is None:
            self.v_extrapolate = self.leader_velocity()
            return
        t0, ph0, v0 = start
        self.v_extrapolate = v0
        self.ph = ph0 + (now - t0) * v0

    def _degraded_flags(self, stale_neighbour: bool, no_leader: bool, hears: bool, now: float,
                        law_error: bool = False) -> int:
        """The degraded modes of this step (``FLAG_*`` bits), counted in ``degraded_ticks``.
        ``stale_neighbour``/``no_leader``: from :meth:`_held_rows`."""
        flags = FLAG_LAW_ERROR if law_error else 0
        if stale_neighbour:
            flags |= FLAG_STALE_NEIGHBOUR
        if no_leader:
            flags |= FLAG_NO_LEADER
        if not hears:
            flags |= FLAG_EXTRAPOLATING
        if self.sensed_t is None or now - self.sensed_t > self.limits.sense_timeout + 1e-9:
            flags |= FLAG_NO_SENSING
        if flags:
            for bit, name in FLAG_NAMES.items():
                if flags & bit:
                    self.degraded_ticks[name] += 1
        return flags


def _carried(x: np.ndarray, age: float, v: list[float]) -> list[float]:
    """``x`` carried forward by ``age`` s at velocity ``v``, as a list."""
    x0, x1, x2 = x.tolist()
    return [x0 + age * v[0], x1 + age * v[1], x2 + age * v[2]]
