"""The README's example of a user's test, run as written (shorter), plus the harness's own promises."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from fxswarm.core.metrics import formation_errors
from fxswarm.runtime.output import load_trajectory

from support import PAPER_FAST, REPO


pytest_plugins = ["pytester"]  # runs a user's test file in a subprocess


@pytest.mark.zenoh
def test_readme_example_robot_3_rejoins(launch_swarm, monkeypatch):
    """The guide's example, asserting what its name says: robot 3, killed and started again,
    commands again and flies back into formation (within the scenario's settle tolerance).

    A lock-step world does not wait for a dead robot, so it would race robot 3's start (a second
    or more of wall time on a loaded machine) to the end of the run: it is frozen meanwhile,
    and the rejoin happens at a tick, not at a wall time. 12 s: started again with fresh
    estimates 1.8 m off its slot, robot 3 is within the 0.2 m tolerance from about 9.5 s (0.12 m
    at the end; lock-step, so only the ticks of the kill and the freeze vary)."""
    monkeypatch.chdir(REPO)  # the example names configs/ relative to the project
    swarm = launch_swarm("configs/paper-fast.toml", duration=12.0)  # [scenario] overrides
    swarm.wait_for_sim_time(2.0)
    swarm.kill("agent-3")
    swarm.wait_for_sim_time(3.0)
    swarm.freeze("world")
    swarm.restart("agent-3")
    swarm.thaw("world")
    back = swarm.sim_time()
    assert swarm.position(3).shape == (3,) and back < 4.0, back
    summary = swarm.wait_done()
    assert summary["complete"] and summary["min_object_distance_m"] > 1.0
    assert not swarm.deaths  # killed through the handle: planned, not a death
    assert summary["faults"]["degraded_ticks"]["world_held_at_zero"]["3"] > 20, "held still while dead"
    traj = load_trajectory(swarm.out)
    t, v3 = traj["t"], np.linalg.norm(traj["v"][:, 2], axis=1)
    # It commands again: from a second after its restart on, the world applies its every command.
    assert v3[t > back + 1.0].all(), "robot 3 does not command again"
    err = formation_errors(traj)[:, 2]
    sc = swarm.scenario
    assert err[t > 2.9].max() > 2 * sc.settle_tolerance, "robot 3 never fell out of formation: nothing tested"
    assert err[-1] <= sc.settle_tolerance, f"robot 3 ends {err[-1]:.3f} m off its slot"


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
