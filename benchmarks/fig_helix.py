"""docs/estimator-helix-line-16.png and the table of docs/estimator.md: configs/line-16-helix.toml
over the helices of issue 39 (radius 2 and 5 m, 0.05 and 0.1 rad/s, climb 0.1 and 1 m/s),
tracking = "feedforward" on the undirected chain (before) and with estimator_graph = "oriented".

    python benchmarks/fig_helix.py docs/estimator-helix-line-16.png
"""
import itertools
import json
import sys
import tomllib
import warnings

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from fxswarm.core.metrics import estimate_errors  # noqa: E402
from fxswarm.core.scenario import parse  # noqa: E402
from fxswarm.launch.sim import Simulation  # noqa: E402

warnings.simplefilter("ignore")
base = tomllib.load(open("configs/line-16-helix.toml", "rb"))
fig, ax = plt.subplots(figsize=(8, 4))
rows = []
for R, w, c in itertools.product((2.0, 5.0), (0.05, 0.1), (0.1, 1.0)):
    for graph in ("undirected", "oriented"):
        raw = json.loads(json.dumps(base))
        raw["leader"] |= {"radius": R, "rate": w, "climb": c}
        raw["estimator"]["estimator_graph"] = graph
        sim = Simulation(parse(raw, "helix"))
        s = sim.run()
        rows.append((R, w, c, graph, s["estimate_error_final_m"], s["formation_error_final_m"]))
        print(*rows[-1], flush=True)
        if (R, w, c) == (5.0, 0.1, 1.0):
            tr = sim.trajectory()
            err = estimate_errors(tr).max(axis=1)
            ax.semilogy(tr["t"], np.maximum(err, 1e-3), label=f'feedforward, estimator_graph = "{graph}"')
ax.axhline(0.2, color="grey", ls="--", lw=1)
ax.set_xlabel("t (s)")
ax.set_ylabel("worst estimate error |ph_i - p0| (m)")
ax.set_title("line-16, leader on a helix: radius 5 m, 0.1 rad/s, climb 1 m/s")
ax.legend()
fig.tight_layout()
fig.savefig(sys.argv[1], dpi=110)
