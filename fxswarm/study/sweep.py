"""``fxswarm sweep CONFIG --scales 1,10,...,100000 --out DIR``: settling time against initial error.

For every controller variant (:mod:`fxswarm.study.variants`; ``<variant>+feedforward``
runs it with the leader-velocity feedforward of docs/estimator.md) and every scale
factor, the scenario's initial errors (each robot's displacement from its slot
and its estimate's error) are multiplied by the factor and the swarm is run
in-process (:class:`fxswarm.launch.sim.Simulation`), the cases in parallel
over the machine's cores (spawned worker processes). ``DIR/sweep.json`` gets
one row per case: initial errors, measured settling times
(:mod:`fxswarm.study.measure`) and the analytic figures beside them; the
figure is drawn by ``fxswarm report``'s own plotting code
(``DIR/settling_vs_initial_error.png``).

What a sweep changes in the scenario, and why:

- avoidance off (unless ``--avoidance``): obstacles dropped and the repulsive
  radius shrunk to a micrometre. The obstacles sit at z = 7..28 m, irrelevant
  or distorting next to displacements of 1e5 m; and robots whose estimates
  still disagree by metres meet one another on the way in, so robot-robot
  avoidance pauses the formation task (it runs in avoidance's null space)
  and measures the merge instead of the law. The claim under test is about
  the law's convergence.
- duration per case (unless ``--duration``): long enough for an upper bound
  on that case to pass, ``1.25 * max(formation exact time, derived estimator
  bound) + 10 s`` (:func:`case_duration`), capped by ``--max-duration``.
- ``dt`` is the scenario's (the paper's 0.01 s) unless ``--dt``: larger steps
  raise the chattering floor (about ``9 dt |dp0/dt|`` plus ``K3 dt`` terms)
  toward the settling tolerance and then delay "settled" artificially.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from fxswarm.core.bounds import (
    estimator_bound_derived,
    estimator_bound_printed,
    fixed_time_bound,
    settling_time,
    settling_time_limit,
)
from fxswarm.core.control import BehaviourGains
from fxswarm.core.observer import oriented_settling_bound
from fxswarm.core.scenario import DISCRETISATIONS, VARIANTS, Scenario, ScenarioError, ScenarioWarning
from fxswarm.runtime.numbers import positive, positive_int
from fxswarm.runtime.output import prepare_run_folder
from fxswarm.study.measure import initial_errors, settle_times
from fxswarm.study.parallel import parallel_map
from fxswarm.study.variants import SWEEP_VARIANTS, case_toml, parse_case, variant_toml

DEFAULT_SCALES = (1.0, 10.0, 100.0, 1000.0, 10000.0, 100000.0)


# --- analytic figures ------------------------------------------------------------------


def formation_exact_time(e0: float, tol: float, g: BehaviourGains) -> float:
    """Continuous-time time for the formation task to go from ``|e| = e0`` to ``tol``, s.

    Along the continuous dynamics ``d rho/dt = -task_rate(rho)`` exactly (SPEC section 3),
    so this is ``T(rho0) - T(rho_tol)`` with ``T`` of SPEC section 6; for the asymptotic
    variant (``r1*r0 = r2*r0 = 1``) ``T`` is infinite and the difference is
    ``ln(rho0/rho_tol) / (lam (b1 + b2))``.
    """
    rho0, rho_tol = e0 * e0 / 2.0, tol * tol / 2.0
    if rho0 <= rho_tol:
        return 0.0
    if g.r2 * g.r0 >= 1.0:
        if math.isclose(g.r1 * g.r0, 1.0) and math.isclose(g.r2 * g.r0, 1.0):
            return math.log(rho0 / rho_tol) / (g.lam * (g.b1 + g.b2) ** g.r0)
        return math.inf
    return settling_time(rho0, g) - settling_time(rho_tol, g)


def initial_estimate_errors(sc: Scenario) -> np.ndarray:
    """``ph_i(0) - p0(0)``, shape (n, 3), m."""
    return np.array([r.estimate for r in sc.robots]) - sc.leader.position(0.0)


def case_bounds(sc: Scenario, e0: float) -> dict:
    """The analytic figures reported beside one case's measurements (s; None = infinite)."""
    tol = sc.settle_tolerance
    observer = {}
    if sc.observer is not None:  # feedforward: the velocity observer settles first (docs/estimator.md)
        if sc.observer_graph == "oriented":
            t_v = oriented_settling_bound(sc.a, sc.b, sc.observer)
        else:  # eq. (obs) on the undirected graph is eq. (11) on velocities
            t_v = estimator_bound_derived(sc.H, sc.observer)
        observer = {"observer_bound_s": _finite(t_v)}
    return observer | {
        "formation_bound_s": _finite(fixed_time_bound(sc.formation)),
        "formation_limit_s": _finite(settling_time_limit(sc.formation)),
        "formation_exact_s": _finite(formation_exact_time(e0, tol, sc.formation)),
        "estimator_printed_s": _finite(estimator_bound_printed(sc.H, sc.estimator)),
        "estimator_derived_s": _finite(estimator_bound_derived(sc.H, sc.estimator)),
        "estimator_derived_from_initial_s": _finite(
            estimator_bound_derived(sc.H, sc.estimator, initial_estimate_errors(sc), tol)),
    }


def case_duration(sc: Scenario, e0: float, max_duration: float) -> float:
    """A run long enough for this case's upper bounds to pass, s (see the module docstring)."""
    b = case_bounds(sc, e0)
    estimator = (b["estimator_derived_from_initial_s"] or max_duration) + (b.get("observer_bound_s") or 0.0)
    longest = max(b["formation_exact_s"] or max_duration, estimator)
    return float(min(max_duration, math.ceil(1.25 * longest + 10.0)))


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


# --- one case (runs in a worker process) ----------------------------------------------


def run_case(raw: dict, source: str, variant: str, scale: float, folder: str | None = None) -> dict:
    """Parse and run one case (``folder``: the base scenario's, for a user's law); return its
    ``sweep.json`` row."""
    from fxswarm.launch.sim import Simulation  # imported in the worker, after spawn

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ScenarioWarning)  # the parent reports the base scenario's warnings
        sc = parse_case(raw, source, folder)
    start = time.perf_counter()
    sim = Simulation(sc, path="auto")  # the batch path when it takes the case: the same trajectory, faster
    summary = sim.run()
    traj = sim.trajectory()
    wall = time.perf_counter() - start
    init = initial_errors(sc)
    settle = settle_times(sc, traj)
    robot_gap = _min_robot_distance(traj["p"])
    return {
        "variant": variant,
        "law": sc.law,
        "scale": scale,
        "duration_s": sc.duration,
        "dt": sc.dt,
        "discretisation": sc.discretisation,
        "tracking": sc.tracking,
        # x axis of the report's figure: the formation task's initial error (the largest of the three)
        "initial_error_m": init["formation_task_m"],
        "initial_errors_m": init,
        "formation_settle_s": settle["formation_task_s"],
        "estimate_settle_s": settle["estimator_s"],
        "formation_true_settle_s": settle["formation_true_s"],
        "settled": settle["formation_task_s"] is not None and settle["estimator_s"] is not None,
        "bounds": case_bounds(sc, init["formation_task_m"]),
        "formation_error_final_m": summary["formation_error_final_m"],
        "estimate_error_final_m": summary["estimate_error_final_m"],
        "avoidance_episodes": len(summary["avoidance_episodes"]),
        "min_robot_distance_m": robot_gap,
        "gains": {"r0": sc.formation.r0, "r1": sc.formation.r1, "r2": sc.formation.r2,
                  "r3": sc.estimator.r3, "r4": sc.estimator.r4, "r5": sc.estimator.r5, "r6": sc.estimator.r6},
        "wall_s": wall,
    }


def _min_robot_distance(p: np.ndarray) -> float:
    """Closest approach of two robots over the run, m (p: (ticks, n, 3))."""
    n = p.shape[1]
    if n < 2:
        return math.inf
    i, j = np.triu_indices(n, 1)
    return float(np.linalg.norm(p[:, i] - p[:, j], axis=2).min())


# --- the sweep -------------------------------------------------------------------------


def plan(
    base: Scenario,
    scales: list[float],
    variants: list[str],
    dt: float | None = None,
    duration: float | None = None,
    max_duration: float = 400.0,
    avoidance: bool = False,
    discretisation: str | None = None,
) -> list[tuple[dict, str, str, float]]:
    """The cases ``(raw TOML, source label, variant, scale, law folder)``, longest first (for load balance)."""
    cases = []
    for variant in variants:
        for scale in scales:
            label = f"{base.source}[{variant} x{scale:g}]"
            raw = case_toml(base, variant, scale, duration or max_duration, dt, avoidance, discretisation)
            if duration is None:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", ScenarioWarning)
                    sc = parse_case(raw, label, base.law_folder)
                raw["scenario"]["duration"] = case_duration(sc, initial_errors(sc)["formation_task_m"], max_duration)
            cases.append((raw, label, variant, scale, base.law_folder))
    cases.sort(key=lambda c: -c[0]["scenario"]["duration"] / c[0]["scenario"].get("dt", base.dt))
    return cases


def run_sweep(cases: list[tuple], workers: int, progress=None) -> list[dict]:
    """Run the cases on ``workers`` spawned processes; rows ordered by variant, then scale."""
    rows = parallel_map(run_case, cases, workers, progress)
    order = {v: k for k, v in enumerate(SWEEP_VARIANTS)}
    return sorted(rows, key=lambda r: (order.get(r["variant"], 99), r["scale"]))


def series(rows: list[dict], variant: str, key: str) -> list[tuple[float, float | None]]:
    """``(scale, rows[key])`` of one variant, by scale."""
    return sorted((r["scale"], r[key]) for r in rows if r["variant"] == variant)


def claims(rows: list[dict]) -> dict:
    """The figures issue 7 asks the sweep to show, computed (never asserted) from its rows."""

    def at(variant: str, key: str, scale: float):
        return next((t for s, t in series(rows, variant, key) if s == scale), None)

    def ratio(variant: str, key: str, lo: float, hi: float):
        a, b = at(variant, key, lo), at(variant, key, hi)
        return None if a is None or b is None or a <= 0 else b / a

    out: dict = {}
    fixed = [r for r in rows if r["variant"] == "fixed-time"]
    if fixed:
        bound = fixed[0]["bounds"]["formation_bound_s"]
        worst = [r["formation_settle_s"] for r in fixed]
        out["fixed_time_formation_settle_max_s"] = None if None in worst else max(worst)
        out["fixed_time_formation_bound_s"] = bound
        out["fixed_time_formation_below_bound"] = None not in worst and bound is not None and max(worst) < bound
        out["fixed_time_estimator_growth_1e4_to_1e5"] = ratio("fixed-time", "estimate_settle_s", 1e4, 1e5)
    for variant in ("asymptotic", "finite-time", "fixed-time") + SWEEP_VARIANTS[len(VARIANTS):]:
        if any(r["variant"] == variant for r in rows):
            key = variant.replace("-", "_").replace("+", "_")
            out[f"{key}_formation_growth_1_to_1e5"] = ratio(variant, "formation_settle_s", 1.0, 1e5)
            out[f"{key}_estimator_growth_1_to_1e5"] = ratio(variant, "estimate_settle_s", 1.0, 1e5)
    within = [r["estimate_settle_s"] <= r["bounds"]["estimator_derived_from_initial_s"]
              for r in rows if r["estimate_settle_s"] is not None
              and r["bounds"]["estimator_derived_from_initial_s"] is not None]
    out["estimator_within_derived_bound"] = f"{sum(within)}/{len(within)} cases"
    return out


def sweep_document(base: Scenario, config: str, rows: list[dict], settings: dict) -> dict:
    """The whole ``sweep.json``."""
    return {
        "config": config,
        "scenario": base.name,
        "settings": settings,
        "bounds": {
            "formation_fixed_time_s": _finite(fixed_time_bound(base.formation)),
            "formation_limit_s": _finite(settling_time_limit(base.formation)),
            "estimator_printed_s": _finite(estimator_bound_printed(base.H, base.estimator)),
            "estimator_printed_note": "the paper's printed T_E; suspect (docs/design.md, 'The estimator bound'): reported, never asserted",
            "estimator_derived_s": _finite(estimator_bound_derived(base.H, base.estimator)),
            "estimator_derived_note": "fxswarm.core.bounds.estimator_bound_derived: proven for the aggregate "
                                      "power, checked against measurements for pairwise",
        },
        "claims": claims(rows),
        "rows": rows,
    }


# --- command line ---------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="scenario file (TOML) with fixed-time gains; the other variants derive from it")
    p.add_argument("--scales", default=",".join(f"{s:g}" for s in DEFAULT_SCALES),
                   help="factors applied to the initial displacement and estimate error (default: %(default)s)")
    p.add_argument("--variants", default=",".join(VARIANTS),
                   help="controller variants (default: %(default)s); each also as <variant>+feedforward "
                        "(estimator tracking = \"feedforward\", docs/estimator.md), or a user's law, "
                        "module:Class or a registered name (docs/controllers.md)")
    p.add_argument("--out", default=None, help="folder for sweep.json and the figure (default: runs/<name>-sweep)")
    p.add_argument("--dt", type=positive, default=None, help="control period, s (default: the scenario's)")
    p.add_argument("--duration", type=positive, default=None,
                   help="simulated time per case, s (default: from each case's bounds)")
    p.add_argument("--max-duration", type=positive, default=400.0, help="cap on the per-case duration, s")
    p.add_argument("--workers", type=positive_int, default=os.cpu_count() or 1, help="parallel processes (default: cores)")
    p.add_argument("--avoidance", action="store_true",
                   help="keep obstacles and collision avoidance (default: off, to measure the laws alone)")
    p.add_argument("--discretisation", choices=DISCRETISATIONS, default=None,
                   help="override the scenario's [controller] discretisation")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def _parse_list(text: str, kind, what: str) -> list:
    try:
        return [kind(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise SystemExit(f"fxswarm sweep: --{what}: expected a comma-separated list, got {text!r}") from None


def main(args: argparse.Namespace) -> int:
    from fxswarm.runtime.config import load_or_exit

    base = load_or_exit(args.config)
    scales = _parse_list(args.scales, float, "scales")
    variants = _parse_list(args.variants, str, "variants")
    bad = [why for v in variants if v not in SWEEP_VARIANTS and (why := _law_refused(v, base))]
    if bad or not scales or any(s <= 0 for s in scales):
        print(f"fxswarm sweep: expected --variants from {', '.join(SWEEP_VARIANTS)} or a law "
              f"(module:Class), and --scales > 0{''.join('; ' + why for why in bad)}", file=sys.stderr)
        return 2
    if base.variant != "fixed-time" or base.estimator_variant != "fixed-time":
        print(f"fxswarm sweep: {args.config}: the variants derive from fixed-time gains; this scenario "
              f"declares controller.variant = {base.variant!r}", file=sys.stderr)
        return 2
    out = prepare_run_folder(args.out or f"runs/{base.name}-sweep", "fxswarm sweep")  # before minutes of work
    cases = plan(base, scales, variants, args.dt, args.duration, args.max_duration, args.avoidance,
                 args.discretisation)

    def progress(row: dict, done: int, total: int) -> None:
        if not args.quiet:
            print(f"  [{done}/{total}] {row['variant']:>11} x{row['scale']:<8g} formation "
                  f"{_fmt(row['formation_settle_s'])} s, estimator {_fmt(row['estimate_settle_s'])} s "
                  f"({row['duration_s']:g} s simulated in {row['wall_s']:.1f} s)", file=sys.stderr)

    start = time.perf_counter()
    signal.signal(signal.SIGTERM, _interrupted)  # SIGTERM stops the workers too, like Ctrl-C
    rows = run_sweep(cases, args.workers, progress)
    settings = {
        "scales": scales, "variants": variants, "dt": args.dt or base.dt,
        "duration_s": args.duration or "per case, from its bounds", "max_duration_s": args.max_duration,
        "settle_tolerance_m": base.settle_tolerance, "avoidance": args.avoidance,
        "discretisation": args.discretisation or base.discretisation, "power": base.estimator.power,
        "tracking": {v: ("feedforward" if v.endswith("+feedforward") else base.tracking) for v in variants},
        "workers": args.workers, "wall_s": time.perf_counter() - start,
    }
    doc = sweep_document(base, args.config, rows, settings)
    out.mkdir(parents=True, exist_ok=True)
    (out / "sweep.json").write_text(json.dumps(doc, indent=2) + "\n")
    figure = write_figure(out, rows)
    if not args.quiet:
        print(json.dumps(doc["claims"], indent=2))
        print(f"wrote {out / 'sweep.json'}" + (f" and {figure}" if figure else ""))
    return 0


def write_figure(out: Path, rows: list[dict]) -> Path | None:
    """Settling time against initial error, drawn by ``fxswarm report``'s figure code."""
    try:
        from fxswarm.report import SETTLING, sweep_rows
        from fxswarm.report.figures import settling_vs_initial_error
    except ImportError:  # the report is another package's; the JSON stands alone
        return None
    return settling_vs_initial_error(sweep_rows({"rows": rows}), out / SETTLING)


def _law_refused(spec: str, base: Scenario) -> str | None:
    """Why a user's law named as a variant cannot fly on ``base`` (None: it can)."""
    try:
        parse_case(variant_toml(base.raw, spec), base.source, base.law_folder)
    except ScenarioError as exc:
        return str(exc)
    return None


def _interrupted(signum, frame) -> None:
    raise KeyboardInterrupt


def _fmt(x: float | None) -> str:
    return "never" if x is None else f"{x:.2f}"
