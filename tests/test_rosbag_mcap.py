"""ROS 2 bags as today's ROS 2 reads them: MCAP or sqlite3 storage, Humble or Jazzy types.

Each bag of a scripted ER(2,1) physics episode is read back with rosbags (its Reader and a
fresh typestore of the distro, and AnyReader through `rosbag.read_bag`): storage, format
version, topics, types, message counts, and every cmd_vel equal to what the controller sent.
"""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest
import yaml

pytest.importorskip("rosbags")
pytest.importorskip("mujoco")

from rosbags.rosbag2 import Reader  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from pimbot.cli import main  # noqa: E402
from pimbot.errors import InvalidParameter  # noqa: E402
from pimbot.robot import episode as ep  # noqa: E402
from pimbot.robot import rosbag  # noqa: E402
from pimbot.robot.messages import Twist, cmd_vel_topic, odom_topic  # noqa: E402

LEVER, START, DOOR = 0, 1, 2
STORES = {"humble": Stores.ROS2_HUMBLE, "jazzy": Stores.ROS2_JAZZY}
SUFFIX = {"mcap": ".mcap", "sqlite3": ".db3"}


@pytest.fixture(scope="module")
def episode():
    """ER(2,1) in physics, robot 0 to the lever and robot 1 to the door: one decision."""
    cfg = ep.PhysicsConfig(n_robots=2, min_at_lever=1)
    script = np.array([[LEVER, DOOR]])
    result = ep.run_episode(ep.ScriptedPolicy(script), cfg, np.random.default_rng(21), True)
    assert result.success and len(result.bus.log) > 100
    return result


def sent(result, topic):
    return [(stamp, m) for stamp, t, m in result.bus.log if t == topic]


@pytest.mark.parametrize("distro", rosbag.ROS_DISTROS)
@pytest.mark.parametrize("storage", rosbag.BAG_STORAGES)
def test_bag_reads_back_with_the_distros_types(episode, tmp_path, storage, distro):
    out = rosbag.write_bag(episode, tmp_path / "bag", storage=storage, distro=distro)
    meta = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["storage_identifier"] == storage
    assert meta["version"] == {"humble": 8, "jazzy": 9}[distro]
    assert [p.name for p in sorted(out.iterdir())] == [f"bag{SUFFIX[storage]}", "metadata.yaml"]

    twist_type = {"humble": "geometry_msgs/msg/Twist", "jazzy": "geometry_msgs/msg/TwistStamped"}
    expected_types = {rosbag.DECISIONS_TOPIC: "std_msgs/msg/String"}
    for i in range(2):
        expected_types[cmd_vel_topic(i)] = twist_type[distro]
        expected_types[odom_topic(i)] = "nav_msgs/msg/Odometry"
    expected_counts = Counter(topic for _, topic, _ in episode.bus.log)
    expected_counts[rosbag.DECISIONS_TOPIC] = episode.steps

    # rosbags' Reader and a typestore of the distro built here, apart from pimbot's reader.
    store = get_typestore(STORES[distro])
    decoded: dict[str, list] = {}
    with Reader(out) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == expected_types
        for c in reader.connections:
            assert c.digest == store.hash_rihs01(c.msgtype)  # the distro's definitions
        assert {t: info.msgcount for t, info in reader.topics.items()} == expected_counts
        for connection, stamp, data in reader.messages():
            message = store.deserialize_cdr(data, connection.msgtype)
            decoded.setdefault(connection.topic, []).append((stamp, message))

    for i in range(2):
        log = sent(episode, cmd_vel_topic(i))
        got = decoded[cmd_vel_topic(i)]
        assert [s for s, _ in got] == [s for s, _ in log]
        for (stamp, message), (_, twist) in zip(got, log, strict=True):
            assert isinstance(twist, Twist)
            if distro == "jazzy":
                assert message.header.frame_id == f"tb3_{i}/base_footprint"
                assert message.header.stamp.sec * 10**9 + message.header.stamp.nanosec == stamp
                message = message.twist
            assert (message.linear.x, message.angular.z) == (twist.linear.x, twist.angular.z)
            assert message.linear.y == message.linear.z == message.angular.x == 0.0
        assert any(abs(m.linear.x) > 0.05 for _, m in log)  # the robot was driven
        odom = decoded[odom_topic(i)][-1][1]
        last = sent(episode, odom_topic(i))[-1][1]
        assert odom.pose.pose.position.x == last.pose.position.x
        assert odom.child_frame_id == f"tb3_{i}/base_footprint"
    events = [json.loads(m.data) for _, m in decoded[rosbag.DECISIONS_TOPIC]]
    assert [e["actions"] for e in events] == episode.actions.tolist()
    assert events[-1]["success"] is True

    # AnyReader (pimbot's read_bag) decodes with the definitions stored in the bag itself.
    messages = rosbag.read_bag(out)
    assert {t: len(v) for t, v in messages.items()} == expected_counts
    first = messages[cmd_vel_topic(1)][0][1]
    first = first.twist if distro == "jazzy" else first
    assert first.linear.x == sent(episode, cmd_vel_topic(1))[0][1].linear.x


def test_mcap_file_alone_is_a_bag(episode, tmp_path):
    # ROS 2 tools read an .mcap without its metadata.yaml: the file carries its schemas.
    out = rosbag.write_bag(episode, tmp_path / "bag", storage="mcap", distro="jazzy")
    with Reader(out / "bag.mcap") as reader:
        counts = {t: info.msgcount for t, info in reader.topics.items()}
        assert counts[cmd_vel_topic(0)] == len(sent(episode, cmd_vel_topic(0)))
        assert reader.topics[cmd_vel_topic(0)].msgtype == "geometry_msgs/msg/TwistStamped"


def test_bag_write_never_goes_through_a_planted_link(episode, tmp_path):
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "keep.txt").write_text("mine")
    out = tmp_path / "bag"
    # The staging name the writer used before (a fixed '<out>.tmp'), planted as a link.
    (tmp_path / "bag.tmp").symlink_to(victim, target_is_directory=True)
    rosbag.write_bag(episode, out, storage="sqlite3", distro="humble")
    assert sorted(p.name for p in victim.iterdir()) == ["keep.txt"]
    assert (out / "bag.db3").is_file()

    # An existing bag is replaced; a link at the target is replaced, its target left alone.
    rosbag.write_bag(episode, out, storage="mcap", distro="jazzy")
    assert sorted(p.name for p in out.iterdir()) == ["bag.mcap", "metadata.yaml"]
    linked = tmp_path / "linked"
    linked.symlink_to(victim, target_is_directory=True)
    rosbag.write_bag(episode, linked)
    assert not linked.is_symlink() and (linked / "linked.mcap").is_file()
    assert sorted(p.name for p in victim.iterdir()) == ["keep.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "bag.tmp", "linked", "victim"]


def test_bag_write_failure_leaves_nothing(episode, tmp_path, monkeypatch):
    out = tmp_path / "bag"
    rosbag.write_bag(episode, out, storage="mcap", distro="jazzy")
    before = sorted(p.name for p in out.iterdir())

    def fail(result, path, storage, distro):
        path.mkdir()
        (path / "half.mcap").write_bytes(b"\x89MCAP")
        raise OSError("disk full")

    monkeypatch.setattr(rosbag, "_write_messages", fail)
    with pytest.raises(OSError, match="disk full"):
        rosbag.write_bag(episode, out, storage="sqlite3", distro="humble")
    assert sorted(p.name for p in out.iterdir()) == before  # the old bag, untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]  # no staging left


def test_bag_refuses_bad_targets_and_choices(episode, tmp_path):
    not_a_bag = tmp_path / "notes"
    not_a_bag.mkdir()
    with pytest.raises(InvalidParameter, match="exists and is not a ROS 2 bag"):
        rosbag.write_bag(episode, not_a_bag)
    with pytest.raises(InvalidParameter, match="bag_storage: must be one of mcap, sqlite3"):
        rosbag.write_bag(episode, tmp_path / "b", storage="zip")
    with pytest.raises(InvalidParameter, match="ros_distro: must be one of humble, jazzy"):
        rosbag.write_bag(episode, tmp_path / "b", distro="iron")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes"]


def test_eval_cli_rejects_unknown_bag_options(tmp_path, capsys):
    for flag, value in (("--bag-storage", "zip"), ("--ros-distro", "iron")):
        assert main(["robot", "eval", str(tmp_path), "--rosbag", "b", flag, value]) == 2
        err = capsys.readouterr().err
        assert err.startswith("pimbot: ") and value in err and "Traceback" not in err
