"""What a sweep case measures: initial errors and settling times, from a trajectory.

Settling uses :func:`fxswarm.core.metrics.settle_time` (first time after which
the worst robot's error stays below the tolerance to the end of the run):

- formation task: ``|e_i| = |p_i - ph_i - p_i0(t)|``, the error against the
  robot's *own* estimate, which is what the formation behaviour drives to zero
  (SPEC section 3) and what the formation bound of SPEC section 6 is about;
- estimator: ``|ph_i - p0|``;
- formation against the true leader ``|p_i - p0 - p_i0|``, the two combined.
"""

from __future__ import annotations

import numpy as np

from fxswarm.core.metrics import estimate_errors, formation_errors, settle_time
from fxswarm.core.scenario import Scenario


def own_formation_errors(traj: dict[str, np.ndarray]) -> np.ndarray:
    """``|p_i - ph_i - p_i0(t)|``, shape (ticks, n), m: the formation task's error."""
    return np.linalg.norm(traj["p"] - traj["ph"] - traj["offsets"], axis=2)


def initial_errors(sc: Scenario) -> dict[str, float]:
    """Worst robot's initial errors (m): against its own estimate, of its estimate, against the leader."""
    p0 = sc.leader.position(0.0)
    p = np.array([r.position for r in sc.robots])
    ph = np.array([r.estimate for r in sc.robots])
    offsets = np.array([r.offset.position(0.0) for r in sc.robots])
    return {
        "formation_task_m": float(np.linalg.norm(p - ph - offsets, axis=1).max()),
        "estimate_m": float(np.linalg.norm(ph - p0, axis=1).max()),
        "formation_true_m": float(np.linalg.norm(p - p0 - offsets, axis=1).max()),
    }


def settle_times(sc: Scenario, traj: dict[str, np.ndarray]) -> dict[str, float | None]:
    """Settling times (s; None = not settled within the run) at ``sc.settle_tolerance``."""
    t, tol = traj["t"], sc.settle_tolerance
    return {
        "formation_task_s": settle_time(t, own_formation_errors(traj), tol),
        "estimator_s": settle_time(t, estimate_errors(traj), tol),
        "formation_true_s": settle_time(t, formation_errors(traj), tol),
    }


def floors(traj: dict[str, np.ndarray], from_fraction: float = 0.5) -> dict[str, float]:
    """Steady-state error floors (m): the max over robots and over the run's last part.

    ``from_fraction = 0.5`` takes the second half, as issue 7 defines the floor.
    """
    k = int(len(traj["t"]) * from_fraction)
    return {
        "estimate_m": float(estimate_errors(traj)[k:].max()),
        "formation_task_m": float(own_formation_errors(traj)[k:].max()),
        "formation_true_m": float(formation_errors(traj)[k:].max()),
    }
