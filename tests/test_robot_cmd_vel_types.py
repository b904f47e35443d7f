"""`pimbot robot serve` names a cmd_vel reader of the other distro's type (issue 41, item 5).

A robot built for the other ROS 2 distro reads its cmd_vel with the other type (Twist on
Humble, TwistStamped on Jazzy) and DDS never matches the two. Serve's `ControllerWire` and a
peer participant (a robot's node) share a loopback DDS domain in this process; the peer's
readers are what DDS discovery shows serve: the other distro's type on a robot's cmd_vel is
said in one line, once, with the `--ros-distro` that fixes it; a third type is said as
neither distro's; a matching reader is not named; odd discovery data raises nothing.
"""

from __future__ import annotations

import json
import os
import time
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("cyclonedds")

from pimbot.robot import ros_wire, serve  # noqa: E402
from pimbot.robot.messages import cmd_vel_topic  # noqa: E402
from pimbot.robot.ros_world import WireConfig  # noqa: E402

OTHER = {"humble": "jazzy", "jazzy": "humble"}


def _domain(offset: int) -> int:
    """A DDS domain of this test process alone (no cross-talk with parallel runs)."""
    return 1 + (os.getpid() * 13 + 41 * offset) % 200


@pytest.fixture(autouse=True)
def loopback(monkeypatch):
    monkeypatch.setenv("CYCLONEDDS_URI", ros_wire.loopback_config())


def _serve_ends(distro: str, domain: int) -> tuple[serve.ControllerWire, list[str]]:
    said: list[str] = []
    ends = serve.ControllerWire(2, WireConfig(distro, domain), serve.ServeConfig(), said.append)
    return ends, said


def _look(ends: serve.ControllerWire, said: list[str], lines: int, limit: float = 10.0) -> None:
    """Looks at discovery (as serve's loop does, a `TYPE_CHECK_S` apart in its clock) until
    `lines` lines were said or `limit` wall seconds passed, then ten times more."""
    clock, deadline = ends.next_type_look, time.perf_counter() + limit
    while len(said) < lines and time.perf_counter() < deadline:
        ends.look_for_other_types(clock)
        clock += serve.TYPE_CHECK_S
        time.sleep(0.05)
    for _ in range(10):
        ends.look_for_other_types(clock)
        clock += serve.TYPE_CHECK_S


def _commanded(ends: serve.ControllerWire, reader: ros_wire.Reader, limit: float = 1.0) -> list:
    """What `reader` takes while serve sends a command every 20 ms for `limit` s at most."""
    got, deadline = [], time.perf_counter() + limit
    while not got and time.perf_counter() < deadline:
        ends.command(np.full(2, 0.1), np.zeros(2))
        time.sleep(0.02)
        got = reader.take()
    return got


@pytest.mark.parametrize("distro", ["humble", "jazzy"])
def test_a_reader_of_the_other_distros_cmd_vel_is_said_once(distro):
    other = OTHER[distro]
    ends, said = _serve_ends(distro, _domain(1 if distro == "humble" else 2))
    robot = ros_wire.Node(ends.node.participant.domain_id, user_data=f"tb3_1 on {other}")
    qos = ros_wire.reliable_qos()
    wrong = robot.reader(cmd_vel_topic(1), ros_wire.cmd_vel_struct(other), qos)
    right = robot.reader(cmd_vel_topic(0), ros_wire.cmd_vel_struct(distro), qos)
    _look(ends, said, lines=1)
    for line in said:
        print(f"serve: {line}")
    assert len(said) == 1, said
    ours = ros_wire.ros_type_name(ros_wire.cmd_vel_struct(distro).__idl_typename__)
    theirs = ros_wire.ros_type_name(ros_wire.cmd_vel_struct(other).__idl_typename__)
    peer = ends.node.participant_name(robot.participant.guid)
    assert f"pid {os.getpid()}" in peer and peer.endswith(f"(tb3_1 on {other})")
    assert said[0] == (
        f"/tb3_1/cmd_vel is read by {peer} as {theirs} ({other.capitalize()}'s cmd_vel type), "
        f"serve writes {ours} (--ros-distro {distro}): DDS never matches the two, so it gets "
        f"no command; for a {other.capitalize()} robot run serve with --ros-distro {other}"
    )
    # as the line says: the reader of the other type gets nothing, the matching one does
    assert _commanded(ends, right) and not _commanded(ends, wrong)
    summary = serve._Played(2).report(ends, 0.0).summary()
    assert json.loads(json.dumps(summary))["type_mismatches"] == said


def test_matching_readers_are_not_named_and_a_third_type_is_neither_distros():
    ends, said = _serve_ends("humble", _domain(3))
    robot = ros_wire.Node(ends.node.participant.domain_id, user_data="robots")
    qos = ros_wire.reliable_qos()
    readers = [robot.reader(cmd_vel_topic(i), ros_wire.Twist, qos) for i in range(2)]
    readers.append(robot.reader(ros_wire.STATUS_TOPIC, ros_wire.Float64, qos))  # no cmd_vel
    peer, twist = ends.node.participant_name(robot.participant.guid), ros_wire.Twist
    matching = [(peer, cmd_vel_topic(i), twist.__idl_typename__) for i in range(2)]
    deadline = time.perf_counter() + 10
    while ends.node.readers(ends.cmd_topics) != matching and time.perf_counter() < deadline:
        time.sleep(0.05)
    assert ends.node.readers(ends.cmd_topics) == matching  # discovered, and judged:
    _look(ends, said, lines=1, limit=1.5)
    assert said == []
    stranger = ros_wire.Node(ends.node.participant.domain_id, user_data="a stranger")
    readers.append(stranger.reader(cmd_vel_topic(0), ros_wire.String, qos))
    _look(ends, said, lines=1)
    print(*(f"serve: {line}" for line in said), sep="\n")
    assert len(said) == 1, said
    assert said[0].startswith("/tb3_0/cmd_vel is read by ") and "(a stranger)" in said[0]
    assert " as std_msgs/msg/String (neither distro's cmd_vel type), serve writes " in said[0]
    assert said[0].endswith(
        "geometry_msgs/msg/Twist (--ros-distro humble): DDS never matches the two, so it gets "
        "no command"
    )


def test_discovery_is_looked_at_once_a_second_at_most(monkeypatch):
    ends, _ = _serve_ends("jazzy", _domain(4))
    looks = []
    monkeypatch.setattr(ends.node, "readers", lambda topics: looks.append(topics) or [])
    for tick in range(100):  # 100 control periods of 5 ms: 0.5 s of serve's clock
        ends.look_at_discovery(10.0 + tick * 0.005)
    assert looks == [["/tb3_0/cmd_vel", "/tb3_1/cmd_vel"]]
    ends.look_at_discovery(10.0 + serve.TYPE_CHECK_S)
    assert len(looks) == 2


def test_odd_discovery_data_raises_nothing():
    ends, said = _serve_ends("humble", _domain(5))
    node = ends.node
    odd = [
        SimpleNamespace(),
        SimpleNamespace(participant_key=None, topic_name=None, type_name=None),
        SimpleNamespace(participant_key=7, topic_name=["rt/tb3_0/cmd_vel"], type_name=3),
        SimpleNamespace(participant_key=8, topic_name="rt/tb3_0/cmd_vel", type_name=b"\xff"),
        SimpleNamespace(participant_key=9, topic_name="rt/tb3_1/cmd_vel", type_name="x" * 10**5),
    ]
    node._readers.update({f"odd {i}": sample for i, sample in enumerate(odd)})
    found = node.readers(ends.cmd_topics)
    assert [(topic, len(dds_type)) for _, topic, dds_type in found] == [
        ("/tb3_0/cmd_vel", 0),
        ("/tb3_1/cmd_vel", 10**5),
    ]
    ends.look_for_other_types(0.0)
    assert len(said) == 1 and len(said[0]) < 400  # the type name is cut short in the line
    assert "x" * ros_wire.MAX_TYPE_NAME + " (neither distro's" in said[0]
    gone = SimpleNamespace(key="odd 4", sample_info=SimpleNamespace(instance_state=None))
    ros_wire._follow(SimpleNamespace(take=lambda N: [gone, SimpleNamespace()]), node._readers)
    assert "odd 4" not in node._readers


def test_type_names_as_ros_names_them():
    assert ros_wire.ros_type_name("geometry_msgs::msg::dds_::TwistStamped_") == (
        "geometry_msgs/msg/TwistStamped"
    )
    assert ros_wire.ros_type_name("MyTwist") == "MyTwist"
    assert ros_wire.ros_type_name("a::b::dds_::_") == "a::b::dds_::_"
    assert ros_wire.ros_type_name(None) == ""
    assert ros_wire.cmd_vel_distros("geometry_msgs::msg::dds_::Twist_") == ["humble"]
    assert ros_wire.cmd_vel_distros("geometry_msgs::msg::dds_::TwistStamped_") == ["jazzy"]
    assert ros_wire.cmd_vel_distros("std_msgs::msg::dds_::String_") == []
    assert serve.type_mismatch("/tb3_0/cmd_vel", "r", "", "humble") is None
    twist = ros_wire.Twist.__idl_typename__
    assert serve.type_mismatch("/tb3_0/cmd_vel", "r", twist, "humble") is None
