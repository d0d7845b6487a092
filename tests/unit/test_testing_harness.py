"""The test harness (fxswarm.testing) before any process starts."""

import pytest

from fxswarm.testing import SwarmUnderTest
from support import PAPER_FAST


def test_waiting_on_the_silence_of_a_robot_the_world_cannot_see_is_an_error_not_a_timeout(tmp_path):
    swarm = SwarmUnderTest(PAPER_FAST, tmp_path)  # built, never started
    with pytest.raises(ValueError, match="robot 99: no links into it"):
        swarm.wait_for_silence(99, ticks=3, timeout=0.1)
