"""ROS 2 on the wire without ROS (pimbot.robot.ros_wire, serve, ros_world).

Byte equality: what cyclonedds serializes for each message type equals what rosbags'
typestore of the same distro serializes for the same values (an independent CDR
implementation). The loopback test runs `pimbot robot world --ros` and `pimbot robot serve`
as two processes talking DDS on 127.0.0.1.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("cyclonedds")
rosbags_typesys = pytest.importorskip("rosbags.typesys")

from pimbot.defenses import channel  # noqa: E402
from pimbot.robot import messages, ros_wire  # noqa: E402

STORES = {"humble": "ROS2_HUMBLE", "jazzy": "ROS2_JAZZY"}


def _store(distro):
    return rosbags_typesys.get_typestore(getattr(rosbags_typesys.Stores, STORES[distro]))


def _ros_header(types, stamp_ns, frame):
    t = types["builtin_interfaces/msg/Time"](
        sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000
    )
    return types["std_msgs/msg/Header"](stamp=t, frame_id=frame)


def _ros_twist(types, linear, angular):
    v = types["geometry_msgs/msg/Vector3"]
    return types["geometry_msgs/msg/Twist"](
        linear=v(linear, 0.0, 0.0), angular=v(0.0, 0.0, angular)
    )


def _odometry(rng):
    x, y, yaw = rng.uniform(-2, 2, 3)
    return messages.Odometry(
        stamp_ns=int(rng.integers(0, 10**12)),
        frame_id="odom",
        child_frame_id="tb3_1/base_footprint",
        pose=messages.Pose(messages.Vector3(x, y, 0.0), messages.Quaternion.from_yaw(yaw)),
        twist=messages.Twist(messages.Vector3(rng.uniform(-0.2, 0.2)), messages.Vector3(z=0.7)),
        position_variance=1e-4,
    )


def _ros_odometry(types, odom):
    p, q = odom.pose.position, odom.pose.orientation
    cov = np.zeros(36)
    cov[[0, 7]] = odom.position_variance
    pose = types["geometry_msgs/msg/PoseWithCovariance"](
        pose=types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](p.x, p.y, p.z),
            orientation=types["geometry_msgs/msg/Quaternion"](q.x, q.y, q.z, q.w),
        ),
        covariance=cov,
    )
    twist = types["geometry_msgs/msg/TwistWithCovariance"](
        twist=_ros_twist(types, odom.twist.linear.x, odom.twist.angular.z), covariance=np.zeros(36)
    )
    return types["nav_msgs/msg/Odometry"](
        header=_ros_header(types, odom.stamp_ns, odom.frame_id),
        child_frame_id=odom.child_frame_id,
        pose=pose,
        twist=twist,
    )


@pytest.mark.parametrize("distro", ["humble", "jazzy"])
def test_cdr_bytes_equal_rosbags_typestore(distro):
    store = _store(distro)
    types = store.types
    rng = np.random.default_rng(3)
    checked = {}
    for k in range(20):
        linear, angular = rng.uniform(-0.22, 0.22), rng.uniform(-2.84, 2.84)
        stamp_ns = int(rng.integers(0, 10**12))
        wire = ros_wire.wire_cmd_vel(distro, linear, angular, stamp_ns, 2)
        name = "geometry_msgs/msg/" + type(wire).__name__
        if distro == "jazzy":
            ros = types[name](
                header=_ros_header(types, stamp_ns, "tb3_2/base_footprint"),
                twist=_ros_twist(types, linear, angular),
            )
        else:
            ros = _ros_twist(types, linear, angular)
        odom = _odometry(rng)
        incentive = channel.IncentiveMessage(0, 1, 0, k, k, float(rng.uniform(0, 50)))
        text = json.dumps(dataclasses_asdict(incentive)) + " ünïcode"
        cases = [
            (name, wire, ros),
            ("nav_msgs/msg/Odometry", ros_wire.wire_odometry(odom), _ros_odometry(types, odom)),
            ("std_msgs/msg/String", ros_wire.String(text), types["std_msgs/msg/String"](text)),
            ("std_msgs/msg/Float64", ros_wire.Float64(k / 7), types["std_msgs/msg/Float64"](k / 7)),
        ]
        for msgtype, ours, theirs in cases:
            expected = bytes(store.serialize_cdr(theirs, msgtype))
            assert ours.serialize() == expected, (distro, msgtype, k)
            assert type(ours).deserialize(expected) == ours
            checked[msgtype] = checked.get(msgtype, 0) + 1
    # the cmd_vel type a TurtleBot3 of the distro takes
    assert ("geometry_msgs/msg/TwistStamped" in checked) == (distro == "jazzy")
    assert len(checked) == 4 and all(n == 20 for n in checked.values())


def dataclasses_asdict(message):
    import dataclasses

    return dataclasses.asdict(message)


def test_dds_type_and_topic_names():
    assert ros_wire.dds_topic("/tb3_0/cmd_vel") == "rt/tb3_0/cmd_vel"
    assert ros_wire.Twist.__idl_typename__ == "geometry_msgs::msg::dds_::Twist_"
    assert ros_wire.Odometry.__idl_typename__ == "nav_msgs::msg::dds_::Odometry_"
    assert ros_wire.cmd_vel_struct("humble") is ros_wire.Twist
    assert ros_wire.cmd_vel_struct("jazzy") is ros_wire.TwistStamped
    odom = _odometry(np.random.default_rng(1))
    x, y, yaw = ros_wire.planar_pose(ros_wire.wire_odometry(odom))
    assert math.isclose(x, odom.pose.position.x) and math.isclose(y, odom.pose.position.y)
    assert math.isclose(yaw, odom.pose.orientation.yaw(), abs_tol=1e-12)


def _domain(offset: int) -> int:
    """A DDS domain of this test process alone (no cross-talk with parallel runs)."""
    return 1 + (os.getpid() * 7 + offset) % 200


@pytest.fixture
def loopback(monkeypatch):
    monkeypatch.setenv("CYCLONEDDS_URI", ros_wire.loopback_config())


def test_authenticated_incentive_topic_rejects_forged_and_replayed_messages(loopback):
    from pimbot.robot.serve import IncentiveLink

    node = ros_wire.Node(_domain(1))
    link = IncentiveLink(node, 3, authenticated=True)
    intruder = node.writer(ros_wire.incentive_topic(1), ros_wire.String, ros_wire.reliable_qos())
    time.sleep(0.3)  # discovery
    incentives = np.arange(9.0).reshape(3, 3)
    assert link.send(0, 0, incentives) == 6
    accepted, verdicts = link.collect(6, timeout=5.0)
    assert verdicts.count("ok") == 6
    np.testing.assert_array_equal(accepted, incentives * (1 - np.eye(3)))
    # a message claiming robot 2 gives 50 to robot 1, without that pair's key
    forged = channel.IncentiveMessage(2, 1, 0, 1, 7, 50.0, tag="0" * 64)
    intruder.write(ros_wire.String(json.dumps(dataclasses_asdict(forged))))
    replay = channel.Sender(0, link.senders[0].keyring).send(1, 0, 0, 1.0)  # sequence 0 again
    intruder.write(ros_wire.String(json.dumps(dataclasses_asdict(replay))))
    intruder.write(ros_wire.String("not json"))
    intruder.write(ros_wire.String("[" * 3000))  # json.loads: RecursionError
    intruder.write(ros_wire.String(" " * 100_000))
    accepted, verdicts = link.collect(2, timeout=5.0)
    assert not accepted.any()
    assert sorted(verdicts) == ["bad tag", "replay: sequence already received"]
    time.sleep(0.2)
    assert link.collect(1, timeout=0.5)[1] == []  # what does not parse is no verdict
    assert node.dropped_counts() == {
        "/tb3_1/incentive": {"not JSON": 1, "nested too deep": 1, "too large": 1}
    }


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "pimbot.cli", *args]


@pytest.fixture(scope="module")
def trained_er21(tmp_path_factory):
    """Clean LIO on ER(2,1), one seed (3, which solves it within 6000 iterations)."""
    from pimbot.training.config import RunConfig
    from pimbot.training.runner import train

    run_dir = tmp_path_factory.mktemp("serve") / "lio_er21_seed3"
    config = RunConfig("escape_room-v0", seeds=1, first_seed=3, iterations=6000, eval_period=500)
    train(config, run_dir, progress=False)
    return run_dir


def test_serve_drives_the_mujoco_world_over_dds_in_two_processes(trained_er21, tmp_path, loopback):
    from pimbot.defenses import audit

    domain = str(_domain(2))
    world_json, serve_json = tmp_path / "world.json", tmp_path / "serve.json"
    log, key = tmp_path / "log" / "serve.audit.jsonl", tmp_path / "key" / "audit.key"
    world = subprocess.Popen(
        _cli("robot", "world", "--robots", "2", "--min-at-lever", "1", "--lockstep",
             "--domain-id", domain, "--seed", "5", "--timeout", "90", "--json", str(world_json)),
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        started = time.perf_counter()
        served = subprocess.run(
            _cli("robot", "serve", str(trained_er21), "--ros-distro", "jazzy",
                 "--domain-id", domain, "--authenticated", "--audit-log", str(log),
                 "--audit-key", str(key), "--timeout", "40", "--json", str(serve_json)),
            capture_output=True, text=True, timeout=90,
        )  # fmt: skip
        world_out, _ = world.communicate(timeout=20)
        wall = time.perf_counter() - started
    finally:
        if world.poll() is None:
            world.kill()
            world.wait()
    assert served.returncode == 0, served.stdout + served.stderr
    assert world.returncode == 0, world_out
    s = json.loads(serve_json.read_text())
    w = json.loads(world_json.read_text())
    print(f"serve: {s}\nworld: {w}\nwall {wall:.1f} s")
    # the trained policy solves ER(2,1): one robot to the lever, the other out by the door
    assert s["success"] and s["gate_open"][-1]
    assert sorted(s["actions"][-1]) == [0, 2] and s["zones"][-1] == s["actions"][-1]
    assert all(all(a) for a in s["arrived"])
    # the world's own (true) zones agree with what the controller read from odometry
    assert w["final_zones"] == s["zones"][-1] and w["gate_opening"] > 0.9
    assert w["ended"] == "controller done"
    # every control period was answered on the wire: one cmd_vel per robot per odometry
    assert w["messages"]["received"] >= 2 * (w["ticks"] - 1)
    assert s["incentives_sent"] == s["incentives_accepted"] == 2 * s["steps"]
    assert s["rejected"] == {}
    assert 0 < s["decision_ms_max"] < 1000
    result = audit.verify(log, audit.load_key(key))
    assert result.ok and result.records == 2 + s["steps"]  # serve, decisions, episode
