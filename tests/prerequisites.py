"""What some tests need beyond the Python packages, and how a test that lacks it skips or fails.

A prerequisite has a name, a pytest marker for the tests that need it, a ``FXSWARM_REQUIRE_*``
variable and a check saying why it is not here. A test calls :func:`require`: where the
prerequisite is missing it skips, the reason starting ``prerequisite NAME missing:``; where its
REQUIRE variable is 1 it fails instead.

On CI (``CI=true``) a skip is a failure (:func:`pytest_runtest_makereport`, imported by
tests/conftest.py) unless its reason names a prerequisite that ``.ci/run`` declared missing in
``FXSWARM_CI_MISSING``, having printed why and which tests that skips (``python
tests/prerequisites.py``, this file's ``main``). Locally a skip stays a skip (``-ra`` lists them).
See docs/testing.md.
"""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

#: Names of the prerequisites ``.ci/run`` could not install (comma-separated); only their skips pass on CI.
CI_MISSING_ENV = "FXSWARM_CI_MISSING"
SKIP_PREFIX = "prerequisite "


@dataclass(frozen=True)
class Prerequisite:
    name: str
    marker: str  # the pytest marker of every test that needs it
    require_env: str  # =1: its absence fails those tests
    problem: Callable[[], str | None]  # why it is not here, or None
    installs: str  # who installs it, for the message where it is missing


def _docker_problem() -> str | None:
    from docker_support import engine_problem

    return engine_problem()


def _compose_problem() -> str | None:
    from docker_support import compose_command

    return None if compose_command() else "no compose tool (`docker compose` or `docker-compose`) answers"


def _browser_problem() -> str | None:
    from browser_support import chromium_binary

    binary = chromium_binary()
    if binary is None:
        return "no Chromium here (Debian: apt-get install chromium; or set FXSWARM_CHROMIUM)"
    return None if shutil.which(binary) or Path(binary).is_file() else f"FXSWARM_CHROMIUM={binary}: no such program"


def _ros2_problem() -> str | None:
    import importlib.util

    return None if importlib.util.find_spec("cyclonedds") else "Cyclone DDS (`cyclonedds`, the [ros2] extra) does not import"


def _snapshot_problem() -> str | None:
    from fxswarm.report.snapshot import can_render

    return can_render()


PREREQUISITES = {p.name: p for p in (
    Prerequisite("docker", "docker", "FXSWARM_REQUIRE_DOCKER", _docker_problem,
                 "the runner provides it; .ci/run does not install it"),
    Prerequisite("compose", "compose", "FXSWARM_REQUIRE_DOCKER", _compose_problem,
                 "the runner provides it; .ci/run does not install it"),
    Prerequisite("browser", "browser", "FXSWARM_REQUIRE_BROWSER", _browser_problem,
                 ".ci/install-browser.sh could not install it"),
    Prerequisite("snapshot", "snapshot", "FXSWARM_REQUIRE_SNAPSHOT", _snapshot_problem,
                 ".ci/install-snapshot-deps.sh could not install it"),
    Prerequisite("ros2", "ros2", "FXSWARM_REQUIRE_ROS2", _ros2_problem,
                 "`make .venv/.installed` installs it with .[dev]; it did not import"),
)}


def unavailable(name: str, problem: str) -> None:
    """Skip the running test for want of prerequisite ``name`` (``problem`` says why); fail it
    instead where its REQUIRE variable is 1."""
    p = PREREQUISITES[name]
    if os.environ.get(p.require_env) == "1":
        pytest.fail(f"{SKIP_PREFIX}{name} missing: {problem}; yet {p.require_env}=1: these tests must run here")
    pytest.skip(f"{SKIP_PREFIX}{name} missing: {problem}")


def require(name: str) -> None:
    """Return if prerequisite ``name`` is here, else :func:`unavailable`."""
    problem = PREREQUISITES[name].problem()
    if problem is not None:
        unavailable(name, problem)


def require_module(name: str) -> None:
    """At a test module's top, for a module whose every test needs prerequisite ``name``: skip
    the whole module at collection where it is missing (fail where its REQUIRE variable is 1).
    Its reason starts like :func:`unavailable`'s, so on CI the collection guard
    (:func:`pytest_make_collect_report`) lets it stand only where ``.ci/run`` declared it missing."""
    p = PREREQUISITES[name]
    problem = p.problem()
    if problem is None:
        return
    if os.environ.get(p.require_env) == "1":
        pytest.fail(f"{SKIP_PREFIX}{name} missing: {problem}; yet {p.require_env}=1: these tests must run here",
                    pytrace=False)
    pytest.skip(f"{SKIP_PREFIX}{name} missing: {problem}", allow_module_level=True)


def declared_missing() -> set[str]:
    return {n.strip() for n in os.environ.get(CI_MISSING_ENV, "").split(",") if n.strip()}


def skip_allowed_on_ci(reason: str, missing: set[str]) -> bool:
    """Whether a skip with ``reason`` may stand on CI: it names a prerequisite declared missing."""
    return any(reason.startswith(f"{SKIP_PREFIX}{name} missing:") for name in missing)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """On CI, a skip (in setup, call or a skipif mark) fails the test unless ``.ci/run`` declared
    its prerequisite missing. An expected failure (xfail) is not a skip."""
    outcome = yield
    report = outcome.get_result()
    if report.skipped and not hasattr(report, "wasxfail"):
        _fail_undeclared_skip(report, "")


def _fail_undeclared_skip(report, prefix: str) -> None:
    """On CI, turn skipped ``report`` into a failure unless its reason was declared missing."""
    if not _on_ci():
        return
    reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
    reason = reason.removeprefix("Skipped: ")
    if skip_allowed_on_ci(reason, declared_missing()):
        return
    report.outcome = "failed"
    report.longrepr = _ci_failure(prefix + reason)


def _on_ci() -> bool:
    return os.environ.get("CI", "").lower() in ("true", "1")


def _ci_failure(reason: str) -> str:
    return (f"skipped on CI (CI=true): {reason}\n.ci/run did not declare this test's prerequisite "
            f"missing ({CI_MISSING_ENV}={os.environ.get(CI_MISSING_ENV, '')!r}), so a skip here "
            f"is a test that did not run. Install what it needs, or have .ci/run say why it cannot.")


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    """On CI, a skip at collection (a module-level ``pytest.importorskip`` or ``pytest.skip(...,
    allow_module_level=True)``) is a collection error unless its prerequisite was declared missing:
    such a skip drops every test of the module before :func:`pytest_runtest_makereport` sees one."""
    outcome = yield
    report = outcome.get_result()
    if report.outcome == "skipped":
        _fail_undeclared_skip(report, f"{collector.nodeid} skipped at collection: ")


def main(argv: list[str]) -> int:
    """For ``.ci/run``: check every prerequisite; for each missing one print (stderr) why and
    which tests that skips; print (stdout) shell lines exporting the REQUIRE variables of those
    present and ``FXSWARM_CI_MISSING``."""
    present, missing = [], {}
    for p in PREREQUISITES.values():
        problem = p.problem()
        if problem is None:
            present.append(p)
        else:
            missing[p.name] = problem
    exports = sorted({p.require_env for p in present} - {PREREQUISITES[n].require_env for n in missing})
    print("".join(f"export {env}=1\n" for env in exports) + f"export {CI_MISSING_ENV}={','.join(missing)}")
    if missing:
        tests = tests_marked([PREREQUISITES[n].marker for n in missing])
        for name, problem in missing.items():
            p = PREREQUISITES[name]
            skipped = tests[p.marker]
            print(f"ci: prerequisite {name} missing ({p.installs}): {problem}\n"
                  f"ci: so these {len(skipped)} tests will skip (marker {p.marker!r}):"
                  + "".join(f"\nci:   {t}" for t in skipped), file=sys.stderr)
    else:
        print("ci: every prerequisite is here: " + ", ".join(PREREQUISITES) + "; no test may skip", file=sys.stderr)
    return 0


def tests_marked(markers: list[str]) -> dict[str, list[str]]:
    """The node ids of the collected tests carrying each marker (one ``pytest --collect-only``)."""
    import contextlib
    import io

    class Collector:
        items: list = []
        skipped: list = []  # (node id, reason) of the modules skipped whole at collection

        def pytest_collection_modifyitems(self, items) -> None:
            Collector.items = [(i.nodeid, {m.name for m in i.iter_markers()}) for i in items]

        def pytest_collectreport(self, report) -> None:
            if report.skipped:
                reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
                Collector.skipped.append((report.nodeid, reason.removeprefix("Skipped: ")))

    os.chdir(Path(__file__).resolve().parents[1])
    with contextlib.redirect_stdout(io.StringIO()):
        pytest.main(["--collect-only", "-q", "-p", "no:cacheprovider"], plugins=[Collector()])
    # A marker is its prerequisite's name (PREREQUISITES), so a module skipped for it is counted too.
    return {m: [node for node, marks in Collector.items if m in marks]
            + [f"{node} (the whole module)" for node, reason in Collector.skipped
               if reason.startswith(f"{SKIP_PREFIX}{m} missing:")] for m in markers}


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
