"""The logger's core: bus messages in, Rerun frames out, on the simulation-time timeline.

:class:`SwarmRecorder` is sans-I/O in the sense that matters here: it never
touches a transport, a thread or a sleep; it is handed messages (from the
in-memory bus, from the Zenoh inbox, or rebuilt from ``trajectory.npz``) and
writes to the ``rerun.RecordingStream`` it was given.

Frames are rate-limited in simulation time (``rate_hz`` frames per simulated
second) and sent as column batches (:mod:`.columns`). Everything a frame
shows about the robots comes from one ``WorldState`` (the world's truth at
that tick); the leader and the desired slots come from the scenario's
analytic paths at the state's time, as in ``core.metrics``, so the logged
errors equal those computed from ``trajectory.npz``.

Link health. The logger hears what the robots and the leader *publish*
(``agent/*/estimate``, ``leader/state``). An edge i-j (or leader-i) is
*stale* at a frame when either end's latest estimate is more than
``stale_ticks`` ticks older than the world's tick, and a sender *drops* when
its sequence numbers skip. Per-receiver inbox faults happen after
publication, so the logger cannot see those: it sees the link as the
network delivered it to the logger.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import rerun as rr

from fxswarm.core import bus as topics
from fxswarm.core.messages import Clock, Estimate, LeaderState, Message, WorldState
from fxswarm.core.metrics import estimate_errors, formation_errors
from fxswarm.core.scenario import Scenario
from fxswarm.logger import style
from fxswarm.logger.columns import EntityColumns


@dataclass(frozen=True)
class RecorderOptions:
    """What and how often to log (the ``[logging]`` table of a scenario may set these)."""

    rate_hz: float = 25.0  # frames per second of *simulation* time
    velocities: bool = False  # velocity arrows on the robots
    trail_s: float = 30.0  # trail length, s of simulation time
    trail_dt: float = 0.2  # trail sampling period, s of simulation time
    stale_ticks: int = 2  # an estimate older than this many ticks makes its links stale
    recent_drop_s: float = 1.0  # a drop within this many simulated seconds turns a link red
    link_health: bool = True  # False when no messages are heard (a replay from trajectory.npz)
    flush_frames: int = 25  # send the column batch after this many frames ...
    flush_wall_s: float = 0.5  # ... or after this much wall time, whichever comes first

    @classmethod
    def from_scenario(cls, sc: Scenario, **overrides) -> "RecorderOptions":
        """Defaults, then the scenario's ``[logging]`` table, then ``overrides`` (not None)."""
        known = set(cls.__dataclass_fields__)
        table = sc.raw.get("logging", {}) if isinstance(sc.raw, dict) else {}
        values = {k: v for k, v in table.items() if k in known}
        values.update({k: v for k, v in overrides.items() if v is not None})
        opts = cls(**values)
        if not (opts.rate_hz > 0 and math.isfinite(opts.rate_hz)):
            raise ValueError(f"{sc.source}: [logging] rate_hz: expected a positive number, got {opts.rate_hz!r}")
        return opts


class LinkHealth:
    """Staleness and sequence gaps of what the robots and the leader publish.

    Senders: robot ids 1..n, and 0 for the leader. Edges: the graph's
    (i, j) with i < j, then (0, i) for each pinned robot i.
    """

    def __init__(self, sc: Scenario) -> None:
        ids = [r.id for r in sc.robots]
        self.edges = [(i, j) for i in ids for j in ids if i < j and sc.a[i - 1, j - 1] > 0]
        self.edges += [(0, i) for i in ids if sc.is_pinned(i)]
        self.names = [f"{'L' if i == 0 else i}-{j}" for i, j in self.edges]
        self.last_tick = np.full(sc.n + 1, -1, dtype=np.int64)  # index = sender id
        self.last_seq = np.zeros(sc.n + 1, dtype=np.int64)
        self.drops = np.zeros(sc.n + 1, dtype=np.int64)
        self.last_drop_t = np.full(sc.n + 1, -np.inf)
        self.stale_frames = np.zeros(len(self.edges), dtype=np.int64)
        self._a = np.array([i for i, _ in self.edges], dtype=int)
        self._b = np.array([j for _, j in self.edges], dtype=int)

    def heard(self, sender: int, seq: int, tick: int, t: float) -> None:
        if not 0 <= sender < len(self.last_tick):
            return
        if self.last_seq[sender] and seq > self.last_seq[sender] + 1:
            self.drops[sender] += seq - self.last_seq[sender] - 1
            self.last_drop_t[sender] = t
        self.last_seq[sender] = max(self.last_seq[sender], seq)
        self.last_tick[sender] = max(self.last_tick[sender], tick)

    def at(self, tick: int, t: float, stale_ticks: int, recent_drop_s: float):
        """Per edge at world tick ``tick``: ``(bad (bool), drops, stale_frames)``, each shape (edges,).

        Counts a stale frame for each edge stale now (call once per logged frame).
        """
        old = (tick - self.last_tick) > stale_ticks
        recent = (t - self.last_drop_t) <= recent_drop_s
        stale = old[self._a] | old[self._b]
        self.stale_frames += stale
        bad = stale | recent[self._a] | recent[self._b]
        return bad, self.drops[self._a] + self.drops[self._b], self.stale_frames.copy()


@dataclass
class _Pace:
    """The last logged frame's clock readings, for the real-time factor and tick rate."""

    t: float
    tick: int
    wall: float


class SwarmRecorder:
    """The swarm of ``scenario`` written to ``rec``: call :meth:`start`, then :meth:`take`, then :meth:`close`."""

    def __init__(self, scenario: Scenario, rec: rr.RecordingStream, options: RecorderOptions | None = None,
                 wall_clock: Callable[[], float] = time.perf_counter) -> None:
        self.sc = scenario
        self.rec = rec
        self.opt = options or RecorderOptions.from_scenario(scenario)
        self.wall_clock = wall_clock
        self.links = LinkHealth(scenario)
        self.frames = 0  # frames logged
        self.skipped = 0  # world states not logged because of the rate limit
        self.dropped = 0  # frames lost before reaching the recorder (set by the inbox owner)
        self._next_due = -math.inf
        self._pace: _Pace | None = None
        self._last_flush = wall_clock()
        self._buffered = 0
        n = scenario.n
        self._trail: deque = deque(maxlen=max(2, int(round(self.opt.trail_s / self.opt.trail_dt)) + 1))
        self._next_trail = -math.inf
        self._moving_obstacles = any(o.max_speed_inf(scenario.duration) > 0 for o in scenario.obstacles)
        self._edge_idx = np.array([(i - 1, j - 1) for i, j in self.links.edges if i > 0], dtype=int).reshape(-1, 2)
        self._leader_edge_idx = np.array([j - 1 for i, j in self.links.edges if i == 0], dtype=int)
        self._cols = {
            path: EntityColumns(path, arch) for path, arch in [
                (style.ROBOTS, rr.Points3D), (style.ESTIMATES, rr.Points3D), (style.SLOTS, rr.Points3D),
                (style.LEADER, rr.Points3D), (style.TRAILS, rr.LineStrips3D), (style.EDGES, rr.LineStrips3D),
                (style.OBSTACLES, rr.Ellipsoids3D), (style.VELOCITIES, rr.Arrows3D),
                (style.FORMATION_ERROR, rr.Scalars), (style.NEAREST_DISTANCE, rr.Scalars),
                (style.ESTIMATE_ERROR, rr.Scalars), (style.AVOID_ACTIVE, rr.Scalars),
                (style.LINK_DROPS, rr.Scalars), (style.LINK_STALE, rr.Scalars),
                (style.REAL_TIME_FACTOR, rr.Scalars), (style.TICK_RATE, rr.Scalars),
                (style.LOGGER_DROPPED, rr.Scalars),
            ]
        }
        self._n = n

    # --- static part ----------------------------------------------------------------------

    def start(self) -> None:
        """Log what never changes: names, colours, sizes, series styles, static obstacles."""
        sc, rec, n = self.sc, self.rec, self._n
        colours = style.robot_colours(n)
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        labels = [str(r.id) for r in sc.robots]
        robot_names = [f"robot {r.id}" for r in sc.robots]
        rec.log(style.ROBOTS, rr.Points3D.from_fields(colors=colours, labels=labels, radii=0.3, show_labels=True),
                static=True)
        rec.log(style.ESTIMATES, rr.Points3D.from_fields(colors=style.robot_colours(n, 0xA0), radii=0.12,
                                                         labels=[f"ph{r.id}" for r in sc.robots], show_labels=False),
                static=True)
        rec.log(style.SLOTS, rr.Points3D.from_fields(colors=style.robot_colours(n, 0x60), radii=0.18), static=True)
        rec.log(style.LEADER, rr.Points3D.from_fields(colors=[style.LEADER_COLOUR], radii=0.25, labels=["leader"],
                                                      show_labels=True), static=True)
        rec.log(style.TRAILS, rr.LineStrips3D.from_fields(colors=colours, radii=0.04), static=True)
        rec.log(style.EDGES, rr.LineStrips3D.from_fields(radii=0.02), static=True)
        rec.log(style.VELOCITIES, rr.Arrows3D.from_fields(colors=colours, radii=0.05), static=True)
        m = len(sc.obstacles)
        if m:
            obstacle_style = rr.Ellipsoids3D.from_fields(
                half_sizes=np.full((m, 3), sc.d), colors=np.full(m, style.OBSTACLE_COLOUR, dtype=np.uint32),
                fill_mode="solid", labels=[f"obstacle {k + 1}" for k in range(m)], show_labels=False)
            rec.log(style.OBSTACLES, obstacle_style, static=True)
            if not self._moving_obstacles:
                centres = np.array([o.position(0.0) for o in sc.obstacles])
                rec.log(style.OBSTACLES, rr.Ellipsoids3D.from_fields(centers=centres), static=True)
        rgb = [style.robot_rgb(i) << 8 | 0xFF for i in range(n)]
        series = {
            style.FORMATION_ERROR: (robot_names, rgb),
            style.ESTIMATE_ERROR: (robot_names, rgb),
            style.AVOID_ACTIVE: (robot_names, rgb),
            style.NEAREST_DISTANCE: (robot_names + [f"d = {sc.d:g} m"], rgb + [style.D_LINE_COLOUR]),
            style.LINK_DROPS: (self.links.names, None),
            style.LINK_STALE: (self.links.names, None),
            style.REAL_TIME_FACTOR: (["real-time factor"], None),
            style.TICK_RATE: (["ticks/s"], None),
            style.LOGGER_DROPPED: (["logger dropped frames"], None),
        }
        for path, (names, colors) in series.items():
            lines = rr.SeriesLines(names=names, colors=np.array(colors, dtype=np.uint32)) if colors else \
                rr.SeriesLines(names=names)
            rec.log(path, lines, static=True)

    # --- messages -------------------------------------------------------------------------

    def take(self, topic: str, msg: Message, wall: float | None = None) -> bool:
        """Take one bus message (``wall``: when it arrived, s); True if it produced a frame."""
        if isinstance(msg, WorldState):
            if msg.t + 1e-9 < self._next_due:
                self.skipped += 1
                return False
            self.frame(msg, wall)
            return True
        if isinstance(msg, Estimate):
            self.links.heard(msg.robot, msg.seq, msg.tick, msg.t)
        elif isinstance(msg, LeaderState):
            self.links.heard(0, msg.seq, msg.tick, msg.t)
        elif isinstance(msg, Clock):
            pass  # the pace is measured on the frames themselves
        return False

    def due(self, t: float) -> bool:
        """Whether a world state at simulation time ``t`` would be logged (cheap; for inboxes)."""
        return t + 1e-9 >= self._next_due

    def frame(self, s: WorldState, wall: float | None = None) -> None:
        """Log one frame from the world's state ``s`` (no rate limit here)."""
        sc, o, c = self.sc, self.opt, self._cols
        t, k = s.t, s.tick
        self._next_due = (math.floor(t * o.rate_hz + 1e-6) + 1) / o.rate_hz
        p0 = sc.leader.position(t)
        offsets = np.array([r.offset.position(t) for r in sc.robots])
        one = {"p": s.p[None], "ph": s.ph[None], "p0": p0[None], "offsets": offsets[None]}
        slots = p0 + offsets

        c[style.ROBOTS].add(t, k, positions=s.p)
        c[style.ESTIMATES].add(t, k, positions=s.ph)
        c[style.SLOTS].add(t, k, positions=slots)
        c[style.LEADER].add(t, k, positions=p0[None])
        if self._moving_obstacles and len(s.obstacles):
            c[style.OBSTACLES].add(t, k, centers=s.obstacles)
        if o.velocities:
            c[style.VELOCITIES].add(t, k, vectors=s.v, origins=s.p)
        if t + 1e-9 >= self._next_trail:
            self._trail.append(s.p.copy())
            self._next_trail = t + o.trail_dt
            hist = np.stack(self._trail, axis=1)  # (n, samples, 3)
            c[style.TRAILS].add(t, k, strips=[hist[i] for i in range(self._n)])

        if o.link_health:
            bad, drops, stale = self.links.at(k, t, o.stale_ticks, o.recent_drop_s)
        else:
            bad = np.zeros(len(self.links.edges), dtype=bool)
        strips = [s.p[[i, j]] for i, j in self._edge_idx] + [np.stack([p0, s.p[j]]) for j in self._leader_edge_idx]
        colours = np.where(bad, style.LINK_BAD, style.LINK_OK).astype(np.uint32)
        c[style.EDGES].add(t, k, strips=strips, colors=colours)

        nearest = np.where(s.nearest >= 0, s.nearest, np.nan)  # -1 on the wire: no object at all
        c[style.FORMATION_ERROR].add(t, k, scalars=formation_errors(one)[0])
        c[style.ESTIMATE_ERROR].add(t, k, scalars=estimate_errors(one)[0])
        c[style.NEAREST_DISTANCE].add(t, k, scalars=np.append(nearest, sc.d))
        c[style.AVOID_ACTIVE].add(t, k, scalars=s.avoid.astype(float))
        if o.link_health and len(self.links.edges):
            c[style.LINK_DROPS].add(t, k, scalars=drops.astype(float))
            c[style.LINK_STALE].add(t, k, scalars=stale.astype(float))
        if wall is not None:
            if self._pace is not None and wall > self._pace.wall:
                elapsed = wall - self._pace.wall
                c[style.REAL_TIME_FACTOR].add(t, k, scalars=np.array([(t - self._pace.t) / elapsed]))
                c[style.TICK_RATE].add(t, k, scalars=np.array([(k - self._pace.tick) / elapsed]))
            self._pace = _Pace(t, k, wall)
            c[style.LOGGER_DROPPED].add(t, k, scalars=np.array([float(self.dropped)]))

        self.frames += 1
        self._buffered += 1
        if self._buffered >= o.flush_frames or self.wall_clock() - self._last_flush >= o.flush_wall_s:
            self.flush()

    def flush_if_due(self) -> None:
        """Idle time: send what is buffered once it has waited ``flush_wall_s`` (a live viewer stays current)."""
        if self._buffered and self.wall_clock() - self._last_flush >= self.opt.flush_wall_s:
            self.flush()

    def flush(self) -> None:
        """Send every buffered column batch to the recording."""
        for cols in self._cols.values():
            cols.send(self.rec)
        self._buffered = 0
        self._last_flush = self.wall_clock()

    def close(self, timeout_s: float = 30.0) -> None:
        """Send what is buffered, wait for the sinks, disconnect."""
        self.flush()
        self.rec.flush(timeout_sec=timeout_s)
        self.rec.disconnect()

    def counters(self) -> dict[str, int]:
        return {"frames": self.frames, "skipped_by_rate": self.skipped, "dropped": self.dropped,
                "link_drops_seen": int(self.links.drops.sum())}


#: What the logger subscribes to, relative to the swarm prefix.
RECORDER_TOPICS = (topics.WORLD_STATE, topics.LEADER_STATE, topics.estimate_topic("*"))  # type: ignore[arg-type]


def attach(bus, recorder: SwarmRecorder) -> None:
    """Subscribe ``recorder`` on an in-process bus (synchronous: for ``Simulation`` and tests)."""
    clock = recorder.wall_clock

    def deliver(topic: str, msg: Message) -> None:
        recorder.take(topic, msg, clock())

    for pattern in RECORDER_TOPICS:
        bus.subscribe(pattern, deliver)
