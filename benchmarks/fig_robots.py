"""docs/robots.md's worked example: configs/paper-fast.toml in the paper's ideal world against
the same swarm as unicycles (omega_max 2 rad/s) with 2 cm pose noise, and as double integrators
(a_max 1 m/s^2). Draws docs/robots-paper-fast.png and prints each run's figures as JSON.

    .venv/bin/python benchmarks/fig_robots.py [--out docs/robots-paper-fast.png]
"""

from __future__ import annotations

import argparse
import json
import tomllib
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from fxswarm.core.metrics import formation_errors  # noqa: E402
from fxswarm.core.scenario import parse  # noqa: E402
from fxswarm.launch.sim import Simulation  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
WORLDS = {
    "ideal (single integrator, exact sensing)": None,
    "unicycles, 2 cm pose noise": {"model": "unicycle", "omega_max": 2.0, "pose_noise": 0.02},
    "double integrators, a_max 1 m/s^2": {"model": "double-integrator", "a_max": 1.0},
}
KEYS = ("formation_error_final_m", "formation_settle_s", "min_object_distance_m", "max_formation_error_after_settle_m")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=str(ROOT / "docs" / "robots-paper-fast.png"))
    args = p.parse_args()
    base = tomllib.loads((ROOT / "configs" / "paper-fast.toml").read_text())
    fig, (ax_err, ax_xy) = plt.subplots(1, 2, figsize=(12, 4.6))
    figures = {}
    for (label, world), colour in zip(WORLDS.items(), ("0.4", "tab:blue", "tab:orange")):
        data = dict(base) | ({"world": world} if world else {})
        sim = Simulation(parse(data, "configs/paper-fast.toml"))
        summary = sim.run()
        figures[label] = {k: summary.get(k) for k in KEYS} | {"world": summary.get("world")}
        tr = sim.trajectory()
        ax_err.semilogy(tr["t"], formation_errors(tr).max(axis=1), color=colour, label=label)
        for i in range(tr["p"].shape[1]):
            ax_xy.plot(tr["p"][:, i, 0], tr["p"][:, i, 1], color=colour, lw=0.8, label=label if i == 0 else None)
        if "heading" in tr:  # the unicycles' headings every 2 s, as short arrows
            k = np.arange(0, len(tr["t"]), 200)
            yaw, p = tr["heading"][k], tr["p"][k]
            ax_xy.quiver(p[..., 0], p[..., 1], np.cos(yaw), np.sin(yaw), color=colour, scale=25, width=0.004)
    ax_err.axhline(base["scenario"]["settle_tolerance"], color="k", ls=":", lw=0.8, label="settle tolerance")
    ax_err.set(xlabel="t (s)", ylabel="max formation error (m)", title="formation error, paper-fast")
    ax_err.legend(fontsize=8)
    ax_xy.set(xlabel="x (m)", ylabel="y (m)", title="robots seen from above (arrows: unicycle headings)",
              aspect="equal")
    ax_xy.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(args.out, dpi=90)
    print(json.dumps(figures, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
