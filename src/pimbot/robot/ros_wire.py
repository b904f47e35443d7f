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

Every message a `Node` takes goes through `Reader.take`, the one door in: a sample that
does not deserialize, or that the reader's `parse` refuses (`Dropped`), is dropped and
counted by topic and reason (`Node.dropped_counts`), never raised; text is parsed as JSON
only within `bounded_json`'s size and nesting bounds. `Node.rivals` reads DDS discovery for
writers of other participants on given topics, named by their host, process and pid;
`Node.readers` for their readers, with each reader's DDS type name (`ros_type_name` gives it
as ROS names it, `cmd_vel_distros` the distros whose cmd_vel type it is).

Cyclone DDS is configured by `CYCLONEDDS_URI`; `loopback_config` gives one for a single
machine without multicast (unicast discovery to 127.0.0.1). No `from __future__ import
annotations` here: cyclonedds reads the field annotations as types.
"""

import dataclasses
import json
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import field

from cyclonedds.builtin import (
    BuiltinDataReader,
    BuiltinTopicDcpsParticipant,
    BuiltinTopicDcpsPublication,
    BuiltinTopicDcpsSubscription,
)
from cyclonedds.core import InstanceState, Policy, Qos
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


def cmd_vel_distros(dds_type: str) -> list[str]:
    """The distros whose cmd_vel type has the DDS type name `dds_type` (none for another)."""
    return [d for d in ROS_DISTROS if cmd_vel_struct(d).__idl_typename__ == dds_type]


MAX_TYPE_NAME = 120
"""The longest type name `ros_type_name` gives back (discovery data is anyone's text)."""


def ros_type_name(dds_type) -> str:
    """A DDS type name as ROS 2 names it (`geometry_msgs::msg::dds_::Twist_` ->
    `geometry_msgs/msg/Twist`); any other type name as it is, "" for one that is no text;
    at most `MAX_TYPE_NAME` characters."""
    if not isinstance(dds_type, str):
        return ""
    parts = dds_type.split("::")
    if len(parts) == 4 and parts[2] == "dds_" and len(parts[3]) > 1 and parts[3][-1] == "_":
        dds_type = f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"
    return dds_type[:MAX_TYPE_NAME]


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


class Dropped(Exception):  # noqa: N818 (a verdict on a message, not a failure)
    """A message refused on the way in: `reason` is the counted category, `detail` what
    exactly was wrong with this one."""

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason, self.detail = reason, detail


MAX_JSON_BYTES = 65_536
"""The largest JSON text a reader parses (a room layout is about 1 KiB)."""
MAX_JSON_DEPTH = 8
"""The deepest nesting of arrays and objects a reader parses (a layout nests 3 deep)."""


def bounded_json(text: str, max_bytes: int = MAX_JSON_BYTES, max_depth: int = MAX_JSON_DEPTH):
    """`json.loads(text)` within bounds (`Dropped` "too large", "nested too deep" or "not
    JSON"): the size is checked first, then the nesting in one pass over the text, so a
    message deep enough to exhaust Python's recursion never reaches the parser."""
    if not isinstance(text, str):
        raise Dropped("not JSON", f"{type(text).__name__}, not text")
    size = len(text.encode("utf-8", "surrogatepass"))
    if size > max_bytes:
        raise Dropped("too large", f"{size} bytes, at most {max_bytes}")
    if text.count("[") + text.count("{") > max_depth:  # else it cannot nest deeper
        depth, deepest, in_string, escaped = 0, 0, False, False
        for char in text:
            if in_string:
                if escaped:
                    escaped = False
                elif char == "\\":
                    escaped = True
                elif char == '"':
                    in_string = False
            elif char == '"':
                in_string = True
            elif char in "[{":
                depth += 1
                deepest = max(deepest, depth)
            elif char in "]}":
                depth -= 1
        if deepest > max_depth:
            raise Dropped("nested too deep", f"{deepest} levels, at most {max_depth}")
    try:
        return json.loads(text)
    except (ValueError, RecursionError) as error:
        raise Dropped("not JSON", str(error).splitlines()[0][:120]) from None


def _describe(participant) -> str:
    """A discovered participant as "PROCESS pid PID on HOST (its user data)"."""
    props = {}
    user = b""
    for policy in participant.qos or ():
        if type(policy).__name__ == "Property":
            props[policy.key] = policy.value
        elif isinstance(policy, Policy.Userdata):
            user = policy.data
    name = (
        f"{props.get('__ProcessName', 'a process')} pid {props.get('__Pid', '?')} "
        f"on {props.get('__Hostname', '?')}"
    )
    if user:
        name += f" ({user.decode('utf-8', 'replace')[:80]})"
    return name


class Node:
    """One DDS participant with ROS-named topics; counts the messages it writes and takes,
    and those it drops (by topic and reason)."""

    def __init__(self, domain_id: int, user_data: str | None = None):
        qos = Qos(Policy.Userdata(user_data.encode())) if user_data else None
        self.participant = DomainParticipant(domain_id, qos=qos)
        self.topics: dict[str, Topic] = {}
        self.sent: dict[str, int] = {}
        self.received: dict[str, int] = {}
        self.dropped: dict[str, Counter] = {}
        self.last_drop: dict[str, str] = {}
        """Per topic: what was wrong with the last message dropped there."""
        self.foreign: dict[str, set[str]] = {}
        """Participant name -> the topics where its messages were dropped (`own_only`)."""
        self._publications = None
        self._subscriptions = None
        self._participants = None
        self._writers: dict = {}
        self._readers: dict = {}
        self._names: dict = {}

    def _topic(self, ros_topic: str, struct: type[IdlStruct]) -> Topic:
        if ros_topic not in self.topics:
            self.topics[ros_topic] = Topic(self.participant, dds_topic(ros_topic), struct)
        return self.topics[ros_topic]

    def writer(self, ros_topic: str, struct: type[IdlStruct], qos: Qos) -> "Writer":
        return Writer(
            self, ros_topic, DataWriter(self.participant, self._topic(ros_topic, struct), qos=qos)
        )

    def reader(
        self,
        ros_topic: str,
        struct: type[IdlStruct],
        qos: Qos,
        parse: Callable | None = None,
        own_only: bool = False,
    ) -> "Reader":
        """A reader whose `take` returns `parse(sample)` for every sample that deserializes
        and parses (`parse` raises `Dropped` to refuse one); `own_only`: samples written
        by another DDS participant are dropped too (and the participant remembered)."""
        reader = DataReader(self.participant, self._topic(ros_topic, struct), qos=qos)
        return Reader(self, ros_topic, reader, parse, own_only)

    def drop(self, topic: str, reason: str, detail: str = "") -> None:
        """Counts one dropped message (never raises)."""
        self.dropped.setdefault(topic, Counter())[reason] += 1
        self.last_drop[topic] = f"{reason}: {detail}" if detail else reason

    def dropped_counts(self) -> dict[str, dict[str, int]]:
        """{topic: {reason: messages dropped}}."""
        return {t: dict(c) for t, c in sorted(self.dropped.items())}

    def messages(self) -> dict[str, int]:
        return {"sent": sum(self.sent.values()), "received": sum(self.received.values())}

    def participant_name(self, key) -> str:
        """A discovered participant's process, pid and host (its GUID while unknown)."""
        if key not in self._names:
            if self._participants is None:
                self._participants = BuiltinDataReader(
                    self.participant, BuiltinTopicDcpsParticipant
                )
            for sample in self._participants.read(N=256):
                self._names[sample.key] = _describe(sample)
        return self._names.get(key, f"participant {key}")

    def rivals(self, ros_topics) -> dict[str, list[str]]:
        """Writers of other participants on `ros_topics`, from DDS discovery: {participant
        name: [its topics]} (empty when none; never raises on discovery data)."""
        if self._publications is None:
            self._publications = BuiltinDataReader(self.participant, BuiltinTopicDcpsPublication)
        _follow(self._publications, self._writers)
        found: dict[str, list[str]] = {}
        for participant, topic, _ in self._others(self._writers, ros_topics):
            found.setdefault(self.participant_name(participant), []).append(topic)
        return {name: sorted(set(topics)) for name, topics in found.items()}

    def readers(self, ros_topics) -> list[tuple[str, str, str]]:
        """Readers of other participants on `ros_topics`, from DDS discovery: (participant
        name, ROS topic, DDS type name; "" where discovery gives none), sorted, each once
        (never raises on discovery data)."""
        if self._subscriptions is None:
            self._subscriptions = BuiltinDataReader(self.participant, BuiltinTopicDcpsSubscription)
        _follow(self._subscriptions, self._readers)
        found = {
            (self.participant_name(participant), topic, type_name)
            for participant, topic, type_name in self._others(self._readers, ros_topics)
        }
        return sorted(found)

    def _others(self, endpoints: dict, ros_topics) -> list[tuple]:
        """(participant key, ROS topic, type name) of each endpoint in `endpoints` (discovery
        samples) of another participant on one of `ros_topics`."""
        wanted = {dds_topic(t): t for t in ros_topics}
        own = self.participant.guid
        found = []
        for sample in endpoints.values():
            participant = getattr(sample, "participant_key", None)
            topic = getattr(sample, "topic_name", None)
            if participant != own and isinstance(topic, str) and topic in wanted:
                type_name = getattr(sample, "type_name", None)
                found.append(
                    (participant, wanted[topic], type_name if isinstance(type_name, str) else "")
                )
        return found


def _follow(builtin: BuiltinDataReader, endpoints: dict) -> None:
    """Brings `endpoints` ({endpoint key: its discovery sample}) up to date with what
    `builtin` (a discovery reader) has seen since: new endpoints in, gone ones out."""
    for sample in builtin.take(N=256):
        info = getattr(sample, "sample_info", None)
        if getattr(info, "instance_state", None) == InstanceState.Alive:
            endpoints[sample.key] = sample
        else:
            endpoints.pop(getattr(sample, "key", None), None)


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
    parse: Callable | None = None
    own_only: bool = False

    def take(self, limit: int = 64) -> list:
        """The samples waiting, parsed (disposals and unregistrations skipped); one that
        does not deserialize or parse is dropped and counted, never raised. One sample
        per call to cyclonedds, so that a bad one costs only itself."""
        out = []
        for _ in range(limit):
            try:
                got = self.reader.take(N=1)
            except Exception as error:  # noqa: BLE001 (bytes that are no message of the type)
                self.node.drop(self.topic, "undecodable", f"{type(error).__name__}: {error}")
                continue
            if not got:
                break
            sample = got[0]
            if not isinstance(sample, IdlStruct):
                continue
            self.node.received[self.topic] = self.node.received.get(self.topic, 0) + 1
            try:
                if self.own_only:
                    self._check_own(sample)
                out.append(sample if self.parse is None else self.parse(sample))
            except Dropped as dropped:
                self.node.drop(self.topic, dropped.reason, dropped.detail)
            except Exception as error:  # noqa: BLE001 (a parser's own slip: still a drop)
                self.node.drop(self.topic, "unparsable", f"{type(error).__name__}: {error}")
        return out

    def _check_own(self, sample) -> None:
        info = getattr(sample, "sample_info", None)
        if info is None:
            return
        data = self.reader.get_matched_publication_data(info.publication_handle)
        key = getattr(data, "participant_key", None)
        if key is not None and key != self.node.participant.guid:
            name = self.node.participant_name(key)
            self.node.foreign.setdefault(name, set()).add(self.topic)
            raise Dropped("from another participant", name)


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
