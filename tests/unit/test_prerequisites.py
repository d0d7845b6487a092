"""On CI a skip fails unless .ci/run declared its prerequisite missing (tests/prerequisites.py)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import prerequisites
from prerequisites import Prerequisite, unavailable

TESTS = Path(__file__).resolve().parents[1]
# The planted runs need pytest and the project's hooks only: no installed plugin (fxswarm's, xdist,
# hypothesis, timeout), whose loading was most of each run's CPU time.
BARE_PYTEST = {"PYTHONPATH": str(TESTS), "PYTEST_DISABLE_PLUGIN_AUTOLOAD": "1", "PYTEST_ADDOPTS": ""}

#: One test of each kind of outcome a CI run can meet.
SAMPLE = '''
import pytest
from prerequisites import unavailable

def test_needs_the_browser():
    unavailable("browser", "no Chromium here")

def test_skips_for_a_reason_no_prerequisite_names():
    pytest.skip("port 9876 is taken")

@pytest.mark.skipif(True, reason="not on this platform")
def test_skipif_mark():
    pass

@pytest.mark.xfail(strict=True, reason="a known gap")
def test_expected_failure():
    assert False

def test_passes():
    pass
'''


def outcomes(tmp_path: Path, **env: str) -> dict[str, str]:
    """Run SAMPLE under the project's conftest hook (a real pytest process) with ``env``; each
    test's outcome from its JUnit report: passed, failed, error (a failure in setup), skipped, xfail."""
    import xml.etree.ElementTree as ET

    (tmp_path / "conftest.py").write_text("from prerequisites import pytest_runtest_makereport  # noqa: F401\n")
    (tmp_path / "test_sample.py").write_text(SAMPLE)
    clean = {k: v for k, v in os.environ.items()
             if k not in ("CI", prerequisites.CI_MISSING_ENV) and not k.startswith("FXSWARM_REQUIRE_")}
    xml = tmp_path / "report.xml"
    r = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-o", "addopts=",
                        f"--junitxml={xml}", str(tmp_path)], capture_output=True, text=True, cwd=tmp_path,
                       env={**clean, **BARE_PYTEST, **env})
    assert xml.is_file(), r.stdout + r.stderr
    found = {}
    for case in ET.parse(xml).iter("testcase"):
        kinds = [c.tag if c.get("type") != "pytest.xfail" else "xfail" for c in case
                 if c.tag in ("failure", "error", "skipped")]
        found[case.get("name")] = kinds[0] if kinds else "passed"
    assert len(found) == 5, r.stdout + r.stderr
    return found


def test_locally_a_skip_stays_a_skip(tmp_path):
    assert outcomes(tmp_path) == {"test_needs_the_browser": "skipped",
                                  "test_skips_for_a_reason_no_prerequisite_names": "skipped",
                                  "test_skipif_mark": "skipped", "test_expected_failure": "xfail",
                                  "test_passes": "passed"}


def test_on_ci_only_a_skip_for_a_declared_missing_prerequisite_stands(tmp_path):
    assert outcomes(tmp_path, CI="true", FXSWARM_CI_MISSING="snapshot,browser") == {
        "test_needs_the_browser": "skipped",
        "test_skips_for_a_reason_no_prerequisite_names": "failure",
        "test_skipif_mark": "error",  # a skipif mark acts in setup: a failed setup is an error
        "test_expected_failure": "xfail", "test_passes": "passed"}


def test_on_ci_a_skip_for_an_undeclared_prerequisite_fails(tmp_path):
    got = outcomes(tmp_path, CI="true", FXSWARM_CI_MISSING="snapshot")
    assert got["test_needs_the_browser"] == "failure"
    assert got["test_expected_failure"] == "xfail" and got["test_passes"] == "passed"


#: Two modules skipped whole at collection: by a module-level importorskip, and for a prerequisite.
SKIPPED_AT_COLLECTION = {
    "test_importorskip.py": 'import pytest\npytest.importorskip("fxswarm_no_such_module")\n\ndef test_x():\n    pass\n',
    "test_needs_browser.py": ('import pytest\npytest.skip("prerequisite browser missing: no Chromium here", '
                              'allow_module_level=True)\n\ndef test_y():\n    pass\n'),
    "test_passes.py": "def test_z():\n    pass\n",
}


def collection_run(tmp_path: Path, *args: str, **env: str) -> subprocess.CompletedProcess:
    (tmp_path / "conftest.py").write_text(
        "from prerequisites import pytest_make_collect_report, pytest_runtest_makereport  # noqa: F401\n")
    for name, text in SKIPPED_AT_COLLECTION.items():
        (tmp_path / name).write_text(text)
    clean = {k: v for k, v in os.environ.items()
             if k not in ("CI", prerequisites.CI_MISSING_ENV) and not k.startswith("FXSWARM_REQUIRE_")}
    return subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-o", "addopts=",
                           "-rA", *args, str(tmp_path)], capture_output=True, text=True, cwd=tmp_path,
                          env={**clean, **BARE_PYTEST, **env})


def test_locally_a_module_skipped_at_collection_stays_skipped(tmp_path):
    r = collection_run(tmp_path)
    assert r.returncode == 0 and "1 passed, 2 skipped" in r.stdout, r.stdout


def test_on_ci_a_module_skipped_at_collection_fails_unless_its_prerequisite_was_declared_missing(tmp_path):
    """The planted importorskip drops its module's tests at collection, before any test report:
    on CI it is an error, while the module skipped for a declared-missing prerequisite stands."""
    r = collection_run(tmp_path, CI="true", FXSWARM_CI_MISSING="browser")
    assert r.returncode != 0, r.stdout
    assert re.search(r"^ERROR test_importorskip.py", r.stdout, re.M), r.stdout
    assert "skipped on CI (CI=true): test_importorskip.py skipped at collection: " in r.stdout
    assert "could not import 'fxswarm_no_such_module'" in r.stdout
    assert re.search(r"^SKIPPED .*test_needs_browser.py.*prerequisite browser missing", r.stdout, re.M), r.stdout
    assert "1 skipped, 1 error" in r.stdout, r.stdout
    # (Undeclared, the prerequisite's skip fails by the same test of its reason: skip_allowed_on_ci.)


def test_on_ci_a_module_skipped_at_collection_fails_on_pytest_xdist_workers_too(tmp_path):
    """`make test` collects on pytest-xdist workers: their collection reports come back to the
    controller, the planted importorskip's as an error there too."""
    r = collection_run(tmp_path, "-p", "xdist", "-n", "2", CI="true", FXSWARM_CI_MISSING="browser")
    assert r.returncode != 0, r.stdout
    assert re.search(r"^ERROR test_importorskip.py", r.stdout, re.M), r.stdout
    assert "1 passed" in r.stdout and "1 error" in r.stdout, r.stdout


def test_a_missing_prerequisite_fails_where_its_require_variable_is_set(monkeypatch):
    monkeypatch.delenv("FXSWARM_REQUIRE_BROWSER", raising=False)
    with pytest.raises(pytest.skip.Exception, match=r"^prerequisite browser missing: no Chromium"):
        unavailable("browser", "no Chromium")
    monkeypatch.setenv("FXSWARM_REQUIRE_BROWSER", "1")
    with pytest.raises(pytest.fail.Exception, match=r"browser missing: no Chromium; yet FXSWARM_REQUIRE_BROWSER=1"):
        unavailable("browser", "no Chromium")


def test_the_ci_check_exports_what_is_here_and_names_what_is_not_and_its_tests(monkeypatch, capsys):
    monkeypatch.setattr(prerequisites, "PREREQUISITES", {p.name: p for p in (
        Prerequisite("docker", "docker", "FXSWARM_REQUIRE_DOCKER", lambda: None, "-"),
        Prerequisite("compose", "compose", "FXSWARM_REQUIRE_DOCKER", lambda: None, "-"),
        Prerequisite("browser", "browser", "FXSWARM_REQUIRE_BROWSER", lambda: "no Chromium here", "install-browser"),
    )})
    monkeypatch.setattr(prerequisites, "tests_marked",
                        lambda markers: {"browser": ["tests/integration/test_web.py::test_draws"]})
    assert prerequisites.main([]) == 0
    out, err = capsys.readouterr()
    assert out.splitlines() == ["export FXSWARM_REQUIRE_DOCKER=1", "export FXSWARM_CI_MISSING=browser"]
    assert "ci: prerequisite browser missing (install-browser): no Chromium here" in err
    assert "ci:   tests/integration/test_web.py::test_draws" in err


def test_a_prerequisite_missing_takes_its_require_variable_off_even_if_another_of_it_is_here(monkeypatch, capsys):
    """docker and compose share FXSWARM_REQUIRE_DOCKER: without an engine it must not be set."""
    monkeypatch.setattr(prerequisites, "PREREQUISITES", {p.name: p for p in (
        Prerequisite("docker", "docker", "FXSWARM_REQUIRE_DOCKER", lambda: "no Docker engine answers", "-"),
        Prerequisite("compose", "compose", "FXSWARM_REQUIRE_DOCKER", lambda: None, "-"),
    )})
    monkeypatch.setattr(prerequisites, "tests_marked", lambda markers: {"docker": []})
    prerequisites.main([])
    assert capsys.readouterr().out.splitlines() == ["export FXSWARM_CI_MISSING=docker"]
