"""The run summary: errors, settling times, avoidance episodes, bounds, from a trajectory."""

from __future__ import annotations

import math

import numpy as np

from fxswarm.core.bounds import estimator_bound_printed, fixed_time_bound, h_of
from fxswarm.core.scenario import Scenario


def formation_errors(traj: dict[str, np.ndarray]) -> np.ndarray:
    """``|p_i - p0 - p_i0(t)|`` against the true leader, shape (ticks, n), m."""
    return np.linalg.norm(traj["p"] - traj["p0"][:, None, :] - traj["offsets"], axis=2)


def estimate_errors(traj: dict[str, np.ndarray]) -> np.ndarray:
    """``|ph_i - p0|``, shape (ticks, n), m."""
    return np.linalg.norm(traj["ph"] - traj["p0"][:, None, :], axis=2)


def settle_time(t: np.ndarray, err: np.ndarray, tol: float) -> float | None:
    """First time after which ``max_i err`` stays below ``tol`` to the end; None if never.

    t: (ticks,); err: (ticks, n) or (ticks,).
    """
    worst = err.max(axis=1) if err.ndim == 2 else err
    above = np.flatnonzero(worst >= tol)
    if len(above) == 0:
        return float(t[0]) if len(t) else None
    last = above[-1]
    if last + 1 >= len(t):
        return None
    return float(t[last + 1])


#: Gaps shorter than this (s) between two runs of the avoidance task join them into one
#: episode: in discrete time a robot held on the zone boundary flickers in and out tick by tick.
EPISODE_MERGE_GAP_S = 0.1


def avoidance_episodes(t: np.ndarray, active: np.ndarray, merge_gap: float = EPISODE_MERGE_GAP_S) -> list[dict]:
    """Runs of ``active[:, i]`` as ``{robot, start_s, end_s}`` (robot ids 1-based).

    Runs separated by less than ``merge_gap`` seconds count as one episode.
    """
    episodes = []
    for i in range(active.shape[1]):
        a = np.concatenate([[False], active[:, i], [False]]).astype(np.int8)
        starts = np.flatnonzero(np.diff(a) == 1)
        ends = np.flatnonzero(np.diff(a) == -1)  # index of the first inactive tick
        runs: list[list[float]] = []
        for s, e in zip(starts, ends):
            start_t = float(t[s])
            end_t = float(t[e]) if e < len(t) else float(t[-1])
            if runs and start_t - runs[-1][1] < merge_gap:
                runs[-1][1] = end_t
            else:
                runs.append([start_t, end_t])
        episodes += [{"robot": i + 1, "start_s": round(s0, 9), "end_s": round(s1, 9)} for s0, s1 in runs]
    return sorted(episodes, key=lambda ep: (ep["start_s"], ep["robot"]))


def _finite_or_none(x: float) -> float | None:
    return None if not math.isfinite(x) else float(x)


def summarise(sc: Scenario, traj: dict[str, np.ndarray], wall_s: float) -> dict:
    """The fields of ``summary.json`` common to ``fxswarm sim`` and ``fxswarm run``."""
    t = traj["t"]
    f_err = formation_errors(traj)
    e_err = estimate_errors(traj)
    tol = sc.settle_tolerance
    near = traj["nearest_distance"]
    obstacle_near = traj["obstacle_distance"]
    return {
        "scenario": sc.name,
        "source": sc.source,
        "robots": sc.n,
        "ticks": int(len(t)),
        "dt": sc.dt,
        "duration_s": float(len(t) * sc.dt),
        "wall_s": wall_s,
        "min_object_distance_m": _finite_or_none(float(near.min())) if near.size else None,
        "min_obstacle_distance_m": _finite_or_none(float(obstacle_near.min())) if obstacle_near.size else None,
        "formation_error_final_m": float(f_err[-1].max()),
        "estimate_error_final_m": float(e_err[-1].max()),
        "formation_settle_s": settle_time(t, f_err, tol),
        "estimate_settle_s": settle_time(t, e_err, tol),
        "settle_tolerance_m": tol,
        "avoidance_episodes": avoidance_episodes(t, traj["avoid_active"]),
        "fixed_time_bounds_s": {
            "formation": _finite_or_none(fixed_time_bound(sc.formation)),
            "avoidance": _finite_or_none(fixed_time_bound(sc.avoidance)),
            "estimator": _finite_or_none(estimator_bound_printed(h_of(sc.graph, sc.b), sc.estimator)),
        },
    }
