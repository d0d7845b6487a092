"""The law API and its registry: what a robot's control law is given, what it returns, and
how a scenario names it. The paper's own law is a user of this API like any other
(``fxswarm.core.paper_law``, registered under the built-in names in pyproject.toml).

A law is a class (docs/controllers.md)::

    class Tether:
        def __init__(self, params: dict, robot_id: int, scenario): ...
        def estimate_rate(self, view) -> "3 numbers": ...           # d ph_i / dt
        def velocity(self, view, estimate_rate) -> "3 numbers": ...  # v_i

named in a scenario's ``[controller] law`` either by a name registered under the
entry-point group :data:`ENTRY_POINT_GROUP` or as ``module:Class`` (a module beside the
scenario file, or any installed one). The agent node (``fxswarm.agents.node``) owns
everything around the law: what the view holds, integrating the estimate, the speed limit
(:func:`limit_speed`, the same for every law), degraded modes and flags, and a law that fails.
No I/O here beyond importing the law's module.
"""

from __future__ import annotations

import importlib
import inspect
import math
import sys
from importlib.metadata import entry_points
from pathlib import Path

from fxswarm.core.control import speed_limited as limit_speed  # noqa: F401 (the API's speed limit)
from fxswarm.core.messages import MAX_TEXT as LAW_ERROR_CHARS  # the message rides on the robot's Command

#: The entry-point group a package registers its laws under (pyproject.toml
#: ``[project.entry-points."fxswarm.laws"]``).
ENTRY_POINT_GROUP = "fxswarm.laws"
#: A law's ``vectors``: numpy arrays of shape (3,) (the default), or plain Python floats
#: (sequences of 3 floats: the built-ins' choice, numpy costs ~1 us a call on 3-vectors).
VECTOR_KINDS = ("numpy", "floats")


class LawError(ValueError):
    """A law cannot be used: the message says why (the caller adds the file and the field)."""


class BatchUnsupported(Exception):
    """A law's batch form cannot step this run exactly as the per-robot form would (the
    message says why): the simulator then steps it per robot (fxswarm.launch.batch)."""


class LawView:
    """What robot ``robot_id`` knows at this tick: the one argument of a law's methods.

    Vectors are numpy arrays of shape (3,) for a law with ``vectors = "numpy"`` (the default),
    sequences of 3 Python floats for ``vectors = "floats"``; m, m/s, s.

    ``t``: time of the sensing; ``dt``: the step this act integrates over; ``d``: the
    scenario's repulsive radius; ``p``: own sensed position; ``ph``: own estimate of the
    leader; ``offset``, ``offset_rate``: ``p_i0(t)`` and its rate; ``rows``, ``weights``:
    the estimates held fresh, neighbours in ascending id then the leader's position if
    pinned and heard, with ``a_ij`` (``b_i``): the one list a consensus sum runs over;
    ``heard_leader``: whether the last row is the leader's; ``nearest``: None or
    ``(po, vo)``; ``vh``: the observed leader velocity with ``[estimator] tracking =
    "feedforward"``, else None; ``heading`` (rad) and ``velocity`` (the velocity the robot
    moves at): sensed where the robot's drive model has them (``heading`` a unicycle's,
    ``velocity`` a unicycle's or a double integrator's; docs/robots.md), else None.

    The node refreshes one view per robot each tick: a law copies what it keeps.
    """

    __slots__ = ("robot_id", "t", "dt", "d", "p", "ph", "offset", "offset_rate", "rows", "weights",
                 "heard_leader", "nearest", "vh", "heading", "velocity")

    def __init__(self, robot_id: int, d: float) -> None:
        self.robot_id, self.d = robot_id, d
        self.t = self.dt = 0.0
        self.p = self.ph = self.offset = self.offset_rate = self.vh = self.nearest = None
        self.heading = self.velocity = None
        self.rows, self.weights, self.heard_leader = [], [], False


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


def make_law(cls: type, params: dict, robot_id: int, scenario):
    """Robot ``robot_id``'s instance of law ``cls``: ``cls(params, robot_id, scenario)``, every
    law alike (the validated scenario is the third argument; a law that needs nothing of it
    ignores it). Raises :class:`LawError` if the constructor raises."""
    try:
        return cls(dict(params), robot_id, scenario)
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

