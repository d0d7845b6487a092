"""``fxswarm run --ros2``: a run shown to ROS 2 tools (RViz, Foxglove, rosbag2) from the world
states the launcher hears. The launcher's, not the world's: it flies nothing (docs/ros2.md).
Needs the ros2 extra (Cyclone DDS): import it after
:func:`fxswarm.world.process.ros2_module_or_exit` has checked that it is there.
"""

from __future__ import annotations

import math

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

from fxswarm.core.messages import WorldState
from fxswarm.core.scenario import Scenario
from fxswarm.world.ros2_msgs import (MARKER_ADD, MARKER_SPHERE, ColorRGBA_, Header_, Marker_, MarkerArray_, Point_,
                                     Pose_, PoseStamped_, Vector3_, dds_topic, time_msg)

#: Where :class:`Ros2View` publishes (ROS 2 topic names; ``{id}``: the robot's id).
VIEW_TOPICS = {"robot": "/fxswarm/robot{id}/pose", "estimate": "/fxswarm/robot{id}/estimate",
               "leader": "/fxswarm/leader/pose", "obstacles": "/fxswarm/obstacles"}


class Ros2View:
    """A run as standard ROS 2 messages, for RViz, Foxglove and rosbag2 (docs/ros2.md).

    From each world state (at most one per ``period`` s of simulation time): each robot's pose
    and estimate (``geometry_msgs/PoseStamped``), the virtual leader's pose (from the scenario's
    path, as every robot's estimate tracks it) and the obstacles (``visualization_msgs/MarkerArray``,
    spheres of the repulsive radius ``d``). Frame ``[ros2] frame``, stamps in simulation time.
    Reliable, keep-last 10: a reliable or a best-effort subscriber matches.
    """

    def __init__(self, sc: Scenario, domain: int, period: float = 0.02) -> None:
        self.sc, self.frame, self.period = sc, sc.ros2.frame, period
        self.participant = DomainParticipant(domain)
        qos = Qos(Policy.Reliability.Reliable(100_000_000), Policy.History.KeepLast(10))

        def writer(topic: str, kind):
            return DataWriter(self.participant, Topic(self.participant, dds_topic(topic), kind), qos=qos)

        ids = [r.id for r in sc.robots]
        self.robots = [writer(VIEW_TOPICS["robot"].replace("{id}", str(i)), PoseStamped_) for i in ids]
        self.estimates = [writer(VIEW_TOPICS["estimate"].replace("{id}", str(i)), PoseStamped_) for i in ids]
        self.leader = writer(VIEW_TOPICS["leader"], PoseStamped_)
        self.obstacles = writer(VIEW_TOPICS["obstacles"], MarkerArray_)
        self.next_t = -math.inf
        self.published = 0  # world states published

    def publish(self, state: WorldState) -> bool:
        """Publish ``state`` if a period of simulation time has passed since the last; whether it did."""
        if state.t < self.next_t or len(state.p) != self.sc.n:
            return False
        self.next_t = state.t + self.period - 1e-9
        header = Header_(stamp=time_msg(max(state.t, 0.0)), frame_id=self.frame)

        def pose(p) -> PoseStamped_:
            return PoseStamped_(header=header, pose=Pose_(position=Point_(*map(float, p))))

        for w, p in zip(self.robots, state.p):
            w.write(pose(p))
        for w, ph in zip(self.estimates, state.ph):
            w.write(pose(ph))
        self.leader.write(pose(self.sc.leader.position(state.t)))
        d = 2.0 * self.sc.d
        self.obstacles.write(MarkerArray_(markers=[
            Marker_(header=header, ns="obstacles", id=k, type=MARKER_SPHERE, action=MARKER_ADD,
                    pose=Pose_(position=Point_(*map(float, o))), scale=Vector3_(d, d, d),
                    color=ColorRGBA_(0.9, 0.2, 0.2, 0.4))
            for k, o in enumerate(state.obstacles)]))
        self.published += 1
        return True
