"""The ROS 2 world's DDS side on the wire (loopback, multicast off): odometry in, a pose in the
wrong frame dropped and counted, differential-drive Twists out, zero Twists acknowledged."""

from __future__ import annotations

import math
import time
import tomllib

import numpy as np
import pytest

from fxswarm.core.scenario import parse
from ros2_support import dds_environment
from support import CONFIGS

from prerequisites import require_module  # noqa: E402

# Every test here speaks DDS: without Cyclone DDS the module skips at collection, which on CI
# fails unless .ci/run declared prerequisite ros2 missing (tests/prerequisites.py).
require_module("ros2")
pytestmark = pytest.mark.ros2

from cyclonedds.core import Policy, Qos  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402

from fxswarm.world import ros2  # noqa: E402
from fxswarm.world.ros2_msgs import Header_, Odometry_, Twist_  # noqa: E402


def until(condition, what: str, timeout: float = 10.0, step=None):
    """Call ``step()`` and check ``condition()`` until it holds, or fail after ``timeout`` s."""
    end = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > end:
            raise AssertionError(f"timed out waiting for {what}")
        if step is not None:
            step()
        time.sleep(0.02)


def test_odometry_in_differential_twists_out_and_a_wrong_frame_dropped(monkeypatch):
    for k, v in dds_environment().items():
        monkeypatch.setenv(k, v)
    data = tomllib.loads((CONFIGS / "ros2-square.toml").read_text())
    data["ros2"] = {"pose_topic": "/tb{id}/odom", "pose_type": "Odometry", "cmd_topic": "/tb{id}/cmd_vel",
                    "frame": "odom", "drive": "differential"}
    sc = parse(data, "turtlebots.toml")
    domain = ros2.domain_id()
    link = ros2.Ros2Link(sc, domain)
    board = ros2.PoseBoard(sc.n, 0.5, time.monotonic)

    robots = DomainParticipant(domain)  # the TurtleBots' side
    odom = [DataWriter(robots, Topic(robots, f"rt/tb{i}/odom", Odometry_)) for i in range(1, 5)]
    cmd = [DataReader(robots, Topic(robots, f"rt/tb{i}/cmd_vel", Twist_),
                      qos=Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(10))) for i in range(1, 5)]
    yaw = [0.0, math.pi / 2, 0.0, 0.0]

    def publish() -> None:
        for i, w in enumerate(odom):
            msg = Odometry_(header=Header_(frame_id="map" if i == 1 else "odom"), child_frame_id=f"tb{i + 1}")
            msg.pose.pose.position.x = float(i)
            msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = math.sin(yaw[i] / 2), math.cos(yaw[i] / 2)
            w.write(msg)
        link.read(board)

    until(lambda: board.unheard() == [2] and link.poses_dropped > 0, "robots 1, 3, 4's odometry", step=publish)
    np.testing.assert_allclose(board.p[[0, 2, 3], 0], [0.0, 2.0, 3.0])
    assert board.yaw[0] == pytest.approx(0.0)

    got: list[list] = [[] for _ in cmd]

    def take() -> None:
        for i, r in enumerate(cmd):
            got[i] += [t for t in r.take(N=16) if isinstance(t, Twist_)]

    board.yaw[1] = math.pi / 2  # robot 2 faces +y
    link.send(np.array([[0.5, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.3, 0.0]]), board.yaw)
    until(lambda: all(got), "a Twist for every robot", step=take)
    first = [g[0] for g in got]
    assert (first[0].linear.x, first[0].angular.z) == (0.5, 0.0)  # ahead: drive straight
    assert first[1].linear.x == pytest.approx(0.0, abs=1e-12) and first[1].angular.z == pytest.approx(-2.0)
    assert (first[2].linear.x, first[2].angular.z) == (0.0, 0.0)
    assert first[3].linear.x == pytest.approx(0.0, abs=1e-12) and first[3].angular.z == pytest.approx(2.0)
    assert all(t.linear.y == 0.0 and t.linear.z == 0.0 for t in first)  # a ground robot drives forward only

    assert link.stop_all() is True  # every robot acknowledged its zero Twist
    take()
    assert all(g[-1] == Twist_() for g in got)
