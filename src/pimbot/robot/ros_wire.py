"""ROS 2 messages on the wire without ROS: the message types as Cyclone DDS IDL structs.

A ROS 2 graph on `rmw_cyclonedds_cpp` is plain DDS: ROS topic `/tb3_0/cmd_vel` is DDS topic
`rt/tb3_0/cmd_vel`, and message type `geometry_msgs/msg/Twist` is the IDL struct
`geometry_msgs::msg::dds_::Twist_` (the ROS 2 design article "Topic and Service name mapping
to DDS", design.ros2.org, and ros2/rosidl_dds `rosidl_generator_dds_idl`), serialized as
XCDR1 (plain CDR, little-endian encapsulation `00 01 00 00`). The structs below follow the
message definitions of ros2/common_interfaces (`geometry_msgs/msg/Twist.msg`,
`TwistStamped.msg`, `nav_msgs/msg/Odometry.msg`, `std_msgs/msg/Header.msg`, `String.msg`,
`Float64.msg`) and ros2/rcl_interfaces (`builtin_interfaces/msg/Time.msg`), which Humble and
Jazzy share; what differs by distro is the type a TurtleBot3 takes on cmd_vel: Twist on
Humble, TwistStamped on Jazzy (ROBOTIS-GIT/turtlebot3 issue #1135). tests/test_ros_wire.py
checks the bytes against rosbags' typestores of both distros.

Topics of the robot Escape Room (ROS names; DDS adds `rt`):

* `/tb3_<i>/cmd_vel` — the distro's cmd_vel type, reliable, keep last 10;
* `/tb3_<i>/odom` — nav_msgs/Odometry; read best-effort (matches any publisher);
* `/tb3_<i>/incentive` — std_msgs/String, the incentive messages addressed to robot i, each
  the JSON of a `pimbot.defenses.channel.IncentiveMessage` (tag empty unless authenticated);
* `/pimbot/layout` — std_msgs/String, the room as JSON, reliable and transient-local (a
  controller that starts later still gets it, like a latched map);
* `/pimbot/gate` — std_msgs/Float64, how far the gate is open (0 closed, 1 open);
* `/pimbot/status` — std_msgs/String, the controller's decisions and its end, as JSON.

Cyclone DDS is configured by `CYCLONEDDS_URI`; `loopback_config` gives one for a single
machine without multicast (unicast discovery to 127.0.0.1). No `from __future__ import
annotations` here: cyclonedds reads the field annotations as types.
"""

import dataclasses
import math
from dataclasses import field

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float64, int32, uint32
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from pimbot.robot import messages
from pimbot.robot.rosbag import ROS_DISTROS, base_frame

LAYOUT_TOPIC = "/pimbot/layout"
GATE_TOPIC = "/pimbot/gate"
STATUS_TOPIC = "/pimbot/status"


@dataclasses.dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclasses.dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclasses.dataclass
class String(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str = ""


@dataclasses.dataclass
class Float64(IdlStruct, typename="std_msgs::msg::dds_::Float64_"):
    data: float64 = 0.0


@dataclasses.dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclasses.dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclasses.dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclasses.dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclasses.dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclasses.dataclass
class TwistStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TwistStamped_"):
    header: Header = field(default_factory=Header)
    twist: Twist = field(default_factory=Twist)


def _zeros36() -> list[float]:
    return [0.0] * 36


@dataclasses.dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose = field(default_factory=Pose)
    covariance: array[float64, 36] = field(default_factory=_zeros36)


@dataclasses.dataclass
class TwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist = field(default_factory=Twist)
    covariance: array[float64, 36] = field(default_factory=_zeros36)


@dataclasses.dataclass
class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)


ROS_TYPES: dict[str, type[IdlStruct]] = {
    "builtin_interfaces/msg/Time": Time,
    "std_msgs/msg/Header": Header,
    "std_msgs/msg/String": String,
    "std_msgs/msg/Float64": Float64,
    "geometry_msgs/msg/Vector3": Vector3,
    "geometry_msgs/msg/Twist": Twist,
    "geometry_msgs/msg/TwistStamped": TwistStamped,
    "nav_msgs/msg/Odometry": Odometry,
}
"""ROS 2 type name -> its wire struct (the ones pimbot publishes and their parts)."""


def check_distro(distro: str) -> str:
    from pimbot.errors import check_choice

    check_choice("ros_distro", distro, ROS_DISTROS)
    return distro


def cmd_vel_struct(distro: str) -> type[IdlStruct]:
    """The type a TurtleBot3 of `distro` takes on cmd_vel."""
    return TwistStamped if check_distro(distro) == "jazzy" else Twist


def dds_topic(ros_topic: str) -> str:
    """ROS 2 topic name -> DDS topic name (`rt` prefix)."""
    return "rt" + ros_topic


def incentive_topic(robot: int) -> str:
    return f"/tb3_{robot}/incentive"


def ros_time(stamp_ns: int) -> Time:
    return Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)


def time_ns(time: Time) -> int:
    return time.sec * 1_000_000_000 + time.nanosec


def wire_twist(linear: float, angular: float) -> Twist:
    return Twist(Vector3(x=float(linear)), Vector3(z=float(angular)))


def wire_cmd_vel(distro: str, linear: float, angular: float, at_ns: int, robot: int):
    """A unicycle command as `distro`'s cmd_vel message (stamped in the robot's base frame
    on Jazzy)."""
    twist = wire_twist(linear, angular)
    if cmd_vel_struct(distro) is Twist:
        return twist
    return TwistStamped(Header(ros_time(at_ns), base_frame(robot)), twist)


def command_of(message) -> tuple[float, float]:
    """(linear.x, angular.z) of a Twist or TwistStamped."""
    twist = message.twist if isinstance(message, TwistStamped) else message
    return twist.linear.x, twist.angular.z


def wire_odometry(odom: messages.Odometry) -> Odometry:
    """pimbot's odometry message as nav_msgs/Odometry (x and y variances on the pose
    covariance diagonal, as `pimbot.robot.rosbag` writes it)."""
    p, q = odom.pose.position, odom.pose.orientation
    covariance = _zeros36()
    covariance[0] = covariance[7] = float(odom.position_variance)
    v, w = odom.twist.linear, odom.twist.angular
    return Odometry(
        header=Header(ros_time(odom.stamp_ns), odom.frame_id),
        child_frame_id=odom.child_frame_id,
        pose=PoseWithCovariance(
            Pose(Point(p.x, p.y, p.z), Quaternion(q.x, q.y, q.z, q.w)), covariance
        ),
        twist=TwistWithCovariance(Twist(Vector3(v.x, v.y, v.z), Vector3(w.x, w.y, w.z))),
    )


def planar_pose(odom: Odometry) -> tuple[float, float, float]:
    """(x, y, yaw) of an odometry message (yaw about z from the quaternion)."""
    p, q = odom.pose.pose.position, odom.pose.pose.orientation
    yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
    return p.x, p.y, yaw


# --- QoS and endpoints -------------------------------------------------------------------

_XCDR1 = Policy.DataRepresentation(use_cdrv0_representation=True)


def reliable_qos(depth: int = 10) -> Qos:
    """ROS 2's default profile: reliable, volatile, keep last `depth`."""
    return Qos(
        Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(depth), _XCDR1
    )


def sensor_qos(depth: int = 5) -> Qos:
    """ROS 2's sensor-data profile: best effort (a reader matches any writer)."""
    return Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(depth), _XCDR1)


def latched_qos() -> Qos:
    """Reliable, transient local, keep last 1: late readers get the last message."""
    return Qos(
        Policy.Reliability.Reliable(duration(seconds=1)),
        Policy.Durability.TransientLocal,
        Policy.History.KeepLast(1),
        _XCDR1,
    )


class Node:
    """One DDS participant with ROS-named topics; counts the messages it writes and takes."""

    def __init__(self, domain_id: int):
        self.participant = DomainParticipant(domain_id)
        self.topics: dict[str, Topic] = {}
        self.sent: dict[str, int] = {}
        self.received: dict[str, int] = {}

    def _topic(self, ros_topic: str, struct: type[IdlStruct]) -> Topic:
        if ros_topic not in self.topics:
            self.topics[ros_topic] = Topic(self.participant, dds_topic(ros_topic), struct)
        return self.topics[ros_topic]

    def writer(self, ros_topic: str, struct: type[IdlStruct], qos: Qos) -> "Writer":
        return Writer(
            self, ros_topic, DataWriter(self.participant, self._topic(ros_topic, struct), qos=qos)
        )

    def reader(self, ros_topic: str, struct: type[IdlStruct], qos: Qos) -> "Reader":
        return Reader(
            self, ros_topic, DataReader(self.participant, self._topic(ros_topic, struct), qos=qos)
        )

    def messages(self) -> dict[str, int]:
        return {"sent": sum(self.sent.values()), "received": sum(self.received.values())}


@dataclasses.dataclass
class Writer:
    node: Node
    topic: str
    writer: DataWriter

    def write(self, message) -> None:
        self.writer.write(message)
        self.node.sent[self.topic] = self.node.sent.get(self.topic, 0) + 1


@dataclasses.dataclass
class Reader:
    node: Node
    topic: str
    reader: DataReader

    def take(self, limit: int = 64) -> list:
        """The valid samples waiting (disposals and unregistrations dropped)."""
        out = [s for s in self.reader.take(N=limit) if isinstance(s, IdlStruct)]
        self.node.received[self.topic] = self.node.received.get(self.topic, 0) + len(out)
        return out


def loopback_config(max_participants: int = 20) -> str:
    """A `CYCLONEDDS_URI` value (inline XML) for one machine: the loopback interface only,
    no multicast, discovery by unicast to 127.0.0.1."""
    return (
        "<CycloneDDS><Domain id='any'><General><Interfaces>"
        "<NetworkInterface name='lo' multicast='false'/></Interfaces>"
        "<AllowMulticast>false</AllowMulticast></General><Discovery>"
        "<ParticipantIndex>auto</ParticipantIndex>"
        f"<MaxAutoParticipantIndex>{max_participants}</MaxAutoParticipantIndex>"
        "<Peers><Peer address='127.0.0.1'/></Peers></Discovery></Domain></CycloneDDS>"
    )
