"""ROS 2 over DDS: the world role as a gateway to ROS 2 robots (``fxswarm world --ros2``).

The simulated world integrates the robots; this one lets them move themselves. Everything
else is the world node's own code (:class:`~fxswarm.world.node.WorldNode`): the nearest object,
each agent's sensing, the hold rule for a silent agent, the record, the summary. Only
:meth:`GatewayWorld.move` differs: it takes the poses the robots published instead of
``p += dt * v``. Real time only. :class:`GatewayWorld` holds no DDS (:class:`Ros2Link` fills
its board and sends what it says); what it has to report goes to its ``warn``.

Safety: every rule on what may reach a robot is in :mod:`fxswarm.world.safety`.

DDS: one participant in domain ``ROS_DOMAIN_ID`` (default 0), configured by the user's own
``CYCLONEDDS_URI`` (untouched here). Poses are read best-effort (that matches a reliable and a
best-effort publisher alike), commands written reliable, keep-last 10 (ROS 2's default QoS, which
a best-effort subscriber matches too).
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable, Collection

import numpy as np
from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from fxswarm.core.drive import unicycle_command
from fxswarm.core.pacing import WallClock
from fxswarm.core.scenario import Ros2Settings, Scenario
from fxswarm.faults.plan import DegradedLimits
from fxswarm.world.node import WorldNode
from fxswarm.world.safety import STOP_ACK_TIMEOUT_S, Safety
from fxswarm.world.ros2_msgs import POSE_TYPES, Twist_, Vector3_, dds_topic, pose_of

DOMAIN_ENV = "ROS_DOMAIN_ID"


def domain_id(env: dict[str, str] | None = None) -> int:
    """ROS 2's domain: ``ROS_DOMAIN_ID`` (0 if unset), as every ROS 2 node reads it."""
    text = (os.environ if env is None else env).get(DOMAIN_ENV, "").strip()
    if not text:
        return 0
    if not text.isdigit() or int(text) > 232:  # ROS 2's range: DDS ports beyond it overflow
        raise ValueError(f"{DOMAIN_ENV}: expected an integer in 0..232, got {text!r}")
    return int(text)


def yaw_of(x: float, y: float, z: float, w: float) -> float:
    """Heading (rad) of a unit quaternion: the rotation about z."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def differential_drive(v: np.ndarray, yaw: float, heading_gain: float, omega_max: float) -> tuple[float, float]:
    """A world-frame velocity ``v`` (3,) as a differential-drive command ``(forward m/s, omega rad/s)``:
    the simulated unicycle's mapping (:func:`fxswarm.core.drive.unicycle_command`, heading form),
    so the lab robot turns a command as the world's unicycle does. The vertical part is dropped
    (a ground robot); the forward speed is limited before, with the whole velocity (:func:`limited`).
    """
    return unicycle_command(float(v[0]), float(v[1]), yaw, heading_gain, omega_max)


class PoseBoard:
    """The latest measured pose of each robot and when it came (``clock`` s): positions (n, 3),
    headings (n,)."""

    def __init__(self, n: int, timeout: float, clock: WallClock) -> None:
        self.p = np.zeros((n, 3))
        self.yaw = np.zeros(n)
        self.heard_at = np.full(n, -np.inf)
        self.timeout, self.clock = timeout, clock

    def put(self, robot: int, position: tuple[float, float, float], yaw: float) -> None:
        self.p[robot - 1] = position
        self.yaw[robot - 1] = yaw
        self.heard_at[robot - 1] = self.clock()

    def age(self) -> np.ndarray:
        """Seconds since each robot's latest pose (inf before its first)."""
        return self.clock() - self.heard_at

    def fresh(self) -> np.ndarray:
        """Whether each robot's latest pose is at most ``timeout`` s old."""
        return self.age() <= self.timeout

    def unheard(self) -> list[int]:
        """Ids of the robots with no pose yet."""
        return [int(i) + 1 for i in np.flatnonzero(np.isinf(self.heard_at))]


class GatewayWorld(WorldNode):
    """The world node on measured poses (:attr:`board`), every command made safe by :attr:`safety`."""

    def __init__(self, scenario: Scenario, board: PoseBoard, limits: DegradedLimits | None = None,
                 warn: Callable[[str], object] = lambda text: print(text, file=sys.stderr)) -> None:
        super().__init__(scenario, limits=limits)
        self.board, self.warn = board, warn
        self.safety = Safety(scenario)  # ValueError without a speed limit

    @property
    def gone(self) -> Collection[int]:
        """Robots whose agent process has left (the world process says): held at zero at once."""
        return self.safety.gone

    @gone.setter
    def gone(self, robots: Collection[int]) -> None:
        self.safety.gone = robots

    def start(self):
        self.p = self.board.p.copy()  # where the robots are, not where the scenario put them
        return super().start()

    def move(self, dt: float) -> None:
        """The robots moved themselves: take their latest poses (a stale one is kept, and its
        robot held at zero; each new stale episode is said). The held commands become what is
        sent (:meth:`Safety.safe`), so teammates sense a held robot as still."""
        fresh = self.board.fresh()
        self.p = np.where(fresh[:, None], self.board.p, self.p)
        became = self.safety.tick(fresh, self.v)
        if len(became):
            age = self.board.age()
            for i in became:
                self.warn(f"fxswarm world: robot {i + 1}'s pose is {age[i]:.2f} s old (limit "
                          f"{self.board.timeout:g} s): holding it at zero")
        self.v = self.safety.safe(self.v)
        if self.drives is not None:  # [world] drive models: the robots' own headings, and they move as sent
            if self.heading is not None:
                self.heading = np.where(fresh, self.board.yaw, self.heading)
            self.vel = self.v

    def velocities(self) -> np.ndarray:
        """The world-frame velocities to send now (n, 3): the held commands made safe (again: a
        command may have landed, on a Zenoh thread, since :meth:`move`)."""
        return self.safety.safe(self.v.copy())

    def report(self) -> dict:
        """Counters for the world's counters file."""
        per = lambda a: {str(r.id): int(x) for r, x in zip(self.sc.robots, a)}  # noqa: E731
        s = self.safety
        return {"ros2_stale_pose_ticks": per(s.stale_pose_ticks), "ros2_stale_episodes": per(s.stale_episodes),
                "ros2_limited_ticks": per(s.limited_ticks), "ros2_v_max": s.v_max}


class Ros2Link:
    """The DDS side: a participant that reads each robot's pose and writes its cmd_vel."""

    def __init__(self, sc: Scenario, domain: int) -> None:
        self.sc, self.settings = sc, sc.ros2
        s: Ros2Settings = sc.ros2
        self.participant = DomainParticipant(domain)
        self.pose_type = pose_type = POSE_TYPES[s.pose_type]
        reader_qos = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(1))
        writer_qos = Qos(Policy.Reliability.Reliable(1_000_000_000), Policy.History.KeepLast(10))
        self.readers, self.writers = [], []
        for r in sc.robots:
            pose = Topic(self.participant, dds_topic(s.topic(s.pose_topic, r.id)), pose_type)
            cmd = Topic(self.participant, dds_topic(s.topic(s.cmd_topic, r.id)), Twist_)
            self.readers.append(DataReader(self.participant, pose, qos=reader_qos))
            self.writers.append(DataWriter(self.participant, cmd, qos=writer_qos))
        self.poses_received = 0
        self.poses_dropped = 0  # wrong frame, not finite
        self.twists_sent = 0
        self._warned: set[int] = set()

    def read(self, board: PoseBoard) -> None:
        """Take every pose that arrived into ``board`` (one in the wrong frame or not finite is
        dropped, counted and said once per robot)."""
        frame = self.settings.frame
        for r, reader in zip(self.sc.robots, self.readers):
            for msg in reader.take(N=16):
                if not isinstance(msg, self.pose_type):  # an InvalidSample: a publisher left, no data
                    continue
                pose = pose_of(msg)
                position = (pose.position.x, pose.position.y, pose.position.z)
                q = pose.orientation
                values = (*position, q.x, q.y, q.z, q.w)
                if msg.header.frame_id != frame or not all(math.isfinite(x) for x in values):
                    self.poses_dropped += 1
                    if r.id not in self._warned:
                        self._warned.add(r.id)
                        print(f"fxswarm world: dropped robot {r.id}'s pose: expected frame {frame!r} and finite "
                              f"numbers, got frame {msg.header.frame_id!r}, {values}", file=sys.stderr)
                    continue
                self.poses_received += 1
                board.put(r.id, position, yaw_of(q.x, q.y, q.z, q.w))

    def send(self, v: np.ndarray, yaw: np.ndarray) -> None:
        """Write each robot's command: ``v`` (n, 3) world-frame velocities, ``yaw`` (n,) headings."""
        s = self.settings
        for i, writer in enumerate(self.writers):
            if s.drive == "differential":
                forward, omega = differential_drive(v[i], float(yaw[i]), s.heading_gain, s.omega_max)
                twist = Twist_(linear=Vector3_(forward, 0.0, 0.0), angular=Vector3_(0.0, 0.0, omega))
            else:
                twist = Twist_(linear=Vector3_(*map(float, v[i])))
            writer.write(twist)
        self.twists_sent += len(self.writers)

    def stop_all(self, timeout: float = STOP_ACK_TIMEOUT_S) -> bool:
        """Every robot: a zero Twist, then wait up to ``timeout`` s for every subscriber to
        acknowledge it; whether all did."""
        for writer in self.writers:
            writer.write(Twist_())
        self.twists_sent += len(self.writers)
        ns = int(timeout * 1e9)
        return all(writer.wait_for_acks(ns) for writer in self.writers)

    def report(self) -> dict:
        return {"ros2_poses_received": self.poses_received, "ros2_poses_dropped": self.poses_dropped,
                "ros2_twists_sent": self.twists_sent}
