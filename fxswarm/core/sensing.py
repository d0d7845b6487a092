"""Sensing as sensors are: noise on the sensed own position and nearest object, a delay in
ticks, a range (docs/robots.md "Sensing"). Pure, seeded from the scenario's seed, so a run
replays exactly and the world node of ``fxswarm sim`` and of ``fxswarm run`` sense alike.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

#: Mixed into the scenario's seed: the sensing noise is its own stream (the fault plan's is another).
SENSING_STREAM = 37


@dataclass(frozen=True)
class Sensing:
    """``[world]`` sensing: ``pose_noise`` (m, std of the sensed own position per axis, per robot
    (n,)), ``obstacle_noise`` (m, std of the sensed nearest object's position per axis),
    ``delay`` (ticks: what a robot senses at tick k was measured at tick k - delay),
    ``range`` (m: a nearest object farther away is not sensed; None: any distance)."""

    pose_noise: tuple[float, ...] = ()
    obstacle_noise: float = 0.0
    delay: int = 0
    range: float | None = None

    @property
    def ideal(self) -> bool:
        """Whether robots sense the truth, at once, at any range (the paper's world)."""
        return not any(self.pose_noise) and self.obstacle_noise == 0.0 and self.delay == 0 and self.range is None


class Sensors:
    """The sensors of ``n`` robots: :meth:`measure` once per tick, in tick order."""

    def __init__(self, sensing: Sensing, n: int, seed: int) -> None:
        self.s = sensing
        self.rng = np.random.default_rng([seed % 2**63, SENSING_STREAM])
        self.pose_sd = np.broadcast_to(np.asarray(sensing.pose_noise or (0.0,), dtype=float), (n,))[:, None]
        self.noisy_pose = bool(self.pose_sd.any())
        self.past: deque = deque(maxlen=sensing.delay + 1)

    def measure(self, p: np.ndarray, po: np.ndarray, vo: np.ndarray, dist: np.ndarray,
                heading: np.ndarray | None, velocity: np.ndarray | None) -> tuple:
        """What each robot senses this tick from the truth: own positions ``p`` (n, 3), nearest
        objects ``po``, ``vo`` (n, 3) at distances ``dist`` (n,), headings (n,) and velocities
        (n, 3) or None. Returns ``(p, po, vo, has, heading, velocity)`` as measured ``delay``
        ticks ago (tick 0's until then): noisy positions, ``has`` (n,) bool whether the nearest
        object was in range. Draws the same random numbers every tick, used or not, so the
        stream does not depend on what is in range."""
        n = len(p)
        s = self.s
        pose = self.rng.standard_normal((n, 3))
        obj = self.rng.standard_normal((n, 3))
        p_s = p + self.pose_sd * pose if self.noisy_pose else p.copy()
        po_s = po + s.obstacle_noise * obj if s.obstacle_noise else po
        has = np.isfinite(dist) if s.range is None else dist <= s.range
        self.past.append((p_s, po_s, vo, has, None if heading is None else heading.copy(),
                          None if velocity is None else velocity.copy()))
        return self.past[0]
