"""The law API: what a robot's control law is given, what it returns, and how a scenario names it.

A law is a class (docs/controllers.md)::

    class Tether:
        def __init__(self, params: dict, robot_id: int): ...
        def estimate_rate(self, view) -> "3 numbers": ...           # d ph_i / dt
        def velocity(self, view, estimate_rate) -> "3 numbers": ...  # v_i

named in a scenario's ``[controller] law`` either by a name registered under the
entry-point group :data:`ENTRY_POINT_GROUP` (the built-ins: :data:`BUILTIN_LAWS`) or as
``module:Class`` (a module beside the scenario file, or any installed one). The agent
node (``fxswarm.agents.node``) owns everything around the law: what the view holds,
integrating the estimate, the speed limit, degraded modes and flags, and a law that fails.

The paper's law is :class:`BehaviouralLaw`, registered under every built-in name: it
goes through this API like any user's law. No I/O here beyond importing the law's module.
"""

from __future__ import annotations

import importlib
import inspect
import math
import sys
from collections.abc import Sequence
from importlib.metadata import entry_points
from pathlib import Path

from fxswarm.core.control import ControlParameters, behaviour_velocity, estimator_rate_step
from fxswarm.core.messages import MAX_TEXT as LAW_ERROR_CHARS  # the message rides on the robot's Command

#: The entry-point group a package registers its laws under (pyproject.toml
#: ``[project.entry-points."fxswarm.laws"]``).
ENTRY_POINT_GROUP = "fxswarm.laws"
#: The law families of the paper's law: the same equations, exponents chosen for fixed-time
#: (the paper), asymptotic or finite-time convergence (fxswarm.core.scenario VARIANTS).
FAMILIES = ("fixed-time", "asymptotic", "finite-time")
#: The suffix of a built-in name that runs the estimator with the leader-velocity feedforward
#: (``[estimator] tracking = "feedforward"``, docs/estimator.md).
FEEDFORWARD_SUFFIX = "+feedforward"
#: Every built-in law name: each family, alone and with feedforward tracking.
BUILTIN_LAWS = FAMILIES + tuple(f + FEEDFORWARD_SUFFIX for f in FAMILIES)
#: A law's ``vectors``: numpy arrays of shape (3,) (the default), or plain Python floats
#: (sequences of 3 floats: the built-ins' choice, numpy costs ~1 us a call on 3-vectors).
VECTOR_KINDS = ("numpy", "floats")


class LawError(ValueError):
    """A law cannot be used: the message says why (the caller adds the file and the field)."""


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


class LawView:
    """What robot ``robot_id`` knows at this tick: the one argument of a law's methods.

    Vectors are numpy arrays of shape (3,) for a law with ``vectors = "numpy"`` (the default),
    sequences of 3 Python floats for ``vectors = "floats"``; m, m/s, s.

    ``t``: time of the sensing; ``dt``: the step this act integrates over; ``d``: the
    scenario's repulsive radius; ``p``: own sensed position; ``ph``: own estimate of the
    leader; ``offset``, ``offset_rate``: ``p_i0(t)`` and its rate; ``rows``, ``weights``:
    every estimate held fresh, neighbours in ascending id then the leader's position if
    pinned and heard, with ``a_ij`` (``b_i``); ``heard_leader``: whether the last row is the
    leader's; ``nearest``: None or ``(po, vo)``; ``vh``: the observed leader velocity with
    ``[estimator] tracking = "feedforward"``, else None. :attr:`neighbours` and
    :attr:`leader` are the same rows as pairs.

    The node refreshes one view per robot each tick: a law copies what it keeps.
    """

    __slots__ = ("robot_id", "t", "dt", "d", "p", "ph", "offset", "offset_rate", "rows", "weights",
                 "heard_leader", "nearest", "vh")

    def __init__(self, robot_id: int, d: float) -> None:
        self.robot_id, self.d = robot_id, d
        self.t = self.dt = 0.0
        self.p = self.ph = self.offset = self.offset_rate = self.vh = self.nearest = None
        self.rows, self.weights, self.heard_leader = [], [], False

    @property
    def neighbours(self) -> list[tuple[float, Sequence[float]]]:
        """``(a_ij, ph_j)`` of each neighbour whose latest estimate is still fresh, ascending id."""
        m = len(self.weights) - self.heard_leader
        return [(float(w), r) for w, r in zip(self.weights[:m], self.rows[:m])]

    @property
    def leader(self) -> tuple[float, Sequence[float]] | None:
        """``(b_i, p0)`` for a pinned robot that hears the leader, else None."""
        return (float(self.weights[-1]), self.rows[-1]) if self.heard_leader else None


class BehaviouralLaw:
    """The paper's law: the fixed-time estimator, eq. (11), and the behaviours merged in
    null space, eqs. (v1), (v2), (v) (fxswarm.core.control).

    Registered under every name of :data:`BUILTIN_LAWS`: the family only chooses the
    exponents of ``[gains]`` and the ``+feedforward`` suffix the estimator's tracking, both
    read by the scenario (fxswarm.core.scenario), so the law reads its gains, ``d``,
    ``[controller] discretisation`` and ``[estimator] tracking`` from the scenario it is given.
    """

    vectors = "floats"

    def __init__(self, params: dict, robot_id: int, scenario=None) -> None:
        if params:
            raise LawError(f"the built-in law takes no parameters (its gains are [gains]); got {sorted(params)}")
        if scenario is None:
            raise LawError("the built-in law needs its scenario")
        sc = scenario
        self.gains = ControlParameters(sc.formation, sc.avoidance, sc.estimator, sc.d,
                                       semi_implicit=sc.discretisation == "semi-implicit")
        self.feedforward = sc.tracking == "feedforward"
        self._explicit_feedforward = self.feedforward and not self.gains.semi_implicit

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


# --- naming a law ------------------------------------------------------------------------

_registered: dict[str, str] | None = None


def registered_laws() -> dict[str, str]:
    """Name -> ``module:attr`` of every law registered under :data:`ENTRY_POINT_GROUP` (read once)."""
    global _registered
    if _registered is None:
        _registered = {ep.name: ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)}
    return _registered


def on_import_path(folder: str | Path | None) -> None:
    """Put ``folder`` (a scenario's) first on the import path, once: a law module beside a
    scenario file imports without installing anything."""
    if folder is None:
        return
    folder = str(Path(folder).resolve())
    if folder not in sys.path:
        sys.path.insert(0, folder)


def resolve_law(spec: str, folder: str | Path | None = None) -> type:
    """The law class ``spec`` names: a registered name (:func:`registered_laws`) or
    ``module:Class``, the module looked for first in ``folder`` (the scenario's), then where
    Python looks. Checks the class has the two methods and a known ``vectors``.

    Raises :class:`LawError` saying why (not found, import failed, not a law). This is the
    check a command that takes law names (``fxswarm sweep --variants``, ``campaign --laws``)
    runs before anything starts; :func:`make_law` then builds one per robot.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise LawError(f"a law name or module:Class, got {spec!r}")
    registered = registered_laws()
    target = registered.get(spec)
    if target is None:
        if ":" not in spec:
            known = ", ".join(sorted(registered)) or "none: reinstall fxswarm"
            raise LawError(f"{spec!r} is neither a registered law ({known}) nor module:Class")
        on_import_path(folder)
        target = spec
    module_name, _, attr = target.partition(":")
    if not module_name or not attr:
        raise LawError(f"{spec!r}: expected module:Class")
    try:
        module = importlib.import_module(module_name)
    except Exception as exc:  # the user's module may raise anything while it loads
        where = f" (looked in {folder} and the installed packages)" \
            if folder is not None and isinstance(exc, ModuleNotFoundError) else ""
        raise LawError(f"cannot import {module_name!r}{where}: {type(exc).__name__}: {exc}") from None
    obj = module
    for part in attr.split("."):
        obj = getattr(obj, part, None)
        if obj is None:
            raise LawError(f"module {module_name!r} has no {attr!r}")
    if not inspect.isclass(obj):
        raise LawError(f"{spec!r} is not a class (got {type(obj).__name__})")
    missing = [m for m in ("estimate_rate", "velocity") if not callable(getattr(obj, m, None))]
    if missing:
        raise LawError(f"class {obj.__name__} lacks the method{'s' * (len(missing) > 1)} "
                       f"{' and '.join(missing)} (a law has estimate_rate(view) and velocity(view, estimate_rate))")
    vectors = getattr(obj, "vectors", "numpy")
    if vectors not in VECTOR_KINDS:
        raise LawError(f"class {obj.__name__}: vectors = {vectors!r}, expected one of "
                       f"{', '.join(repr(v) for v in VECTOR_KINDS)}")
    return obj


def make_law(cls: type, params: dict, robot_id: int, scenario=None):
    """Robot ``robot_id``'s instance of law ``cls``: ``cls(params, robot_id)``, with
    ``scenario=`` too if the constructor takes it. Raises :class:`LawError` if it raises."""
    try:
        takes_scenario = "scenario" in inspect.signature(cls).parameters
    except (TypeError, ValueError):
        takes_scenario = False
    try:
        if takes_scenario:
            return cls(dict(params), robot_id, scenario=scenario)
        return cls(dict(params), robot_id)
    except LawError as exc:
        raise LawError(f"{cls.__name__}(params, robot_id={robot_id}): {exc}") from None
    except Exception as exc:  # the user's constructor may raise anything on its params
        raise LawError(f"{cls.__name__}(params, robot_id={robot_id}) raised {type(exc).__name__}: {exc}") from None


def checked_vector(x) -> list[float]:
    """``x`` as 3 finite floats; raises ValueError otherwise (the node's law_error)."""
    if type(x) is list and len(x) == 3:  # the built-ins' return: checked without a call per number
        a, b, c = x
        # x - x is 0 for a finite float, NaN for an infinite or NaN one: one comparison for all three
        if type(a) is float and type(b) is float and type(c) is float and (a - a) + (b - b) + (c - c) == 0.0:
            return x
    try:
        a, b, c = x
        finite = math.isfinite(a) and math.isfinite(b) and math.isfinite(c)
    except (TypeError, ValueError):  # not 3 things, or not numbers
        finite = False
    if finite:
        return [float(a), float(b), float(c)]
    raise ValueError(f"expected 3 finite numbers, got {_short(x)}")


def _short(x) -> str:
    text = repr(x)
    return text if len(text) <= 80 else text[:77] + "..."


def describe_failure(method: str, exc: BaseException) -> str:
    """One line for a law's failure at run time (the summary's first law_error message)."""
    text = f"{method}: {type(exc).__name__}: {exc}"
    return text if len(text) <= LAW_ERROR_CHARS else text[: LAW_ERROR_CHARS - 3] + "..."

