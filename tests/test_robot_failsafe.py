"""`pimbot robot serve` fails safe on the wire (issue 42, part 1).

Each test runs `pimbot robot serve` as a second process on loopback DDS, as
tests/test_ros_wire.py does, against robots played by this test process: point robots that
integrate every cmd_vel they get and publish their odometry, in lockstep. The robots record
every command serve sends, so the tests judge what a real robot would have received:

* odometry with NaN, inf and huge values, and junk bytes, is dropped and counted; every
  command stays finite and within the TurtleBot3 Burger's limits; no NumPy warning;
* odometry that goes silent mid-drive stops every robot within the odometry timeout, and
  driving resumes when it is back; for good, serve gives up with the robots stopped;
* Ctrl-C and SIGTERM mid-drive: the last command to every robot is zero, one line, no
  traceback;
* another participant publishing cmd_vel for the robots (a second controller) is named and
  serve stops; two serves on one domain take none of each other's incentive messages.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("cyclonedds")

from pimbot.robot import ros_wire  # noqa: E402
from pimbot.robot.messages import cmd_vel_topic, odom_topic  # noqa: E402
from pimbot.robot.ros_world import layout_json  # noqa: E402
from pimbot.robot.world import MAX_ANGULAR, MAX_LINEAR, sample_layout  # noqa: E402

DT = 0.05
SHORT = ("--physics", "decision_time_limit=6", "--physics", "settle_time=0.2")


def _domain(offset: int) -> int:
    """A DDS domain of this test process alone (no cross-talk with parallel runs)."""
    return 1 + (os.getpid() * 11 + 37 * offset) % 200


@pytest.fixture(autouse=True)
def loopback(monkeypatch):
    monkeypatch.setenv("CYCLONEDDS_URI", ros_wire.loopback_config())


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A small LIO ER(2,1) run: serve needs a policy, not a good one."""
    from pimbot.training.config import RunConfig
    from pimbot.training.runner import train

    out = tmp_path_factory.mktemp("failsafe") / "lio_er21"
    train(RunConfig("escape_room-v0", seeds=1, iterations=20, eval_period=10), out, progress=False)
    return out


def _serve(run_dir, domain: int, *extra: str, json_out=None) -> subprocess.Popen:
    args = [sys.executable, "-m", "pimbot.cli", "robot", "serve", str(run_dir),
            "--domain-id", str(domain), "--ros-distro", "humble", *SHORT, *extra]  # fmt: skip
    if json_out is not None:
        args += ["--json", str(json_out)]
    return subprocess.Popen(
        args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )


def _finish(process: subprocess.Popen, timeout: float = 60) -> tuple[str, str]:
    try:
        return process.communicate(timeout=timeout)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


class Robots:
    """Point robots on the wire: odometry out, every cmd_vel recorded and integrated."""

    def __init__(self, domain: int, n: int = 2, seed: int = 3):
        self.n = n
        self.layout = sample_layout(np.random.default_rng(seed), n)
        self.poses = np.array(self.layout.start_poses, float)
        self.node = node = ros_wire.Node(domain)
        self.room = node.writer(ros_wire.LAYOUT_TOPIC, ros_wire.String, ros_wire.latched_qos())
        self.room.write(ros_wire.String(layout_json(self.layout)))
        self.odom = [
            node.writer(odom_topic(i), ros_wire.Odometry, ros_wire.reliable_qos()) for i in range(n)
        ]
        self.cmd = [
            node.reader(cmd_vel_topic(i), ros_wire.Twist, ros_wire.reliable_qos()) for i in range(n)
        ]
        self.status = node.reader(ros_wire.STATUS_TOPIC, ros_wire.String, ros_wire.reliable_qos())
        self.commands: list[list[tuple[float, float, float]]] = [[] for _ in range(n)]
        """Per robot: (wall time, linear, angular) of every command received."""
        self.latest = np.zeros((n, 2))
        self.tick = 0
        self.events: list[dict] = []

    def odometry(self, i: int, x=None, q=None):
        """Robot i's odometry now; `x`, `q` (a quaternion) replace its own."""
        px, py, yaw = self.poses[i]
        msg = ros_wire.Odometry()
        msg.header = ros_wire.Header(ros_wire.ros_time(int(self.tick * DT * 1e9)), "odom")
        msg.pose.pose.position = ros_wire.Point(px if x is None else x, py, 0.0)
        q = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)) if q is None else q
        msg.pose.pose.orientation = ros_wire.Quaternion(*q)
        return msg

    def publish(self) -> None:
        for i, writer in enumerate(self.odom):
            writer.write(self.odometry(i))

    def take(self) -> np.ndarray:
        """Records the commands waiting; which robots got one."""
        got = np.zeros(self.n, bool)
        now = time.perf_counter()
        for i, reader in enumerate(self.cmd):
            for message in reader.take():
                linear, angular = ros_wire.command_of(message)
                self.commands[i].append((now, linear, angular))
                self.latest[i] = linear, angular
                got[i] = True
        for message in self.status.take():
            self.events.append(json.loads(message.data))
        return got

    def step(self, wait: float = 1.0, move: bool = True) -> None:
        """One lockstep period: odometry out, then the commands (or `wait` s), then move
        (unless not `move`: the robots hold their poses, so no episode can end)."""
        self.publish()
        answered = np.zeros(self.n, bool)
        deadline = time.perf_counter() + wait
        while not answered.all() and time.perf_counter() < deadline:
            answered |= self.take()
            time.sleep(0.0005)
        linear, angular = self.latest[:, 0], self.latest[:, 1]
        if move and np.isfinite(self.latest).all():
            self.poses[:, 2] += angular * DT
            self.poses[:, 0] += linear * np.cos(self.poses[:, 2]) * DT
            self.poses[:, 1] += linear * np.sin(self.poses[:, 2]) * DT
        self.tick += 1

    def idle(self, seconds: float) -> None:
        """Publishes nothing for `seconds`, still recording commands."""
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            self.take()
            time.sleep(0.002)

    def driving(self) -> bool:
        return bool(np.abs(self.latest[:, 0]).max() > 0.05)

    def done(self) -> bool:
        return any(e.get("done") for e in self.events)

    def all_commands(self) -> np.ndarray:
        return np.array([(lin, ang) for c in self.commands for _, lin, ang in c])

    def last_commands(self) -> list[tuple[float, float]]:
        return [c[-1][1:] for c in self.commands]


def _run_until(robots: Robots, serve: subprocess.Popen, condition, limit: float = 120) -> None:
    """Steps the robots until `condition()` or serve ends (fails after `limit` s)."""
    deadline = time.perf_counter() + limit
    while not condition():
        assert serve.poll() is None, _finish(serve)
        assert time.perf_counter() < deadline, "serve did not get there in time"
        robots.step()


def _check_commands(robots: Robots) -> np.ndarray:
    commands = robots.all_commands()
    assert len(commands) > 0
    assert np.isfinite(commands).all()
    assert (np.abs(commands[:, 0]) <= MAX_LINEAR).all()
    assert (np.abs(commands[:, 1]) <= MAX_ANGULAR).all()
    return commands


def _junk_odometry(robots: Robots, i: int) -> ros_wire.Odometry:
    """An odometry message whose bytes do not decode (its frame name is not UTF-8): CDR
    that DDS passes on, and that a reader's deserializer refuses."""
    msg = robots.odometry(i)
    junk = msg.serialize().replace(b"odom", b"\xff\xfe\xfd\xfc")
    msg.serialize = lambda use_version_2=False, **kw: junk
    return msg


def test_nan_inf_huge_and_junk_odometry_are_dropped_counted_and_never_commanded(run_dir, tmp_path):
    domain = _domain(1)
    robots = Robots(domain)
    out = tmp_path / "serve.json"
    serve = _serve(run_dir, domain, "--timeout", "60", json_out=out)
    bad = [math.nan, math.inf, -math.inf, 1e300, -1e308]
    intruder = robots.node.writer(
        ros_wire.incentive_topic(0), ros_wire.String, ros_wire.reliable_qos(depth=64)
    )
    gate = robots.node.writer(ros_wire.GATE_TOPIC, ros_wire.Float64, ros_wire.sensor_qos())
    sent = {"not finite": 0, "position out of range": 0, "undecodable": 0}
    deadline = time.perf_counter() + 150
    while not robots.done() and serve.poll() is None and time.perf_counter() < deadline:
        k = robots.tick
        if k > 0 and k % 3 == 0:  # every third period: a bad message before the good one
            value = bad[(k // 3) % len(bad)]
            for i, writer in enumerate(robots.odom):
                if (k // 3) % 4 == 3:
                    writer.write(_junk_odometry(robots, i))
                    sent["undecodable"] += 1
                else:
                    writer.write(
                        robots.odometry(i, x=value, q=(0.0, 0.0, value, 1.0) if i else None)
                    )
                    sent[
                        "not finite"
                        if abs(value) == math.inf or value != value
                        else "position out of range"
                    ] += 1  # noqa: E501
            gate.write(ros_wire.Float64(math.nan))
            intruder.write(ros_wire.String("[" * 5000))
        robots.step()
    stdout, stderr = _finish(serve)
    assert serve.returncode == 0, stdout + stderr
    print(stdout, stderr)
    assert "Traceback" not in stderr and "Warning" not in stderr, stderr
    commands = _check_commands(robots)
    assert robots.last_commands() == [(0.0, 0.0)] * 2
    report = json.loads(out.read_text())
    assert report["ended"] == "done" and report["commands_limited"] == {}
    dropped = report["dropped"]
    # every bad odometry message was dropped, by reason, on both robots' topics
    odom = {r: dropped[odom_topic(0)].get(r, 0) + dropped[odom_topic(1)].get(r, 0) for r in sent}
    # (less a few sent before serve's readers matched, or after it stopped reading)
    assert all(0.9 * sent[r] <= odom[r] <= sent[r] for r in sent), (odom, sent)
    assert min(odom.values()) > 20
    assert "not finite" in dropped[ros_wire.GATE_TOPIC]
    assert set(dropped[ros_wire.incentive_topic(0)]) == {"from another participant"}
    assert "another controller" in stdout and "incentive messages on /tb3_0/incentive" in stdout
    print(f"{len(commands)} commands, all finite within limits; dropped {dropped}")


def test_silent_odometry_stops_every_robot_then_resumes_then_gives_up(run_dir, tmp_path):
    domain = _domain(2)
    robots = Robots(domain)
    out = tmp_path / "serve.json"
    serve = _serve(run_dir, domain, "--timeout", "4", "--odometry-timeout", "0.5", json_out=out)
    _run_until(robots, serve, robots.driving)
    assert robots.driving()
    went_silent = time.perf_counter()
    robots.idle(1.5)
    stopped = [next(t for t, lin, ang in c if t > went_silent and lin == ang == 0.0)
               for c in robots.commands]  # fmt: skip
    delay = max(stopped) - went_silent
    assert 0.4 < delay < 1.2, delay  # the odometry timeout (0.5 s) and a little
    assert robots.last_commands() == [(0.0, 0.0)] * 2
    for _ in range(20):  # odometry back: serve drives again
        robots.step()
    assert serve.poll() is None and robots.driving()
    went_silent = time.perf_counter()
    robots.idle(6.0)  # for good: serve gives up after --timeout 4 s
    stdout, stderr = _finish(serve)
    print(stdout, stderr, f"stop {delay:.2f} s after the odometry went silent")
    assert serve.returncode == 1, stdout + stderr
    assert "Traceback" not in stderr
    assert robots.last_commands() == [(0.0, 0.0)] * 2
    lines = stdout.splitlines()
    assert any("no odometry on" in line and "stopped every robot" in line for line in lines)
    assert any("odometry back after" in line for line in lines)
    assert any(line.startswith("serve: ended early (no odometry)") for line in lines)
    report = json.loads(out.read_text())
    assert report["ended"] == "no odometry" and len(report["stops"]) >= 2
    _check_commands(robots)


@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_ctrl_c_and_sigterm_mid_drive_stop_every_robot(run_dir, tmp_path, signum, code):
    domain = _domain(3 + signum)
    robots = Robots(domain)
    out = tmp_path / "serve.json"
    serve = _serve(run_dir, domain, json_out=out)
    _run_until(robots, serve, robots.driving)
    for _ in range(3):
        robots.step()
    assert robots.driving()
    before = robots.latest.tolist()
    os.kill(serve.pid, signum)
    end = time.perf_counter() + 20
    while serve.poll() is None and time.perf_counter() < end:
        robots.step(wait=0.05, move=False)  # odometry goes on; no robot reaches the exit
    robots.idle(0.3)
    stdout, stderr = _finish(serve)
    print(
        stdout, stderr, f"last commands before {signum}: {before}, after: {robots.last_commands()}"
    )
    assert serve.returncode == code, stdout + stderr
    assert "Traceback" not in stderr and stderr.strip() == "", stderr
    assert robots.last_commands() == [(0.0, 0.0)] * 2
    what = "interrupted" if signum == signal.SIGINT else "terminated"
    stops = [line for line in stdout.splitlines() if "stopped every robot" in line]
    assert stops == [f"serve: stopped every robot (zero cmd_vel to tb3_0, tb3_1): {what}"]
    assert json.loads(out.read_text())["ended"] == what
    assert robots.done()  # the world is told on the status topic
    _check_commands(robots)


def test_a_second_controller_on_cmd_vel_is_named_and_serve_stops(run_dir, tmp_path):
    domain = _domain(9)
    robots = Robots(domain)
    serve = _serve(run_dir, domain)
    _run_until(robots, serve, robots.driving)
    teleop = robots.node.writer(cmd_vel_topic(1), ros_wire.Twist, ros_wire.reliable_qos())
    teleop.write(ros_wire.wire_twist(0.1, 0.0))
    end = time.perf_counter() + 20
    while serve.poll() is None and time.perf_counter() < end:
        robots.step(wait=0.05)
    robots.idle(0.3)
    stdout, stderr = _finish(serve)
    print(stdout, stderr)
    assert serve.returncode == 1, stdout + stderr
    assert "Traceback" not in stderr
    line = next(x for x in stdout.splitlines() if "second controller:" in x)
    assert f"pid {os.getpid()}" in line and "/tb3_1/cmd_vel" in line
    assert robots.last_commands()[0] == (0.0, 0.0)  # robot 1's last may be the teleop's


def test_two_serves_on_one_domain_name_each_other_and_take_none_of_the_others_messages(
    run_dir, tmp_path
):
    domain = _domain(10)
    robots = Robots(domain)
    outs = [tmp_path / "a.json", tmp_path / "b.json"]
    serves = [_serve(run_dir, domain, "--timeout", "30", json_out=o) for o in outs]
    end = time.perf_counter() + 120
    while any(s.poll() is None for s in serves) and time.perf_counter() < end:
        robots.step(wait=0.05)
    results = [_finish(s) for s in serves]
    for serve, (stdout, stderr), out in zip(serves, results, outs, strict=True):
        print(stdout, stderr)
        assert serve.returncode == 1, stdout + stderr
        assert "Traceback" not in stderr
        assert "second controller:" in stdout and "pimbot robot serve, pid" in stdout
        report = json.loads(out.read_text())
        assert report["ended"] == "second controller"
        assert report["incentives_accepted"] <= report["incentives_sent"]
    assert robots.last_commands() == [(0.0, 0.0)] * 2


_BROKEN_CONTROLLER = """
import sys
import numpy as np
from pimbot.robot import serve
from pimbot.robot.episode import PhysicsConfig
from pimbot.robot.ros_world import WireConfig

go_to_goal, calls = serve.ctl.go_to_goal, [0]

def broken(*args, **kwargs):  # NaN commands for a while, then a failure mid-drive
    calls[0] += 1
    linear, angular, arrived = go_to_goal(*args, **kwargs)
    if 10 <= calls[0] < 20:
        linear = np.full_like(linear, np.nan)
    if calls[0] == 40:
        raise RuntimeError("the controller broke")
    return linear, angular, arrived

serve.ctl.go_to_goal = broken
policy = lambda obs, sent, t: (np.array([0, 2]), np.zeros((2, 2)))
serve.serve_episode(policy, PhysicsConfig(decision_time_limit=6, settle_time=0.2),
                    WireConfig("humble", int(sys.argv[1])))
"""


def test_nan_commands_and_an_internal_error_mid_drive_stop_every_robot(tmp_path):
    domain = _domain(12)
    robots = Robots(domain)
    serve = subprocess.Popen(
        [sys.executable, "-c", _BROKEN_CONTROLLER, str(domain)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    end = time.perf_counter() + 60
    while serve.poll() is None and time.perf_counter() < end:
        robots.step(wait=0.2)
    robots.idle(0.3)
    stdout, stderr = _finish(serve)
    print(stdout, stderr)
    assert serve.returncode == 1 and "RuntimeError: the controller broke" in stderr
    _check_commands(robots)  # the NaN commands went out as zeros
    assert robots.last_commands() == [(0.0, 0.0)] * 2
    stop = "serve: stopped every robot (zero cmd_vel to tb3_0, tb3_1): error: RuntimeError: "
    assert stdout.splitlines() == [stop + "the controller broke"]
    assert robots.done() and robots.events[-1]["commands_limited"] == {"not finite": 20}


def test_serve_refuses_a_layout_that_is_no_room_in_one_line(run_dir, tmp_path):
    good = json.loads(layout_json(sample_layout(np.random.default_rng(0), 2)))
    cases = {
        "nan width": ({**good, "width": math.nan}, "every number must be finite"),
        "negative zone": ({**good, "zone_half": -0.3}, "zone_half must be in"),
        "two zones in one place": (
            {**good, "zone_centres": [good["zone_centres"][0]] * 2 + [good["zone_centres"][2]]},
            "the lever and start zones overlap",
        ),
        "deep": ("[" * 1000, "nested too deep"),
        "binary": (b"\xff\xfe\x00junk", "not UTF-8 text"),
        "huge": (" " * 70_000, "larger than 65536 bytes"),
    }
    for name, (layout, expected) in cases.items():
        path = tmp_path / f"{name}.json"
        if isinstance(layout, bytes):
            path.write_bytes(layout)
        else:
            path.write_text(layout if isinstance(layout, str) else json.dumps(layout))
        done = subprocess.run(
            [sys.executable, "-m", "pimbot.cli", "robot", "serve", str(run_dir),
             "--layout", str(path), "--domain-id", str(_domain(11))],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 2 and len(lines) == 1, (name, done.stderr)
        assert lines[0].startswith("pimbot: error: layout: ") and expected in lines[0], lines


def test_bounded_json_and_safe_command_units():
    from pimbot.robot import controller

    assert ros_wire.bounded_json('{"a": [1, {"b": "[[[["}]}', max_depth=3) == {
        "a": [1, {"b": "[[[["}]
    }
    for text, reason in [
        ("[" * 10, "nested too deep"),
        ("x" * 70_000, "too large"),
        ("{", "not JSON"),
        ('"\\', "not JSON"),
    ]:
        with pytest.raises(ros_wire.Dropped) as caught:
            ros_wire.bounded_json(text)
        assert caught.value.reason == reason
    with np.errstate(all="raise"):
        linear, angular, counts = controller.safe_command(
            [math.nan, 0.5, -1.0, 0.1], [0.0, math.inf, 9.0, -0.2]
        )
    assert linear.tolist() == [0.0, 0.0, -MAX_LINEAR, 0.1]
    assert angular.tolist() == [0.0, 0.0, MAX_ANGULAR, -0.2]
    assert counts == {"not finite": 2, "beyond the limits": 1}
    assert dataclasses.is_dataclass(ros_wire.Odometry)
