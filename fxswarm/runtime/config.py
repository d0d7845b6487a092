"""A command line's edge: the scenario and its one fault plan, or one line on stderr and exit 2.

The fault plan is resolved here, once per command: ``fxswarm sim`` and ``fxswarm run`` from
the scenario's ``[faults]`` and their ``--fault`` flags; ``fxswarm compose`` also from
``FXSWARM_FAULTS``; a role process receives the resolved plan (``--fault-plan``, or
``FXSWARM_FAULT_PLAN`` from compose) and only validates it, or, started by hand, resolves its
own ``--fault`` flags the same way.
"""

from __future__ import annotations

import os
import sys
import warnings

from fxswarm.core.scenario import Scenario, ScenarioError, ScenarioWarning, load
from fxswarm.faults.plan import FAULTS_ENV, PLAN_ENV, FaultPlan, load_plan, resolve


def load_or_exit(path: str, *, check_law: bool = True):
    """Load a scenario; on error print it and exit 2 (scenario warnings go to stderr).
    ``check_law=False``: its law is not imported (an observer flies nothing)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ScenarioWarning)
        try:
            sc = load(path, check_law=check_law)
        except ScenarioError as exc:
            print(f"fxswarm: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
    for w in caught:
        print(f"fxswarm: warning: {w.message}", file=sys.stderr)
    return sc


def plan_or_exit(sc: Scenario, flags: list[str] | None, env: dict[str, str] | None = None) -> FaultPlan:
    """The plan of ``sc``'s ``[faults]``, ``--fault`` ``flags`` (and ``FXSWARM_FAULTS`` of ``env``
    when given); on error print it and exit 2."""
    try:
        return resolve(sc, flags, env)
    except ScenarioError as exc:
        print(f"fxswarm: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


def process_plan_or_exit(sc: Scenario, given: str | None, flags: list[str] | None, who: str,
                         env: dict[str, str] | None = None) -> FaultPlan:
    """A role process's plan: ``given`` (``--fault-plan JSON|FILE``), else ``FXSWARM_FAULT_PLAN``
    of ``env`` (default: this process's environment), validated; else resolved here from the
    scenario and ``flags``. A plan and ``--fault`` flags together are refused, as is
    ``FXSWARM_FAULTS`` beside a received plan (compose resolves it when writing the file, not at
    ``up``): either would silently fault one process differently from the others."""
    env = os.environ if env is None else env
    source = "--fault-plan"
    if given is None and env.get(PLAN_ENV):
        given, source = env[PLAN_ENV], PLAN_ENV
        if env.get(FAULTS_ENV, "").strip():
            _refuse(who, f"{FAULTS_ENV}: expected it when the compose file is written "
                         f"(`{FAULTS_ENV}=... fxswarm compose CONFIG -o FILE` resolves it into {PLAN_ENV} "
                         f"for every service), not at `up`; got {env[FAULTS_ENV]!r}")
    if given is None:
        return plan_or_exit(sc, flags)
    if flags:
        _refuse(who, f"--fault: expected either a resolved plan ({source}) or --fault flags, got both")
    if source != PLAN_ENV and not given.lstrip().startswith("{"):
        source = f"--fault-plan {given}"  # a file: name it
    try:
        return load_plan(given, sc, source)
    except ScenarioError as exc:
        _refuse(who, str(exc))


def _refuse(who: str, text: str):
    print(f"{who}: {text}", file=sys.stderr)
    raise SystemExit(2)
