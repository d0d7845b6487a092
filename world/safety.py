"""What may reach a real robot: the ROS 2 gateway's safety rules, all of them here (pure, no DDS).

- A speed limit is required: ``[ros2] v_max``, else ``[scenario] v_max`` (:func:`speed_limit`);
  a scenario without one is refused before anything starts (:func:`require_speed_limit`).
- Every command is limited to it, direction kept (:func:`limited`).
- A robot whose pose is older than ``[ros2] pose_timeout``, or whose agent process is gone, is
  sent zero (:class:`Safety`). A silent agent's command is zeroed before that, by the world's
  hold rule (:class:`~fxswarm.world.node.WorldNode`, the same as in simulation).
- On every way out of the world process (end of run, SIGINT/SIGTERM, a crash) every robot is
  sent a zero Twist and the world waits for the robots to acknowledge it
  (:data:`STOP_ACK_TIMEOUT_S`; the sending is DDS, :meth:`fxswarm.world.ros2.Ros2Link.stop_all`).
  A SIGKILL leaves nothing to do that: robots need their own cmd_vel timeout.
"""

from __future__ import annotations

from collections.abc import Collection

import numpy as np

from fxswarm.core.scenario import Scenario

STOP_ACK_TIMEOUT_S = 1.0  # how long the world waits for the robots to acknowledge the zero Twist


def speed_limit(sc: Scenario) -> float | None:
    """The limit on every command sent to a robot, m/s: ``[ros2] v_max``, else ``[scenario] v_max``."""
    return sc.ros2.v_max if sc.ros2.v_max is not None else sc.v_max


def require_speed_limit(sc: Scenario) -> float:
    """:func:`speed_limit`, or ValueError naming the file and the fields: real robots need one."""
    v_max = speed_limit(sc)
    if v_max is None:
        raise ValueError(f"{sc.source}: ros2.v_max: expected a speed limit (m/s) for real robots, in [ros2] v_max "
                         "or [scenario] v_max")
    return v_max


def limited(v: np.ndarray, v_max: float) -> np.ndarray:
    """``v`` (n, 3) with each row's norm scaled down to at most ``v_max`` m/s (direction kept)."""
    speed = np.linalg.norm(v, axis=1)
    scale = np.minimum(1.0, v_max / np.maximum(speed, 1e-12))
    return v * scale[:, None]


class Safety:
    """The rules above for ``n`` robots, with counters; :meth:`safe` is what may be sent."""

    def __init__(self, sc: Scenario) -> None:
        self.v_max = require_speed_limit(sc)
        self.gone: Collection[int] = ()  # robots whose agent process has left: held at zero at once
        self.stale = np.zeros(sc.n, dtype=bool)  # robots whose pose is too old now
        self.stale_pose_ticks = np.zeros(sc.n, dtype=int)
        self.stale_episodes = np.zeros(sc.n, dtype=int)
        self.limited_ticks = np.zeros(sc.n, dtype=int)  # ticks a command was above v_max

    def tick(self, fresh: np.ndarray, v: np.ndarray) -> np.ndarray:
        """A tick with these poses ``fresh`` (n,) and commands ``v`` (n, 3): count it; return the
        robots whose pose has just gone stale (a new episode, for the caller to say)."""
        became = ~fresh & ~self.stale
        self.stale_episodes += became
        self.stale = ~fresh
        self.stale_pose_ticks += self.stale
        self.limited_ticks += np.linalg.norm(v, axis=1) > self.v_max + 1e-9
        return np.flatnonzero(became)

    def safe(self, v: np.ndarray) -> np.ndarray:
        """Velocities ``v`` (n, 3) as they may reach the robots: limited to ``v_max``, zero for a
        robot whose agent is gone or whose pose is stale."""
        v = limited(v, self.v_max)
        v[self.stale] = 0.0
        for r in self.gone:
            v[r - 1] = 0.0
        return v
