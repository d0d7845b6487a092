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

Link health is measured where it matters, at the receiver: each robot
reports in its ``Command``, per link into it, how old the estimate it holds
is and how many of that sender's messages it missed (sequence gaps after its
inbox, fault filters included); the world publishes these per directed link
in ``WorldState.link_age`` / ``link_drops``. So the recorder needs nothing
but the world's state: an edge i-j (or leader-i) is *stale* at a frame when
either direction's estimate is more than ``stale_ticks`` ticks old, and
*red* when stale or when either direction's drop count rose within
``recent_drop_s`` simulated seconds. Its drop series is the sum of both
directions' counts.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable

import numpy as np
import rerun as rr

from fxswarm.core import bus as topics
from fxswarm.core.messages import Message, WorldState
from fxswarm.core.metrics import estimate_errors, formation_errors
from fxswarm.core.motion import offset_groups
from fxswarm.core.scenario import Scenario
from fxswarm.logger import style
from fxswarm.logger.columns import send_rows, strips_array
from fxswarm.core.scenario import directed_links


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
    flush_frames: int = 100  # send the column batches after this many frames ...
    flush_wall_s: float = 0.5  # ... or after this much wall time, whichever comes first

    @classmethod
    def from_scenario(cls, sc: Scenario, **overrides) -> "RecorderOptions":
        """Defaults, then the scenario's ``[logging]`` table (checked when the scenario was read),
        then ``overrides`` (not None)."""
        return cls(**{**sc.logging, **{k: v for k, v in overrides.items() if v is not None}})


class LinkHealth:
    """Staleness and drops per graph edge, from the robots' own reports in ``WorldState``.

    Edges: the graph's (i, j) with i < j, then (0, i) for each pinned robot i
    (the leader's link). Each edge is made of its directed links (j -> i and
    i -> j; the leader's only 0 -> i) in ``WorldState.link_*``
    (:func:`fxswarm.world.node.directed_links` order).
    """

    def __init__(self, sc: Scenario) -> None:
        ids = [r.id for r in sc.robots]
        rows, cols = sc.graph.entry_rows(), sc.graph.indices
        upper = cols > rows  # row by row, ascending: as a double loop over i < j
        self.edges = list(zip((rows[upper] + 1).tolist(), (cols[upper] + 1).tolist()))
        self.edges += [(0, i) for i in ids if sc.is_pinned(i)]
        self.names = [f"{'L' if i == 0 else i}-{j}" for i, j in self.edges]
        self.directed = directed_links(sc)
        pos = {link: k for k, link in enumerate(self.directed)}
        self._into_j = np.array([pos[(i, j)] for i, j in self.edges], dtype=int)  # i -> j (or leader -> j)
        self._into_i = np.array([pos[(j, i)] if i else pos[(0, j)] for i, j in self.edges], dtype=int)
        self._both = np.array([i > 0 for i, _ in self.edges], dtype=bool)  # a leader edge has one direction
        self.last_drops = np.zeros(len(self.directed), dtype=np.int64)  # per directed link, as last reported
        self.last_drop_t = np.full(len(self.directed), -math.inf)  # when a link's count last rose, s
        self.stale_frames = np.zeros(len(self.edges), dtype=np.int64)
        self.unreported = 0  # frames whose state carried no (or a wrongly sized) link report

    @property
    def drops(self) -> np.ndarray:
        """(edges,) messages missed on each edge, both directions, as last reported."""
        d = self.last_drops
        return d[self._into_j] + np.where(self._both, d[self._into_i], 0)

    def at(self, state: WorldState, stale_ticks: int, recent_drop_s: float):
        """Per edge at ``state``: ``(bad (bool), drops, stale_frames)``, each shape (edges,).

        Counts a stale frame for each edge stale now (call once per logged frame).
        """
        t = state.t
        age, drops = state.link_age, state.link_drops
        if len(age) != len(self.directed) or len(drops) != len(self.directed):
            self.unreported += 1
            age, drops = np.zeros(len(self.directed), dtype=np.int64), self.last_drops
        rose = drops > self.last_drops
        if rose.any():
            self.last_drop_t[rose] = t
        self.last_drops = np.asarray(drops, dtype=np.int64)
        old = age > stale_ticks
        stale = old[self._into_j] | old[self._into_i]
        recent = (t - self.last_drop_t) <= recent_drop_s
        self.stale_frames += stale
        bad = stale | recent[self._into_j] | recent[self._into_i]
        return bad, self.drops, self.stale_frames.copy()


class _OffsetTable:
    """Every robot's desired offset at many times, (F, n, 3), without a Python call per robot.

    The values are :meth:`fxswarm.core.motion.Offset.position`'s bit for bit (``base + a *
    math.sin(omega t + phase)`` per moving axis): robots sharing one sinusoid (usually all) are
    one group, and ``math.sin`` runs once per group, axis and frame, not per robot."""

    def __init__(self, sc: Scenario) -> None:
        self.base, self.groups = offset_groups(sc.robots)

    def at(self, t: np.ndarray) -> np.ndarray:
        out = np.broadcast_to(self.base, (len(t), *self.base.shape)).copy()
        for (amp, omega, phase), ids in self.groups:
            for k in range(3):
                if amp[k]:
                    wave = np.array([amp[k] * math.sin(omega[k] * x + phase[k]) for x in t.tolist()])
                    out[:, ids, k] = out[:, ids, k] + wave[:, None]
        return out


@dataclass
class _Frame:
    """One frame as buffered until the next flush: the state plus what had to be known at its time."""

    state: WorldState
    bad: np.ndarray  # (edges,) bool: link shown red
    drops: np.ndarray | None  # (edges,) drops seen so far (None without link health)
    stale: np.ndarray | None  # (edges,) stale frames so far
    trail: tuple[np.ndarray, ...] | None  # the trail's samples, each (n, 3), on frames where it moves on
    pace: tuple[float, float] | None  # (real-time factor, ticks per wall second)
    dropped: int


class SwarmRecorder:
    """The swarm of ``scenario`` written to ``rec``: call :meth:`start`, then :meth:`take`, then :meth:`close`.

    :meth:`frame` only buffers (a few tens of microseconds); :meth:`flush`
    turns the buffered frames into one column batch per entity, with the
    errors computed for all frames at once by ``core.metrics``.
    """

    def __init__(self, scenario: Scenario, rec: rr.RecordingStream, options: RecorderOptions | None = None,
                 wall_clock: Callable[[], float] = time.perf_counter) -> None:
        self.sc = scenario
        self.rec = rec
        self.opt = options or RecorderOptions.from_scenario(scenario)
        self.wall_clock = wall_clock
        self.links = LinkHealth(scenario)
        self.frames = 0  # frames logged
        self.skipped = 0  # world states not logged because of the rate limit
        self.dropped = 0  # messages lost before reaching the recorder (set by the inbox owner)
        self.sink_error: str | None = None  # a sink that failed at close (e.g. a viewer gone)
        self._n = scenario.n
        self._next_due = -math.inf
        self._last_pace: tuple[float, int, float] | None = None  # (t, tick, wall) of the last timed frame
        self._last_flush = wall_clock()
        self._pending: list[_Frame] = []
        self._trail: deque = deque(maxlen=max(2, int(round(self.opt.trail_s / self.opt.trail_dt)) + 1))
        self._next_trail = -math.inf
        self._moving_obstacles = any(o.max_speed_inf(scenario.duration) > 0 for o in scenario.obstacles)
        robot_edges = [(i - 1, j - 1) for i, j in self.links.edges if i > 0]
        self._edge_a = np.array([a for a, _ in robot_edges], dtype=int)
        self._edge_b = np.array([b for _, b in robot_edges], dtype=int)
        self._leader_edge = np.array([j - 1 for i, j in self.links.edges if i == 0], dtype=int)
        self._offsets = _OffsetTable(scenario)

    # --- static part ----------------------------------------------------------------------

    def start(self) -> None:
        """Log what never changes: names, colours, sizes, series styles, static obstacles."""
        sc, rec, n = self.sc, self.rec, self._n
        colours = style.robot_colours(n)
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log(style.LAW, rr.TextDocument(f"law: {sc.law}"), static=True)  # which controller flew
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
        if sc.world is not None and "unicycle" in sc.world.models:
            rec.log(style.HEADINGS, rr.Arrows3D.from_fields(colors=colours, radii=0.08), static=True)
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
        """Take one bus message (``wall``: when it arrived, s); True if it produced a frame.

        Only ``WorldState`` matters (link health rides in it); anything else is ignored."""
        if type(msg) is not WorldState:
            return False
        if msg.t + 1e-9 < self._next_due:
            self.skipped += 1
            return False
        self.frame(msg, wall)
        return True

    def due(self, t: float) -> bool:
        """Whether a world state at simulation time ``t`` would be logged (cheap; for inboxes)."""
        return t + 1e-9 >= self._next_due

    def frame(self, s: WorldState, wall: float | None = None) -> None:
        """Buffer one frame of the world's state ``s`` (no rate limit here); flush when due."""
        o = self.opt
        t, k = s.t, s.tick
        self._next_due = (math.floor(t * o.rate_hz + 1e-6) + 1) / o.rate_hz
        if o.link_health:
            bad, drops, stale = self.links.at(s, o.stale_ticks, o.recent_drop_s)
        else:
            bad, drops, stale = np.zeros(len(self.links.edges), dtype=bool), None, None
        trail = None
        if t + 1e-9 >= self._next_trail:
            self._trail.append(s.p)
            self._next_trail = t + o.trail_dt
            trail = tuple(self._trail)  # references only: the points are copied once, at the flush
        pace = None
        if wall is not None:
            last = self._last_pace
            if last is not None and wall > last[2]:
                pace = ((t - last[0]) / (wall - last[2]), (k - last[1]) / (wall - last[2]))
            self._last_pace = (t, k, wall)
        self._pending.append(_Frame(s, bad, drops, stale, trail, pace, self.dropped))
        self.frames += 1
        if len(self._pending) >= o.flush_frames or self.wall_clock() - self._last_flush >= o.flush_wall_s:
            self.flush()

    def flush_if_due(self) -> None:
        """Idle time: send what is buffered once it has waited ``flush_wall_s`` (a live viewer stays current)."""
        if self._pending and self.wall_clock() - self._last_flush >= self.opt.flush_wall_s:
            self.flush()

    def flush(self) -> None:
        """Send every buffered frame, one column batch per entity."""
        frames, self._pending = self._pending, []
        self._last_flush = self.wall_clock()
        if not frames:
            return
        sc, rec, n = self.sc, self.rec, self._n
        states = [f.state for f in frames]
        t = np.array([s.t for s in states])
        k = np.array([s.tick for s in states])
        p = np.stack([s.p for s in states])  # (F, n, 3)
        ph = np.stack([s.ph for s in states])
        p0 = np.array([sc.leader.position(x) for x in t])  # (F, 3)
        offsets = self._offsets.at(t)  # (F, n, 3)
        traj = {"p": p, "ph": ph, "p0": p0, "offsets": offsets}
        flat = p.reshape(-1, 3)

        send_rows(rec, style.ROBOTS, rr.Points3D, t, k, n, positions=flat)
        send_rows(rec, style.ESTIMATES, rr.Points3D, t, k, n, positions=ph.reshape(-1, 3))
        send_rows(rec, style.SLOTS, rr.Points3D, t, k, n, positions=(p0[:, None, :] + offsets).reshape(-1, 3))
        send_rows(rec, style.LEADER, rr.Points3D, t, k, 1, positions=p0)
        if self._moving_obstacles:
            obstacles = np.stack([s.obstacles for s in states])
            send_rows(rec, style.OBSTACLES, rr.Ellipsoids3D, t, k, obstacles.shape[1],
                      centers=obstacles.reshape(-1, 3))
        if self.opt.velocities:
            v = np.stack([s.v for s in states]).reshape(-1, 3)
            send_rows(rec, style.VELOCITIES, rr.Arrows3D, t, k, n, vectors=v, origins=flat)
        if all(s.heading is not None for s in states):  # unicycles: each robot's orientation
            yaw = np.stack([s.heading for s in states]).reshape(-1)
            arrows = style.HEADING_LENGTH * np.column_stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)])
            send_rows(rec, style.HEADINGS, rr.Arrows3D, t, k, n, vectors=arrows, origins=flat)
        self._send_trails(frames, t, k)
        self._send_edges(frames, p, p0, t, k)

        nearest = np.stack([s.nearest for s in states])
        nearest = np.where(nearest >= 0, nearest, np.nan)  # -1 on the wire: no object at all
        with_d = np.concatenate([nearest, np.full((len(t), 1), sc.d)], axis=1)
        send_rows(rec, style.FORMATION_ERROR, rr.Scalars, t, k, n, scalars=formation_errors(traj).reshape(-1))
        send_rows(rec, style.ESTIMATE_ERROR, rr.Scalars, t, k, n, scalars=estimate_errors(traj).reshape(-1))
        send_rows(rec, style.NEAREST_DISTANCE, rr.Scalars, t, k, n + 1, scalars=with_d.reshape(-1))
        avoid = np.stack([s.avoid for s in states]).astype(float)
        send_rows(rec, style.AVOID_ACTIVE, rr.Scalars, t, k, n, scalars=avoid.reshape(-1))
        edges = len(self.links.edges)
        if self.opt.link_health and edges:
            send_rows(rec, style.LINK_DROPS, rr.Scalars, t, k, edges,
                      scalars=np.concatenate([f.drops for f in frames]).astype(float))
            send_rows(rec, style.LINK_STALE, rr.Scalars, t, k, edges,
                      scalars=np.concatenate([f.stale for f in frames]).astype(float))
        timed = [i for i, f in enumerate(frames) if f.pace is not None]
        if timed:
            pace = np.array([frames[i].pace for i in timed])
            send_rows(rec, style.REAL_TIME_FACTOR, rr.Scalars, t[timed], k[timed], 1, scalars=pace[:, 0])
            send_rows(rec, style.TICK_RATE, rr.Scalars, t[timed], k[timed], 1, scalars=pace[:, 1])
            send_rows(rec, style.LOGGER_DROPPED, rr.Scalars, t[timed], k[timed], 1,
                      scalars=np.array([float(frames[i].dropped) for i in timed]))

    def _send_trails(self, frames: list[_Frame], t: np.ndarray, k: np.ndarray) -> None:
        rows = [i for i, f in enumerate(frames) if f.trail is not None]
        if not rows:
            return
        n, samples = self._n, [len(frames[i].trail) for i in rows]
        # Written once, straight into the float32 buffer Arrow takes: row r is (n, samples, 3),
        # robot by robot, at 1 000 robots and 151 samples 1.8 MB a trail frame.
        points = np.empty((n * sum(samples), 3), dtype=np.float32)
        start = 0
        for i, m in zip(rows, samples):
            np.stack(frames[i].trail, axis=1, out=points[start:start + n * m].reshape(n, m, 3), casting="same_kind")
            start += n * m
        lengths = np.repeat(samples, n)
        send_rows(self.rec, style.TRAILS, rr.LineStrips3D, t[rows], k[rows], self._n,
                  strips=strips_array(points, lengths))

    def _send_edges(self, frames: list[_Frame], p: np.ndarray, p0: np.ndarray, t: np.ndarray, k: np.ndarray) -> None:
        edges = len(self.links.edges)
        if not edges:
            return
        r = len(self._edge_a)
        segments = np.empty((len(t), edges, 2, 3), dtype=np.float32)  # in LinkHealth.edges order
        segments[:, :r, 0] = p[:, self._edge_a]
        segments[:, :r, 1] = p[:, self._edge_b]
        segments[:, r:, 0] = p0[:, None, :]  # the leader's edges: leader to pinned robot
        segments[:, r:, 1] = p[:, self._leader_edge]
        colours = np.where(np.concatenate([f.bad for f in frames]), style.LINK_BAD, style.LINK_OK).astype(np.uint32)
        send_rows(self.rec, style.EDGES, rr.LineStrips3D, t, k, edges,
                  strips=strips_array(segments.reshape(-1, 3), np.full(len(t) * edges, 2)), colors=colours)

    def close(self, timeout_s: float = 30.0) -> None:
        """Send what is buffered, wait for the sinks, disconnect.

        A viewer that went away (a closed window) makes Rerun's flush raise; the
        other sinks (the ``.rrd`` file) still get everything, so that is noted
        in :attr:`sink_error`, not raised."""
        self.flush()
        try:
            self.rec.flush(timeout_sec=timeout_s)
        except RuntimeError as exc:
            self.sink_error = str(exc)
        self.rec.disconnect()

    def counters(self) -> dict[str, int]:
        return {"frames": self.frames, "skipped_by_rate": self.skipped, "dropped": self.dropped,
                "link_drops_seen": int(self.links.last_drops.sum()), "link_unreported_frames": self.links.unreported,
                **({"sink_error": self.sink_error} if self.sink_error else {})}


#: What the logger subscribes to, relative to the swarm prefix: the world's state alone (one
#: message per tick; the robots' link reports ride in it).
RECORDER_TOPICS = (topics.WORLD_STATE,)


def attach(bus, recorder: SwarmRecorder) -> None:
    """Subscribe ``recorder`` on an in-process bus (synchronous: for ``Simulation`` and tests)."""
    clock = recorder.wall_clock

    def on_state(topic: str, msg: Message) -> None:
        recorder.take(topic, msg, clock())

    bus.subscribe(topics.WORLD_STATE, on_state)
