"""Analytic paths: the virtual leader, the desired offsets, moving obstacles.

Each path is a frozen dataclass with ``position(t)`` and ``velocity(t)``
(shape (3,), metres and metres per second, ``t`` in seconds); velocities are
exact derivatives, not finite differences, because the control law feeds
them forward.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


def _vec(x) -> np.ndarray:
    return np.asarray(x, dtype=float).reshape(3)


@dataclass(frozen=True)
class Static:
    """A point that does not move."""

    point: tuple[float, float, float]

    def position(self, t: float) -> np.ndarray:
        return _vec(self.point)

    def velocity(self, t: float) -> np.ndarray:
        return np.zeros(3)

    def max_speed_inf(self, duration: float) -> float:
        return 0.0


@dataclass(frozen=True)
class ConstantVelocity:
    """``start + velocity * t``."""

    start: tuple[float, float, float]
    vel: tuple[float, float, float]

    def position(self, t: float) -> np.ndarray:
        return _vec(self.start) + _vec(self.vel) * t

    def velocity(self, t: float) -> np.ndarray:
        return _vec(self.vel)

    def max_speed_inf(self, duration: float) -> float:
        return float(np.max(np.abs(self.vel)))


@dataclass(frozen=True)
class Helix:
    """``centre + [R cos(w t + phi), R sin(w t + phi), climb t]``: the paper's leader."""

    centre: tuple[float, float, float]
    radius: float
    rate: float  # angular rate w, rad/s
    climb: float  # vertical speed, m/s
    phase: float = 0.0

    def position(self, t: float) -> np.ndarray:
        a = self.rate * t + self.phase
        c = self.centre
        return np.array(
            [c[0] + self.radius * math.cos(a), c[1] + self.radius * math.sin(a), c[2] + self.climb * t]
        )

    def velocity(self, t: float) -> np.ndarray:
        a = self.rate * t + self.phase
        rw = self.radius * self.rate
        return np.array([-rw * math.sin(a), rw * math.cos(a), self.climb])

    def max_speed_inf(self, duration: float) -> float:
        return max(abs(self.radius * self.rate), abs(self.climb))


@dataclass(frozen=True)
class Circle:
    """A circle in a horizontal plane: ``centre + R [cos(w t + phi), sin(w t + phi), 0]``."""

    centre: tuple[float, float, float]
    radius: float
    rate: float
    phase: float = 0.0

    def _helix(self) -> Helix:
        return Helix(self.centre, self.radius, self.rate, 0.0, self.phase)

    def position(self, t: float) -> np.ndarray:
        return self._helix().position(t)

    def velocity(self, t: float) -> np.ndarray:
        return self._helix().velocity(t)

    def max_speed_inf(self, duration: float) -> float:
        return abs(self.radius * self.rate)


@dataclass(frozen=True)
class Waypoints:
    """Piecewise-linear through ``points`` at ``times`` (s); holds the last point after."""

    times: tuple[float, ...]
    points: tuple[tuple[float, float, float], ...]

    def _segment(self, t: float) -> int:
        ts = self.times
        if t <= ts[0]:
            return -1
        for k in range(len(ts) - 1):
            if t < ts[k + 1]:
                return k
        return len(ts) - 1

    def position(self, t: float) -> np.ndarray:
        k = self._segment(t)
        if k < 0:
            return _vec(self.points[0])
        if k >= len(self.times) - 1:
            return _vec(self.points[-1])
        t0, t1 = self.times[k], self.times[k + 1]
        a = (t - t0) / (t1 - t0)
        return (1 - a) * _vec(self.points[k]) + a * _vec(self.points[k + 1])

    def velocity(self, t: float) -> np.ndarray:
        k = self._segment(t)
        if k < 0 or k >= len(self.times) - 1:
            return np.zeros(3)
        t0, t1 = self.times[k], self.times[k + 1]
        return (_vec(self.points[k + 1]) - _vec(self.points[k])) / (t1 - t0)

    def max_speed_inf(self, duration: float) -> float:
        pts = np.asarray(self.points, dtype=float)
        dts = np.diff(np.asarray(self.times, dtype=float))
        if len(dts) == 0:
            return 0.0
        return float(np.max(np.abs(np.diff(pts, axis=0)) / dts[:, None]))


@dataclass(frozen=True)
class Offset:
    """A desired offset from the leader: ``base + amplitude * sin(omega t + phase)`` per axis."""

    base: tuple[float, float, float]
    amplitude: tuple[float, float, float] = (0.0, 0.0, 0.0)
    omega: tuple[float, float, float] = (0.0, 0.0, 0.0)
    phase: tuple[float, float, float] = (0.0, 0.0, 0.0)
    _arrays: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "_arrays", tuple(_vec(x) for x in (self.base, self.amplitude, self.omega, self.phase))
        )

    def position(self, t: float) -> np.ndarray:
        return self.state(t)[0]

    def velocity(self, t: float) -> np.ndarray:
        return self.state(t)[1]

    def positions(self, t: np.ndarray) -> np.ndarray:
        """Positions at many times ``t`` (k,), shape (k, 3)."""
        base, amp, omega, phase = self._arrays
        return base + amp * np.sin(np.multiply.outer(t, omega) + phase)

    def state(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity at ``t`` in one pass (the agent needs both every tick)."""
        pos, vel = self.state_lists(t)
        return np.array(pos), np.array(vel)

    def state_lists(self, t: float) -> tuple[list[float], list[float]]:
        """:meth:`state` as ``[x, y, z]`` lists (m, m/s), for the agent's float hot path."""
        # Per-axis scalar maths: on 3-vectors it is several times cheaper than numpy calls.
        pos, vel = list(self.base), [0.0, 0.0, 0.0]
        for k in range(3):
            a = self.amplitude[k]
            if a:
                angle = self.omega[k] * t + self.phase[k]
                pos[k] += a * math.sin(angle)
                vel[k] = a * self.omega[k] * math.cos(angle)
        return pos, vel


Path = Static | ConstantVelocity | Helix | Circle | Waypoints


def offset_groups(robots) -> tuple[np.ndarray, list[tuple[tuple, np.ndarray]]]:
    """Every robot's offset base (n, 3), and the robots sharing each moving sinusoid:
    ``[((amplitude, omega, phase), robot indices)]`` in first-seen order. Arrays of offsets over
    many robots (the batch path, the logger) compute one ``math.sin`` per group, not per robot."""
    base = np.array([r.offset.base for r in robots], dtype=float).reshape(-1, 3)
    groups: dict[tuple, list[int]] = {}
    for i, r in enumerate(robots):
        o = r.offset
        if any(o.amplitude):
            groups.setdefault((tuple(o.amplitude), tuple(o.omega), tuple(o.phase)), []).append(i)
    return base, [(key, np.array(ids)) for key, ids in groups.items()]
