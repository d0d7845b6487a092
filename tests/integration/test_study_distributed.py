"""The semi-implicit discretisation over real processes and Zenoh: the same node code, so the
lock-step run must equal the in-process one bit for bit, as the Euler path does."""

from __future__ import annotations

import pytest

from fxswarm.core.scenario import load

from support import PAPER_FAST


@pytest.mark.zenoh
def test_semi_implicit_lockstep_run_is_bit_identical_to_the_sim(launch_swarm):
    swarm = launch_swarm(PAPER_FAST, duration=1.0, **{"controller.discretisation": "semi-implicit"})
    summary = swarm.wait_done(timeout=120)
    assert load(swarm.swarm.config).discretisation == "semi-implicit"
    swarm.assert_matches_sim(keys=("p", "ph", "v"))
    assert summary["complete"] and summary["missed_ticks"] == 0
