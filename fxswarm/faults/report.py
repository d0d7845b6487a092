"""What faults did to a run: per-link counts, degraded modes, excursions and recovery times."""

from __future__ import annotations

import numpy as np

from fxswarm.core.metrics import formation_errors, settle_time
from fxswarm.core.scenario import Scenario
from fxswarm.faults.plan import FaultPlan

#: Names of the Command.flags bits, in bit order (see fxswarm.agents.node FLAG_*).
FLAG_BITS = ("stale_neighbour", "no_leader", "extrapolating", "no_sensing", "law_error")
LAW_ERROR_BIT = FLAG_BITS.index("law_error")


def first_settle_index(err: np.ndarray, tol: float) -> int | None:
    """First tick at which every robot's error is under ``tol``; err: (ticks, n)."""
    under = np.flatnonzero(err.max(axis=1) < tol)
    return int(under[0]) if len(under) else None


def max_error_after_settle(t: np.ndarray, err: np.ndarray, tol: float) -> float | None:
    """Largest formation error (m) from the first time the formation was under ``tol`` on."""
    k = first_settle_index(err, tol)
    return None if k is None else float(err[k:].max())


def recoveries(sc: Scenario, plan: FaultPlan, traj: dict[str, np.ndarray]) -> list[dict]:
    """For each partition, leader outage and process fault: the time (s) after it ended until
    its robots' formation error stayed under the settle tolerance to the end (None: never).

    Robots: the isolated ones for an isolation, the killed/frozen robot, else all.
    """
    t = traj["t"]
    if len(t) == 0:
        return []
    err = formation_errors(traj)
    tol = sc.settle_tolerance
    events = []
    for cut in plan.cuts:
        events.append((cut.label, cut.start, cut.end, cut.robots(sc.n)))
    for p in plan.processes:
        robots = [int(p.target[6:])] if p.target.startswith("agent:") else list(range(1, sc.n + 1))
        end = p.restart if p.restart is not None else float(t[-1])
        events.append((p.label, p.at, end, robots))
    out = []
    for label, start, end, robots in events:
        cols = [r - 1 for r in robots]
        after = t >= end - 1e-9
        back = settle_time(t[after], err[after][:, cols], tol) if after.any() else None
        during = (t >= start - 1e-9) & (t < end - 1e-9)
        out.append({
            "event": label, "start_s": start, "end_s": end, "robots": robots,
            "max_error_during_m": float(err[during][:, cols].max()) if during.any() else None,
            "max_error_after_m": float(err[after][:, cols].max()) if after.any() else None,
            "recovery_s": None if back is None else round(back - end, 9),
        })
    return out


def degraded_counts(world, n: int) -> dict:
    """Ticks each robot spent in each degraded mode (from its commands' flags, as the world saw
    them) and ticks the world held a silent robot at zero velocity; robot ids as string keys."""
    out: dict[str, dict[str, int]] = {}
    flag_ticks = getattr(world, "flag_ticks", None)
    for bit, name in enumerate(FLAG_BITS):
        if flag_ticks is not None:
            out[name] = {str(i + 1): int(flag_ticks[i, bit]) for i in range(n) if flag_ticks[i, bit]}
    held = getattr(world, "held_at_zero", None)
    if held is not None:
        out["world_held_at_zero"] = {str(i + 1): int(held[i]) for i in range(n) if held[i]}
    return out


def law_summary(sc: Scenario, world) -> dict:
    """summary.json's ``law``: its name and, per robot whose law failed (robot ids as string
    keys), the ticks it failed and the first failure's message."""
    errors = {}
    flag_ticks = getattr(world, "flag_ticks", None)
    if flag_ticks is not None:
        first = getattr(world, "law_errors", {})
        for i in range(sc.n):
            if flag_ticks[i, LAW_ERROR_BIT]:
                errors[str(i + 1)] = {"ticks": int(flag_ticks[i, LAW_ERROR_BIT]), "first": first.get(i + 1)}
    return {"name": sc.law, "errors": errors}


def fault_summary(sc: Scenario, plan: FaultPlan, traj: dict[str, np.ndarray], world,
                  links: dict[str, dict[str, int]], restarts: dict[str, int] | None = None) -> dict:
    """The summary.json additions of issue 4 (the same keys for ``sim`` and ``run``)."""
    err = formation_errors(traj) if len(traj["t"]) else np.zeros((0, sc.n))
    return {
        "max_formation_error_after_settle_m": max_error_after_settle(traj["t"], err, sc.settle_tolerance)
        if len(err) else None,
        "faults": {
            "seed": plan.seed,
            "links": links,
            "recoveries": recoveries(sc, plan, traj),
            "degraded_ticks": degraded_counts(world, sc.n),
            "restarts": restarts or {},
        },
    }
