"""What may reach a real robot (world/safety.py): pure, so checked without the ros2 extra."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from fxswarm.core.scenario import parse
from fxswarm.world.safety import Safety, limited, require_speed_limit

from support import CONFIGS

CONFIG = CONFIGS / "ros2-square.toml"


def scenario(**ros2_table):
    data = tomllib.loads(CONFIG.read_text())
    data["ros2"].update(ros2_table)
    return parse(data, "ros2-square.toml")


def test_a_command_is_scaled_to_the_limit_keeping_its_direction():
    v = limited(np.array([[3.0, 4.0, 0.0], [0.1, 0.0, 0.0]]), 1.0)
    assert v[0] == pytest.approx([0.6, 0.8, 0.0]) and v[1].tolist() == [0.1, 0.0, 0.0]


def test_without_a_speed_limit_the_file_and_fields_are_named():
    data = tomllib.loads(CONFIG.read_text())
    data["ros2"].pop("v_max", None)
    data["scenario"].pop("v_max", None)
    with pytest.raises(ValueError, match=r"ros2-square.toml: ros2.v_max: expected a speed limit"):
        require_speed_limit(parse(data, "ros2-square.toml"))


def test_a_stale_pose_or_a_gone_agent_gets_zero_and_each_stale_episode_is_counted_once():
    sc = scenario(v_max=0.5)
    safety = Safety(sc)
    v = np.tile([1.0, 0.0, 0.0], (sc.n, 1))
    fresh = np.ones(sc.n, dtype=bool)
    fresh[1] = False
    assert safety.tick(fresh, v).tolist() == [1]  # robot 2's pose just went stale
    assert safety.tick(fresh, v).tolist() == []  # the same episode
    safety.gone = (3,)
    out = safety.safe(v)
    assert out[1].tolist() == [0.0, 0.0, 0.0] and out[2].tolist() == [0.0, 0.0, 0.0]
    assert out[0] == pytest.approx([0.5, 0.0, 0.0])
    assert safety.stale_episodes[1] == 1 and safety.stale_pose_ticks[1] == 2 and safety.limited_ticks[0] == 2
