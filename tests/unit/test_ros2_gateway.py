"""The ROS 2 world's pure parts (no DDS on the wire): [ros2] checks, the gateway node's safety
rules, the differential-drive mapping, ROS 2's type names, and the command line's refusals."""

from __future__ import annotations

import math
import os
import subprocess
import tomllib

import numpy as np
import pytest

from fxswarm.core.scenario import ScenarioError, load, parse
from fxswarm.testing import dump_toml
from support import CONFIGS, fxswarm_command
from fxswarm.world.node import nearest_objects
from prerequisites import require

CONFIG = CONFIGS / "ros2-square.toml"



# fxswarm.world.ros2 and ros2_msgs import Cyclone DDS (the [ros2] extra): only the tests that use
# them ask for it (these fixtures, marker ros2); the scenario and command-line checks run without.
@pytest.fixture
def ros2():
    require("ros2")
    from fxswarm.world import ros2

    return ros2


@pytest.fixture
def ros2_msgs():
    require("ros2")
    from fxswarm.world import ros2_msgs

    return ros2_msgs


def with_ros2(folder, **table) -> str:
    data = tomllib.loads(CONFIG.read_text())
    data["ros2"] = table
    path = folder / "ros2.toml"
    path.write_text(dump_toml(data))
    return str(path)


# --- [ros2] ------------------------------------------------------------------------------------


@pytest.mark.parametrize("table, field", [
    ({"pose_type": "Pose"}, "ros2.pose_type"),
    ({"pose_type": "TwistStamped"}, "ros2.pose_type"),
    ({"cmd_topic": "robot{id}/cmd_vel"}, "ros2.cmd_topic"),  # not absolute
    ({"cmd_topic": "/robot/cmd_vel"}, "ros2.cmd_topic"),  # no {id}: every robot on one topic
    ({"pose_topic": "/robot{id}//pose"}, "ros2.pose_topic"),
    ({"pose_topic": "/robot{id}/pose!"}, "ros2.pose_topic"),
    ({"pose_topic": "/{id}/pose"}, "ros2.pose_topic"),  # a token starting with a digit
    ({"pose_topic": "/robot{id}/cmd_vel"}, "ros2.cmd_topic"),  # the same topic both ways
    ({"frame": "my frame"}, "ros2.frame"),
    ({"v_max": 0}, "ros2.v_max"),
    ({"drive": "tracked"}, "ros2.drive"),
    ({"rate": 50}, "ros2.rate"),
])
def test_a_bad_ros2_table_is_refused_naming_the_field(table, field):
    data = tomllib.loads(CONFIG.read_text())
    data["ros2"] = table
    with pytest.raises(ScenarioError, match=f"^x.toml: {field}: expected"):
        parse(data, "x.toml")


def test_the_ros2_table_defaults_are_the_issue_s(ros2_msgs):
    s = load(CONFIG).ros2
    assert (s.pose_topic, s.pose_type, s.cmd_topic, s.frame, s.drive) == (
        "/robot{id}/pose", "PoseStamped", "/robot{id}/cmd_vel", "world", "holonomic")
    assert s.topic(s.cmd_topic, 3) == "/robot3/cmd_vel" and ros2_msgs.dds_topic("/robot3/cmd_vel") == "rt/robot3/cmd_vel"


@pytest.mark.parametrize("args, field", [
    (("--world", "ros2"), "ros2.pose_type"),
    (("--world", "ros2", "--clock", "realtime"), "ros2.pose_type"),
])
def test_fxswarm_run_refuses_an_unknown_message_type_before_anything_starts(tmp_path, args, field, fxswarm_here):
    out = tmp_path / "run"
    code, _, err = fxswarm_here("run", with_ros2(tmp_path, pose_type="Pose"), *args, "--out", out)
    assert code == 2 and f"ros2.toml: {field}: expected one of 'PoseStamped', 'Odometry'" in err
    assert not out.exists()  # nothing started, no run folder


def test_fxswarm_world_refuses_a_malformed_topic(tmp_path, fxswarm_here):
    code, _, err = fxswarm_here("world", with_ros2(tmp_path, cmd_topic="/robot{id}/cmd vel"), "--ros2",
                                "--clock", "realtime")
    assert code == 2 and "ros2.cmd_topic: expected an absolute ROS 2 topic" in err, err


#: Run first in the child: importing Cyclone DDS fails, as where fxswarm[ros2] is not installed.
NO_CYCLONEDDS = """
import importlib.abc, sys
class Absent(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] == "cyclonedds":
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
sys.meta_path.insert(0, Absent())
"""


@pytest.mark.parametrize("command", [("run", "--world", "ros2"), ("world", "--ros2", "--clock", "realtime")])
def test_without_the_extra_the_ros2_world_names_it_and_exits_2(tmp_path, command):
    shim = tmp_path / "shim"
    shim.mkdir()
    (shim / "sitecustomize.py").write_text(NO_CYCLONEDDS)
    env = {**os.environ, "PYTHONPATH": f"{shim}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    out = tmp_path / "run"
    r = subprocess.run(fxswarm_command(command[0], CONFIG, *command[1:], "--out", out),
                       capture_output=True, text=True, timeout=60, env=env)
    assert r.returncode == 2, r.stderr
    assert "needs the ros2 extra" in r.stderr and "pip install 'fxswarm[ros2]'" in r.stderr, r.stderr
    assert not out.exists()
    # The shim is real: the same interpreter cannot import Cyclone DDS.
    probe = subprocess.run(fxswarm_command("--help")[:1] + ["-c", "import cyclonedds"], env=env,
                           capture_output=True, text=True, timeout=60)
    assert probe.returncode != 0 and "No module named 'cyclonedds'" in probe.stderr


@pytest.mark.parametrize("args, says", [
    (("--world", "ros2", "--clock", "lockstep"), "real time (--clock realtime) at --speed 1 only"),
    (("--world", "ros2", "--speed", "2"), "real time (--clock realtime) at --speed 1 only"),
])
def test_fxswarm_run_ros2_is_real_time_at_speed_1_only(tmp_path, args, says, fxswarm_here):
    code, _, err = fxswarm_here("run", CONFIG, *args, "--out", tmp_path / "run")
    assert code == 2 and says in err, err


def test_a_ros2_world_without_a_speed_limit_is_refused(tmp_path, fxswarm_here):
    data = tomllib.loads(CONFIG.read_text())
    del data["scenario"]["v_max"]
    path = tmp_path / "no-limit.toml"
    path.write_text(dump_toml(data))
    code, _, err = fxswarm_here("run", path, "--world", "ros2", "--out", tmp_path / "run")
    assert code == 2 and "ros2.v_max: expected a speed limit" in err, err


@pytest.mark.parametrize("value, ok", [("", 0), ("7", 7), ("232", 232), ("233", None), ("x", None), ("-1", None)])
def test_ros_domain_id_is_read_as_ros_2_reads_it(value, ok, ros2):
    if ok is None:
        with pytest.raises(ValueError, match="ROS_DOMAIN_ID"):
            ros2.domain_id({"ROS_DOMAIN_ID": value})
    else:
        assert ros2.domain_id({"ROS_DOMAIN_ID": value}) == ok


# --- the gateway node --------------------------------------------------------------------------


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def gateway(ros2, **ros2_table):
    data = tomllib.loads(CONFIG.read_text())
    data["ros2"].update(ros2_table)
    sc = parse(data, "ros2-square.toml")
    clock = Clock()
    board = ros2.PoseBoard(sc.n, sc.ros2.pose_timeout, clock)
    measured = np.array([[3.0, 0.0, 1.0], [0.0, 3.0, 1.0], [-3.0, 0.0, 1.0], [0.0, -0.4, 1.0]])
    for i, p in enumerate(measured, 1):
        board.put(i, tuple(p), 0.0)
    return ros2.GatewayWorld(sc, board), board, clock, measured


def commands(world, v):
    from fxswarm.core.messages import Command

    for i, vi in enumerate(v, 1):
        world.take_command(Command("agent", i, 1, world.tick, world.t, i, np.array(vi, float), np.zeros(3), False))


def test_the_gateway_senses_the_measured_poses_as_the_simulated_world_would(ros2):
    world, board, clock, measured = gateway(ros2)
    out = world.start()
    np.testing.assert_array_equal(world.p, measured)  # the robots' poses, not the scenario's positions
    po, _, dist, _, _ = nearest_objects(measured, np.zeros((4, 3)), np.zeros((0, 3)), np.zeros((0, 3)))
    senses = [m for t, m in out if "/sense/" in t]
    assert [s.robot for s in senses] == [1, 2, 3, 4]
    for s, p_i, po_i in zip(senses, measured, po):
        np.testing.assert_array_equal(s.p, p_i)
        np.testing.assert_array_equal(s.po, po_i)
    # The next tick takes the poses that came meanwhile: no integration of its own.
    commands(world, [[1.0, 0, 0]] * 4)
    board.put(1, (3.5, 0.0, 1.0), 0.0)
    world.advance(world.sc.dt)
    np.testing.assert_array_equal(world.p[0], [3.5, 0.0, 1.0])
    np.testing.assert_array_equal(world.p[1:], measured[1:])


def test_commands_are_limited_to_v_max_keeping_their_direction(ros2):
    world, *_ = gateway(ros2, v_max=0.5)
    world.start()
    commands(world, [[3.0, 4.0, 0.0], [0.1, 0.0, 0.0], [0, 0, 0], [0, 0, -2.0]])
    world.advance(world.sc.dt)
    v = world.velocities()
    np.testing.assert_allclose(v, [[0.3, 0.4, 0], [0.1, 0, 0], [0, 0, 0], [0, 0, -0.5]])
    assert world.report()["ros2_limited_ticks"] == {"1": 1, "2": 0, "3": 0, "4": 1}


def test_a_stale_pose_holds_its_robot_at_zero_and_is_said(capsys, ros2):
    world, board, clock, _ = gateway(ros2)
    world.start()
    commands(world, [[0.2, 0, 0]] * 4)
    clock.t += 0.4
    for i in (1, 2, 4):
        board.put(i, (0.0, 0.0, float(i)), 0.0)  # robot 3 falls silent
    world.advance(world.sc.dt)
    assert (world.velocities()[:, 0] == 0.2).all()  # 0.4 s: within pose_timeout (0.5 s)
    clock.t += 0.2
    for i in (1, 2, 4):
        board.put(i, (0.0, 0.0, float(i)), 0.0)
    world.advance(world.sc.dt)
    assert world.velocities()[:, 0].tolist() == [0.2, 0.2, 0.0, 0.2]
    assert "robot 3's pose is 0.60 s old (limit 0.5 s): holding it at zero" in capsys.readouterr().err
    world.advance(world.sc.dt)
    assert capsys.readouterr().err == ""  # said once per episode
    assert world.v[2, 0] == 0.0  # as its teammates sense it: still
    board.put(3, (0.0, 0.0, 3.0), 0.0)
    commands(world, [[0.2, 0, 0]] * 4)
    world.advance(world.sc.dt)
    assert world.velocities()[2, 0] == 0.2  # its pose is back: so are its commands
    assert world.report()["ros2_stale_episodes"]["3"] == 1


def test_a_gone_or_silent_agent_s_robot_gets_zero(ros2):
    world, board, clock, _ = gateway(ros2)
    world.start()
    commands(world, [[0.2, 0, 0]] * 4)
    world.gone = {2}
    assert world.velocities()[:, 0].tolist() == [0.2, 0.0, 0.2, 0.2]
    world.gone = ()
    # Agent 4 silent: the world's own hold rule (silent_hold, 0.5 s) zeroes it.
    for _ in range(30):
        clock.t += world.sc.dt
        for i in range(1, 5):
            board.put(i, (0.0, 0.0, float(i)), 0.0)
        commands(world, [[0.2, 0, 0]] * 3)
        world.advance(world.sc.dt)
    assert world.velocities()[:, 0].tolist() == [0.2, 0.2, 0.2, 0.0]


# --- the differential-drive mapping ------------------------------------------------------------


@pytest.mark.parametrize("v, yaw, forward, omega", [
    ((1.0, 0.0, 0.0), 0.0, 1.0, 0.0),  # ahead: drive, no turn
    ((0.0, 1.0, 0.0), 0.0, 0.0, 2.0),  # 90 degrees left: turn in place (cos 90 = 0), at omega_max
    ((0.0, -0.5, 0.0), math.pi / 2, 0.0, -2.0),  # behind: turn, never reverse
    ((0.5, 0.5, 0.3), math.pi / 4, math.hypot(0.5, 0.5), 0.0),  # the vertical part is dropped
    ((0.0, 0.0, 0.0), 1.0, 0.0, 0.0),
])
def test_differential_drive_turns_toward_the_velocity_and_never_reverses(v, yaw, forward, omega, ros2):
    f, w = ros2.differential_drive(np.array(v), yaw, heading_gain=2.0, omega_max=2.0)
    assert f == pytest.approx(forward, abs=1e-12) and w == pytest.approx(omega, abs=1e-12)


def test_a_small_heading_error_turns_proportionally(ros2):
    f, w = ros2.differential_drive(np.array([1.0, 0.0, 0.0]), 0.1, heading_gain=2.0, omega_max=2.0)
    assert w == pytest.approx(-0.2) and f == pytest.approx(math.cos(0.1))


def test_yaw_of_a_quaternion(ros2):
    half = math.pi / 8
    assert ros2.yaw_of(0.0, 0.0, math.sin(half), math.cos(half)) == pytest.approx(math.pi / 4)


# --- ROS 2's names on the wire -----------------------------------------------------------------


@pytest.mark.parametrize("cls, name", [
    ("Twist_", "geometry_msgs::msg::dds_::Twist_"),
    ("PoseStamped_", "geometry_msgs::msg::dds_::PoseStamped_"),
    ("Odometry_", "nav_msgs::msg::dds_::Odometry_"),
    ("Header_", "std_msgs::msg::dds_::Header_"),
    ("Time_", "builtin_interfaces::msg::dds_::Time_"),
    ("MarkerArray_", "visualization_msgs::msg::dds_::MarkerArray_"),
])
def test_types_carry_ros_2_s_dds_names(cls, name, ros2_msgs):
    assert getattr(ros2_msgs, cls).__idl_typename__ == name


def test_a_twist_is_48_bytes_of_doubles_after_the_header(ros2_msgs):
    # CDR: 4 bytes of encapsulation header, then 6 doubles, as a ROS 2 node sends it.
    assert len(ros2_msgs.Twist_().serialize()) == 4 + 48
