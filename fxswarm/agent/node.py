"""The agent node: one robot's distributed estimator and behavioural control, sans I/O.

It takes messages (its own sensing, its graph neighbours' estimates, the
leader if pinned) and returns messages to send (its estimate to its
neighbours, its velocity command to the world). No transport, no clock, no
sleep: the runners drive it in lock-step or in real time.
"""

from __future__ import annotations

from collections import deque
import numpy as np

from fxswarm.agent.links import InLinks
from fxswarm.core import bus as topics
from fxswarm.core.control import robot_control, robot_control_floats
from fxswarm.core.messages import Command, Estimate, LeaderState, Message, Sense
from fxswarm.core.scenario import Scenario
from fxswarm.faults.plan import degraded_limits

# Degraded modes, reported to the world in Command.flags (bit set) and counted per robot.
FLAG_STALE_NEIGHBOUR = 1  # a neighbour silent longer than the staleness limit left the sums
FLAG_NO_LEADER = 2  # pinned, but the leader is silent: the estimator runs on neighbours alone
FLAG_EXTRAPOLATING = 4  # hears nobody: the estimate moves with the last estimated leader velocity
FLAG_NO_SENSING = 8  # no sensing for longer than the limit: commands zero velocity
FLAG_NAMES = {FLAG_STALE_NEIGHBOUR: "stale_neighbour", FLAG_NO_LEADER: "no_leader",
              FLAG_EXTRAPOLATING: "extrapolating", FLAG_NO_SENSING: "no_sensing"}
#: Time constant (s) of the running mean of the estimate's rate used as the leader's velocity
#: when extrapolating: the sign term makes the raw rate chatter by +-K3 per axis.
LEADER_VELOCITY_TAU_S = 1.0


class AgentNode:
    """Robot ``robot_id``'s node.

    Lock-step: on ``Sense(k)`` it sends ``Estimate(k)`` of its current
    estimate; once it holds ``Estimate(k)`` from every neighbour and, if
    pinned, ``LeaderState(k)``, it computes and sends ``Command(k)`` and steps
    its estimate by ``dt`` (explicit Euler, SPEC section 7).
    Real time: :meth:`act` computes on whatever it holds, whenever called.
    """

    def __init__(self, scenario: Scenario, robot_id: int, lockstep: bool = True) -> None:
        self.sc = scenario
        self.id = robot_id
        self.lockstep = lockstep
        robot = scenario.robots[robot_id - 1]
        self.offset = robot.offset
        self.ph = np.array(robot.estimate, dtype=float)
        self.neighbour_ids = scenario.neighbours(robot_id)
        self.pinned = scenario.is_pinned(robot_id)
        weights = [scenario.a[robot_id - 1, j - 1] for j in self.neighbour_ids]
        if self.pinned:
            weights.append(scenario.b[robot_id - 1])
        self.weights = np.array(weights, dtype=float)
        self._weight_list = self.weights.tolist()
        self._estimate_topic, self._command_topic = topics.estimate_topic(robot_id), topics.command_topic(robot_id)
        self.sense: Sense | None = None
        self.estimates: dict[int, Estimate] = {}  # latest held per neighbour (zero-order hold)
        self.leader: LeaderState | None = None
        self.acted_tick = -1
        # Lock-step pipelining: a robot sends its tick-(k+1) estimate as soon as it has acted on
        # tick k (the estimate is final then), so neighbours hold it before tick k+1's sensing
        # arrives; a neighbour's estimate for a tick after the one this robot acts on next waits
        # in `ahead` until then (docs/DESIGN.md "Lock-step pipelining").
        self.estimate_tick = -1  # the newest tick whose estimate this robot has sent
        self.ahead: dict[int, list[Message]] = {}  # per neighbour (0: the leader): messages for later ticks
        self.seq_estimate = 0
        self.seq_command = 0
        self.speed_limited = 0  # how often the optional speed limit bit
        # Degraded modes (docs/DESIGN.md "Faults"): limits, what was last really sensed, counts.
        self.limits = degraded_limits(scenario)
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

    # --- wiring -------------------------------------------------------------------------

    def subscriptions(self) -> list[str]:
        """The only topics this robot hears: locality is the point of the paper."""
        subs = [topics.sense_topic(self.id)] + [topics.estimate_topic(j) for j in self.neighbour_ids]
        if self.pinned:
            subs.append(topics.LEADER_STATE)
        return subs

    def handle(self, topic: str, msg: Message) -> list[topics.Outgoing]:
        """Take one message; return what to send because of it."""
        out: list[topics.Outgoing] = []
        if isinstance(msg, Sense):
            if msg.robot != self.id:
                return out
            if self.sense is not None and msg.tick < self.sense.tick:
                return out  # an old sensing message overtaken by a newer one
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
        cmd = self.act(self.sc.dt)
        k = self.acted_tick + 1
        if self.ahead:
            self._take_ahead(k)
        if k >= self.sc.ticks:
            return [cmd]  # the run's last tick: no next one to estimate for
        self.estimate_tick = k
        return [cmd, self.estimate_message(k, k * self.sc.dt)]

    def waiting_for(self, tick: int) -> list[str]:
        """Senders whose tick-``tick`` message this agent still lacks (lock-step)."""
        missing = [f"agent:{j}" for j in self.neighbour_ids
                   if (h := self.estimates.get(j)) is None or h.tick < tick]
        if self.pinned and (self.leader is None or self.leader.tick < tick):
            missing.append("leader")
        if self.expects is not None:  # a fault filter knows these will not come this tick
            missing = [m for m in missing if self.expects(m, tick)]
        return missing

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
        self.seq_estimate += 1
        msg = Estimate("agent", self.id, self.seq_estimate, tick, t, self.id, self.ph.copy())
        return self._estimate_topic, msg

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
        its delay times the leader's speed to the lag, compounded over the graph (docs/DESIGN.md
        "Delay compensation"). Lock-step without faults holds only current values: no change.
        """
        rows: list[list[float]] = []
        weights: list[float] = []
        stale_neighbour = False
        held = self.estimates
        v = self.v_leader.tolist() if self.compensate and now is not None else None
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

    def act(self, dt: float) -> topics.Outgoing:
        """Compute the command from what is held, step the estimate by ``dt``, return the command."""
        s = self.sense
        assert s is not None, "act() before any sensing"
        now = s.t if self.lockstep else (self.sensed_t if self.sensed_t is not None else s.t) + self.since_sense_s
        fresh_by = now - self.limits.staleness - 1e-9  # heard before this: stale (s)
        rows, weights, stale_neighbour, no_leader = self._held_rows(fresh_by, now)
        hears = len(weights) > 0
        if not hears and self.v_extrapolate is None:
            self._start_extrapolating(now)
        if self.sc.discretisation == "semi-implicit":
            out = robot_control(
                s.p, self.ph, np.array(rows, dtype=float).reshape(-1, 3), np.array(weights, dtype=float),
                *self.offset.state(s.t), s.po, s.vo, self.sc.d, self.sc.formation, self.sc.avoidance,
                self.sc.estimator, self.sc.v_max,
                dph=None if hears else self.v_extrapolate,  # hearing nobody: extrapolate
                semi_implicit_dt=dt,
            )
            v, dph, avoid_active, limited = out.v.tolist(), out.dph.tolist(), out.avoid_active, out.speed_limited
        else:  # the default, explicit Euler: the law on Python floats (3-vectors: numpy calls cost more)
            p_i0, dp_i0 = self.offset.state_lists(s.t)
            v, dph, _, avoid_active, limited = robot_control_floats(
                s.p.tolist(), self.ph.tolist(), rows, weights, p_i0, dp_i0,
                None if s.po is None else s.po.tolist(), None if s.vo is None else s.vo.tolist(),
                self.sc.d, self.sc.formation, self.sc.avoidance, self.sc.estimator, self.sc.v_max,
                dph=None if hears else self.v_extrapolate.tolist(),  # hearing nobody: extrapolate
            )
        flags = self._degraded_flags(stale_neighbour, no_leader, hears, now)
        if hears:
            gain = min(1.0, dt / LEADER_VELOCITY_TAU_S)
            vl = self.v_leader.tolist()
            self.v_leader = np.array([vl[0] + gain * (dph[0] - vl[0]), vl[1] + gain * (dph[1] - vl[1]),
                                      vl[2] + gain * (dph[2] - vl[2])])
            self.v_extrapolate = None
        self.history.append((now, self.ph, self.v_leader))
        if flags & FLAG_NO_SENSING:
            v = [0.0, 0.0, 0.0]  # blind for too long: stop rather than fly on old sensing
        self.speed_limited += limited
        ph_used = self.ph
        ph = ph_used.tolist()
        self.ph = np.array([ph[0] + dt * dph[0], ph[1] + dt * dph[1], ph[2] + dt * dph[2]])  # explicit Euler (SPEC 7)
        self.acted_tick = s.tick
        self.seq_command += 1
        if not self.lockstep:
            self.since_sense_s += dt
        cmd = Command("agent", self.id, self.seq_command, s.tick, s.t, self.id, np.array(v), ph_used, avoid_active,
                      flags, self.link_ages(now), tuple(self.in_links.drops))
        return self._command_topic, cmd

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
            self.v_extrapolate = self.v_leader
            return
        t0, ph0, v0 = start
        self.v_extrapolate = v0
        self.ph = ph0 + (now - t0) * v0

    def _degraded_flags(self, stale_neighbour: bool, no_leader: bool, hears: bool, now: float) -> int:
        """The degraded modes of this step (``FLAG_*`` bits), counted in ``degraded_ticks``.
        ``stale_neighbour``/``no_leader``: from :meth:`_held_rows`."""
        flags = 0
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
