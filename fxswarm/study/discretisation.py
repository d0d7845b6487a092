"""The discretisation study: steady-state error floors of explicit Euler and the semi-implicit step.

A *floor* is the worst robot's error over the second half of a run
(:func:`fxswarm.study.measure.floors`), once every transient is over. Each case
is a scenario with one thing changed (control period ``dt``, leader climb
rate, or the discretisation) and is reported beside the lower limit
``hops * dt * |dp0/dt|``: information crosses the graph one hop per tick while
the leader keeps moving, so no step of this information pattern can do better
(``hops`` = the largest graph distance from a robot to a pinned robot, plus one
for the leader link).

Each case may also set the estimator's ``tracking`` (``"feedforward"``: the leader's velocity
observed and fed forward, docs/estimator.md), which removes the hop-dependent lag that sets
Euler's floor on long graphs.

Floors are measured without obstacles unless a case keeps them: the paper's
obstacles sit where the second half of ``paper.toml`` passes them, and an
avoidance episode is not a discretisation floor.
"""

from __future__ import annotations

import copy
import math
import time
import warnings

import numpy as np

from fxswarm.core.graph import hops_to_leader
from fxswarm.core.scenario import Scenario, ScenarioWarning, parse
from fxswarm.study.measure import floors, settle_times


def graph_hops(sc: Scenario) -> int:
    """Ticks for the leader's position to reach the farthest robot: its hops to a pinned robot, plus one."""
    return int(hops_to_leader(sc.graph, sc.b).max()) + 1


def leader_speed_max(sc: Scenario) -> float:
    """``max_t |dp0/dt|`` over the run, sampled at the control ticks, m/s."""
    t = np.arange(sc.ticks) * sc.dt
    return float(max(np.linalg.norm(sc.leader.velocity(x)) for x in t[:: max(1, len(t) // 2000)]))


def case_toml(
    raw: dict,
    discretisation: str,
    dt: float | None = None,
    duration: float | None = None,
    climb: float | None = None,
    obstacles: bool = False,
    tracking: str | None = None,
) -> dict:
    """A copy of scenario TOML ``raw`` with the study's knobs set (None = keep the scenario's)."""
    out = copy.deepcopy(raw)
    out["controller"] = dict(out.get("controller", {}), discretisation=discretisation)
    if tracking is not None:
        out["estimator"] = dict(out.get("estimator", {}), tracking=tracking)
    if dt is not None:
        out["scenario"]["dt"] = float(dt)
    if duration is not None:
        out["scenario"]["duration"] = float(duration)
    if climb is not None:
        if out["leader"].get("kind") != "helix":
            raise ValueError("varying the leader's speed needs a helix leader (its 'climb', m/s)")
        out["leader"]["climb"] = float(climb)
    if not obstacles:
        out.pop("obstacles", None)
    return out


def run_floor_case(raw: dict, source: str, series: str) -> dict:
    """Run one case; its floors, settle times and the lower limit (one row of the benchmark JSON)."""
    from fxswarm.launch.sim import Simulation  # in the (spawned) worker

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ScenarioWarning)
        sc = parse(raw, source)
    start = time.perf_counter()
    sim = Simulation(sc, path="auto")  # the batch path when it takes the case: the same trajectory, faster
    summary = sim.run()
    traj = sim.trajectory()
    speed = leader_speed_max(sc)
    hops = graph_hops(sc)
    return {
        "series": series,
        "source": source,
        "discretisation": sc.discretisation,
        "tracking": sc.tracking,
        "dt": sc.dt,
        "duration_s": sc.duration,
        "obstacles": len(sc.obstacles),
        "leader_speed_mps": speed,
        "K3": sc.estimator.K3,
        "hops": hops,
        "floor_limit_m": hops * sc.dt * speed,
        "floors_m": floors(traj),
        "final_estimate_errors_m": [float(x) for x in np.linalg.norm(traj["ph"][-1] - traj["p0"][-1], axis=1)],
        "settle_s": settle_times(sc, traj),
        "avoidance_episodes": len(summary["avoidance_episodes"]),
        "wall_s": time.perf_counter() - start,
    }


def ratio(a: float | None, b: float | None) -> float | None:
    """``a / b``, None when either is missing or ``b`` is 0."""
    if a is None or b is None or b == 0 or not math.isfinite(b):
        return None
    return a / b
