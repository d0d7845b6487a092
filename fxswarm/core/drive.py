"""Robot drive models: how a law's world-frame velocity becomes motion (docs/robots.md).

Pure functions and one frozen settings class, no I/O. The world node integrates its robots
with :func:`step_unicycle` and :func:`step_double_integrator` (the single integrator,
``p += dt v``, stays in the world node, untouched); the ROS 2 gateway's ``drive =
"differential"`` sends what :func:`unicycle_command` gives, so the simulated unicycle and
the lab's differential-drive robot turn the same velocity into the same command.

Units: m, s, rad. Headings are yaw angles about +z from +x.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: The drive models a scenario may name (``[world] model``, ``[[robots]] model``).
MODELS = ("single-integrator", "unicycle", "double-integrator")


@dataclass(frozen=True)
class Drive:
    """One robot's drive model and its limits.

    ``model``: one of :data:`MODELS`; ``v_max``: speed limit, m/s (None: none);
    unicycle: ``omega_max`` yaw-rate limit (rad/s), ``heading_gain`` (1/s), ``lookahead``
    (m; > 0: the look-ahead-point form), ``planar`` (the vertical command is dropped: a
    ground robot); double integrator: ``a_max`` (m/s^2, None: none), ``tau`` first-order lag
    of the velocity (s; 0: none).
    """

    model: str = "single-integrator"
    v_max: float | None = None
    omega_max: float = 2.0
    heading_gain: float = 2.0
    lookahead: float = 0.0
    planar: bool = False
    a_max: float | None = None
    tau: float = 0.0


def unicycle_command(vx: float, vy: float, heading: float, heading_gain: float, omega_max: float,
                     v_max: float | None = None, lookahead: float = 0.0) -> tuple[float, float]:
    """The world-frame planar velocity ``(vx, vy)`` (m/s) as a unicycle's ``(forward speed m/s,
    yaw rate rad/s)`` at ``heading`` (rad): the one mapping of the simulated unicycle and the
    ROS 2 gateway's differential drive.

    Heading form (``lookahead`` = 0): turn toward the velocity's direction at ``heading_gain``
    times the heading error ``e`` (wrapped to [-pi, pi]), and drive forward at ``|v| cos e``,
    never backward (a robot facing away turns in place first). Look-ahead form (``lookahead``
    = L > 0): the point L ahead of the axle is steered as a single integrator,
    ``u = vx cos th + vy sin th``, ``omega = (-vx sin th + vy cos th) / L``. The yaw rate is
    limited to ``omega_max``, the forward speed to ``v_max`` (None: not limited).
    """
    if lookahead > 0.0:
        c, s = math.cos(heading), math.sin(heading)
        forward, omega = vx * c + vy * s, (vy * c - vx * s) / lookahead
    else:
        speed = math.hypot(vx, vy)
        if speed < 1e-9:
            return 0.0, 0.0
        error = math.remainder(math.atan2(vy, vx) - heading, math.tau)
        forward, omega = speed * max(math.cos(error), 0.0), heading_gain * error
    if v_max is not None:
        forward = max(-v_max, min(v_max, forward))
    return forward, max(-omega_max, min(omega_max, omega))


def step_unicycle(p: np.ndarray, heading: np.ndarray, v: np.ndarray, dt: float,
                  drives: list[Drive]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One explicit Euler step of the unicycles ``p`` (k, 3), ``heading`` (k,) on the
    commanded world-frame velocities ``v`` (k, 3), robot ``i`` with ``drives[i]``:
    ``(forward, omega) = unicycle_command(...)``; ``x += dt forward cos th``,
    ``y += dt forward sin th``, ``z += dt v_z`` (0 if planar), ``th += dt omega``. With a
    look-ahead L the state is the look-ahead point, ``p = axle + L [cos th, sin th, 0]``.

    Returns ``(p, heading, velocity, speed_limited, omega_limited)``: the new state, the
    world-frame velocity it moved at (k, 3), and per robot whether the forward speed / the
    yaw rate was at its limit (bool (k,)).
    """
    k = len(p)
    p_new, th_new, vel = np.empty((k, 3)), np.empty(k), np.empty((k, 3))
    at_v, at_w = np.zeros(k, dtype=bool), np.zeros(k, dtype=bool)
    for i, (pi, th, vi, dr) in enumerate(zip(p.tolist(), heading.tolist(), v.tolist(), drives)):
        forward, omega = unicycle_command(vi[0], vi[1], th, dr.heading_gain, dr.omega_max, dr.v_max, dr.lookahead)
        vz = 0.0 if dr.planar else vi[2]
        if dr.v_max is not None:
            at_v[i] = abs(forward) >= dr.v_max - 1e-12
            if abs(vz) > dr.v_max:  # the climb rate is limited as the forward speed
                vz, at_v[i] = math.copysign(dr.v_max, vz), True
        at_w[i] = abs(omega) >= dr.omega_max - 1e-12
        c, s = math.cos(th), math.sin(th)
        th1 = th + dt * omega
        if dr.lookahead > 0.0:
            L = dr.lookahead
            ax, ay = pi[0] - L * c + dt * forward * c, pi[1] - L * s + dt * forward * s
            x, y = ax + L * math.cos(th1), ay + L * math.sin(th1)
            vel[i] = ((x - pi[0]) / dt, (y - pi[1]) / dt, vz)
        else:
            x, y = pi[0] + dt * forward * c, pi[1] + dt * forward * s
            vel[i] = (forward * c, forward * s, vz)
        p_new[i] = (x, y, pi[2] + dt * vz)
        th_new[i] = th1
    return p_new, th_new, vel, at_v, at_w


def step_double_integrator(p: np.ndarray, vel: np.ndarray, v: np.ndarray, dt: float,
                           drives: list[Drive]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One semi-implicit Euler step of the double integrators ``p``, ``vel`` (k, 3) tracking the
    commanded velocities ``v`` (k, 3): the command limited to ``v_max``; the acceleration
    ``a = (v - vel) / max(tau, dt)`` (a first-order lag of time constant ``tau``; with tau = 0
    the command is reached in one step if ``a_max`` allows), its norm limited to ``a_max``;
    ``vel += dt a``; ``p += dt vel`` (the new velocity: with no limits this is the single
    integrator exactly).

    Returns ``(p, vel, speed_limited, accel_limited)``, the last two bool (k,).
    """
    target = v.copy()
    at_v = _clip_norms(target, np.array([np.inf if d.v_max is None else d.v_max for d in drives]))
    tau = np.array([max(d.tau, dt) for d in drives])
    a = (target - vel) / tau[:, None]
    at_a = _clip_norms(a, np.array([np.inf if d.a_max is None else d.a_max for d in drives]))
    vel_new = vel + dt * a
    return p + dt * vel_new, vel_new, at_v, at_a


def _clip_norms(x: np.ndarray, limit: np.ndarray) -> np.ndarray:
    """Scale each row of ``x`` (k, 3) longer than its ``limit`` (k,) down to it, in place; which were."""
    norm = np.sqrt(np.einsum("ij,ij->i", x, x))
    over = norm > limit
    if over.any():
        x[over] *= (limit[over] / norm[over])[:, None]
    return over
