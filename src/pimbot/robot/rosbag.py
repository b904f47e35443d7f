"""Export of a physics episode as a real ROS 2 bag (the `rosbags` package; no ROS needed).

Topics: `/tb3_<i>/cmd_vel` and `/tb3_<i>/odom` (nav_msgs/msg/Odometry) for every robot,
as the decision loop published them on its bus, and `/escape_room/decisions`
(std_msgs/msg/String, one JSON object per decision step: actions, zones, rewards, gate,
success). Two choices follow the ROS 2 the bag is meant for:

* storage: `mcap`, rosbag2's default since Iron (rosbag2 0.19,
  ros2/rosbag2 `rosbag2_storage_default_plugins/CHANGELOG.rst`), or `sqlite3`, Humble's
  default (Humble reads MCAP with `ros-humble-rosbag2-storage-mcap`);
* distro: the message definitions of `humble` or `jazzy` (rosbags' typestores). On
  Jazzy `cmd_vel` is geometry_msgs/msg/TwistStamped, stamped when it was published and
  framed in the robot's base frame, since TurtleBot3's Jazzy bringup takes only that
  (ROBOTIS-GIT/turtlebot3 issue #1135); on Humble it is a plain geometry_msgs/msg/Twist.
  Bag format version 9 for Jazzy (what its rosbag2 writes), 8 for Humble.

docs/robot.md says how to play such a bag on a TurtleBot3 and what was not tried here.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

from pimbot.atomic_files import staged_directory
from pimbot.errors import check_choice
from pimbot.robot.messages import Odometry, Twist, cmd_vel_topic, odom_topic

if TYPE_CHECKING:  # importing this module imports neither mujoco nor numpy (CLI start-up)
    from pimbot.robot.episode import EpisodeResult

ROS_DISTROS = ("humble", "jazzy")
BAG_STORAGES = ("mcap", "sqlite3")
DECISIONS_TOPIC = "/escape_room/decisions"
TWIST = "geometry_msgs/msg/Twist"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
STRING = "std_msgs/msg/String"
BAG_VERSION = {"humble": 8, "jazzy": 9}


def cmd_vel_type(distro: str) -> str:
    """The message type a TurtleBot3 of `distro` takes on cmd_vel."""
    return TWIST_STAMPED if distro == "jazzy" else TWIST


def base_frame(robot: int) -> str:
    """Robot `robot`'s base frame: its odometry's child frame and its commands' frame."""
    return f"tb3_{robot}/base_footprint"


def typestore(distro: str):
    """rosbags' typestore with `distro`'s message definitions."""
    from rosbags.typesys import Stores, get_typestore

    check_choice("ros_distro", distro, ROS_DISTROS)
    return get_typestore({"humble": Stores.ROS2_HUMBLE, "jazzy": Stores.ROS2_JAZZY}[distro])


def _header(types, stamp_ns: int, frame_id: str):
    stamp = types["builtin_interfaces/msg/Time"](
        sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000
    )
    return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)


def _ros_twist(types, twist: Twist):
    vector = types["geometry_msgs/msg/Vector3"]
    return types[TWIST](
        linear=vector(x=twist.linear.x, y=twist.linear.y, z=twist.linear.z),
        angular=vector(x=twist.angular.x, y=twist.angular.y, z=twist.angular.z),
    )


def ros_cmd_vel(types, msgtype: str, twist: Twist, stamp_ns: int, frame_id: str):
    """`twist` as a `msgtype` (Twist or TwistStamped) of the typestore `types`."""
    if msgtype == TWIST:
        return _ros_twist(types, twist)
    return types[TWIST_STAMPED](
        header=_header(types, stamp_ns, frame_id), twist=_ros_twist(types, twist)
    )


def _ros_odometry(types, odom: Odometry):
    import numpy as np

    p, q = odom.pose.position, odom.pose.orientation
    pose_covariance = np.zeros(36)
    pose_covariance[[0, 7]] = odom.position_variance
    pose = types["geometry_msgs/msg/PoseWithCovariance"](
        pose=types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=p.x, y=p.y, z=p.z),
            orientation=types["geometry_msgs/msg/Quaternion"](x=q.x, y=q.y, z=q.z, w=q.w),
        ),
        covariance=pose_covariance,
    )
    twist = types["geometry_msgs/msg/TwistWithCovariance"](
        twist=_ros_twist(types, odom.twist), covariance=np.zeros(36)
    )
    return types[ODOMETRY](
        header=_header(types, odom.stamp_ns, odom.frame_id),
        child_frame_id=odom.child_frame_id,
        pose=pose,
        twist=twist,
    )


def decision_events(result: EpisodeResult) -> list[tuple[int, dict]]:
    """(stamp_ns, event) per decision step, stamped when its rules were applied."""
    import numpy as np

    ends = np.cumsum(result.decision_seconds)
    return [
        (
            int(round(ends[t] * 1e9)),
            {
                "step": t,
                "actions": result.actions[t].tolist(),
                "zones_before": result.positions[t].tolist(),
                "zones_after": result.positions[t + 1].tolist(),
                "rewards": result.rewards[t].tolist(),
                "gate_open": bool(result.gate_open[t]),
                "success": bool(result.success and t == result.steps - 1),
            },
        )
        for t in range(result.steps)
    ]


def check_bag_target(out: Path) -> None:
    """Raises InvalidParameter unless `out` is free or holds a ROS 2 bag to replace."""
    from pimbot.errors import InvalidParameter

    if out.is_symlink() or not out.exists():
        return  # a link is replaced, its target left alone
    if not (out.is_dir() and (out / "metadata.yaml").exists()):
        raise InvalidParameter(f"rosbag: {out} exists and is not a ROS 2 bag; choose a new path")


def write_bag(
    result: EpisodeResult, out: str | Path, *, storage: str = "mcap", distro: str = "jazzy"
) -> Path:
    """Writes `result` (recorded with `record=True`) as a ROS 2 bag directory at `out`.

    Args:
        result: the episode; its bus log holds every message.
        out: the bag directory; an existing bag there is replaced.
        storage: "mcap" or "sqlite3".
        distro: "humble" or "jazzy": the message definitions and cmd_vel's type.

    The bag is built in a directory created exclusively beside `out` and renamed into
    place, so a failure leaves no half-written bag and no pre-existing file or link is
    written through.
    """
    from pimbot.errors import InvalidParameter

    check_choice("bag_storage", storage, BAG_STORAGES)
    check_choice("ros_distro", distro, ROS_DISTROS)
    if not result.bus.log:
        raise InvalidParameter("rosbag: the episode was not recorded (run it with record=True)")
    out = Path(out)
    check_bag_target(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with staged_directory(out) as new:
        _write_messages(result, new, storage, distro)
    return out


def _write_messages(result: EpisodeResult, path: Path, storage: str, distro: str) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = typestore(distro)
    types, twist_type = store.types, cmd_vel_type(distro)
    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    frames = {cmd_vel_topic(i): base_frame(i) for i in range(result.world.num_robots)}
    with Writer(path, version=BAG_VERSION[distro], storage_plugin=plugin) as writer:
        connections = {
            DECISIONS_TOPIC: writer.add_connection(DECISIONS_TOPIC, STRING, typestore=store)
        }
        for i in range(result.world.num_robots):
            for topic, msgtype in ((cmd_vel_topic(i), twist_type), (odom_topic(i), ODOMETRY)):
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
        for stamp, topic, message in result.bus.log:
            if isinstance(message, Twist):
                msgtype = twist_type
                ros = ros_cmd_vel(types, msgtype, message, stamp, frames[topic])
            else:
                ros, msgtype = _ros_odometry(types, message), ODOMETRY
            writer.write(connections[topic], stamp, store.serialize_cdr(ros, msgtype))
        for stamp, event in decision_events(result):
            ros = types[STRING](data=json.dumps(event))
            writer.write(connections[DECISIONS_TOPIC], stamp, store.serialize_cdr(ros, STRING))


def read_bag(path: str | Path) -> dict[str, list[tuple[int, object]]]:
    """All messages of a bag, deserialized with the definitions stored in the bag itself
    (rosbags' AnyReader): topic -> [(stamp_ns, message)] in bag order."""
    from rosbags.highlevel import AnyReader

    messages: dict[str, list[tuple[int, object]]] = {}
    with AnyReader([Path(path)]) as reader:
        for connection, stamp, data in reader.messages():
            message = reader.deserialize(data, connection.msgtype)
            messages.setdefault(connection.topic, []).append((stamp, message))
    return messages
