"""Scenario files (TOML): load, validate, and describe a swarm run.

Every error names the file, the field path and what was expected, e.g.
``configs/x.toml: robots[3].position: expected 3 numbers, got 2``. Field
paths index arrays from 0, as TOML does; robot ids are 1-based (robot
``robots[k]`` has id ``k+1``), as in the paper.
"""

from __future__ import annotations

import math
import re
import tomllib
import warnings
from dataclasses import dataclass, field
from pathlib import Path as FilePath
from typing import Any

import numpy as np

from fxswarm.core import motion
from fxswarm.core.bus import SWARM_NAME_RULE, is_swarm_name
from fxswarm.core.control import BehaviourGains, EstimatorGains
from fxswarm.core.drive import MODELS, Drive
from fxswarm.core.sensing import Sensing
from fxswarm.core.laws import LawError, make_law, resolve_law
from fxswarm.core.paper_law import BUILTIN_LAWS, FAMILIES, builtin_name, family_gains, split_builtin
from fxswarm.core.observer import DEFAULT_OBSERVER_GAINS, OBSERVER_GRAPHS, TRACKINGS, max_acceleration_inf
from fxswarm.core.resilience import RESILIENCE, leader_reach
from fxswarm.core.swarm import expand as expand_swarm
from fxswarm.core.graph import TOPOLOGIES, SparseGraph, adjacency, h_matrix, topology_edges, unreached_robots


class ScenarioError(ValueError):
    """A scenario file is malformed; the message names file, field and expectation."""


@dataclass(frozen=True)
class Robot:
    """One robot: 1-based id, initial position (m), offset path, initial estimate (m)."""

    id: int
    position: tuple[float, float, float]
    offset: motion.Offset
    estimate: tuple[float, float, float]


@dataclass(frozen=True)
class Scenario:
    """A validated scenario. Arrays are indexed by robot id - 1."""

    name: str
    source: str
    duration: float
    dt: float
    seed: int
    settle_tolerance: float
    d: float
    v_max: float | None
    robots: tuple[Robot, ...]
    graph: SparseGraph = field(repr=False)  # the symmetric weights a_ij, by rows (dense: ``a``)
    b: np.ndarray = field(repr=False)  # (n,) leader pinning gains b_i
    leader: motion.Path
    obstacles: tuple[motion.Path, ...]
    formation: BehaviourGains
    avoidance: BehaviourGains
    estimator: EstimatorGains
    raw: dict = field(repr=False, default_factory=dict)  # the parsed TOML, for sections owned elsewhere
    variant: str = "fixed-time"  # [controller] variant: the behaviours' law family (VARIANTS)
    estimator_variant: str = "fixed-time"  # [controller] estimator_variant: the estimator's law family
    discretisation: str = "euler"  # [controller] discretisation: "euler" (SPEC section 7) or "semi-implicit"
    delay_compensation: str = "leader-velocity"  # [controller] delay_compensation (DELAY_COMPENSATIONS)
    tracking: str = "paper"  # [estimator] tracking: "paper" (eq. (11)) or "feedforward" (fxswarm.core.observer)
    observer: EstimatorGains | None = None  # eq. (obs)'s gains (L1, L2, L3 as K1, K2, K3); only with feedforward
    observer_graph: str = "oriented"  # [estimator] observer_graph (OBSERVER_GRAPHS): the links eq. (obs) uses
    estimator_graph: str = "undirected"  # [estimator] estimator_graph: "oriented": eq. (11) sums upstream only
    resilience: str = "none"  # [estimator] resilience (fxswarm.core.resilience.RESILIENCE): "w-msr" trims
    tolerate: int = 0  # [estimator] tolerate: F, the liars W-MSR is built for (docs/resilience.md)
    logging: dict = field(repr=False, default_factory=dict)  # [logging], checked: the keys given (the logger's defaults)
    zenoh: dict = field(repr=False, default_factory=dict)  # [zenoh], checked: the keys given (the command line wins)
    ros2: "Ros2Settings | None" = None  # [ros2]: how the ROS 2 world reaches the robots (defaults if absent)
    law: str = "fixed-time"  # [controller] law: a built-in name (fxswarm.core.laws) or module:Class
    law_params: dict = field(repr=False, default_factory=dict)  # [controller.params], handed to the law
    law_folder: str | None = None  # the scenario's folder: where a law module beside it is imported from
    world: "WorldSettings | None" = None  # [world] and the robots' drive keys; None: the paper's ideal world
    swarm: dict | None = field(repr=False, default=None)  # the [swarm] table as written (raw holds its expansion)

    @property
    def n(self) -> int:
        return len(self.robots)

    @property
    def ticks(self) -> int:
        return int(round(self.duration / self.dt))

    @property
    def a(self) -> np.ndarray:
        """The weights ``a_ij`` as a dense (n, n) matrix, built on each call: for analysis of
        small swarms (763 MB at 10 000 robots; the run itself reads :attr:`graph`)."""
        return self.graph.dense()

    @property
    def H(self) -> np.ndarray:
        return h_matrix(self.a, self.b)

    def neighbours(self, robot_id: int) -> list[int]:
        """Graph neighbours (1-based ids, ascending) of a robot."""
        return (self.graph.row(robot_id - 1)[0] + 1).tolist()

    def weights(self, robot_id: int) -> list[float]:
        """The weights ``a_ij`` of a robot's :meth:`neighbours`, in their order."""
        return self.graph.row(robot_id - 1)[1].tolist()

    def is_pinned(self, robot_id: int) -> bool:
        return bool(self.b[robot_id - 1] > 0)


# --- reading TOML with field paths -------------------------------------------------


class _Fields:
    """Typed access to a TOML table that reports errors with file and field path."""

    def __init__(self, source: str, table: dict, path: str = "") -> None:
        self.source, self.table, self.path = source, table, path

    def fail(self, key: str | None, expected: str, got: Any = None, *, show_got: bool = True) -> None:
        where = self.sub_path(key) if key is not None else (self.path or "(top level)")
        got_text = f", got {_describe(got)}" if show_got else ""
        raise ScenarioError(f"{self.source}: {where}: expected {expected}{got_text}")

    def sub_path(self, key: str | int) -> str:
        if isinstance(key, int):
            return f"{self.path}[{key}]"
        return f"{self.path}.{key}" if self.path else key

    def has(self, key: str) -> bool:
        return key in self.table

    def table_at(self, key: str, required: bool = False) -> "_Fields":
        value = self.table.get(key, None)
        if value is None:
            if required:
                self.fail(key, "a table", show_got=False)
            value = {}
        if not isinstance(value, dict):
            self.fail(key, "a table", value)
        return _Fields(self.source, value, self.sub_path(key))

    def tables(self, key: str, required: bool = False) -> list["_Fields"]:
        value = self.table.get(key, None)
        if value is None:
            if required:
                self.fail(key, "an array of tables ([[" + key + "]])", show_got=False)
            return []
        if not isinstance(value, list):
            self.fail(key, "an array of tables", value)
        out = []
        for k, item in enumerate(value):
            if not isinstance(item, dict):
                _Fields(self.source, {}, self.sub_path(key)).fail(k, "a table", item)
            out.append(_Fields(self.source, item, f"{self.sub_path(key)}[{k}]"))
        return out

    def number(self, key: str, default: float | None = None, *, positive: bool = False,
               nonnegative: bool = False) -> float:
        if key not in self.table:
            if default is None:
                self.fail(key, "a number", show_got=False)
            return float(default)
        value = self.table[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            self.fail(key, "a finite number", value)
        if positive and value <= 0:
            self.fail(key, "a number > 0", value)
        if nonnegative and value < 0:
            self.fail(key, "a number >= 0", value)
        return float(value)

    def optional_number(self, key: str, *, positive: bool = False) -> float | None:
        if key not in self.table:
            return None
        return self.number(key, positive=positive)

    def integer(self, key: str, default: int, *, minimum: int | None = None) -> int:
        value = self.table.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(key, "an integer", value)
        if minimum is not None and value < minimum:
            self.fail(key, f"an integer >= {minimum}", value)
        return value

    def boolean(self, key: str) -> bool:
        value = self.table.get(key)
        if not isinstance(value, bool):
            self.fail(key, "true or false", value)
        return value

    def strings(self, key: str) -> list[str]:
        value = self.table.get(key)
        if not isinstance(value, list) or not all(isinstance(x, str) for x in value):
            self.fail(key, "a list of strings", value)
        return value

    def string(self, key: str, default: str | None = None, choices: tuple[str, ...] | None = None) -> str:
        if key not in self.table:
            if default is None:
                self.fail(key, "a string" + (f" (one of {', '.join(choices)})" if choices else ""),
                          show_got=False)
            return default
        value = self.table[key]
        if not isinstance(value, str):
            self.fail(key, "a string", value)
        if choices is not None and value not in choices:
            self.fail(key, f"one of {', '.join(repr(c) for c in choices)}", value)
        return value

    def vector(self, key: str, default: tuple | None = None) -> tuple[float, float, float]:
        if key not in self.table:
            if default is None:
                self.fail(key, "3 numbers", show_got=False)
            return default
        return _vector(self, key, self.table[key])

    def numbers(self, key: str) -> list[float]:
        value = self.table.get(key)
        if not isinstance(value, list) or not all(_is_num(x) for x in value):
            self.fail(key, "a list of numbers", value)
        return [float(x) for x in value]

    def check_known(self, allowed: set[str]) -> None:
        for key in self.table:
            if key not in allowed:
                self.fail(key, f"no such field here (known: {', '.join(sorted(allowed))})", show_got=False)


def _is_num(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _vector(f: _Fields, key: str | int, value: Any) -> tuple[float, float, float]:
    if not isinstance(value, list):
        f.fail(key, "3 numbers", value)
    if len(value) != 3:
        f.fail(key, "3 numbers", f"{len(value)}", show_got=True)
    if not all(_is_num(x) for x in value):
        f.fail(key, "3 finite numbers", value)
    return (float(value[0]), float(value[1]), float(value[2]))


def _describe(value: Any) -> str:
    if isinstance(value, str) and value.isdigit():
        return value  # a count, already phrased by the caller
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):  # short enough to show: the wrong id is in it
        text = repr(value)
        return text if len(text) <= 60 else f"a list of {len(value)}"
    return repr(value)


# --- sections ----------------------------------------------------------------------


def _path(f: _Fields, kinds: tuple[str, ...]) -> motion.Path:
    kind = f.string("kind", choices=kinds)
    if kind == "static":
        f.check_known({"kind", "position"})
        return motion.Static(f.vector("position"))
    if kind == "constant_velocity":
        f.check_known({"kind", "position", "velocity"})
        return motion.ConstantVelocity(f.vector("position"), f.vector("velocity"))
    if kind == "helix":
        f.check_known({"kind", "centre", "radius", "rate", "climb", "phase"})
        return motion.Helix(f.vector("centre", (0.0, 0.0, 0.0)), f.number("radius", nonnegative=True),
                            f.number("rate"), f.number("climb", 0.0), f.number("phase", 0.0))
    if kind == "circle":
        f.check_known({"kind", "centre", "radius", "rate", "phase"})
        return motion.Circle(f.vector("centre"), f.number("radius", nonnegative=True),
                             f.number("rate"), f.number("phase", 0.0))
    # waypoints
    f.check_known({"kind", "times", "points"})
    times = f.numbers("times")
    points_raw = f.table.get("points")
    if not isinstance(points_raw, list):
        f.fail("points", "a list of 3-number lists", points_raw)
    pf = _Fields(f.source, {}, f.sub_path("points"))
    points = tuple(_vector(pf, k, p) for k, p in enumerate(points_raw))
    if len(times) < 1 or len(times) != len(points):
        f.fail("times", f"as many times as points ({len(points)})", f"{len(times)}")
    if any(t1 <= t0 for t0, t1 in zip(times, times[1:])):
        f.fail("times", "strictly increasing times", times)
    return motion.Waypoints(tuple(times), points)


LEADER_KINDS = ("static", "constant_velocity", "helix", "waypoints")
OBSTACLE_KINDS = ("static", "constant_velocity", "circle", "helix", "waypoints")


def _behaviour(f: _Fields, lam_key: str, lam_default: float) -> BehaviourGains:
    return BehaviourGains(
        lam=f.number(lam_key, lam_default, positive=True),
        b1=f.number("b1", positive=True), b2=f.number("b2", positive=True),
        r0=f.number("r0", positive=True), r1=f.number("r1", positive=True), r2=f.number("r2", positive=True),
    )


#: Controller variants ([controller] variant / estimator_variant): the same law, its exponents chosen
#: so that convergence is fixed-time (the paper), finite-time, or asymptotic (exponential).
VARIANTS = FAMILIES
DISCRETISATIONS = ("euler", "semi-implicit")
#: [controller] delay_compensation: what a robot does with a neighbour's estimate (or the leader's
#: state) older than its own time: carry it forward at its estimated leader velocity, or use it as is.
DELAY_COMPENSATIONS = ("leader-velocity", "none")


def _exponent_condition(x: float, relation: str) -> bool:
    if relation == "> 1":
        return x > 1.0
    if relation == "< 1":
        return x < 1.0
    return math.isclose(x, 1.0, rel_tol=1e-9)  # "= 1"


#: What each variant needs of the behaviours' effective exponents ``r1*r0`` (large errors) and
#: ``r2*r0`` (small errors), and of the estimator's ``r3/r4`` and ``r5/r6`` (SPEC sections 2, 6).
BEHAVIOUR_CONDITIONS = {
    "fixed-time": {"r1": "> 1", "r2": "< 1"},
    "finite-time": {"r1": "< 1", "r2": "< 1"},
    "asymptotic": {"r1": "= 1", "r2": "= 1"},
}
ESTIMATOR_CONDITIONS = {
    "fixed-time": {"r3": "> 1", "r5": "< 1"},
    "finite-time": {"r3": "< 1", "r5": "< 1"},
    "asymptotic": {"r3": "= 1", "r5": "= 1"},
}


def _check_behaviour_variant(f: _Fields, g: BehaviourGains, variant: str) -> None:
    """The exponent conditions of ``variant`` (BEHAVIOUR_CONDITIONS) on the behaviours' gains."""
    for key, relation in BEHAVIOUR_CONDITIONS[variant].items():
        value = (g.r1 if key == "r1" else g.r2) * g.r0
        if not _exponent_condition(value, relation):
            f.fail(key, f"{key}*r0 {relation} for the {variant} law (controller.variant; "
                   f"{key}*r0 = {value:g})", show_got=False)


def _check_estimator_variant(f: _Fields, g: EstimatorGains, variant: str) -> None:
    """The exponent conditions of ``variant`` (ESTIMATOR_CONDITIONS) on the estimator's gains."""
    for key, relation in ESTIMATOR_CONDITIONS[variant].items():
        num, den = (g.r3, g.r4) if key == "r3" else (g.r5, g.r6)
        if not _exponent_condition(num / den, relation):
            pair = "r3/r4" if key == "r3" else "r5/r6"
            f.fail(key, f"{pair} {relation} for the {variant} estimator (controller.estimator_variant; "
                   f"{pair} = {num / den:g})", show_got=False)


#: [estimator] fields of the velocity observer (eq. (obs), fxswarm.core.observer): its gains
#: L1, L2, L3 (defaults: fxswarm.core.observer.DEFAULT_OBSERVER_GAINS).
OBSERVER_FIELDS = ("observer_K1", "observer_K2", "observer_K3", "observer_graph")


def _tracking(ef: _Fields, estimator: EstimatorGains, default: str = "paper") -> tuple[str, EstimatorGains | None, str]:
    """``[estimator] tracking`` and, for "feedforward", the observer's gains (same exponents and
    ``power`` as eq. (11))."""
    tracking = ef.string("tracking", default, TRACKINGS)
    if tracking != "feedforward":
        for key in OBSERVER_FIELDS:
            if ef.has(key):
                ef.fail(key, 'no observer gain unless tracking = "feedforward" (the observer runs only then)',
                        show_got=False)
        return tracking, None, "oriented"
    observer = EstimatorGains(
        K1=ef.number("observer_K1", DEFAULT_OBSERVER_GAINS[0], positive=True),
        K2=ef.number("observer_K2", DEFAULT_OBSERVER_GAINS[1], positive=True),
        K3=ef.number("observer_K3", DEFAULT_OBSERVER_GAINS[2], positive=True),
        r3=estimator.r3, r4=estimator.r4, r5=estimator.r5, r6=estimator.r6, power=estimator.power,
    )
    return tracking, observer, ef.string("observer_graph", "oriented", OBSERVER_GRAPHS)


#: [zenoh] mode and topology: the role commands' --mode and `fxswarm run`'s --topology take the same.
ZENOH_MODES = ("peer", "client", "router")
RUN_TOPOLOGIES = ("auto", "mesh", "routed")


def _logging(lf: _Fields) -> dict:
    """[logging], checked here so a wrong key fails before any process starts, not in the logger."""
    lf.check_known({"rate_hz", "velocities", "trail_s", "trail_dt", "stale_ticks", "recent_drop_s",
                    "flush_frames", "flush_wall_s"})
    out: dict = {}
    for key in lf.table:
        if key == "velocities":
            out[key] = lf.boolean(key)
        elif key in ("stale_ticks", "flush_frames"):
            out[key] = lf.integer(key, 0, minimum=0 if key == "stale_ticks" else 1)
        else:
            out[key] = lf.number(key, positive=key in ("rate_hz", "trail_dt"), nonnegative=True)
    return out


def _zenoh(zf: _Fields) -> dict:
    """[zenoh], checked as the command line's Zenoh options are."""
    zf.check_known({"swarm", "mode", "connect", "listen", "multicast", "lease_ms", "topology", "routers"})
    out: dict = {}
    for key in zf.table:
        if key in ("connect", "listen", "routers"):
            out[key] = zf.strings(key)
        elif key == "multicast":
            out[key] = zf.boolean(key)
        elif key == "lease_ms":
            out[key] = zf.integer(key, 0, minimum=1)
        elif key == "swarm":
            out[key] = zf.string(key)
            if not is_swarm_name(out[key]):
                zf.fail(key, f"a swarm name ({SWARM_NAME_RULE})", out[key])
        else:
            out[key] = zf.string(key, choices={"mode": ZENOH_MODES, "topology": RUN_TOPOLOGIES}.get(key))
    return out


@dataclass(frozen=True)
class Ros2Settings:
    """[ros2]: the ROS 2 world's topics and limits (docs/ros2.md). Topics hold ``{id}``, the robot's id."""

    pose_topic: str = "/robot{id}/pose"
    pose_type: str = "PoseStamped"  # POSE_TYPES: geometry_msgs/PoseStamped or nav_msgs/Odometry
    cmd_topic: str = "/robot{id}/cmd_vel"
    frame: str = "world"  # the frame poses must come in and commands are meant in
    v_max: float | None = None  # m/s per command; None: [scenario] v_max
    pose_timeout: float = 0.5  # s without a pose before a robot is held at zero
    drive: str = "holonomic"  # or "differential": (v, omega) from the world-frame velocity and heading
    heading_gain: float = 2.0  # differential: omega = heading_gain * heading error, 1/s
    omega_max: float = 2.0  # differential: |omega| limit, rad/s

    def topic(self, pattern: str, robot: int) -> str:
        return pattern.replace("{id}", str(robot))


POSE_TYPES = ("PoseStamped", "Odometry")
DRIVES = ("holonomic", "differential")
_ROS_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_FRAME_ID = re.compile(r"[A-Za-z0-9_./-]+")


def _ros2_topic(f: _Fields, key: str, default: str) -> str:
    """A ROS 2 topic name pattern: absolute, tokens of letters, digits and _ (not starting with a
    digit), and ``{id}`` (the robot's id) exactly once."""
    value = f.string(key, default)
    expected = 'an absolute ROS 2 topic with {id} once, e.g. "/robot{id}/cmd_vel"'
    tokens = value.replace("{id}", "1").split("/")
    if (value.count("{id}") != 1 or not value.startswith("/")
            or not all(_ROS_TOKEN.fullmatch(t) for t in tokens[1:])):
        f.fail(key, expected, value)
    return value


def _ros2(f: _Fields) -> Ros2Settings:
    """[ros2], checked before anything starts (unknown message type, malformed topic)."""
    f.check_known({"pose_topic", "pose_type", "cmd_topic", "frame", "v_max", "pose_timeout", "drive",
                   "heading_gain", "omega_max"})
    d = Ros2Settings()
    settings = Ros2Settings(
        pose_topic=_ros2_topic(f, "pose_topic", d.pose_topic), pose_type=f.string("pose_type", d.pose_type, POSE_TYPES),
        cmd_topic=_ros2_topic(f, "cmd_topic", d.cmd_topic), frame=f.string("frame", d.frame),
        v_max=f.optional_number("v_max", positive=True), pose_timeout=f.number("pose_timeout", d.pose_timeout, positive=True),
        drive=f.string("drive", d.drive, DRIVES), heading_gain=f.number("heading_gain", d.heading_gain, positive=True),
        omega_max=f.number("omega_max", d.omega_max, positive=True))
    if not _FRAME_ID.fullmatch(settings.frame):
        f.fail("frame", "a frame id (letters, digits, _ . / -)", settings.frame)
    if settings.pose_topic == settings.cmd_topic:
        f.fail("cmd_topic", "a topic other than pose_topic", settings.cmd_topic)
    return settings


@dataclass(frozen=True)
class WorldSettings:
    """[world] and the drive keys of the [[robots]] entries (docs/robots.md): per robot its drive
    model and initial heading (rad), and the robots' sensing."""

    drives: tuple[Drive, ...]
    headings: tuple[float, ...]
    sensing: Sensing

    @property
    def ideal_motion(self) -> bool:
        """Every robot a single integrator with no speed limit of its own (the paper's world)."""
        return all(d.model == "single-integrator" and d.v_max is None for d in self.drives)

    @property
    def models(self) -> tuple[str, ...]:
        """The models flown, each once, in :data:`~fxswarm.core.drive.MODELS` order."""
        return tuple(m for m in MODELS if any(d.model == m for d in self.drives))


#: [world] keys; a [[robots]] entry may give those in ROBOT_WORLD_KEYS for itself.
WORLD_KEYS = {"model", "v_max", "omega_max", "heading_gain", "lookahead", "planar", "a_max", "tau",
              "pose_noise", "obstacle_noise", "sensing_delay", "sensing_range"}
ROBOT_WORLD_KEYS = ("model", "heading", "v_max", "pose_noise")


def _is_planar(leader: motion.Path, robots: list[Robot], duration: float) -> bool:
    """Whether the leader stays at one height and no offset moves vertically: a ground swarm."""
    z0 = leader.position(0.0)[2]
    if any(abs(leader.position(duration * k / 64)[2] - z0) > 1e-9 for k in range(65)):
        return False
    return all(r.offset.amplitude[2] == 0.0 for r in robots)


def _world(wf: _Fields, robot_tables: list[_Fields], robots: list[Robot], sc_v_max: float | None,
           d: float, leader: motion.Path, duration: float) -> WorldSettings | None:
    """[world] and the robots' own drive keys, checked; None if the scenario gives none of them."""
    wf.check_known(WORLD_KEYS)
    if not wf.table and not any(rf.has(k) for rf in robot_tables for k in ROBOT_WORLD_KEYS):
        return None
    model = wf.string("model", "single-integrator", MODELS)
    world_v_max = wf.optional_number("v_max", positive=True)
    omega_max = wf.number("omega_max", 2.0, positive=True)
    heading_gain = wf.number("heading_gain", 2.0, positive=True)
    lookahead = wf.number("lookahead", 0.0, nonnegative=True)
    planar = wf.boolean("planar") if wf.has("planar") else _is_planar(leader, robots, duration)
    a_max = wf.optional_number("a_max", positive=True)
    tau = wf.number("tau", 0.0, nonnegative=True)
    pose_noise = wf.number("pose_noise", 0.0, nonnegative=True)
    sensing_range = wf.optional_number("sensing_range", positive=True)
    if sensing_range is not None and sensing_range < d:
        wf.fail("sensing_range", f"a range >= d = {d:g} m (a robot must sense what it must avoid)", sensing_range)
    drives, headings, noise = [], [], []
    for rf in robot_tables:
        m = rf.string("model", model, MODELS)
        v_max = rf.optional_number("v_max", positive=True)
        if v_max is None:
            v_max = world_v_max if world_v_max is not None or m == "single-integrator" else sc_v_max
        drives.append(Drive(m, v_max, omega_max, heading_gain, lookahead, planar, a_max, tau))
        headings.append(rf.number("heading", 0.0))
        noise.append(rf.number("pose_noise", pose_noise, nonnegative=True))
    sensing = Sensing(tuple(noise), wf.number("obstacle_noise", 0.0, nonnegative=True),
                      wf.integer("sensing_delay", 0, minimum=0), sensing_range)
    return WorldSettings(tuple(drives), tuple(headings), sensing)


def _builtin_law(cf: _Fields) -> tuple[str | None, str | None]:
    """``(family, tracking)`` a built-in ``[controller] law`` name sets (None, None: no such name)."""
    if not cf.has("law"):
        return None, None
    spec = cf.string("law")
    return split_builtin(spec) if spec in BUILTIN_LAWS else (None, None)


def _law(scenario: Scenario, cf: _Fields) -> None:
    """The scenario's law resolved and built for every robot, or :class:`ScenarioError` naming
    ``controller.law`` and the cause: before any process starts."""
    try:
        cls = resolve_law(scenario.law, scenario.law_folder)
        for r in scenario.robots:
            make_law(cls, scenario.law_params, r.id, scenario)
    except LawError as exc:
        raise ScenarioError(f"{scenario.source}: {cf.sub_path('law')}: {exc}") from None


def _header(sc: _Fields, source: str) -> tuple[str, float, float]:
    """``[scenario]``'s name, duration and dt, checked."""
    sc.check_known({"name", "duration", "dt", "seed", "settle_tolerance", "d", "v_max"})
    name = sc.string("name", FilePath(source).stem)
    if not is_swarm_name(name):  # it names the run's folder and, by default, its swarm
        sc.fail("name", f"a name for the run folder and the swarm ({SWARM_NAME_RULE})", name)
    duration = sc.number("duration", positive=True)
    dt = sc.number("dt", positive=True)
    if dt > duration:
        sc.fail("dt", f"a control period no longer than the duration ({duration:g} s)", dt)
    return name, duration, dt


def _control(top: _Fields, source: str) -> dict:
    """``[gains]``, ``[controller]`` and ``[estimator]``: the law's gains and settings, as the
    :class:`Scenario` fields of those names (and ``law`` from ``[controller] law`` or the variant)."""
    gf = top.table_at("gains", required=True)
    gf.check_known({"b1", "b2", "r0", "r1", "r2", "lam_f", "lam_o", "K1", "K2", "K3", "r3", "r4", "r5", "r6"})
    cf = top.table_at("controller")
    cf.check_known({"variant", "estimator_variant", "discretisation", "delay_compensation", "law", "params"})
    family, law_tracking = _builtin_law(cf)  # law = "<family>[+feedforward]" sets these (docs/controllers.md)
    if family is not None:
        gf = _Fields(source, family_gains(gf.table, family), gf.path)
    formation = _behaviour(gf, "lam_f", 1.0)
    variant = cf.string("variant", family or "fixed-time", VARIANTS)
    estimator_variant = cf.string("estimator_variant", variant, VARIANTS)
    if family is not None and (variant, estimator_variant) != (family, family):
        cf.fail("variant" if variant != family else "estimator_variant",
                f"{family!r} or nothing with law = {cf.table['law']!r}",
                variant if variant != family else estimator_variant)
    out = dict(formation=formation, avoidance=_behaviour(gf, "lam_o", 1.0), variant=variant,
               estimator_variant=estimator_variant,
               discretisation=cf.string("discretisation", "euler", DISCRETISATIONS),
               delay_compensation=cf.string("delay_compensation", "leader-velocity", DELAY_COMPENSATIONS))
    _check_behaviour_variant(gf, formation, variant)
    out.update(_estimator(top.table_at("estimator"), gf, estimator_variant, law_tracking, cf))
    out.update(law=cf.string("law") if cf.has("law") else builtin_name(variant, out["tracking"]),
               law_params=dict(cf.table_at("params").table))
    return out


def _estimator(ef: _Fields, gf: _Fields, estimator_variant: str, law_tracking: str | None, cf: _Fields) -> dict:
    """``[estimator]`` with the estimator's gains from ``[gains]``, as :class:`Scenario` fields."""
    ef.check_known({"power", "tracking", "observer_K1", "observer_K2", "observer_K3", "observer_graph",
                    "resilience", "tolerate", "estimator_graph"})
    estimator = EstimatorGains(
        K1=gf.number("K1", positive=True), K2=gf.number("K2", positive=True), K3=gf.number("K3", positive=True),
        r3=gf.number("r3", positive=True), r4=gf.number("r4", positive=True),
        r5=gf.number("r5", positive=True), r6=gf.number("r6", positive=True),
        power=ef.string("power", "pairwise", ("pairwise", "aggregate")),
    )
    _check_estimator_variant(gf, estimator, estimator_variant)
    tracking, observer, observer_graph = _tracking(ef, estimator, law_tracking or "paper")
    if law_tracking is not None and tracking != law_tracking:
        ef.fail("tracking", f"{law_tracking!r} or nothing with law = {cf.table['law']!r}", tracking)
    estimator_graph = ef.string("estimator_graph", "undirected", OBSERVER_GRAPHS)
    resilience = ef.string("resilience", "none", RESILIENCE)
    if resilience != "none" and estimator_graph == "oriented":
        ef.fail("estimator_graph", '"undirected" with resilience = "w-msr" (W-MSR trims every neighbour\'s '
                "value; its graph condition is for the undirected graph)", estimator_graph)
    tolerate = ef.integer("tolerate", 1 if resilience == "w-msr" else 0)
    if resilience == "none" and ef.has("tolerate"):
        ef.fail("tolerate", 'no tolerate unless resilience = "w-msr"', show_got=False)
    if resilience == "w-msr" and tolerate < 1:
        ef.fail("tolerate", "an integer >= 1 (F, the liars W-MSR is built for)", tolerate)
    return dict(estimator=estimator, tracking=tracking, observer=observer, observer_graph=observer_graph,
                estimator_graph=estimator_graph, resilience=resilience, tolerate=tolerate)


def _robots(top: _Fields) -> tuple[list[_Fields], list[Robot]]:
    """The ``[[robots]]`` tables and their robots (offsets: a sinusoid shared by all robots,
    ``[formation]``, overridable per robot)."""
    ff = top.table_at("formation")
    ff.check_known({"amplitude", "omega", "phase"})
    zero = (0.0, 0.0, 0.0)
    shared = {k: ff.vector(k, zero) for k in ("amplitude", "omega", "phase")}
    robot_tables = top.tables("robots", required=True)
    if not robot_tables:
        top.fail("robots", "at least one [[robots]] table", show_got=False)
    robots = []
    for k, rf in enumerate(robot_tables):
        rf.check_known({"position", "offset", "estimate", "amplitude", "omega", "phase", *ROBOT_WORLD_KEYS})
        offset = motion.Offset(
            rf.vector("offset"),
            *(rf.vector(key, shared[key]) for key in ("amplitude", "omega", "phase")),
        )
        robots.append(Robot(k + 1, rf.vector("position"), offset, rf.vector("estimate", zero)))
    return robot_tables, robots


def _edges(grf: _Fields, source: str, n: int) -> tuple[list[tuple[int, int]], list[float] | None]:
    """``[graph]``'s edges (from ``topology`` or ``edges``) and their weights (None: all 1)."""
    if grf.has("edges") == grf.has("topology"):
        grf.fail("topology", "exactly one of 'topology' (" + ", ".join(TOPOLOGIES) + ") or 'edges'",
                 show_got=False)
    if grf.has("topology"):
        if grf.has("weights"):
            grf.fail("weights", "weights only with 'edges' (a topology's edges all weigh 1)", show_got=False)
        return topology_edges(grf.string("topology", choices=TOPOLOGIES), n), None
    raw_edges = grf.table.get("edges")
    if not isinstance(raw_edges, list):
        grf.fail("edges", "a list of [i, j] robot id pairs", raw_edges)
    edges = []
    ef_ = _Fields(source, {}, grf.sub_path("edges"))
    for k, e in enumerate(raw_edges):
        if (not isinstance(e, list) or len(e) != 2 or not all(isinstance(x, int) and not isinstance(x, bool)
                                                              for x in e)):
            ef_.fail(k, "a pair [i, j] of robot ids", e)
        if not all(1 <= x <= n for x in e) or e[0] == e[1]:
            ef_.fail(k, f"two different robot ids in 1..{n}", e)
        edges.append((e[0], e[1]))
    weights = grf.numbers("weights") if grf.has("weights") else None
    if weights is not None:
        if len(weights) != len(edges):
            grf.fail("weights", f"one weight per edge ({len(edges)})", f"{len(weights)}")
        if any(w < 0 for w in weights):
            grf.fail("weights", "weights >= 0", weights)
    return edges, weights


def _graph(grf: _Fields, source: str, n: int) -> tuple[SparseGraph, np.ndarray]:
    """``[graph]`` as the weights ``a`` (by rows) and the pinning gains ``b`` (n,), checked: every
    robot reaches one that hears the leader."""
    grf.check_known({"topology", "edges", "weights", "pinned", "pin_gain"})
    edges, weights = _edges(grf, source, n)
    raw_pinned = grf.table.get("pinned")
    if not isinstance(raw_pinned, list) or not all(isinstance(x, int) and not isinstance(x, bool)
                                                   for x in raw_pinned):
        grf.fail("pinned", "a list of the robot ids that hear the leader", raw_pinned)
    if not raw_pinned:
        grf.fail("pinned", "at least one robot that hears the leader (H = L + diag(b) must be positive "
                 "definite)", raw_pinned)
    for x in raw_pinned:
        if not 1 <= x <= n:
            grf.fail("pinned", f"robot ids in 1..{n}", raw_pinned)
    pin_gain = grf.number("pin_gain", 1.0, positive=True)
    a = adjacency(n, edges, weights)
    b = np.zeros(n)
    b[[x - 1 for x in raw_pinned]] = pin_gain
    lost = unreached_robots(a, b)
    if lost:
        grf.fail(None, "a connected graph in which every robot reaches one that hears the leader "
                 f"(H = L + diag(b) positive definite); robots {lost} are cut off from pinned robots "
                 f"{sorted(raw_pinned)}", show_got=False)
    return a, b


def parse(data: dict, source: str = "<scenario>", folder: str | None = None, *, check_law: bool = True) -> Scenario:
    """Validate a parsed TOML document into a :class:`Scenario`. ``folder``: where a law module
    named ``module:Class`` is looked for first (default: the folder of ``source``, if a file);
    ``check_law=False``: the law is not imported (for an observer, which flies nothing)."""
    swarm = data.get("swarm") if isinstance(data.get("swarm"), dict) else None
    data = expand_swarm(data, source, folder if folder is not None else _folder_of(source))  # [swarm] -> robots
    top = _Fields(source, data)
    top.check_known({"scenario", "gains", "estimator", "graph", "leader", "formation", "robots",
                     "obstacles", "faults", "controller", "logging", "zenoh", "ros2", "world"})
    sc = top.table_at("scenario", required=True)
    name, duration, dt = _header(sc, source)
    control = _control(top, source)
    robot_tables, robots = _robots(top)
    a, b = _graph(top.table_at("graph", required=True), source, len(robots))
    leader = _path(top.table_at("leader", required=True), LEADER_KINDS)
    obstacles = tuple(_path(of, OBSTACLE_KINDS) for of in top.tables("obstacles"))
    v_max, d = sc.optional_number("v_max", positive=True), sc.number("d", positive=True)
    scenario = Scenario(
        name=name, source=source, duration=duration, dt=dt, seed=sc.integer("seed", 0),
        settle_tolerance=sc.number("settle_tolerance", 0.2, positive=True), d=d, v_max=v_max,
        robots=tuple(robots), graph=a, b=b, leader=leader, obstacles=obstacles, raw=data, **control,
        logging=_logging(top.table_at("logging")), zenoh=_zenoh(top.table_at("zenoh")),
        ros2=_ros2(top.table_at("ros2")),
        law_folder=folder if folder is not None else _folder_of(source),
        world=_world(top.table_at("world"), robot_tables, robots, v_max, d, leader, duration),
        swarm=swarm,
    )
    if check_law:
        _law(scenario, top.table_at("controller"))
    _warn_assumptions(scenario)
    return scenario


def _warn_assumptions(scenario: Scenario) -> None:
    """A :class:`ScenarioWarning` for each assumption of the paper (or of W-MSR) the valid
    ``scenario`` breaks."""
    source, leader, observer = scenario.source, scenario.leader, scenario.observer
    if observer is not None:
        accel = max_acceleration_inf(leader)
        if observer.K3 < accel:
            warnings.warn(
                f"{source}: estimator.observer_K3 = {observer.K3:g} is below the leader's top acceleration "
                f"per axis ({accel:g} m/s^2): the velocity observer's fixed-time guarantee does not hold "
                "(docs/estimator.md)", ScenarioWarning, stacklevel=3,
            )
    tolerate = scenario.tolerate
    if scenario.resilience == "w-msr":
        unreached = leader_reach(scenario.graph, scenario.b, 2 * tolerate + 1)
        if unreached:
            warnings.warn(
                f"{source}: estimator.resilience = \"w-msr\" with tolerate = {tolerate}: the graph does not meet "
                f"the condition for {tolerate} liar(s) (every robot pinned or linked to {2 * tolerate + 1} robots "
                f"that meet it); robots {', '.join(map(str, unreached))} do not (docs/resilience.md; "
                "fxswarm check)", ScenarioWarning, stacklevel=3,
            )
    leader_speed = leader.max_speed_inf(scenario.duration)
    if scenario.estimator.K3 < leader_speed:
        warnings.warn(
            f"{source}: gains.K3 = {scenario.estimator.K3:g} is below the leader's top speed per axis "
            f"({leader_speed:g} m/s): the estimator's fixed-time guarantee (Assumption 1) does not hold",
            ScenarioWarning, stacklevel=3,
        )


class ScenarioWarning(UserWarning):
    """A scenario is valid but breaks an assumption of the paper."""


def load(path: str | FilePath, *, check_law: bool = True) -> Scenario:
    """Read and validate a scenario file; raises :class:`ScenarioError` naming file and field."""
    source = str(path)
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise ScenarioError(f"{source}: no such scenario file") from None
    except OSError as exc:  # a folder, no permission, ...
        raise ScenarioError(f"{source}: cannot read the scenario file: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{source}: not valid TOML: {exc}") from None
    return parse(data, source, str(FilePath(path).parent), check_law=check_law)


def _folder_of(source: str) -> str | None:
    """The folder of scenario file ``source``; None if ``source`` names no file."""
    path = FilePath(source)
    return str(path.parent) if path.is_file() else None


def directed_links(sc: Scenario) -> list[tuple[int, int]]:
    """The directed links ``(sender, receiver)`` in ``WorldState.link_*`` order: for each robot
    ``i`` in ascending id, ``(j, i)`` for its neighbours ``j`` in ascending id, then ``(0, i)``
    (the leader) if ``i`` is pinned. Robot ``i``'s ``Command.link_*`` are its run of this list."""
    out = []
    for r in sc.robots:
        out += [(j, r.id) for j in sc.neighbours(r.id)]
        if sc.is_pinned(r.id):
            out.append((0, r.id))
    return out
