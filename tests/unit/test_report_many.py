"""``fxswarm report`` figures stay readable at a thousand robots: the swarm's spread and its
worst robot, a short legend, not a line and a legend entry per robot."""

import numpy as np

from fxswarm.report import figures


def swarm_trajectory(n: int, ticks: int = 12) -> dict:
    rng = np.random.default_rng(1)
    t = np.arange(ticks) * 0.1
    p0 = np.stack([t, 0 * t, 0.5 * t], axis=1)
    offsets = np.repeat(rng.uniform(-10, 10, (1, n, 3)), ticks, axis=0)
    decay = np.exp(-t)[:, None, None]
    p = p0[:, None, :] + offsets + decay * rng.normal(size=(1, n, 3))
    near = np.abs(rng.normal(2.0, 0.5, (ticks, n)))
    near[:, n // 2] = np.inf  # a robot sensing nothing
    return {"t": t, "p": p, "ph": p0[:, None, :] + decay * rng.normal(size=(1, n, 3)), "p0": p0,
            "offsets": offsets, "nearest_distance": near, "obstacle_distance": near + 1.0,
            "obstacles": np.zeros((ticks, 2, 3)) + [0.0, 0.0, 5.0]}


def test_figures_of_hundreds_of_robots_show_the_spread_with_a_short_legend(tmp_path, monkeypatch):
    kept = []
    real_save = figures._save
    monkeypatch.setattr(figures, "_save", lambda fig, path, law=None: kept.append(fig) or real_save(fig, path, law))
    traj = swarm_trajectory(300)  # any swarm above MANY_ROBOTS; 1000 draws the same, slower
    figures.formation_error(traj, tmp_path / "f.png", tolerance=0.2)
    figures.estimate_error(traj, tmp_path / "e.png")
    figures.obstacle_distances(traj, tmp_path / "o.png", d=1.0)
    figures.trajectories_3d(traj, tmp_path / "t.png", d=1.0)
    for fig in kept:
        for ax in fig.axes:
            legend = ax.get_legend()
            if legend is not None:
                assert len(legend.get_texts()) <= 8, [x.get_text() for x in legend.get_texts()]
        assert (tmp_path / "f.png").stat().st_size > 10_000
    labels = [x.get_text() for x in kept[0].axes[0].get_legend().get_texts()]
    assert "all 300 robots (min to max)" in labels and any("(largest)" in x for x in labels)
    small = swarm_trajectory(6)  # a small swarm keeps its line per robot
    kept.clear()
    figures.formation_error(small, tmp_path / "s.png")
    assert [x.get_text() for x in kept[0].axes[0].get_legend().get_texts()] == [f"robot {i}" for i in range(1, 7)]
