"""docs/resilience-liar-8.png: one drifting liar on liar-8, the paper's law against W-MSR."""
import sys, tomllib
import numpy as np
import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
from fxswarm.core.scenario import parse
from fxswarm.core.metrics import formation_errors
from fxswarm.faults.plan import resolve
from fxswarm.launch.sim import Simulation

def run(path, resilient, lie=True):
    data = tomllib.load(open(path, "rb"))
    if resilient:
        data["estimator"] |= {"resilience": "w-msr", "tolerate": 1}
    sc = parse(data, path)
    plan = resolve(sc, ["lie agent:3 at=5 drift=0.5,0,0"] if lie else [])
    sim = Simulation(sc, plan)
    s = sim.run()
    tr = sim.trajectory()
    return tr, s

fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=False)
PANELS = ((axes[0], "configs/liar-8.toml", "liar-8 (meets the condition for F = 1)"),
          (axes[1], "configs/paper-fast.toml", "paper-fast ring (does not)"))
for ax, path, title in PANELS:
    for resilient, colour, name in ((False, "tab:red", "paper's estimator"), (True, "tab:blue", 'resilience = "w-msr"')):
        tr, s = run(path, resilient)
        err = formation_errors(tr)
        honest = [i for i in range(err.shape[1]) if i != 2]
        ax.semilogy(tr["t"], np.maximum(err[:, honest].max(axis=1), 1e-3), color=colour, label=name)
        print(path, name, "honest final formation error", s["resilience"]["honest_formation_error_final_m"],
              "min object", s["resilience"]["honest_min_object_distance_m"], "discarded", s["resilience"]["discarded"])
    ax.axvline(5.0, color="grey", ls=":", lw=1)
    ax.axhline(0.3, color="grey", ls="--", lw=1)
    ax.set_title(title)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("worst honest robot's formation error (m)")
    ax.legend()
fig.suptitle("robot 3 lies from t = 5 s: its estimate drifts 0.5 m/s along x (lie agent:3 at=5 drift=0.5,0,0)")
fig.tight_layout()
fig.savefig(sys.argv[1], dpi=110)
