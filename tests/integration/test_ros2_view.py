"""``fxswarm run --ros2``: a run of the simulated world, seen by a plain DDS subscriber as ROS 2 sees it
(loopback, multicast off): robot and leader poses, estimates, obstacles as markers."""

from __future__ import annotations

import importlib.util
import os
import time
import tomllib

import numpy as np
import pytest

from fxswarm.core.scenario import load
from fxswarm.testing import dump_toml
from ros2_support import ROBOTS, dds_environment, running
from support import CONFIGS, fxswarm_command, measured

from prerequisites import require_module  # noqa: E402

# Every test here speaks DDS: without Cyclone DDS the module skips at collection, which on CI
# fails unless .ci/run declared prerequisite ros2 missing (tests/prerequisites.py).
require_module("ros2")
pytestmark = pytest.mark.ros2

from cyclonedds.core import Policy, Qos  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402

from fxswarm.world.ros2_msgs import MARKER_SPHERE, MarkerArray_  # noqa: E402


def stand_in_types():
    """PoseStamped as the stand-in robots write it from the .msg files (not fxswarm's own)."""
    spec = importlib.util.spec_from_file_location("ros2_robots", ROBOTS)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.PoseStamped


@pytest.mark.zenoh
def test_fxswarm_run_ros2_publishes_poses_estimates_leader_and_obstacle_markers(tmp_path, monkeypatch):
    for k, v in dds_environment().items():
        monkeypatch.setenv(k, v)
    data = tomllib.loads((CONFIGS / "ros2-square.toml").read_text())
    data["scenario"]["duration"] = 4.0
    data["obstacles"] = [{"kind": "static", "position": [0.0, 0.0, 5.0]}]
    config = tmp_path / "view.toml"
    config.write_text(dump_toml(data))
    sc = load(config)

    PoseStamped = stand_in_types()
    dp = DomainParticipant(int(os.environ["ROS_DOMAIN_ID"]))
    qos = Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(1000))
    names = [f"robot{i}/pose" for i in range(1, 5)] + [f"robot{i}/estimate" for i in range(1, 5)] + ["leader/pose"]
    readers = {n: DataReader(dp, Topic(dp, f"rt/fxswarm/{n}", PoseStamped), qos=qos) for n in names}
    markers = DataReader(dp, Topic(dp, "rt/fxswarm/obstacles", MarkerArray_), qos=qos)
    got: dict[str, list] = {n: [] for n in [*names, "obstacles"]}

    with running(fxswarm_command("run", config, "--ros2", "--clock", "realtime", "--no-logger", "--quiet",
                                 "--out", tmp_path / "run")) as run:
        end = time.monotonic() + 120
        while run.poll() is None and time.monotonic() < end:
            for n, r in readers.items():
                got[n] += [s for s in r.take(N=100) if isinstance(s, PoseStamped)]
            got["obstacles"] += [s for s in markers.take(N=100) if isinstance(s, MarkerArray_)]
            time.sleep(0.05)
        _, err = run.communicate(timeout=30)
    assert run.returncode == 0, err
    for n, r in readers.items():
        got[n] += [s for s in r.take(N=1000) if isinstance(s, PoseStamped)]
    got["obstacles"] += [s for s in markers.take(N=1000) if isinstance(s, MarkerArray_)]

    last_t = got["leader/pose"][-1]
    t = last_t.header.stamp.sec + last_t.header.stamp.nanosec * 1e-9
    p0 = sc.leader.position(t)
    apart = [float(np.linalg.norm(np.array([p.x, p.y, p.z]) - p0 - r.offset.position(t)))
             for r in sc.robots for p in [got[f"robot{r.id}/pose"][-1].pose.position]]
    measured("ros2_view", load1=os.getloadavg()[0], fewest=min(len(v) for v in got.values()), worst_m=max(apart))
    # 50 Hz of simulation time for 4 s: about 200 of each (some may be lost while discovering).
    # Measured (23 runs of issue 40 at load average 11-22, the machine shared with other test
    # runs; MEASURED lines): the fewest 200 every time; the worst robot 0.014-0.054 m off its
    # place at the end (bound 0.5 m: 9x).
    assert all(len(v) >= 100 for v in got.values()), {n: len(v) for n, v in got.items()}
    for n in names:
        stamps = [s.header.stamp.sec + s.header.stamp.nanosec * 1e-9 for s in got[n]]
        assert all(b > a for a, b in zip(stamps, stamps[1:])), n  # in order, simulation time
        assert {s.header.frame_id for s in got[n]} == {"world"}
    for s in got["leader/pose"]:  # the leader's path at the stamp's time
        t = s.header.stamp.sec + s.header.stamp.nanosec * 1e-9
        p = s.pose.position
        np.testing.assert_allclose([p.x, p.y, p.z], sc.leader.position(t), atol=1e-6)
    # The robots end in formation around the leader, as the run's summary says.
    assert max(apart) < 0.5, apart
    (marker,) = got["obstacles"][-1].markers
    assert (marker.type, marker.header.frame_id, marker.ns) == (MARKER_SPHERE, "world", "obstacles")
    assert (marker.pose.position.x, marker.pose.position.y, marker.pose.position.z) == (0.0, 0.0, 5.0)
    assert marker.scale.x == 2 * sc.d
