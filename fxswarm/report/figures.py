"""The paper's figures from a run's ``trajectory.npz``, as PNG files (matplotlib, Agg).

Each function takes the loaded trajectory (shapes as in ``WorldNode.trajectory``:
``t`` (T,), ``p``/``ph``/``offsets`` (T, n, 3), ``p0`` (T, 3), distances (T, n),
``obstacles`` (T, m, 3)) and writes one PNG; robot colours are the viewer's.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # no display, no GUI toolkit: reports are made on servers

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from fxswarm.core.metrics import estimate_errors, formation_errors  # noqa: E402
from fxswarm.logger.style import robot_hex  # noqa: E402

DPI = 110


#: Above this many robots a figure shows the swarm's spread, not a line and a legend entry per robot.
MANY_ROBOTS = 24


def _per_robot(ax, t: np.ndarray, values: np.ndarray, label: str = "robot {}") -> None:
    n = values.shape[1]
    if n > MANY_ROBOTS:  # a thousand lines are one blot: the band, the median and the worst
        import warnings

        with warnings.catch_warnings():  # a tick where no robot has a value (inf: nothing sensed)
            warnings.simplefilter("ignore", RuntimeWarning)
            lo, q10, med, q90, hi = np.nanpercentile(values, [0, 10, 50, 90, 100], axis=1)
            peak = np.nanmax(values, axis=0)
        ax.fill_between(t, lo, hi, color="#4e79a7", alpha=0.15, lw=0, label=f"all {n} robots (min to max)")
        ax.fill_between(t, q10, q90, color="#4e79a7", alpha=0.35, lw=0, label="10 % to 90 % of robots")
        ax.plot(t, med, color="#4e79a7", lw=1.4, label="median robot")
        worst = int(np.nanargmax(peak)) if np.isfinite(peak).any() else 0
        ax.plot(t, values[:, worst], color="#e15759", lw=1.0, label=f"robot {worst + 1} (largest)")
        return
    for i in range(n):
        ax.plot(t, values[:, i], color=robot_hex(i), lw=1.2, label=label.format(i + 1))


def _save(fig, path: Path, law: str | None = None) -> Path:
    if law is not None:  # which controller flew: runs of several laws side by side stay apart
        fig.suptitle(f"law: {law}", fontsize=10, x=0.99, ha="right")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def formation_error(traj: dict, out: Path, tolerance: float | None = None, settle_s: float | None = None,
                    law: str | None = None) -> Path:
    """Fig. 6: ``|e_i| = |p_i - p0 - p_i0(t)|`` per robot against time."""
    t, err = traj["t"], formation_errors(traj)
    fig, (ax, ax_log) = plt.subplots(1, 2, figsize=(11, 4))
    _per_robot(ax, t, err)
    _per_robot(ax_log, t, np.maximum(err, 1e-6))
    ax_log.set_yscale("log")
    for a in (ax, ax_log):
        if tolerance is not None:
            a.axhline(tolerance, color="0.4", ls=":", lw=1, label=f"tolerance {tolerance:g} m")
        if settle_s is not None:
            a.axvline(settle_s, color="0.2", ls="--", lw=1, label=f"settled {settle_s:.2f} s")
        a.set_xlabel("t (s)")
        a.grid(alpha=0.3)
    ax.set_ylabel("formation error |e_i| (m)")
    ax.set_title("formation error per robot (paper Fig. 6)")
    ax_log.set_title("same, log scale")
    ax.legend(fontsize=8, ncol=2)
    return _save(fig, out, law)


def obstacle_distances(traj: dict, out: Path, d: float, law: str | None = None) -> Path:
    """Fig. 8: each robot's distance to its nearest obstacle, and to its nearest object, with ``d``."""
    t = traj["t"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, key, title in ((axes[0], "obstacle_distance", "to the nearest obstacle (paper Fig. 8)"),
                           (axes[1], "nearest_distance", "to the nearest object (obstacle or teammate)")):
        dist = np.where(np.isfinite(traj[key]), traj[key], np.nan)
        _per_robot(ax, t, dist)
        ax.axhline(d, color="#e15759", lw=1.5, ls="--", label=f"d = {d:g} m")
        ax.set_title(title)
        ax.set_xlabel("t (s)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("distance (m)")
    top = np.nanpercentile(np.where(np.isfinite(traj["obstacle_distance"]), traj["obstacle_distance"], np.nan), 90) \
        if np.isfinite(traj["obstacle_distance"]).any() else 4 * d
    axes[0].set_ylim(0, max(3 * d, float(top)))
    axes[0].legend(fontsize=8, ncol=2)
    return _save(fig, out, law)


def _sphere(ax, centre: np.ndarray, r: float, colour: str) -> None:
    u, v = np.mgrid[0:2 * np.pi:24j, 0:np.pi:12j]
    ax.plot_surface(centre[0] + r * np.cos(u) * np.sin(v), centre[1] + r * np.sin(u) * np.sin(v),
                    centre[2] + r * np.cos(v), color=colour, alpha=0.18, linewidth=0)


def trajectories_3d(traj: dict, out: Path, d: float, law: str | None = None) -> Path:
    """Fig. 9: robots' paths in 3D, the leader's, and the obstacles as spheres of radius ``d``."""
    p, p0, obstacles = traj["p"], traj["p0"], traj["obstacles"]
    fig = plt.figure(figsize=(7.5, 7))
    ax = fig.add_subplot(projection="3d")
    n = p.shape[1]
    if n > MANY_ROBOTS:  # thin paths of up to 200 robots, one legend entry; every start and end
        step = -(-n // 200)
        for i in range(0, n, step):
            ax.plot(p[:, i, 0], p[:, i, 1], p[:, i, 2], color=robot_hex(i), lw=0.4, alpha=0.5,
                    label=(f"{n} robots" if step == 1 else f"every {step}th robot of {n}") if i == 0 else None)
        ax.scatter(*p[0].T, color="0.4", marker="o", s=4, label="start")
        ax.scatter(*p[-1].T, color="k", marker="^", s=6, label="end")
    for i in range(n if n <= MANY_ROBOTS else 0):
        ax.plot(p[:, i, 0], p[:, i, 1], p[:, i, 2], color=robot_hex(i), lw=1.3, label=f"robot {i + 1}")
        ax.scatter(*p[0, i], color=robot_hex(i), marker="o", s=18)
        ax.scatter(*p[-1, i], color=robot_hex(i), marker="^", s=28)
    ax.plot(p0[:, 0], p0[:, 1], p0[:, 2], color="k", ls="--", lw=1, label="virtual leader")
    if obstacles.shape[1]:
        moving = not np.allclose(obstacles[0], obstacles[-1])
        for k in range(obstacles.shape[1]):
            if moving:
                ax.plot(obstacles[:, k, 0], obstacles[:, k, 1], obstacles[:, k, 2], color="#c8503c", lw=0.8)
            _sphere(ax, obstacles[-1 if moving else 0, k], d, "#c8503c")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_title("trajectories with obstacles (radius d) (paper Fig. 9)")
    span = np.ptp(p.reshape(-1, 3), axis=0)
    horizontal = max(span[0], span[1], 1.0)
    ax.set_box_aspect((max(span[0], 1), max(span[1], 1), min(max(span[2], 1), 1.6 * horizontal)))
    ax.legend(fontsize=8, loc="upper left")
    return _save(fig, out, law)


def estimate_error(traj: dict, out: Path, settle_s: float | None = None, law: str | None = None) -> Path:
    """``|ph_i - p0|`` per robot against time, log scale: convergence and the sign term's chatter."""
    t, err = traj["t"], estimate_errors(traj)
    fig, ax = plt.subplots(figsize=(8, 4))
    _per_robot(ax, t, np.maximum(err, 1e-9))
    ax.set_yscale("log")
    if settle_s is not None:
        ax.axvline(settle_s, color="0.2", ls="--", lw=1, label=f"settled {settle_s:.2f} s")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("estimate error |ph_i - p0| (m)")
    ax.set_title("distributed estimator: error of each robot's leader estimate")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8, ncol=2)
    return _save(fig, out, law)


def settling_vs_initial_error(rows: list[dict], out: Path) -> Path:
    """Settling time against initial error (log x), one line per variant and settling kind.

    ``rows``: normalised sweep rows (see :func:`fxswarm.report.sweep_rows`).
    """
    fig, ax = plt.subplots(figsize=(8, 4.5))
    variants = sorted({r["variant"] for r in rows})
    markers = {"formation": "o", "estimator": "s"}
    styles = {"formation": "-", "estimator": "--"}
    for k, variant in enumerate(variants):
        colour = robot_hex(k)
        for kind in ("formation", "estimator"):
            pts = sorted((r["initial_error"], r[kind]) for r in rows
                         if r["variant"] == variant and r.get(kind) is not None and r["initial_error"] > 0)
            if not pts:
                continue
            x, y = zip(*pts)
            ax.plot(x, y, styles[kind], marker=markers[kind], color=colour, label=f"{variant}: {kind}")
        unsettled = [r["initial_error"] for r in rows if r["variant"] == variant and r.get("formation") is None]
        if unsettled:
            ax.scatter(unsettled, [0] * len(unsettled), marker="x", color=colour, label=f"{variant}: never settled")
    ax.set_xscale("log")
    ax.set_xlabel("initial error (m)")
    ax.set_ylabel("settling time (s)")
    ax.set_title("settling time against initial error: bounded (fixed time) vs growing")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    return _save(fig, out)
