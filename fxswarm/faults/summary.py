"""``summary.json``: the one builder every runner uses (``fxswarm sim``, the world process of
``fxswarm run`` and of a compose run, and the launcher that outlives it).

It lives in the faults layer, the lowest one that sees both the trajectory metrics
(:mod:`fxswarm.core.metrics`) and the fault plan. A runner passes what only it knows
through the parameters; the keys it adds are listed in ``docs/`` with the rest.
"""

from __future__ import annotations

import numpy as np

from fxswarm.core.metrics import estimate_errors, formation_errors, summarise
from fxswarm.core.scenario import Scenario
from fxswarm.faults.plan import FaultPlan
from fxswarm.faults.report import fault_summary, law_summary

LINK_COUNTS = ("delivered", "dropped", "delayed", "duplicated")


def build_summary(sc: Scenario, traj: dict[str, np.ndarray], plan: FaultPlan, *, wall_s: float,
                  world=None, links: dict[str, dict[str, int]] | None = None,
                  restarts: dict[str, int] | None = None, runner: dict | None = None,
                  processes: dict[str, dict] | None = None, process_events: list[dict] | None = None,
                  router_outages: list[dict] | None = None, discarded: dict[int, int] | None = None) -> dict:
    """The run's summary, as a dict ready for JSON.

    traj: the world's trajectory (arrays keyed as in ``trajectory.npz``); wall_s: the run's
    wall time, s; world: the world node (its degraded-mode counts), None if not at hand;
    links: per-link fault counts counted in this process (``"src->dst/kind"`` ->
    delivered/dropped/delayed/duplicated); restarts: ``"agent:<id>"`` -> restarts seen in
    this process; runner: the runner's own top-level facts (e.g. ``clock``,
    ``missed_ticks``, ``counters``), added after the common metrics. processes and
    process_events: see :func:`add_processes`. router_outages: the runner's
    :meth:`~fxswarm.runtime.connectivity.Connectivity.report` (none in one process).
    discarded: robot id -> neighbour values its W-MSR trimming discarded (the in-process
    runner's count; a process run's come with ``processes``).

    ``complete`` (a runner's) says every tick ran; ``degraded`` whether it ran with robots the
    world could not hear (``{"ticks": n, "robots": [ids]}``, ticks 0 for a healthy run).
    """
    summary = summarise(sc, traj, wall_s)
    summary.update(runner or {})
    degraded = getattr(world, "degraded", None)
    summary["degraded"] = degraded() if degraded is not None else {"ticks": 0, "robots": []}
    summary["router_outages"] = list(router_outages or [])
    summary["law"] = law_summary(sc, world)
    drive_report = getattr(world, "drive_report", None)
    if sc.world is not None and drive_report is not None:  # [world]: the models, the sensing, the limits hit
        summary["world"] = drive_report()
    summary.update(fault_summary(sc, plan, traj, world, dict(links or {}), restarts))
    if sc.resilience != "none" or plan.lies:
        summary["resilience"] = resilience_summary(sc, plan, traj, discarded)
    if processes is not None:
        add_processes(summary, processes, process_events)
    return summary


def add_processes(summary: dict, processes: dict[str, dict], process_events: list[dict] | None = None) -> dict:
    """Put the role processes' counters into ``summary`` (in place; returned too).

    processes: ``"<role>-<id>"`` -> that process's counters file. Their per-link fault counts
    (each process counts its own inbox) are summed into ``faults.links``, replacing the
    in-process counts. process_events: the process faults a launcher sent, ``{action, target,
    t_s, done_t_s}`` in time order; they become ``faults.process_events`` and, counted, ``faults.restarts``
    (as ``fxswarm sim`` counts its stand-ins' restarts).
    """
    summary["processes"] = processes
    if "resilience" in summary:  # each agent counted what its trimming discarded
        counts = {str(c["id"]): int(c["discarded"]) for c in processes.values()
                  if c.get("role") == "agent" and "discarded" in c}
        summary["resilience"]["discarded"] = dict(sorted(counts.items(), key=lambda kv: int(kv[0])))
    faults = summary.setdefault("faults", {})
    faults["links"] = merged_links(processes)
    if process_events:
        faults["process_events"] = list(process_events)
        restarts: dict[str, int] = {}
        for e in process_events:
            if e["action"] == "restart":
                restarts[e["target"]] = restarts.get(e["target"], 0) + 1
        faults["restarts"] = restarts
    return summary


def merged_links(processes: dict[str, dict]) -> dict[str, dict[str, int]]:
    """The processes' per-link counts summed, sorted by link."""
    merged: dict[str, dict[str, int]] = {}
    for counters in processes.values():
        for key, c in (counters.get("links") or {}).items():
            m = merged.setdefault(key, dict.fromkeys(LINK_COUNTS, 0))
            for name in LINK_COUNTS:
                m[name] += int(c.get(name, 0))
    return dict(sorted(merged.items()))


def resilience_summary(sc: Scenario, plan: FaultPlan, traj: dict[str, np.ndarray],
                       discarded: dict[int, int] | None) -> dict:
    """summary.json's ``resilience`` (a run with ``[estimator] resilience`` or a lie fault):
    the estimator, F, the liars, the honest robots' final formation error and nearest object,
    and the values each robot's trimming discarded (robot ids as string keys; None when not
    counted in this process)."""
    liars = sorted(x.robot for x in plan.lies)
    honest = [i for i in range(sc.n) if i + 1 not in liars]
    t = traj["t"]
    out: dict = {"estimator": sc.resilience, "tolerate": sc.tolerate, "liars": liars,
                 "lies": [x.label for x in plan.lies]}
    if len(t) and honest:
        f_err = formation_errors(traj)[:, honest]
        e_err = estimate_errors(traj)[:, honest]
        near = traj["nearest_distance"][:, honest]
        out["honest_formation_error_final_m"] = float(f_err[-1].max())
        out["honest_estimate_error_final_m"] = float(e_err[-1].max())
        out["honest_min_object_distance_m"] = float(near.min()) if near.size and np.isfinite(near.min()) else None
    out["discarded"] = None if discarded is None else {str(k): int(v) for k, v in sorted(discarded.items())}
    return out
