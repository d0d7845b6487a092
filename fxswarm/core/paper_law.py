"""The paper's law family, registered like any user's law (pyproject.toml ``fxswarm.laws``):
the fixed-time estimator, eq. (11), and the behaviours merged in null space, eqs. (v1), (v2),
(v) (fxswarm.core.control holds the equations), with its exponent families and the
leader-velocity feedforward.

This is the one definition of the law the robots fly: the agent node, the in-process
simulator and every process call :class:`BehaviouralLaw` through the law API
(fxswarm.core.laws), and :func:`robot_control`, which the oracle and fidelity tests check,
runs that same class on one view with the same speed limit the node applies
(:func:`fxswarm.core.laws.limit_speed`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from fxswarm.core.control import (
    ControlOutput, ControlParameters, Vec, behaviour_velocity, estimator_rate_step, in_repulsive_zone,
)
from fxswarm.core.laws import LawError, LawView, limit_speed

#: The law families of the paper's law: the same equations, exponents chosen for fixed-time
#: (the paper), asymptotic or finite-time convergence (fxswarm.core.scenario VARIANTS).
FAMILIES = ("fixed-time", "asymptotic", "finite-time")
#: The suffix of a built-in name that runs the estimator with the leader-velocity feedforward
#: (``[estimator] tracking = "feedforward"``, docs/estimator.md).
FEEDFORWARD_SUFFIX = "+feedforward"
#: Every built-in law name: each family, alone and with feedforward tracking.
BUILTIN_LAWS = FAMILIES + tuple(f + FEEDFORWARD_SUFFIX for f in FAMILIES)
def split_builtin(name: str) -> tuple[str, str]:
    """``(family, tracking)`` of a built-in law name, e.g. ``("asymptotic", "feedforward")``."""
    if name.endswith(FEEDFORWARD_SUFFIX):
        return name[: -len(FEEDFORWARD_SUFFIX)], "feedforward"
    return name, "paper"


def builtin_name(family: str, tracking: str) -> str:
    """The built-in law name of a family and an estimator tracking (inverse of :func:`split_builtin`)."""
    return family + (FEEDFORWARD_SUFFIX if tracking == "feedforward" else "")


#: Effective large-error exponent of the finite-time family (``r1*r0`` and ``r3/r4``): close
#: enough to 1 that a sweep's largest scales settle in a few minutes of simulated time.
FINITE_TIME_TOP_EXPONENT = 0.9


def variant_gains(gains: dict, variant: str) -> dict:
    """The ``[gains]`` table of family ``variant``, derived from a fixed-time ``[gains]`` table.

    Only exponents change; ``lam_*``, ``b*`` and ``K*`` are the paper's, so that the
    families differ in the one property being compared.
    """
    if variant not in FAMILIES:
        raise ValueError(f"unknown controller variant {variant!r}; expected one of {', '.join(FAMILIES)}")
    g = dict(gains)
    if variant == "asymptotic":
        g.update(r0=1.0, r1=1.0, r2=1.0, r3=float(g["r4"]), r5=float(g["r6"]))
    elif variant == "finite-time":
        g.update(r1=FINITE_TIME_TOP_EXPONENT / float(g["r0"]), r3=FINITE_TIME_TOP_EXPONENT * float(g["r4"]))
    return g


def family_gains(gains: dict, family: str) -> dict:
    """``[gains]`` for ``law = "<family>"``: the paper's fixed-time exponents are turned into the
    family's (:func:`variant_gains`, as ``fxswarm sweep --variants`` does), so one scenario
    flies every family; gains already of another kind are left as given (and checked)."""
    keys = ("r0", "r1", "r2", "r3", "r4", "r5", "r6")
    values = [gains.get(k) for k in keys]
    if family == "fixed-time" or not all(type(x) in (int, float) and math.isfinite(x) and x > 0 for x in values):
        return gains
    r0, r1, r2, r3, r4, r5, r6 = (float(x) for x in values)
    if r1 * r0 > 1.0 and r2 * r0 < 1.0 and r3 / r4 > 1.0 and r5 / r6 < 1.0:
        return variant_gains(gains, family)
    return gains


class BehaviouralLaw:
    """The paper's law: the fixed-time estimator, eq. (11), and the behaviours merged in
    null space, eqs. (v1), (v2), (v) (fxswarm.core.control).

    Registered under every name of :data:`BUILTIN_LAWS`: the family only chooses the
    exponents of ``[gains]`` and the ``+feedforward`` suffix the estimator's tracking, both
    read by the scenario (fxswarm.core.scenario), so the law reads its gains, ``d``,
    ``[controller] discretisation`` and ``[estimator] tracking`` from the scenario it is given.
    """

    vectors = "floats"

    def __init__(self, params: dict, robot_id: int, scenario) -> None:
        if params:
            raise LawError(f"the built-in law takes no parameters (its gains are [gains]); got {sorted(params)}")
        if scenario is None:
            raise LawError("the built-in law needs its scenario")
        sc = scenario
        self._setup(ControlParameters(sc.formation, sc.avoidance, sc.estimator, sc.d,
                                      semi_implicit=sc.discretisation == "semi-implicit"),
                    sc.tracking == "feedforward")

    @classmethod
    def from_parameters(cls, gains: ControlParameters, feedforward: bool) -> "BehaviouralLaw":
        """The law on ``gains`` directly, without a scenario (:func:`robot_control`)."""
        law = cls.__new__(cls)
        law._setup(gains, feedforward)
        return law

    def _setup(self, gains: ControlParameters, feedforward: bool) -> None:
        self.gains = gains
        self.feedforward = feedforward
        self._explicit_feedforward = feedforward and not gains.semi_implicit

    def estimate_rate(self, view: LawView) -> list[float]:
        """``dph_i/dt``: eq. (11) (eq. (11ff) with feedforward; the semi-implicit step's mean rate)."""
        return estimator_rate_step(view.ph, view.rows, view.weights, self.gains, view.dt,
                                   view.vh if self.feedforward else None)

    def velocity(self, view: LawView, estimate_rate: Sequence[float]) -> list[float]:
        """``v_i``: eq. (v2) (eq. (v2ff): following ``vh`` under explicit Euler with feedforward,
        when the rate is eq. (11ff)'s, not an extrapolation's), merged with eq. (v1) by eq. (v)."""
        reference = view.vh if self._explicit_feedforward and view.weights else None
        nearest = view.nearest
        po, vo = (None, None) if nearest is None else nearest
        return behaviour_velocity(view.p, view.ph, estimate_rate, reference, view.offset, view.offset_rate,
                                  po, vo, self.gains, view.dt)[0]


def robot_control(
    p: Vec,
    ph: Vec,
    rows: Sequence[Vec],
    ws: Sequence[float],
    p0: Vec,
    dp0: Vec,
    po: Vec | None,
    vo: Vec | None,
    law: ControlParameters,
    dt: float,
    dph: Vec | None = None,
    feedforward: Vec | None = None,
) -> ControlOutput:
    """One robot's whole law from local data only, as the robots fly it: :class:`BehaviouralLaw`
    on one view, then the speed limit ``law.v_max`` (the node's, :func:`fxswarm.core.laws.limit_speed`).

    p: the robot's position, m. ph: its estimate of the leader, m.
    rows: the estimates it holds, shape (m, 3) (the leader's position as one more
    row when pinned and heard), with their weights ``ws`` (``a_ij``, ``b_i``), (m,).
    p0, dp0: its formation offset and the offset's rate (m, m/s).
    po, vo: the nearest object's position and velocity (None when it senses
    nothing); the avoidance task is on only inside the repulsive zone of radius
    ``law.d`` (SPEC section 4). dt: the step, s (used by the semi-implicit step).
    dph: given, the robot hears nobody and the node extrapolates its estimate at this rate
    (the law only steers: ``rows`` are not used); None: the law's eq. (11).
    feedforward: the observed leader velocity ``vh`` (m/s; ``[estimator] tracking =
    "feedforward"``, fxswarm.core.observer): eqs. (11ff) and, under explicit Euler, (v2ff)
    (docs/estimator.md).
    """
    flown = BehaviouralLaw.from_parameters(law, feedforward is not None)
    view = LawView(0, law.d)
    view.t, view.dt, view.p, view.ph, view.offset, view.offset_rate = 0.0, dt, p, ph, p0, dp0
    view.vh = feedforward
    view.nearest = None if po is None else (po, vo if vo is not None else (0.0, 0.0, 0.0))
    if dph is None:
        view.rows, view.weights = rows, ws
        dph = flown.estimate_rate(view)
    v, limited = limit_speed(flown.velocity(view, dph), law.v_max)
    e = [p[0] - ph[0] - p0[0], p[1] - ph[1] - p0[1], p[2] - ph[2] - p0[2]]  # eq. (ctbf)
    active = po is not None and in_repulsive_zone(p, po, law.d)
    return ControlOutput(v, list(dph), e, active, limited)
