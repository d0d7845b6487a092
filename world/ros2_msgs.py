"""ROS 2 message types as Cyclone DDS sees them: the .msg fields in order, ROS 2's DDS type names.

A ROS 2 node is, on the wire, a DDS participant: ``geometry_msgs/msg/Twist`` is the DDS type
``geometry_msgs::msg::dds_::Twist_`` (package, ``msg``, ``dds_``, the name with a trailing
underscore), a topic ``/robot1/cmd_vel`` is the DDS topic ``rt/robot1/cmd_vel``. With these
types any ROS 2 node (rmw_cyclonedds_cpp or Fast DDS) reads and writes what fxswarm does, with
no ROS 2 installed here (docs/ros2.md). float64 is IDL double, string IDL string.
"""

from dataclasses import dataclass, field

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float32, float64, int32, sequence, uint8, uint32


def dds_topic(topic: str) -> str:
    """ROS 2 topic ``/a/b`` -> DDS topic ``rt/a/b`` (``rt/`` for topics; services use rq/, rr/)."""
    return "rt" + topic


@dataclass
class Time_(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Duration_(IdlStruct, typename="builtin_interfaces::msg::dds_::Duration_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header_(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time_ = field(default_factory=Time_)
    frame_id: str = ""


@dataclass
class ColorRGBA_(IdlStruct, typename="std_msgs::msg::dds_::ColorRGBA_"):
    r: float32 = 0.0
    g: float32 = 0.0
    b: float32 = 0.0
    a: float32 = 0.0


@dataclass
class Vector3_(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Point_(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion_(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Pose_(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point_ = field(default_factory=Point_)
    orientation: Quaternion_ = field(default_factory=Quaternion_)


@dataclass
class PoseStamped_(IdlStruct, typename="geometry_msgs::msg::dds_::PoseStamped_"):
    header: Header_ = field(default_factory=Header_)
    pose: Pose_ = field(default_factory=Pose_)


@dataclass
class Twist_(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3_ = field(default_factory=Vector3_)
    angular: Vector3_ = field(default_factory=Vector3_)


@dataclass
class PoseWithCovariance_(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose_ = field(default_factory=Pose_)
    covariance: array[float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class TwistWithCovariance_(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist_ = field(default_factory=Twist_)
    covariance: array[float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class Odometry_(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    header: Header_ = field(default_factory=Header_)
    child_frame_id: str = ""
    pose: PoseWithCovariance_ = field(default_factory=PoseWithCovariance_)
    twist: TwistWithCovariance_ = field(default_factory=TwistWithCovariance_)


@dataclass
class CompressedImage_(IdlStruct, typename="sensor_msgs::msg::dds_::CompressedImage_"):
    header: Header_ = field(default_factory=Header_)
    format: str = ""
    data: sequence[uint8] = field(default_factory=list)


@dataclass
class UVCoordinate_(IdlStruct, typename="visualization_msgs::msg::dds_::UVCoordinate_"):
    u: float32 = 0.0
    v: float32 = 0.0


@dataclass
class MeshFile_(IdlStruct, typename="visualization_msgs::msg::dds_::MeshFile_"):
    filename: str = ""
    data: sequence[uint8] = field(default_factory=list)


@dataclass
class Marker_(IdlStruct, typename="visualization_msgs::msg::dds_::Marker_"):
    """visualization_msgs/Marker as of ROS 2 Iron and Jazzy (Humble's lacks texture and mesh_file)."""

    header: Header_ = field(default_factory=Header_)
    ns: str = ""
    id: int32 = 0
    type: int32 = 0
    action: int32 = 0
    pose: Pose_ = field(default_factory=Pose_)
    scale: Vector3_ = field(default_factory=Vector3_)
    color: ColorRGBA_ = field(default_factory=ColorRGBA_)
    lifetime: Duration_ = field(default_factory=Duration_)
    frame_locked: bool = False
    points: sequence[Point_] = field(default_factory=list)
    colors: sequence[ColorRGBA_] = field(default_factory=list)
    texture_resource: str = ""
    texture: CompressedImage_ = field(default_factory=CompressedImage_)
    uv_coordinates: sequence[UVCoordinate_] = field(default_factory=list)
    text: str = ""
    mesh_resource: str = ""
    mesh_file: MeshFile_ = field(default_factory=MeshFile_)
    mesh_use_embedded_materials: bool = False


@dataclass
class MarkerArray_(IdlStruct, typename="visualization_msgs::msg::dds_::MarkerArray_"):
    markers: sequence[Marker_] = field(default_factory=list)


#: Marker.type and Marker.action values used here (visualization_msgs/Marker constants).
MARKER_SPHERE, MARKER_ADD = 2, 0

#: [ros2] pose_type -> the DDS type a robot's pose arrives as.
POSE_TYPES = {"PoseStamped": PoseStamped_, "Odometry": Odometry_}


def time_msg(seconds: float) -> Time_:
    """builtin_interfaces/Time of ``seconds`` (>= 0)."""
    sec = int(seconds)
    return Time_(sec=sec, nanosec=min(int(round((seconds - sec) * 1e9)), 999_999_999))


def pose_of(msg) -> Pose_:
    """The Pose in a PoseStamped or an Odometry."""
    return msg.pose.pose if isinstance(msg, Odometry_) else msg.pose
