"""The world node: integrates the robots, moves the obstacles, tells each robot what it senses.

Sans I/O. Lock-step: :meth:`start` emits tick 0; every ``Command(k)`` is
held; once all robots' commands for tick ``k`` are in (or :meth:`timeout`
is called), it integrates ``p += dt * v``, records the tick and emits tick
``k+1``. Real time: :meth:`advance` integrates on the commands it holds.
It records the whole run for ``trajectory.npz``.

When to close a tick without every command (:class:`TickTimer`, lock-step)
and when to tick, hold the clock or count a tick late (:class:`RealTimeWorld`,
real time) are decided here too, on an injectable clock
(``fxswarm.core.pacing``): the process only waits, feeds and publishes.

Link health: each robot's ``Command`` reports, per link into it, the age of
the estimate it holds and the messages it missed; the world publishes them
in ``WorldState`` per directed link (:func:`directed_links`), the age grown
by the ticks since that robot's report (a silent robot's links age).
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable, Collection

import numpy as np

from fxswarm.core import bus as topics
from fxswarm.core.drive import step_double_integrator, step_unicycle
from fxswarm.core.messages import Clock, Command, Message, Sense, WorldState
from fxswarm.core.motion import Static
from fxswarm.core.nearest import NearestCache, have_tree, nearest_objects_blocked, nearest_objects_tree, norms
from fxswarm.core.pacing import Deadline, Pacer, WallClock
from fxswarm.core.scenario import Scenario
from fxswarm.core.sensing import Sensors
from fxswarm.faults.plan import LEADER, DegradedLimits, degraded_limits


#: Above this many robots the nearest object comes from a KD-tree, not an n x (n + m) matrix.
DENSE_NEAREST_MAX = 400


def nearest_objects(p: np.ndarray, v: np.ndarray, obstacles: np.ndarray, obstacle_v: np.ndarray):
    """For each robot, its nearest object among the obstacles and the other robots.

    p, v: robots' positions and velocities (n, 3); obstacles, obstacle_v: (m, 3).
    Returns ``(po, vo, dist, is_obstacle)`` of shapes (n, 3), (n, 3), (n,), (n,),
    and ``obstacle_dist`` (n,): the distance to the nearest obstacle alone
    (inf without obstacles). With one robot and no obstacle, ``dist`` is inf.
    """
    n = len(p)
    if n > DENSE_NEAREST_MAX:  # no n x n matrix (fxswarm.core.nearest): the same answer from a KD-tree
        if have_tree():
            return nearest_objects_tree(p, v, obstacles, obstacle_v)
        return nearest_objects_blocked(p, v, obstacles, obstacle_v)  # without scipy: in blocks of rows
    objects = np.concatenate([obstacles, p])
    object_v = np.concatenate([obstacle_v, v])
    dist = norms(p[:, None, :] - objects[None, :, :])
    m = len(obstacles)
    rows, own = _self_index(n, m)
    dist[rows, own] = np.inf  # a robot is not its own nearest object
    obstacle_dist = dist[:, :m].min(axis=1) if m else np.full(n, np.inf)
    k = dist.argmin(axis=1)
    return objects[k], object_v[k], dist[rows, k], k < m, obstacle_dist


@functools.lru_cache(maxsize=8)
def _self_index(n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """``(arange(n), m + arange(n))``, read-only: built once per swarm shape, not every tick."""
    rows, own = np.arange(n), m + np.arange(n)
    rows.setflags(write=False)
    own.setflags(write=False)
    return rows, own


class WorldNode:
    """The world of scenario ``sc``: robots' true state, obstacles, the clock, the record."""

    def __init__(self, scenario: Scenario, record: bool = True, limits: DegradedLimits | None = None,
                 record_every: int = 1) -> None:
        self.sc = scenario
        n, ticks = scenario.n, scenario.ticks
        self.record_every = record_every  # trajectory.npz keeps ticks 0, K, 2K, ... (fxswarm sim --record-every)
        self.p = np.array([r.position for r in scenario.robots], dtype=float)
        # Above the dense limit with scipy: KD-tree candidate lists kept across ticks (fxswarm.core.nearest)
        self._nearest = NearestCache() if n > DENSE_NEAREST_MAX and have_tree() else nearest_objects
        self.v = np.zeros((n, 3))  # held commands (zero until a robot speaks)
        self.ph = np.array([r.estimate for r in scenario.robots], dtype=float)
        self.avoid = np.zeros(n, dtype=bool)
        self.tick = 0
        self.commands: dict[int, Command] = {}  # commands received for the current tick
        self.missed_ticks = 0
        self.misses = np.zeros(n, dtype=int)
        self.seq = 0
        self.done = False
        # Faults (docs/design.md "Fault model"): which commands to wait for, silent robots, degraded modes.
        self.expects = None  # lock-step: expects("agent:<id>", tick) -> bool, set by a fault filter
        self.limits = limits if limits is not None else degraded_limits(scenario)  # the run's plan's, else the file's
        self.silent_s = np.zeros(n)  # how long each robot's agent has been silent, s
        self._anyone_silent = False  # whether silent_s has a non-zero entry (fast path when not)
        self.held_at_zero = np.zeros(n, dtype=int)  # ticks a silent robot was held at zero velocity
        self.degraded_ticks = 0  # ticks with at least one robot held at zero: it could not hear them
        self.unheard_since: int | None = None  # first tick of the current stretch with every robot held
        self.flag_ticks = np.zeros((n, 8), dtype=int)  # ticks each Command.flags bit was set, per robot
        self.law_errors: dict[int, str] = {}  # per robot: the first law_error message heard
        self._heard: set[int] = set()  # real time: robots heard since the last advance
        self._sensed: tuple | None = None
        self._tick_said: list[topics.Outgoing] = []  # lock-step: the current tick's sensing, as sent
        # Static obstacles never move: their (read-only) state is built once, not every tick.
        self._fixed_obstacles = None
        if all(isinstance(o, Static) for o in scenario.obstacles):
            self._fixed_obstacles = self.obstacle_state(0.0)
            for a in self._fixed_obstacles:
                a.setflags(write=False)
        # Link health (see the module's docstring): each robot's last report and the tick it was for.
        self.in_degree = [len(scenario.neighbours(r.id)) + scenario.is_pinned(r.id) for r in scenario.robots]
        self._link_age: list[tuple[int, ...]] = [(0,) * m for m in self.in_degree]
        self._link_drops: list[tuple[int, ...]] = [(0,) * m for m in self.in_degree]
        self._link_tick = [-1] * n
        self._links_key: tuple | None = None  # what the cached arrays were built from
        self._links_cached: tuple[np.ndarray, np.ndarray] | None = None
        self.link_reports_invalid = 0  # commands whose link reports had the wrong number of links
        self._models(scenario)
        self.record = record
        if record:
            self.rec_t = np.arange(0, ticks, record_every) * scenario.dt
            ticks = len(self.rec_t)
            self.rec_p = np.zeros((ticks, n, 3))
            self.rec_ph = np.zeros((ticks, n, 3))
            self.rec_v = np.zeros((ticks, n, 3))
            self.rec_near = np.zeros((ticks, n))
            self.rec_near_obstacle = np.zeros((ticks, n))
            self.rec_avoid = np.zeros((ticks, n), dtype=bool)
            self.rec_obstacles = np.zeros((ticks, len(scenario.obstacles), 3))
            if self.drives is not None:
                self.rec_heading = np.zeros((ticks, n))
                self.rec_velocity = np.zeros((ticks, n, 3))

    def _models(self, sc: Scenario) -> None:
        """The robots' drive models and sensors ([world], docs/robots.md). ``drives`` and
        ``sensors`` stay None in the paper's world (every robot an unlimited single integrator
        sensing the truth): then :meth:`move` and :meth:`_emit_tick` are what they always were."""
        w = sc.world
        self.drives = None if w is None or w.ideal_motion else w.drives
        self.sensors = None if w is None or w.sensing.ideal else Sensors(w.sensing, sc.n, sc.seed)
        n = sc.n
        self.vel = np.zeros((n, 3))  # with drive models: the velocity each robot moves at
        self.heading = None  # (n,) rad, with a unicycle in the swarm
        self.saturated = {}  # limit -> ticks each robot spent at it (n,)
        if self.drives is None:
            return
        models = [d.model for d in self.drives]
        self._uni = [i for i, m in enumerate(models) if m == "unicycle"]
        self._di = [i for i, m in enumerate(models) if m == "double-integrator"]
        self._si_limits = np.array([np.inf if d.v_max is None or m != "single-integrator" else d.v_max
                                    for d, m in zip(self.drives, models)])
        self.heading = np.array(w.headings, dtype=float) if self._uni else None
        self.saturated = {"speed": np.zeros(n, dtype=int)}
        if self._uni:
            self.saturated["yaw_rate"] = np.zeros(n, dtype=int)
        if self._di:
            self.saturated["acceleration"] = np.zeros(n, dtype=int)

    @property
    def t(self) -> float:
        return self.tick * self.sc.dt

    def subscriptions(self) -> list[str]:
        return [topics.command_topic(r.id) for r in self.sc.robots]

    def obstacle_state(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        obs = self.sc.obstacles
        if not obs:
            return np.zeros((0, 3)), np.zeros((0, 3))
        return np.array([o.position(t) for o in obs]), np.array([o.velocity(t) for o in obs])

    # --- lock-step ----------------------------------------------------------------------

    def start(self) -> list[topics.Outgoing]:
        """Emit tick 0."""
        return self._emit_tick()

    def handle(self, topic: str, msg: Message) -> list[topics.Outgoing]:
        if not isinstance(msg, Command) or self.done:
            return []
        if msg.tick == self.tick:
            self.commands[msg.robot] = msg
            if len(self.commands) == self.sc.n or (self.expects is not None and not self.waiting_for()):
                return self._finish_tick()
        elif msg.tick > self.tick:
            return []  # from the future: cannot happen in lock-step; ignore
        return []

    def is_late(self, msg: Message) -> bool:
        """Lock-step: whether ``msg`` is a command for a tick already closed (counted stale)."""
        return isinstance(msg, Command) and msg.tick < self.tick

    def waiting_for(self) -> list[int]:
        """Robots whose command for the current tick has not arrived."""
        missing = [r.id for r in self.sc.robots if r.id not in self.commands]
        if self.expects is not None:  # a fault filter knows these will not come this tick
            missing = [r for r in missing if self.expects(f"agent:{r}", self.tick)]
        return missing

    def timeout(self) -> list[topics.Outgoing]:
        """A tick's deadline passed: hold the last command of each silent robot and go on."""
        if self.done:
            return []
        missing = self.waiting_for()
        self.missed_ticks += 1 if missing else 0
        for rid in missing:
            self.misses[rid - 1] += 1
        return self._finish_tick()

    def _finish_tick(self) -> list[topics.Outgoing]:
        for rid, cmd in self.commands.items():
            self.v[rid - 1] = cmd.v
            self.ph[rid - 1] = cmd.ph
            self.avoid[rid - 1] = cmd.avoid_active
            if cmd.flags:
                self.flag_ticks[rid - 1] += (cmd.flags >> np.arange(8)) & 1
                if cmd.law_error is not None:
                    self.law_errors.setdefault(rid, cmd.law_error)
            self._take_links(cmd)
        self._note_silence(self.commands, self.sc.dt)
        self.commands = {}
        out = [self._state_message()]
        self._record()
        self.move(self.sc.dt)
        self.tick += 1
        if self.tick >= self.sc.ticks:
            self.done = True
            return out
        return out + self._emit_tick()

    # --- real time ----------------------------------------------------------------------

    def take_command(self, msg: Command) -> None:
        """Real time: hold a robot's latest command (zero-order hold)."""
        self.v[msg.robot - 1] = msg.v
        self.ph[msg.robot - 1] = msg.ph
        self.avoid[msg.robot - 1] = msg.avoid_active
        self._heard.add(msg.robot)
        if msg.flags:
            self.flag_ticks[msg.robot - 1] += (msg.flags >> np.arange(8)) & 1
            if msg.law_error is not None:
                self.law_errors.setdefault(msg.robot, msg.law_error)
        self._take_links(msg)

    def advance(self, dt: float) -> list[topics.Outgoing]:
        """Real time: record, integrate ``dt`` seconds on the held commands, emit the next tick."""
        self._note_silence(self._heard, dt)
        self._heard = set()
        out = [self._state_message()]
        self._record()
        self.move(dt)
        self.tick += 1
        if self.tick >= self.sc.ticks:
            self.done = True
            return out
        return out + self._emit_tick()

    # --- shared -------------------------------------------------------------------------

    def move(self, dt: float) -> None:
        """The robots move ``dt`` s on the held commands: explicit Euler (SPEC section 7). The
        ROS 2 world (:mod:`fxswarm.world.ros2`) takes the robots' measured poses here instead.
        With drive models ([world] model), each robot moves as its model does on the command."""
        if self.drives is None:
            self.p = self.p + dt * self.v
            return
        v = self.v
        p = self.p + dt * v  # the single integrators (the others' rows are overwritten below)
        vel = v.copy()
        speed = np.sqrt(np.einsum("ij,ij->i", v, v))
        over = speed > self._si_limits  # a single integrator's own speed limit
        if over.any():
            vel[over] *= (self._si_limits[over] / speed[over])[:, None]
            p[over] = self.p[over] + dt * vel[over]
            self.saturated["speed"] += over
        drives = self.drives
        if self._uni:
            u = self._uni
            p[u], self.heading[u], vel[u], at_v, at_w = step_unicycle(
                self.p[u], self.heading[u], v[u], dt, [drives[i] for i in u])
            self.saturated["speed"][u] += at_v
            self.saturated["yaw_rate"][u] += at_w
        if self._di:
            k = self._di
            p[k], vel[k], at_v, at_a = step_double_integrator(self.p[k], self.vel[k], v[k], dt, [drives[i] for i in k])
            self.saturated["speed"][k] += at_v
            self.saturated["acceleration"][k] += at_a
        self.p, self.vel = p, vel

    def drive_report(self) -> dict | None:
        """summary.json's ``world``: the models flown, the sensing, and per limit the ticks each
        robot spent at it (robot ids as string keys, robots never at it left out); None in the
        paper's world (no [world] table)."""
        w = self.sc.world
        if w is None:
            return None
        s = w.sensing
        return {"models": {str(r.id): d.model for r, d in zip(self.sc.robots, w.drives)},
                "pose_noise_m": max(s.pose_noise, default=0.0), "obstacle_noise_m": s.obstacle_noise,
                "sensing_delay_ticks": s.delay, "sensing_range_m": s.range,
                "saturated_ticks": {limit: {str(i + 1): int(x) for i, x in enumerate(a) if x}
                                    for limit, a in self.saturated.items()}}

    def _note_silence(self, heard, dt: float) -> None:
        """Robots not ``heard`` this step keep their last command until silent longer than
        the limit; then the world holds them at zero velocity (a robot whose agent died stops)."""
        if len(heard) == self.sc.n and not self._anyone_silent:
            return  # the usual case: everyone heard and nobody was silent, so nothing changes
        silent = np.ones(self.sc.n, dtype=bool)
        silent[[r - 1 for r in heard]] = False
        self.silent_s = np.where(silent, self.silent_s + dt, 0.0)
        self._anyone_silent = bool(silent.any())
        hold = silent & (self.silent_s > self.limits.silent_hold + 1e-9)
        if hold.any():
            self.v[hold] = 0.0
            self.held_at_zero += hold
            self.degraded_ticks += 1
        if not hold.all():
            self.unheard_since = None
        elif self.unheard_since is None:
            self.unheard_since = self.tick

    def degraded(self) -> dict:
        """summary.json's ``degraded``: ``{"ticks": ticks with a robot held at zero because the world
        had not heard it for longer than ``silent_hold``, "robots": [their ids]}``."""
        return {"ticks": int(self.degraded_ticks),
                "robots": [r.id for r, held in zip(self.sc.robots, self.held_at_zero) if held]}

    def _take_links(self, cmd: Command) -> None:
        """Hold robot ``cmd.robot``'s link report (one with the wrong number of links is counted, not held)."""
        i = cmd.robot - 1
        m = self.in_degree[i]
        if len(cmd.link_age) != m or len(cmd.link_drops) != m:
            self.link_reports_invalid += 1
            return
        self._link_age[i], self._link_drops[i], self._link_tick[i] = cmd.link_age, cmd.link_drops, cmd.tick

    def link_health(self) -> tuple[np.ndarray, np.ndarray]:
        """``(age, drops)`` per directed link (:func:`directed_links` order), int64 (L,), at this
        tick; read-only, and the same arrays as the last tick's while nothing changed (the usual
        lock-step case: every robot reports zeros every tick)."""
        k = self.tick
        since = tuple([k - t if t < k else 0 for t in self._link_tick])  # ticks since each robot's report
        key = (tuple(self._link_age), tuple(self._link_drops), since)
        if key == self._links_key:
            return self._links_cached
        age = np.fromiter(itertools.chain.from_iterable(self._link_age), dtype=np.int64)
        drops = np.fromiter(itertools.chain.from_iterable(self._link_drops), dtype=np.int64)
        age += np.repeat(np.array(since, dtype=np.int64), self.in_degree)
        age.setflags(write=False)
        drops.setflags(write=False)
        self._links_key, self._links_cached = key, (age, drops)
        return age, drops

    def _sense_now(self):
        t = self.t
        obstacles, obstacle_v = self._fixed_obstacles or self.obstacle_state(t)
        po, vo, dist, _, obstacle_dist = self._nearest(
            self.p, self.v if self.drives is None else self.vel, obstacles, obstacle_v)
        self._sensed = (obstacles, dist, obstacle_dist)
        return po, vo, dist

    def _emit_tick(self) -> list[topics.Outgoing]:
        t, k = self.t, self.tick
        po, vo, dist = self._sense_now()
        self.seq += 1
        if self.sensors is not None or self.drives is not None:
            return self._emit_sensed(po, vo, dist)
        out: list[topics.Outgoing] = []  # no clock message: the leader takes the tick from robot 1's sensing
        # Rows of fresh arrays (one copy of p, po and vo are new), and plain floats for the test:
        # numpy calls per robot cost more than the work (issue 2).
        for r, p_i, po_i, vo_i, dist_i in zip(self.sc.robots, self.p.copy(), po, vo, dist.tolist()):
            has = math.isfinite(dist_i)
            out.append((topics.sense_topic(r.id), Sense(
                "world", 0, self.seq, k, t, r.id, p_i, po_i if has else None, vo_i if has else None)))
        self._tick_said = out
        return out

    def _emit_sensed(self, po: np.ndarray, vo: np.ndarray, dist: np.ndarray) -> list[topics.Outgoing]:
        """:meth:`_emit_tick` with drive models or sensors: each robot's sensing as its sensors
        measured it (:class:`~fxswarm.core.sensing.Sensors`), with its heading and velocity
        where its model has them."""
        t, k = self.t, self.tick
        heading, velocity = self.heading, None if self.drives is None else self.vel
        if self.sensors is not None:
            p, po, vo, has, heading, velocity = self.sensors.measure(self.p, po, vo, dist, heading, velocity)
        else:
            p, has = self.p.copy(), np.isfinite(dist)
        drives = self.drives
        out: list[topics.Outgoing] = []
        for i, r in enumerate(self.sc.robots):
            model = "single-integrator" if drives is None else drives[i].model
            h = float(heading[i]) if heading is not None and model == "unicycle" else None
            vi = velocity[i].copy() if velocity is not None and model != "single-integrator" else None
            out.append((topics.sense_topic(r.id), Sense(
                "world", 0, self.seq, k, t, r.id, p[i].copy(), po[i].copy() if has[i] else None,
                vo[i].copy() if has[i] else None, h, vi)))
        self._tick_said = out
        return out

    def ask_again(self) -> list[topics.Outgoing]:
        """Lock-step, after a router outage: the current tick's sensing again, as sent, and a
        ``Clock`` on ``RESYNC`` asking everyone to say again what they said for this tick (each
        holds by tick, so repeats change nothing; what was lost with the router arrives now)."""
        if self.done:
            return []
        return [*self._tick_said, (topics.RESYNC, Clock("world", 0, self.seq, self.tick, self.t))]

    def _state_message(self) -> topics.Outgoing:
        obstacles, dist, _ = self._sensed if self._sensed is not None else self._sense_now()
        return topics.WORLD_STATE, WorldState(
            "world", 0, self.seq, self.tick, self.t, self.p.copy(), self.v.copy(), self.ph.copy(),
            np.where(np.isfinite(dist), dist, -1.0), self.avoid.copy(), obstacles.copy(), *self.link_health(),
            None if self.heading is None else self.heading.copy())

    def _record(self) -> None:
        k, every = self.tick, self.record_every
        if not self.record or k >= self.sc.ticks or k % every:
            return
        k //= every
        obstacles, dist, obstacle_dist = self._sensed if self._sensed is not None else self._sense_now()
        self.rec_p[k] = self.p
        self.rec_ph[k] = self.ph
        self.rec_v[k] = self.v
        self.rec_near[k] = dist
        self.rec_near_obstacle[k] = obstacle_dist
        self.rec_avoid[k] = self.avoid
        self.rec_obstacles[k] = obstacles
        if self.drives is not None:
            self.rec_velocity[k] = self.vel
            if self.heading is not None:
                self.rec_heading[k] = self.heading

    def trajectory(self) -> dict[str, np.ndarray]:
        """The recorded run, as saved to ``trajectory.npz`` (shapes in README)."""
        ticks = -(-min(self.tick, self.sc.ticks) // self.record_every)  # the ticks recorded so far
        t = self.rec_t[:ticks]
        return {
            "t": t,
            "p": self.rec_p[:ticks],
            "ph": self.rec_ph[:ticks],
            "p0": np.array([self.sc.leader.position(x) for x in t]).reshape(-1, 3),
            "v": self.rec_v[:ticks],
            "nearest_distance": self.rec_near[:ticks],
            "obstacle_distance": self.rec_near_obstacle[:ticks],
            "avoid_active": self.rec_avoid[:ticks],
            "obstacles": self.rec_obstacles[:ticks],
            "offsets": np.stack([r.offset.positions(t) for r in self.sc.robots], axis=1).reshape(-1, self.sc.n, 3),
        } | ({} if self.drives is None else {  # with drive models: the velocity moved at (v: the command)
            "velocity": self.rec_velocity[:ticks],
            **({} if self.heading is None else {"heading": self.rec_heading[:ticks]})})


#: Lock-step, while the world asks again for a tick (after a router outage or a planned
#: restart): how often it asks, s, when the tick's own deadline is longer.
ASK_AGAIN_S = 1.0


class TickTimer:
    """Lock-step: closes a tick whose commands do not all arrive within ``timeout`` s of
    ``clock`` (the silent robots hold their last command and the miss is counted:
    :meth:`WorldNode.timeout`), or at once when every robot still missing is gone. So a
    dead or frozen process never deadlocks the run."""

    def __init__(self, world: WorldNode, timeout: float, clock: WallClock, ask_limit: float = 30.0) -> None:
        self.world = world
        self.deadline = Deadline(timeout, clock)
        # While asking: again every ASK_AGAIN_S, however long the tick's deadline (a test's 60 s).
        self.again = Deadline(min(timeout, ASK_AGAIN_S), clock)
        self.tick = world.tick
        self.clock = clock
        self.ask_limit = ask_limit
        self.asking: Deadline | None = None  # after a router outage: asking again instead of closing
        self.asked = 0  # times the world asked again (for the summary)

    def wait_s(self) -> float:
        """Seconds until the current tick's deadline."""
        return self.deadline.wait_s()

    def check(self, gone: Collection[int] = (), unsure: bool = False) -> list[topics.Outgoing]:
        """Close the current tick if its deadline has passed or every robot it waits for is in
        ``gone`` (robot ids whose process has left); a new tick restarts the deadline.

        ``unsure``: some process has left without being judged gone yet, or went with a router
        and is expected back: the tick is held (its deadline restarts), since closing it could
        make a robot act on data the simulator would not have used. After an outage
        (:meth:`ask_again`) a passed deadline asks again, up to ``ask_limit`` s, instead of closing."""
        world = self.world
        if world.done:
            return []
        if world.tick != self.tick:
            self.tick = world.tick
            self.deadline.restart()
            self.asking = None
            return []
        if unsure:
            self.deadline.restart()
            return []
        waiting = world.waiting_for()
        if self.asking is not None and not self.asking.passed() and (
                (waiting and self.again.passed()) or self.deadline.passed()):
            # Asking again: every ASK_AGAIN_S while a robot is missing (a repeat changes nothing,
            # and what was said again can be lost too: right after a planned restart, estimates
            # between the new process and a neighbour were, in 2 of 40 loaded faults-crash runs),
            # and on a passed deadline instead of closing the tick.
            if self.deadline.passed():
                self.deadline.restart()
            self.again.restart()
            self.asked += 1
            return world.ask_again()
        if not self.deadline.passed() and not (waiting and all(r in gone for r in waiting)):
            return []
        out = world.timeout()
        self.tick = world.tick
        self.deadline.restart()
        self.asking = None
        return out

    def ask_again(self) -> list[topics.Outgoing]:
        """A router outage is over (everyone lost with it is back), or a planned restart is up:
        ask again for the current tick now, and every ``ASK_AGAIN_S`` (at most the tick's
        deadline) until it closes (or ``ask_limit`` s pass)."""
        if self.world.done:
            return []
        if self.asking is None:
            self.asking = Deadline(self.ask_limit, self.clock)
        self.deadline.restart()
        self.again.restart()
        self.asked += 1
        return self.world.ask_again()


class RestartHold:
    """Lock-step under ``fxswarm run``: a robot's planned restart (``[[faults.processes]]`` kill
    with ``restart``) lands at its tick, as in ``fxswarm sim``, not whenever its new process is up.

    In lock-step the launcher restarts a process once the world's published state is one tick
    before the restart time (:class:`fxswarm.faults.process.ProcessSchedule`), and a new process
    takes seconds of wall time to come up (8 s at load 20). So the world holds the restart's own
    tick (the first whose time is at or past it, as :class:`~fxswarm.faults.process.Mortal`
    restarts in ``fxswarm sim``) until the robot's token has come up once more than at the
    start for each restart due (``ups``: :attr:`fxswarm.runtime.liveness.Liveness.ups`), at most
    ``limit_s`` s each; then it asks again for that tick, so the new process hears it. A token
    that went and came back with a router outage counts as up too: that restart then goes
    unheld, as before.
    """

    def __init__(self, plan_processes, ups: dict[str, int], dt: float, clock: WallClock, limit_s: float) -> None:
        self.ups, self.dt, self.clock, self.limit_s = ups, dt, clock, limit_s
        due: list[tuple[float, str, int]] = []
        count: dict[str, int] = {}
        for f in sorted((f for f in plan_processes if f.action == "kill" and f.restart is not None
                         and f.target.startswith("agent:")), key=lambda f: f.restart):
            name = "agent/" + f.target.split(":", 1)[1]
            count[name] = count.get(name, 0) + 1
            due.append((f.restart, name, 1 + count[name]))  # ups needed: the first start and each restart
        self.pending = due
        self.since: Deadline | None = None  # holding for pending[0] since
        self.given_up: list[str] = []

    def check(self, tick: int) -> tuple[bool, list[str]]:
        """At the current ``tick`` (whose previous state the launcher has seen): (hold it?,
        robots whose restart has just come up: ask again for this tick)."""
        t = tick * self.dt
        back: list[str] = []
        while self.pending and self.pending[0][0] <= t + 1e-9:
            _, name, needed = self.pending[0]
            if self.ups.get(name, 0) >= needed:
                back.append(name)
            elif self.since is None:
                self.since = Deadline(self.limit_s, self.clock)
                return True, back
            elif not self.since.passed():
                return True, back
            else:
                self.given_up.append(name)
            self.pending.pop(0)
            self.since = None
        return False, back


class RealTimeWorld:
    """Real time: the world ticks every ``period`` s of ``clock`` on the latest command of each
    robot (zero-order hold), and measures the latency from each sensing to its command.

    A tick that starts more than a period late is counted (``late_ticks``) and the schedule
    slips: the simulation runs slower than asked (reported as ``achieved_speed``) instead of
    integrating missed ticks on stale commands, which a delayed fixed-time law does not
    survive. Likewise the clock holds (``held_ticks``) while a live robot has not answered
    for more than ``max_lag`` ticks (0: never): on a shared machine a robot starved of CPU is
    an artefact (in the field each robot has its own), so the world waits for it, up to
    ``hold_limit`` s at a time. While it holds, it sends each lagging robot its sensing of the
    current tick again, once a period: a robot acts only on fresh sensing, so one whose sensing
    or answer was lost on the way (messages are dropped, not queued, when a link is congested)
    would otherwise stay silent until the limit, and the swarm would crawl at a tick per
    ``hold_limit`` with its CPUs idle. A robot that has acted on that tick sends its command
    again (:meth:`~fxswarm.agents.node.AgentNode.handle`). The leader is waited for likewise:
    it stamps its states with the world's time as it last heard it, so a leader starved of CPU
    speaks of the past, and once its states are older than the robots' staleness limit the
    pinned robots drop them and the whole swarm flies on without its anchor (docs/design.md
    "Real time"). ``sent_at[k]`` is the clock time the world sent sensing for tick ``k``; the
    first command of each robot for tick ``k`` gives one latency sample.
    """

    def __init__(self, world: WorldNode, period: float, clock: WallClock, max_lag: int = 10,
                 hold_limit: float = 1.0, cut_off: Callable[[int, float], bool] | None = None) -> None:
        self.inner = world
        self.cut_off = cut_off  # (robot, t) -> whether a fault plan cuts it off from the world now
        self.clock = clock
        self.pacer = Pacer(period, clock)
        self.max_lag, self.hold_limit = max_lag, hold_limit
        self.holding: Deadline | None = None  # running while the clock is held for a lagging robot
        self.started: float | None = None
        self.sent_at: dict[int, float] = {}
        self.answered: set[tuple[int, int]] = set()
        self.latencies: list[float] = []  # s
        self.last_tick: dict[int, int] = {}  # robot -> the latest tick it has answered
        self.sent: list[topics.Outgoing] = []  # the current tick's messages (sensing asked again while holding)
        self.asked_again = 0  # sensing messages sent again while holding
        # robot -> when its latest new command arrived, and the longest wall time between two (s):
        # how stale the world saw its command get (a robot cut off or starved).
        self.heard_at: dict[int, float] = {}
        self.longest_silence: dict[int, float] = {}
        self.leader_t: float | None = None  # the newest time stamp of the leader's states heard, s
        self.leader_clock = topics.leader_clock_topic(world.sc.robots[0].id)  # asked again when it lags
        self.held_for: dict[int, int] = {}  # robot (LEADER: the leader) -> held periods it lagged in

    def subscriptions(self) -> list[str]:
        return self.inner.subscriptions()

    def handle(self, topic: str, msg: Message) -> list:
        if isinstance(msg, Command):
            self.inner.take_command(msg)
            now = None
            if msg.tick > self.last_tick.get(msg.robot, -1):
                self.last_tick[msg.robot] = msg.tick
                now = self.clock()
                silence = now - self.heard_at.get(msg.robot, now)
                if silence > self.longest_silence.get(msg.robot, 0.0):
                    self.longest_silence[msg.robot] = silence
                self.heard_at[msg.robot] = now
            sent = self.sent_at.get(msg.tick)
            if sent is not None and (msg.robot, msg.tick) not in self.answered:
                self.answered.add((msg.robot, msg.tick))
                self.latencies.append((now or self.clock()) - sent)
        return []

    def heard_leader(self, topic: str, msg: Message) -> None:
        """The leader's state: how far its time has got. Subscribed past the fault filters (the
        world process does it): waiting is about the machine, not the plan, and a leader whose
        states the plan withholds from the robots still speaks on time."""
        if self.leader_t is None or msg.t > self.leader_t:
            self.leader_t = msg.t

    def start(self) -> list[topics.Outgoing]:
        """Emit tick 0 now; tick 1 is due one period later."""
        self.started = self.clock()
        self.pacer.next_due = self.started + self.pacer.period
        out = self.inner.start()
        self._sent(self.inner.tick, out)
        return out

    def lagging(self, alive: Collection[int], leader_alive: bool = False) -> list[int]:
        """The robots in ``alive`` (ids of live processes) more than ``max_lag`` ticks behind, and
        ``LEADER`` if its process is alive and its latest state is as far behind (once heard at
        all: a leader the world cannot hear, say under an older access policy, is not waited
        for), but for those a fault plan cuts off from the world now: their silence is the
        experiment, not an artefact of the machine, so it is not waited for (as lock-step does
        not wait)."""
        if self.max_lag <= 0:
            return []
        oldest = self.inner.tick - self.max_lag
        behind = [r for r in alive if self.last_tick.get(r, -1) < oldest]
        if leader_alive and self.leader_t is not None and round(self.leader_t / self.inner.sc.dt) < oldest:
            behind.append(LEADER)
        if behind and self.cut_off is not None:
            t = self.inner.t
            behind = [r for r in behind if not self.cut_off(r, t)]
        return behind

    def tick(self, alive: Collection[int] = (), leader_alive: bool = False) -> list[topics.Outgoing]:
        """The pacer's tick is due: hold the clock for the lagging live robots and leader (up to
        ``hold_limit`` s at a time) and send them their sensing again (the leader: the sensing it
        keeps time by), else integrate one ``dt`` on the held commands and emit the next tick."""
        world = self.inner
        lagging = self.lagging(alive, leader_alive)
        if lagging:
            if self.holding is None:
                self.holding = Deadline(self.hold_limit, self.clock)
            if not self.holding.passed():
                self.pacer.hold()
                for r in lagging:
                    self.held_for[r] = self.held_for.get(r, 0) + 1
                keys = {self.leader_clock if r == LEADER else topics.sense_topic(r) for r in lagging}
                again = [m for m in self.sent if m[0] in keys]
                self.asked_again += len(again)
                return again
        self.holding = None
        self.pacer.on_time()
        out = world.advance(world.sc.dt)
        self._sent(world.tick, out)
        return out

    def report(self) -> dict:
        """``late_ticks``, ``held_ticks`` (and ``held_for``: of those, the periods each robot id, or
        ``leader``, lagged in), ``sensing_sent_again`` (while holding), ``achieved_speed``
        (simulation s per clock s), ``sense_to_command`` (:func:`latency_stats`) and
        ``longest_silence_s`` (per robot id, the longest wall time between two of its new commands)."""
        elapsed = self.clock() - self.started if self.started is not None else 0.0
        world = self.inner
        held_for = {"leader" if r == LEADER else str(r): k for r, k in sorted(self.held_for.items())}
        return {"late_ticks": self.pacer.late, "held_ticks": self.pacer.held, "held_for": held_for,
                "sensing_sent_again": self.asked_again,
                "achieved_speed": world.tick * world.sc.dt / elapsed if elapsed > 0 else None,
                "sense_to_command": latency_stats(self.latencies),
                "longest_silence_s": {str(r): round(s, 4) for r, s in sorted(self.longest_silence.items())}}

    def _sent(self, tick: int, out: list[topics.Outgoing]) -> None:
        self.sent_at[tick] = self.clock()
        self.sent = out
        old = tick - 1000  # keep the maps bounded: a command later than 1000 ticks is no answer
        self.sent_at.pop(old, None)
        if len(self.answered) > 20_000:
            self.answered = {(r, k) for r, k in self.answered if k > old}


def latency_stats(samples: list[float]) -> dict:
    """p50/p99/max of latencies given in s, reported in ms."""
    if not samples:
        return {"n": 0}
    a = np.asarray(samples) * 1e3
    return {"n": int(a.size), "p50_ms": float(np.percentile(a, 50)), "p99_ms": float(np.percentile(a, 99)),
            "max_ms": float(a.max()), "mean_ms": float(a.mean())}
