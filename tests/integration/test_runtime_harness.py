"""The README's example of a user's test, run as written (shorter), plus the harness's own promises."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from support import PAPER_FAST, REPO


pytest_plugins = ["pytester"]  # runs a user's test file in a subprocess


@pytest.mark.zenoh
def test_readme_example_robot_3_rejoins(launch_swarm, monkeypatch):
    monkeypatch.chdir(REPO)  # the example names configs/ relative to the project
    swarm = launch_swarm("configs/paper-fast.toml", duration=4.0)  # [scenario] overrides
    swarm.wait_for_sim_time(1.0)
    swarm.kill("agent-3")
    swarm.wait_for_sim_time(1.5)
    swarm.restart("agent-3")
    assert swarm.position(3).shape == (3,) and swarm.state().t >= 1.5
    summary = swarm.wait_done()
    assert summary["complete"] and summary["min_object_distance_m"] > 1.0
    assert not swarm.deaths  # killed through the handle: planned, not a death


@pytest.mark.zenoh
@pytest.mark.slow
def test_the_fixture_tears_everything_down(pytester):
    """A test that fails mid-run still leaves no process behind."""
    pytester.makepyfile(f"""
        import json
        def test_fails(launch_swarm):
            swarm = launch_swarm({str(PAPER_FAST)!r}, duration=100.0)
            swarm.wait_for_sim_time(0.2)
            open("pids.json", "w").write(json.dumps(list(swarm.pids().values())))
            assert False, "on purpose"
    """)
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(failed=1)
    import json

    pids = json.loads((pytester.path / "pids.json").read_text())
    assert len(pids) >= 9
    for pid in pids:
        try:
            os.kill(pid, 0)
            stat = Path(f"/proc/{pid}/stat").read_text()
            assert stat.rsplit(")", 1)[1].split()[0] == "Z", f"process {pid} outlived its test"
        except ProcessLookupError:
            pass
