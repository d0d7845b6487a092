"""The ROS 2 world: fxswarm's agents and leader over Zenoh fly robots that speak ROS 2 over DDS.

The robots are plain Cyclone DDS participants (``ros2_robots.py``): they subscribe each
``rt/robot<i>/cmd_vel`` and publish each ``rt/robot<i>/pose`` at 50 Hz with ROS 2's type names.
All DDS stays on the loopback interface, multicast off (``tests/cyclonedds-loopback.xml``), in
a domain of the test's own.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time

import numpy as np
import pytest

from fxswarm.core.scenario import load
from ros2_support import Robots, dds_environment, running
from support import CONFIGS, fxswarm_command, measured

from prerequisites import require_module  # noqa: E402

# Every test here speaks DDS: without Cyclone DDS the module skips at collection, which on CI
# fails unless .ci/run declared prerequisite ros2 missing (tests/prerequisites.py).
require_module("ros2")
pytestmark = pytest.mark.ros2

CONFIG = CONFIGS / "ros2-square.toml"
#: Final formation error allowed, m (the simulated world ends at 0.07 m on this scenario).
FORMATION_TOLERANCE_M = 0.25
#: No two robots (or robot and obstacle) closer than this, m: the scenario's repulsive radius d.
COLLISION_M = 0.5


@pytest.fixture
def dds(monkeypatch):
    env = dds_environment()
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    return env


@pytest.fixture
def robots(tmp_path, dds):
    made: list[Robots] = []

    def start(*extra: str, scenario=CONFIG) -> Robots:
        r = Robots(scenario, tmp_path, *extra)
        made.append(r)
        r.wait_for("ready")
        return r

    yield start
    for r in made:
        r.kill()


def shape_error(positions: np.ndarray, offsets: np.ndarray) -> float:
    """How far the robots are from the formation's shape, whatever the leader did: max over robots
    of |(p_i - mean p) - (o_i - mean o)|, m."""
    return float(np.linalg.norm((positions - positions.mean(0)) - (offsets - offsets.mean(0)), axis=1).max())


@pytest.mark.zenoh
def test_ros2_world_flies_dds_robots_into_formation_and_leaves_every_one_at_zero(tmp_path, robots):
    stand_in = robots()
    out = tmp_path / "run"
    run = subprocess.run(fxswarm_command("run", CONFIG, "--world", "ros2", "--no-logger", "--quiet", "--out", out),
                         capture_output=True, text=True, timeout=180)
    assert run.returncode == 0, run.stderr
    stand_in.wait_for("moving", timeout=1)  # said long ago: every robot was driven
    stand_in.wait_for("stopped", timeout=10)  # and every robot's latest Twist is zero
    report = stand_in.finish()
    summary = json.loads((out / "summary.json").read_text())
    sc = load(CONFIG)
    offsets = np.array([r.offset.position(sc.duration) for r in sc.robots])
    world = summary["processes"]["world-0"]
    measured("ros2_world", load1=os.getloadavg()[0], nonzero_twists_min=min(report["nonzero_twists"]),
             formation_error_final_m=summary["formation_error_final_m"],
             min_object_distance_m=summary["min_object_distance_m"], poses_received=world["ros2_poses_received"],
             shape_error_m=shape_error(np.array(report["positions"]), offsets), closest_m=report["closest_m"])
    # Measured (23 runs of issue 40 at load average 12-27, the machine shared with other test
    # runs; MEASURED lines): nonzero twists 397-400 each (50 Hz of simulation time for 8 s), final
    # formation error 0.014-0.107 m (sim 0.07; bound 0.25: 2.3x the worst), closest approach
    # 1.80-1.96 m (bound 0.5 m, the repulsive radius), poses received 1282-1605 (bound 1000), the
    # robots' own shape error 0.007-0.077 m (bound 0.25, 3x).
    assert report["last_twist"] == [[0.0, 0.0, 0.0]] * 4
    assert min(report["nonzero_twists"]) > 100, report["nonzero_twists"]  # 50 Hz for 8 s: about 400 each

    detail = {k: summary.get(k) for k in ("complete", "formation_error_final_m", "min_object_distance_m",
                                          "late_ticks", "sense_to_command")}
    assert summary["complete"] and summary["clock"] == "realtime", detail
    assert summary["formation_error_final_m"] <= FORMATION_TOLERANCE_M, detail
    assert summary["min_object_distance_m"] >= COLLISION_M, detail
    assert world["ros2_zero_twists_acknowledged"] is True
    assert world["ros2_poses_received"] > 1000 and world["ros2_poses_dropped"] == 0
    # The robots' own account (their integration, not the world's record) agrees.
    assert shape_error(np.array(report["positions"]), offsets) <= FORMATION_TOLERANCE_M, report["positions"]
    assert report["closest_m"] >= COLLISION_M, report["closest_m"]


@pytest.mark.zenoh
def test_ctrl_c_on_fxswarm_run_leaves_every_robot_at_zero(tmp_path, robots):
    stand_in = robots()
    with running(fxswarm_command("run", CONFIG, "--world", "ros2", "--no-logger", "--quiet",
                                 "--out", tmp_path / "run")) as run:
        stand_in.wait_for("moving", timeout=90)
        run.send_signal(signal.SIGINT)
        stand_in.wait_for("stopped", timeout=10)
        _, err = run.communicate(timeout=30)
    assert run.returncode == 130, err
    assert stand_in.finish()["last_twist"] == [[0.0, 0.0, 0.0]] * 4


@pytest.fixture
def flying(robots, launch_swarm):
    """The stand-in robots flown by a swarm whose world is the ROS 2 one, 2 s into the run."""
    stand_in = robots()
    swarm = launch_swarm(CONFIG, clock="realtime", world_args=("--ros2",))
    stand_in.wait_for("moving", timeout=60)
    swarm.wait_for_sim_time(2.0)
    return stand_in, swarm


@pytest.mark.zenoh
def test_sigterm_to_the_ros2_world_mid_run_leaves_every_robot_at_zero(flying):
    stand_in, swarm = flying
    swarm.terminate("world")
    stand_in.wait_for("stopped", timeout=10)
    report = stand_in.finish()
    assert report["last_twist"] == [[0.0, 0.0, 0.0]] * 4
    world = swarm.swarm.children["world"]
    assert world.popen.wait(10) == 128 + 15  # ended by SIGTERM, mid-run


@pytest.mark.zenoh
def test_when_the_gateway_loses_the_swarm_every_robot_gets_zero_within_5_s(flying):
    stand_in, swarm = flying
    for r in swarm.scenario.robots:
        swarm.kill(f"agent-{r.id}")
    killed = time.monotonic()
    stand_in.wait_for("stopped", timeout=5)
    # The world runs on to the end, every robot held at zero, and says it flew alone (exit 1).
    summary = swarm.wait_done(expect_exit=1)
    assert summary["complete"] and summary["degraded"]["robots"] == [1, 2, 3, 4], summary["degraded"]
    report = stand_in.finish()
    assert report["last_twist"] == [[0.0, 0.0, 0.0]] * 4
    # Judged on the robots' clock, not on the "stopped" line, which a hold before the kill (a
    # pose gone stale under load) may have said already: no non-zero Twist 5 s after the kill.
    # Measured (20 runs of issue 40 at load average 15-33): the last 0.30-0.39 s after it (13x).
    to_zero = max(report["last_nonzero_at"]) - killed
    measured("ros2_gateway_lost", load1=os.getloadavg()[0], to_zero_s=to_zero)
    assert to_zero <= 5.0, report["last_nonzero_at"]


@pytest.mark.zenoh
def test_a_robot_whose_pose_goes_stale_is_reported_and_held_at_zero(tmp_path, robots):
    stand_in = robots("--mute", "2:1.0")
    out = tmp_path / "run"
    with running(fxswarm_command("run", CONFIG, "--world", "ros2", "--no-logger", "--quiet", "--out", out)) as run:
        stand_in.wait_for("muted 2", timeout=90)
        stand_in.wait_for("held 2", timeout=5)  # pose_timeout is 0.5 s
        _, err = run.communicate(timeout=120)
    assert run.returncode == 0, err
    report = stand_in.finish()
    assert report["last_twist"][1] == [0.0, 0.0, 0.0]
    summary = json.loads((out / "summary.json").read_text())
    world = summary["processes"]["world-0"]
    assert world["ros2_stale_episodes"]["2"] == 1 and world["ros2_stale_pose_ticks"]["2"] > 100
    assert all(world["ros2_stale_episodes"][r] == 0 for r in "134"), world["ros2_stale_episodes"]
    world_log = (out / "logs" / "world.log").read_text()
    assert "robot 2's pose is" in world_log and "holding it at zero" in world_log
