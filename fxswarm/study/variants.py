"""The controller variants the paper compares itself to, as changes to a scenario's TOML.

The three variants share the law's structure (paper eqs. (11), (v1), (v2)) and
differ only in exponents, so each is a choice of gains (SPEC sections 2, 6):

- ``fixed-time``: the paper's gains, unchanged (``r1*r0 > 1``, ``r2*r0 < 1``,
  ``r3/r4 > 1``, ``r5/r6 < 1``): settling time bounded whatever the initial error.
- ``asymptotic``: every exponent 1 (``r0 = r1 = r2 = 1``, ``r3 = r4``, ``r5 = r6``):
  the behaviours' task functions decay exponentially, so the time to reach a
  tolerance grows like ``log(initial error)``. The estimator keeps its sign
  term (``K3``), which it needs to follow a moving leader.
- ``finite-time``: only the large-error exponent lowered below 1
  (``r1*r0 = 0.9``, ``r3/r4 = 0.9``; ``r2``, ``r5/r6`` kept): each settles in
  finite time, but that time grows like a power of the initial error
  (``T ~ rho0^(1 - r1*r0) / (1 - r1*r0)`` for the behaviours).

Each variant also comes as ``<variant>+feedforward`` (:data:`SWEEP_VARIANTS`): the same
gains with ``[estimator] tracking = "feedforward"`` (fxswarm.core.observer, docs/estimator.md),
the leader's velocity observed and fed forward in the estimator.

Building the variant as TOML and parsing it again (rather than patching a
``Scenario``) keeps ``Scenario.raw`` consistent and runs the variant's own
validation (``fxswarm.core.scenario.BEHAVIOUR_CONDITIONS``).
"""

from __future__ import annotations

import copy

import numpy as np

# The sweep's names for the built-in laws (fxswarm.core.paper_law): one list, one split, one derivation.
from fxswarm.core.paper_law import BUILTIN_LAWS as SWEEP_VARIANTS
from fxswarm.core.paper_law import FEEDFORWARD_SUFFIX, FINITE_TIME_TOP_EXPONENT, variant_gains  # noqa: F401
from fxswarm.core.paper_law import split_builtin as split_variant
from fxswarm.core.scenario import VARIANTS, Scenario, parse

#: The repulsive radius (m) that switches the avoidance behaviour off in practice: two robots
#: would have to come within a micrometre of each other.
NO_AVOIDANCE_D = 1e-6


def variant_toml(raw: dict, variant: str, discretisation: str | None = None) -> dict:
    """A deep copy of scenario TOML ``raw`` running ``variant`` (behaviours and estimator alike;
    a ``+feedforward`` suffix sets ``[estimator] tracking = "feedforward"``). A variant that is
    no built-in is a user's law (``module:Class`` or a registered name, docs/controllers.md),
    flown on the scenario as it is, ``[controller.params]`` included."""
    out = copy.deepcopy(raw)
    if variant not in SWEEP_VARIANTS:
        controller = dict(out.get("controller", {}), law=variant)
        if discretisation is not None:
            controller["discretisation"] = discretisation
        out["controller"] = controller
        return out
    variant, tracking = split_variant(variant)
    if tracking != "paper":
        out["estimator"] = dict(out.get("estimator", {}), tracking=tracking)
    out["gains"] = variant_gains(raw["gains"], variant)
    controller = dict(out.get("controller", {}))
    controller.pop("law", None)  # the base's own law, if any, and its parameters: not this variant's
    controller.pop("params", None)
    controller["variant"] = variant
    controller["estimator_variant"] = variant
    if discretisation is not None:
        controller["discretisation"] = discretisation
    out["controller"] = controller
    return out


def slots(sc: Scenario, t: float = 0.0) -> np.ndarray:
    """Every robot's desired position ``p0(t) + p_i0(t)``, shape (n, 3), m."""
    p0 = sc.leader.position(t)
    return np.array([p0 + r.offset.position(t) for r in sc.robots])


def scaled_toml(sc: Scenario, raw: dict, scale: float) -> dict:
    """TOML ``raw`` (of scenario ``sc``) with the initial errors multiplied by ``scale``.

    Each robot's displacement from its slot at t = 0 and its initial estimate's
    error ``ph_i(0) - p0(0)`` are scaled; the slots and the leader are not.
    """
    out = copy.deepcopy(raw)
    start_slots = slots(sc)
    p0 = sc.leader.position(0.0)
    for table, robot, slot in zip(out["robots"], sc.robots, start_slots):
        table["position"] = [float(x) for x in slot + scale * (np.array(robot.position) - slot)]
        table["estimate"] = [float(x) for x in p0 + scale * (np.array(robot.estimate) - p0)]
    return out


def case_toml(
    sc: Scenario,
    variant: str,
    scale: float,
    duration: float,
    dt: float | None = None,
    avoidance: bool = False,
    discretisation: str | None = None,
) -> dict:
    """One sweep case: ``sc``'s TOML with ``variant``, initial errors times ``scale``, and
    ``duration``/``dt`` set.

    Unless ``avoidance``, the obstacles are dropped and the repulsive radius shrunk to
    :data:`NO_AVOIDANCE_D`, so that the avoidance behaviour never switches on and the
    formation task's own convergence is what gets measured (see ``fxswarm.study.sweep``).
    """
    raw = variant_toml(scaled_toml(sc, sc.raw, scale), variant, discretisation)
    raw["scenario"] = dict(raw["scenario"], duration=float(duration))
    if dt is not None:
        raw["scenario"]["dt"] = float(dt)
    if not avoidance:
        raw.pop("obstacles", None)
        raw["scenario"]["d"] = NO_AVOIDANCE_D
    return raw


def parse_case(raw: dict, source: str, folder: str | None = None) -> Scenario:
    """Parse a case built by :func:`case_toml` (validation included); ``folder``: the base
    scenario's, where a user's law module is found."""
    return parse(raw, source, folder)
