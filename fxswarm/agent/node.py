"""The agent node: one robot's distributed estimator and behavioural control, sans I/O.

It takes messages (its own sensing, its graph neighbours' estimates, the
leader if pinned) and returns messages to send (its estimate to its
neighbours, its velocity command to the world). No transport, no clock, no
sleep: the runners drive it in lock-step or in real time.
"""

from __future__ import annotations

import numpy as np

from fxswarm.core import bus as topics
from fxswarm.core.control import robot_control
from fxswarm.core.messages import Command, Estimate, LeaderState, Message, Sense
from fxswarm.core.scenario import Scenario


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
        self.sense: Sense | None = None
        self.estimates: dict[int, Estimate] = {}  # latest held per neighbour (zero-order hold)
        self.leader: LeaderState | None = None
        self.acted_tick = -1
        self.seq_estimate = 0
        self.seq_command = 0
        self.speed_limited = 0  # how often the optional speed limit bit

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
            if self.lockstep:
                out.append(self.estimate_message(msg.tick, msg.t))
        elif isinstance(msg, Estimate):
            if msg.robot in self.neighbour_ids and msg.robot != self.id:
                held = self.estimates.get(msg.robot)
                if held is None or msg.tick >= held.tick:
                    self.estimates[msg.robot] = msg
        elif isinstance(msg, LeaderState):
            if self.pinned and (self.leader is None or msg.tick >= self.leader.tick):
                self.leader = msg
        if self.lockstep and self.ready():
            out.append(self.act(self.sc.dt))
        return out

    def waiting_for(self, tick: int) -> list[str]:
        """Senders whose tick-``tick`` message this agent still lacks (lock-step)."""
        missing = [f"agent:{j}" for j in self.neighbour_ids
                   if (h := self.estimates.get(j)) is None or h.tick < tick]
        if self.pinned and (self.leader is None or self.leader.tick < tick):
            missing.append("leader")
        return missing

    def ready(self) -> bool:
        """Lock-step: whether this robot holds everything it expects for its current tick."""
        s = self.sense
        if s is None or s.tick <= self.acted_tick:
            return False
        k = s.tick
        for j in self.neighbour_ids:
            held = self.estimates.get(j)
            if held is None or held.tick < k:
                return False
        return not self.pinned or (self.leader is not None and self.leader.tick >= k)

    # --- messages out -------------------------------------------------------------------

    def estimate_message(self, tick: int, t: float) -> topics.Outgoing:
        self.seq_estimate += 1
        msg = Estimate("agent", self.id, self.seq_estimate, tick, t, self.id, self.ph.copy())
        return topics.estimate_topic(self.id), msg

    def held_estimates(self) -> tuple[np.ndarray, np.ndarray]:
        """The estimates this robot holds, shape (m, 3), neighbours in ascending id then the
        leader (``ph_0 := p0``), with their weights ``a_ij`` / ``b_i``, shape (m,)."""
        ids = self.neighbour_ids
        held = self.estimates
        if len(held) == len(ids) and (not self.pinned or self.leader is not None):
            rows = [held[j].ph for j in ids]  # the usual case: everyone heard, weights as built
            weights = self.weights
        else:
            rows = [held[j].ph for j in ids if j in held]
            weights = [w for j, w in zip(ids, self.weights) if j in held]
            if self.pinned and self.leader is not None:
                weights.append(self.weights[-1])
            weights = np.array(weights, dtype=float)
        if self.pinned and self.leader is not None:
            rows.append(self.leader.p0)
        return np.array(rows).reshape(-1, 3), weights

    def act(self, dt: float) -> topics.Outgoing:
        """Compute the command from what is held, step the estimate by ``dt``, return the command."""
        s = self.sense
        assert s is not None, "act() before any sensing"
        neighbours, weights = self.held_estimates()
        p_i0, dp_i0 = self.offset.state(s.t)
        out = robot_control(
            s.p, self.ph, neighbours, weights, p_i0, dp_i0,
            s.po, s.vo, self.sc.d, self.sc.formation, self.sc.avoidance, self.sc.estimator, self.sc.v_max,
        )
        self.speed_limited += out.speed_limited
        ph_used = self.ph
        self.ph = self.ph + dt * out.dph  # explicit Euler (SPEC section 7)
        self.acted_tick = s.tick
        self.seq_command += 1
        cmd = Command("agent", self.id, self.seq_command, s.tick, s.t, self.id, out.v, ph_used, out.avoid_active)
        return topics.command_topic(self.id), cmd
