"""Robots as ROS 2 sees them, played by plain Cyclone DDS (no fxswarm inside): the tests' stand-in.

    python ros2_robots.py SCENARIO --report FILE [--mute ID:T] [--frame FRAME]

Each robot i of the scenario starts at its ``[[robots]]`` position, subscribes
``rt/robot<i>/cmd_vel`` (``geometry_msgs::msg::dds_::Twist_``, reliable, as a ROS 2 driver does),
moves at the latest Twist's linear velocity (world frame) and publishes
``rt/robot<i>/pose`` (``geometry_msgs::msg::dds_::PoseStamped_``, frame ``world``) at 50 Hz.

The message types are written out here from the ROS 2 .msg files on purpose, not imported from
fxswarm: a wrong type name on either side means no match on the wire, and the test sees it.

It says on stdout (a line each, flushed), for the test to wait on:
``ready`` (its readers and writers exist), ``moving`` (every robot has had a non-zero Twist),
``stopped`` (after that, every robot's latest Twist is zero; said again after each new start),
``muted I`` (``--mute I:T``: robot I stops publishing its pose T s after its first Twist),
``held I`` (a muted robot then received a zero Twist).
On SIGTERM/SIGINT it writes ``--report`` (JSON: positions, last Twists, counts, when each robot
last took a non-zero Twist (``time.monotonic()``), the closest two robots came) and exits 0.
"""

import argparse
import json
import math
import os
import signal
import sys
import time
import tomllib
from dataclasses import dataclass, field

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import float64, int32, uint32
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

RATE_HZ = 50.0


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
class PoseStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseStamped_"):
    header: Header = field(default_factory=Header)
    pose: Pose = field(default_factory=Pose)


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


def say(line: str) -> None:
    print(line, flush=True)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenario")
    ap.add_argument("--report", required=True)
    ap.add_argument("--mute", default=None, metavar="ID:T")
    ap.add_argument("--frame", default="world")
    args = ap.parse_args()
    with open(args.scenario, "rb") as fh:
        positions = [list(map(float, r["position"])) for r in tomllib.load(fh)["robots"]]
    n = len(positions)
    mute_id, mute_after = (int(args.mute.split(":")[0]), float(args.mute.split(":")[1])) if args.mute else (0, 0.0)

    stop = []
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda s, f: stop.append(s))

    dp = DomainParticipant(int(os.environ.get("ROS_DOMAIN_ID", "0")))  # as every ROS 2 node
    readers, writers = [], []
    for i in range(1, n + 1):
        cmd = Topic(dp, f"rt/robot{i}/cmd_vel", Twist)
        pose = Topic(dp, f"rt/robot{i}/pose", PoseStamped)
        readers.append(DataReader(dp, cmd, qos=Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(10))))
        writers.append(DataWriter(dp, pose, qos=Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(10))))
    say("ready")

    v = [[0.0, 0.0, 0.0] for _ in range(n)]
    received = [0] * n
    nonzero = [0] * n
    last_nonzero_at = [None] * n  # time.monotonic() (system-wide): when each last took a non-zero Twist
    first_twist: float | None = None
    moving = stopped = muted = held = False
    closest = math.inf
    last = time.monotonic()
    next_due = last
    while not stop:
        now = time.monotonic()
        # Moved on the Twists in force since the last turn, before taking new ones: a robot does
        # not apply a command before it arrives (this process starved of CPU would, by a whole stall).
        for i in range(n):
            for k in range(3):
                positions[i][k] += (now - last) * v[i][k]
        last = now
        for i, reader in enumerate(readers):
            for t in reader.take(N=32):
                if not isinstance(t, Twist):  # an InvalidSample: a writer went away, no data
                    continue
                v[i] = [t.linear.x, t.linear.y, t.linear.z]
                received[i] += 1
                if any(v[i]):
                    nonzero[i] += 1
                    last_nonzero_at[i] = now
                    first_twist = now if first_twist is None else first_twist
                elif muted and i + 1 == mute_id and not held:
                    held = True
                    say(f"held {mute_id}")
        if not moving and all(nonzero):
            moving = True
            say("moving")
        if moving:
            all_zero = all(not any(x) for x in v)
            if all_zero and not stopped:
                say("stopped")
            stopped = all_zero
        for i in range(n):
            for j in range(i + 1, n):
                closest = min(closest, math.dist(positions[i], positions[j]))
        if mute_id and first_twist is not None and not muted and now - first_twist >= mute_after:
            muted = True
            say(f"muted {mute_id}")
        stamp = time.time()
        for i, writer in enumerate(writers):
            if muted and i + 1 == mute_id:
                continue
            x, y, z = positions[i]
            writer.write(PoseStamped(
                header=Header(stamp=Time(sec=int(stamp), nanosec=int((stamp % 1) * 1e9)), frame_id=args.frame),
                pose=Pose(position=Point(x, y, z))))
        next_due += 1.0 / RATE_HZ
        time.sleep(max(0.0, next_due - time.monotonic()))
    with open(args.report, "w") as fh:
        json.dump({"positions": positions, "last_twist": v, "twists_received": received,
                   "nonzero_twists": nonzero, "last_nonzero_at": last_nonzero_at,
                   "closest_m": closest}, fh)
    return 0


if __name__ == "__main__":
    sys.exit(main())
