"""The robot controller on the ROS 2 wire (`pimbot robot serve`): a trained run drives robots.

Per robot it reads `/tb3_<i>/odom` and writes `/tb3_<i>/cmd_vel` with ROS 2's names and types
(`pimbot.robot.ros_wire`; Twist on Humble, TwistStamped on Jazzy), over DDS. One episode:

  1. the room comes from `/pimbot/layout` (what `pimbot robot world` publishes) or
     from a layout file (for robots in a real room);
  2. per decision step, every robot's zone is read from its odometry (a robot in no zone
     keeps its last); the run's joint decision (`evaluate.decision_function`: the acting
     policy, the attack's hooks — a bypassing adversary idles, a fake-incentive adversary
     sends its constant — and the incentive emission) picks each robot's zone;
  3. the incentives go out as messages on `/tb3_<j>/incentive` (std_msgs/String, the JSON of
     `defenses.channel.IncentiveMessage`), HMAC-signed and verified by each recipient's
     `channel.Receiver` when `authenticated` (forged, altered, replayed or reordered
     messages are rejected and counted); the observation carries the incentives each robot
     sent, as in training, and the recipients' ledger of what they accepted is reported;
  4. the go-to-goal controller (`controller.go_to_goal`, one command per robot for every
     fresh odometry) drives the robots to their slots, then holds them for the settle time;
  5. the Escape Room rules apply to the zones read from odometry, with the gate's state from
     `/pimbot/gate` (without a gate topic: open when M robots are in the lever zone); the
     step goes out on `/pimbot/status` (JSON), and its end as {"done": true, ...}.

Time is the odometry's (simulated time in the MuJoCo world, the clock on a robot). With an
audit log every decision and the episode's end are appended as keyed records
(`defenses.audit`). The keys of the authenticated channel are made per run in this process,
which plays every robot; robots on separate machines would share each pair's key out of band.

Failing safe, as ROS 2's twist_mux and the TurtleBot3 bring-up do with stale inputs:

* every command leaves through `ControllerWire.command`, which passes it through
  `controller.safe_command` (a robot whose command is not finite gets zero, the rest is
  clamped to the TurtleBot3 Burger's limits) and counts what it changed;
* every message comes in through `ros_wire.Reader.take` with this module's parsers
  (`_odometry`, `_gate`, `_layout`, `_incentive_parser`): what does not deserialize, parse,
  or lie in range is dropped and counted by topic and reason (the status topic and the
  report carry the counts); JSON is parsed within `ros_wire.bounded_json`'s bounds;
* the robots get a zero command, said in one line, when a robot's odometry has been silent
  for `ServeConfig.odometry_timeout` (driving resumes when it is back), and when serve ends
  for any reason: the episode's end, Ctrl-C or SIGTERM, an error, lost odometry, or a second
  controller — a writer of another DDS participant on the robots' cmd_vel topics, found by
  DDS discovery; another participant's incentive messages are dropped and it is named once.

A robot built for the other distro reads its cmd_vel with the other type, and DDS never
matches a reader and a writer of different types: that robot silently gets no command.
Serve reads DDS discovery for the readers on the robots' cmd_vel topics and says in one
line, once per reader, when one takes another type than serve writes (`type_mismatch`:
the other distro's type, with the `--ros-distro` that fixes it, or neither's).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import signal
import socket
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable

import numpy as np
from cyclonedds.util import duration

from pimbot.defenses import channel
from pimbot.errors import InvalidParameter
from pimbot.robot import controller as ctl
from pimbot.robot import ros_wire
from pimbot.robot.episode import (
    DOOR,
    GATE_OPEN_FRACTION,
    LEVER,
    START,
    PhysicsConfig,
    er_rewards,
    observation,
)
from pimbot.robot.messages import cmd_vel_topic, odom_topic
from pimbot.robot.ros_wire import Dropped
from pimbot.robot.ros_world import WireConfig, layout_from_json
from pimbot.robot.world import Layout

RESEND_S = 0.25
"""Wall seconds without fresh odometry after which the last commands are sent again."""
ODOM_LIMIT_M = 1000.0
"""Odometry farther than this from the origin (m, any axis) is dropped as out of range."""
UNIT_TOLERANCE = 0.01
"""How far an odometry quaternion's norm may be from 1."""
GATE_RANGE = (-0.5, 1.5)
"""The gate openings accepted on /pimbot/gate (a fraction of its travel; a little slack)."""
MAX_INCENTIVE = 1e6
"""The largest |value| of an incentive message."""
INCENTIVE_BYTES = 4096
"""The largest incentive message (its JSON is about 200 bytes)."""
RIVAL_CHECK_S = 0.05
"""Wall seconds between two looks at DDS discovery for a second controller."""
TYPE_CHECK_S = 1.0
"""Wall seconds between two looks at DDS discovery for cmd_vel readers of another type."""
ACK_S = 0.5
"""Wall seconds the zero commands of a stop wait for the robots to acknowledge them."""


class WireTimeout(InvalidParameter):
    """Nothing came on a topic the controller waits for (one line, names the topic)."""


class SecondController(InvalidParameter):
    """Another DDS participant publishes cmd_vel for the robots this controller drives."""


def _say(line: str) -> None:
    print(f"serve: {line}", flush=True)


@dataclasses.dataclass(frozen=True)
class ServeConfig:
    """The controller's own settings."""

    authenticated: bool = False
    """Sign incentive messages (HMAC-SHA256, per-pair keys) and verify them on receipt."""
    odometry_timeout: float = 0.5
    """Wall seconds a robot's odometry may be silent, while the controller waits for it,
    before every robot gets a zero command (driving resumes when it is back)."""
    timeout: float = 60.0
    """Wall seconds to wait for the room, and for odometry, before giving up."""
    incentive_timeout: float = 2.0
    """Wall seconds a decision waits for its incentive messages to come back."""

    def __post_init__(self) -> None:
        for name in ("odometry_timeout", "timeout", "incentive_timeout"):
            value = getattr(self, name)
            if isinstance(value, bool) or not 0 < value < math.inf:
                raise InvalidParameter(f"{name}: must be a finite number > 0, got {value}")


@dataclasses.dataclass
class ServeReport:
    """One episode served on the wire (T decision steps, N robots)."""

    success: bool
    actions: list[list[int]]  # [T][N]
    zones: list[list[int]]  # [T + 1][N], from odometry
    rewards: list[list[float]]  # [T][N]
    gate_open: list[bool]  # [T]
    arrived: list[list[bool]]  # [T][N]
    decision_ms: list[float]
    """Per step: wall ms from the observation to the first command (policy + incentives)."""
    incentives_sent: int
    incentives_accepted: int
    rejected: dict[str, int]
    """Incentive messages the channel rejected, by reason (authenticated: bad tag, replay…)."""
    received_totals: list[list[float]]
    """[giver][recipient] incentive accepted by the recipients over the episode."""
    messages: dict[str, int]
    sim_seconds: float
    """Seconds of the robots' clock (odometry stamps) from the first odometry to the end."""
    wall_s: float
    ended: str = "done"
    """done, no room, no odometry, second controller, interrupted, terminated or error."""
    problem: str | None = None
    """The line that ended it early (None when done)."""
    dropped: dict[str, dict[str, int]] = dataclasses.field(default_factory=dict)
    """Messages dropped on the way in, {topic: {reason: count}}."""
    commands_limited: dict[str, int] = dataclasses.field(default_factory=dict)
    """Commands made safe on the way out: robots stopped (not finite) or clamped."""
    stops: list[str] = dataclasses.field(default_factory=list)
    """Each time every robot got a zero command, and why."""
    type_mismatches: list[str] = dataclasses.field(default_factory=list)
    """The lines said about readers of a robot's cmd_vel with another type (`type_mismatch`)."""

    def summary(self) -> dict:
        out = dataclasses.asdict(self)
        ms = np.asarray(self.decision_ms) if self.decision_ms else np.zeros(1)
        out["decision_ms_mean"], out["decision_ms_max"] = float(ms.mean()), float(ms.max())
        out["steps"] = len(self.actions)
        return out


class WirePolicy:
    """One seed's joint decision: (obs [N, D], sent [N, N], t) -> (actions [N], incentives
    [N, N] emitted now, row = giver)."""

    def __init__(self, decision, state, key):
        self.decision, self.state, self.key = decision, state, key

    def __call__(self, obs: np.ndarray, sent: np.ndarray, t: int):
        import jax
        import jax.numpy as jnp

        self.key, key = jax.random.split(self.key)
        given = jnp.asarray(sent, jnp.float32)
        actions, total = self.decision(self.state, key, jnp.asarray(obs), given, t)
        return np.asarray(actions), np.asarray(total - given, np.float64)


# --- what comes in: one parser per topic, each raising Dropped -----------------------------


def _odometry(message) -> tuple[int, tuple[float, float, float]]:
    """(stamp ns, (x, y, yaw)) of a nav_msgs/Odometry that is finite and plausible."""
    stamp = message.header.stamp
    if stamp.sec < 0 or not 0 <= stamp.nanosec < 1_000_000_000:
        raise Dropped("stamp out of range", f"{stamp.sec} s {stamp.nanosec} ns")
    p, q = message.pose.pose.position, message.pose.pose.orientation
    if not all(map(math.isfinite, (p.x, p.y, p.z, q.x, q.y, q.z, q.w))):
        raise Dropped("not finite", f"position ({p.x}, {p.y}, {p.z})")
    if max(abs(p.x), abs(p.y), abs(p.z)) > ODOM_LIMIT_M:
        raise Dropped("position out of range", f"({p.x:g}, {p.y:g}, {p.z:g}) m")
    norm = math.hypot(q.x, q.y, q.z, q.w)
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        raise Dropped("orientation not a unit quaternion", f"norm {norm:g}")
    return ros_wire.time_ns(stamp), ros_wire.planar_pose(message)


def _gate(message) -> float:
    opening = message.data
    if not math.isfinite(opening):
        raise Dropped("not finite", str(opening))
    if not GATE_RANGE[0] <= opening <= GATE_RANGE[1]:
        raise Dropped("out of range", f"{opening:g}, a fraction of the gate's travel expected")
    return float(opening)


def _layout(message) -> Layout:
    try:
        return layout_from_json(message.data)
    except InvalidParameter as error:
        raise Dropped("not a room layout", str(error).removeprefix("layout: ")) from None


_INCENTIVE_FIELDS = frozenset(f.name for f in dataclasses.fields(channel.IncentiveMessage))


def _incentive_parser(n: int, recipient: int, authenticated: bool) -> Callable:
    """The parser of robot `recipient`'s incentive topic: a well-formed message to it from
    another of the `n` robots, with a value of at most `MAX_INCENTIVE`."""

    def parse(message) -> channel.IncentiveMessage:
        raw = ros_wire.bounded_json(message.data, INCENTIVE_BYTES, max_depth=1)
        if not isinstance(raw, dict) or set(raw) != _INCENTIVE_FIELDS:
            raise Dropped("not an incentive message", "its JSON object's fields differ")
        incentive = channel.IncentiveMessage(**raw)
        problem = channel.malformed(incentive)
        if problem and (authenticated or not problem.startswith("malformed tag")):
            raise Dropped("malformed", problem)
        if not (0 <= incentive.giver < n and incentive.giver != recipient):
            raise Dropped("out of range", f"giver {incentive.giver}, robots 0 to {n - 1}")
        if incentive.recipient != recipient:
            raise Dropped("out of range", f"recipient {incentive.recipient} on robot {recipient}")
        if abs(incentive.value) > MAX_INCENTIVE:
            raise Dropped("out of range", f"value {incentive.value:g}, at most {MAX_INCENTIVE:g}")
        if max(incentive.episode, incentive.step, incentive.sequence) >= 2**63:
            raise Dropped("out of range", "episode, step or sequence beyond 64 bits")
        return incentive

    return parse


def type_mismatch(topic: str, reader: str, dds_type: str, distro: str) -> str | None:
    """The line that says `reader` (a participant's name) reads `topic` (a cmd_vel) with
    DDS type `dds_type` where serve writes `distro`'s type, so that it gets no command: with
    the `--ros-distro` that fixes it when it is the other distro's type. None when the types
    are the same or the reader's type is unknown ("")."""
    ours = ros_wire.cmd_vel_struct(distro).__idl_typename__
    if not dds_type or dds_type == ours:
        return None
    theirs, serves = ros_wire.ros_type_name(dds_type), ros_wire.ros_type_name(ours)
    what, fix = "neither distro's cmd_vel type", ""
    for other in ros_wire.cmd_vel_distros(dds_type):
        name = other.capitalize()
        what, fix = (
            f"{name}'s cmd_vel type",
            f"; for a {name} robot run serve with --ros-distro {other}",
        )
    return (
        f"{topic} is read by {reader} as {theirs} ({what}), serve writes {serves} "
        f"(--ros-distro {distro}): DDS never matches the two, so it gets no command{fix}"
    )


class IncentiveLink:
    """The incentive topics of every robot: signing senders and verifying receivers. A
    recipient takes only messages of this process's participant (`Reader.own_only`)."""

    def __init__(self, node: ros_wire.Node, n: int, authenticated: bool):
        self.n, self.authenticated = n, authenticated
        self.topics = topics = [ros_wire.incentive_topic(j) for j in range(n)]
        qos = ros_wire.reliable_qos(depth=64)
        self.writers = [node.writer(t, ros_wire.String, qos) for t in topics]
        self.readers = [
            node.reader(t, ros_wire.String, qos, _incentive_parser(n, j, authenticated), True)
            for j, t in enumerate(topics)
        ]
        keys = channel.KeyRing.generate(n) if authenticated else None
        self.senders = [channel.Sender(i, keys) for i in range(n)] if keys else None
        self.receivers = [channel.Receiver(j, keys) for j in range(n)] if keys else None
        self.sequence = Counter()

    def send(self, episode: int, step: int, incentives: np.ndarray) -> int:
        """Publishes every giver's incentive to every other robot; returns the count."""
        count = 0
        for i in range(self.n):
            for j in range(self.n):
                if i == j:
                    continue
                value = float(incentives[i, j])
                if self.senders is not None:
                    message = self.senders[i].send(j, episode, step, value)
                else:
                    message = channel.IncentiveMessage(
                        i, j, episode, step, self.sequence[i, j], value
                    )
                    self.sequence[i, j] += 1
                self.writers[j].write(ros_wire.String(json.dumps(dataclasses.asdict(message))))
                count += 1
        return count

    def collect(self, expected: int, timeout: float) -> tuple[np.ndarray, list[str]]:
        """The incentives accepted [giver, recipient] and each message's verdict, waiting
        for `expected` messages or `timeout` wall seconds (dropped messages not counted)."""
        accepted, verdicts = np.zeros((self.n, self.n)), []
        deadline = time.perf_counter() + timeout
        while len(verdicts) < expected and time.perf_counter() < deadline:
            for j, reader in enumerate(self.readers):
                for message in reader.take():
                    reason = self._verdict(j, message)
                    verdicts.append(reason)
                    if reason == "ok":
                        accepted[message.giver, j] += message.value
            time.sleep(0.0005)
        return accepted, verdicts

    def _verdict(self, recipient: int, message: channel.IncentiveMessage) -> str:
        if self.receivers is not None:
            return self.receivers[recipient].receive(message).reason
        return "ok"  # parsed: well formed, in range, to this recipient from another robot


class _SignalsHeld:
    """Holds SIGINT and SIGTERM back (main thread) while a stop is written: a second
    Ctrl-C arrives after the zero commands, not in their middle."""

    def __enter__(self):
        self.held = threading.current_thread() is threading.main_thread()
        if self.held:
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
        return self

    def __exit__(self, *exc) -> None:
        if self.held:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})


class ControllerWire:
    """The controller's endpoints and the latest odometry of every robot."""

    def __init__(self, n: int, wire: WireConfig, serve: ServeConfig, say=_say):
        self.n, self.distro, self.serve, self.say = n, wire.distro, serve, say
        who = f"pimbot robot serve, pid {os.getpid()} on {socket.gethostname()}"
        self.node = node = ros_wire.Node(wire.domain_id, user_data=who)
        cmd = ros_wire.cmd_vel_struct(wire.distro)
        self.cmd_topics = [cmd_vel_topic(i) for i in range(n)]
        self.commands = [node.writer(t, cmd, ros_wire.reliable_qos()) for t in self.cmd_topics]
        self.odometry = [
            node.reader(odom_topic(i), ros_wire.Odometry, ros_wire.sensor_qos(), _odometry)
            for i in range(n)
        ]
        self.layout = node.reader(
            ros_wire.LAYOUT_TOPIC, ros_wire.String, ros_wire.latched_qos(), _layout
        )
        self.gate = node.reader(ros_wire.GATE_TOPIC, ros_wire.Float64, ros_wire.sensor_qos(), _gate)
        self.status = node.writer(ros_wire.STATUS_TOPIC, ros_wire.String, ros_wire.reliable_qos())
        self.incentives = IncentiveLink(node, n, serve.authenticated)
        self.poses = np.zeros((n, 3))
        self.stamps = np.full(n, -1, np.int64)
        self.first_ns: int | None = None
        self.heard = np.full(n, -np.inf)
        """Wall time at which each robot's odometry last moved on."""
        self.gate_opening: float | None = None
        self.last_command: tuple[np.ndarray, np.ndarray] | None = None
        self.commanded_at = -np.inf
        self.stopped_at: float | None = None
        """Wall time of a stop for silent odometry, while it lasts."""
        self.limited: Counter = Counter()
        self.stops: list[str] = []
        self.named: set[str] = set()
        self.next_look = 0.0
        self.type_mismatches: list[str] = []
        """The lines said about cmd_vel readers of another type (`type_mismatch`)."""
        self.next_type_look = 0.0

    # -- in --

    def poll(self) -> None:
        now = time.perf_counter()
        for i, reader in enumerate(self.odometry):
            for stamp, pose in reader.take():
                if stamp < self.stamps[i]:
                    self.node.drop(odom_topic(i), "out of order", f"stamp {stamp} ns")
                    continue
                if stamp > self.stamps[i]:
                    self.heard[i] = now
                self.stamps[i], self.poses[i] = stamp, pose
        for opening in self.gate.take():
            self.gate_opening = opening
        self.look_at_discovery(now)

    def look_at_discovery(self, now: float) -> None:
        """The checks of DDS discovery, each at its own pace."""
        self.look_for_rivals(now)
        self.look_for_other_types(now)

    def look_for_rivals(self, now: float) -> None:
        """Raises SecondController when another participant publishes cmd_vel for these
        robots (DDS discovery); names once each participant that publishes on, or whose
        messages were dropped from, the incentive topics."""
        if now < self.next_look:
            return
        self.next_look = now + RIVAL_CHECK_S
        rivals = self.node.rivals(self.cmd_topics + self.incentives.topics)
        for name, topics in rivals.items():
            driving = [t for t in topics if t in self.cmd_topics]
            if driving:
                raise SecondController(
                    f"second controller: {name} publishes {', '.join(driving)} too (DDS "
                    "discovery); serve does not share robots with another controller"
                )
        foreign = {name: sorted(t) for name, t in self.node.foreign.items()}
        for name, topics in {**foreign, **rivals}.items():
            if name not in self.named:
                self.named.add(name)
                self.say(
                    f"another controller, {name}, publishes incentive messages on "
                    f"{', '.join(topics)}: its messages are dropped"
                )

    def look_for_other_types(self, now: float) -> None:
        """Says once per reader, in one line, when another participant reads a robot's
        cmd_vel with another type than serve writes (DDS discovery, every `TYPE_CHECK_S`)."""
        if now < self.next_type_look:
            return
        self.next_type_look = now + TYPE_CHECK_S
        for reader, topic, dds_type in self.node.readers(self.cmd_topics):
            line = type_mismatch(topic, reader, dds_type, self.distro)
            if line is not None and line not in self.type_mismatches:
                self.type_mismatches.append(line)
                self.say(line)

    @property
    def now_ns(self) -> int:
        return int(self.stamps.min())

    def wait_odometry(self, after_ns: int, timeout: float) -> None:
        """Waits until every robot's odometry is newer than `after_ns` (WireTimeout after
        `timeout` s), sending the last commands again every `RESEND_S` meanwhile (as a ROS
        controller publishing on a timer would: a command sent before the robot's reader
        was matched is lost). A robot silent for `odometry_timeout` since its last odometry
        and the last command stops every robot until the odometry is back."""
        now = time.perf_counter()
        deadline, resend = now + timeout, now + RESEND_S
        while True:
            self.poll()
            fresh = self.stamps > after_ns
            now = time.perf_counter()
            if fresh.all():
                if self.first_ns is None:
                    self.first_ns = self.now_ns
                if self.stopped_at is not None:
                    self.say(f"odometry back after {now - self.stopped_at:.1f} s: driving again")
                    self.stopped_at = None
                return
            silent = now - np.maximum(self.heard, self.commanded_at)
            late = ~fresh & (silent > self.serve.odometry_timeout)
            if late.any() and self.stopped_at is None and self.last_command is not None:
                topics = ", ".join(odom_topic(i) for i in np.flatnonzero(late))
                self.stop(
                    f"no odometry on {topics} for {self.serve.odometry_timeout:g} s; waiting "
                    f"up to {timeout:g} s for it"
                )
                self.stopped_at = now
            if now > resend and self.last_command is not None:
                self._write(*self.last_command)
                resend = now + RESEND_S
            if now > deadline:
                stale = [odom_topic(i) for i in np.flatnonzero(~fresh)]
                raise WireTimeout(
                    f"odometry: nothing new on {', '.join(stale)} for {timeout:g} s "
                    f"(domain {self.node.participant.domain_id}, is a robot or "
                    "`pimbot robot world` running?)"
                )
            time.sleep(0.0002)

    def wait_layout(self, timeout: float) -> Layout:
        deadline = time.perf_counter() + timeout
        while time.perf_counter() < deadline:
            for layout in self.layout.take():
                return layout
            self.look_at_discovery(time.perf_counter())
            time.sleep(0.01)
        last = self.node.last_drop.get(ros_wire.LAYOUT_TOPIC)
        dropped = f" (dropped: {last})" if last else ""
        raise WireTimeout(f"layout: no room on {ros_wire.LAYOUT_TOPIC} for {timeout:g} s{dropped}")

    # -- out --

    def command(self, linear: np.ndarray, angular: np.ndarray) -> None:
        """Sends one command per robot: the one way a command leaves (`_write`)."""
        self.commanded_at = time.perf_counter()
        self.last_command = self._write(linear, angular)

    def _write(self, linear, angular) -> tuple[np.ndarray, np.ndarray]:
        linear, angular, changed = ctl.safe_command(linear, angular)
        self.limited.update({k: v for k, v in changed.items() if v})
        at = max(self.now_ns, 0)
        for i, writer in enumerate(self.commands):
            writer.write(ros_wire.wire_cmd_vel(self.distro, linear[i], angular[i], at, i))
        return linear, angular

    def stop(self, why: str) -> None:
        """A zero command to every robot, said in one line (and on the status topic)."""
        zero = np.zeros(self.n)
        with _SignalsHeld():
            self.command(zero, zero)
            for writer in self.commands:
                writer.writer.wait_for_acks(duration(seconds=ACK_S))
        robots = ", ".join(f"tb3_{i}" for i in range(self.n))
        line = f"stopped every robot (zero cmd_vel to {robots}): {why}"
        self.stops.append(line)
        self.say(line)
        self.publish_status({"stopped": why})

    def publish_status(self, event: dict) -> None:
        self.status.write(ros_wire.String(json.dumps(event, sort_keys=True)))

    def counters(self) -> dict:
        """What was dropped on the way in and made safe on the way out, so far."""
        return {"dropped": self.node.dropped_counts(), "commands_limited": dict(self.limited)}

    def flush(self) -> None:
        """Waits (at most 1 s) until the readers of the status have acknowledged it."""
        self.status.writer.wait_for_acks(duration(seconds=1))


def _drive(ends: ControllerWire, goals, driving, cfg: PhysicsConfig, timeout: float):
    """`episode.drive` on the wire: one command per robot for every fresh odometry, until
    the driving robots arrive or the decision's simulated time is up; returns arrived [N]."""
    started = ends.now_ns
    active, arrived = driving.copy(), np.zeros(len(driving), bool)
    progress = ctl.Progress(len(driving))
    progress.reset(started / 1e9)
    while active.any() and (ends.now_ns - started) / 1e9 < cfg.decision_time_limit:
        poses, at = ends.poses.copy(), ends.now_ns
        detour = progress.update(at / 1e9, np.linalg.norm(goals - poses[:, :2], axis=1))
        linear, angular, reached = ctl.go_to_goal(poses, goals, active, cfg.controller, detour)
        arrived |= reached & active
        active &= ~reached
        ends.command(linear, angular)
        ends.wait_odometry(at, timeout)
    return arrived


def _settle(ends: ControllerWire, cfg: PhysicsConfig, timeout: float) -> None:
    started, zero = ends.now_ns, np.zeros(ends.n)
    while (ends.now_ns - started) / 1e9 < cfg.settle_time - 1e-9:
        at = ends.now_ns
        ends.command(zero, zero)
        ends.wait_odometry(at, timeout)


def _zones(ends: ControllerWire, layout: Layout, previous: np.ndarray) -> np.ndarray:
    zones = layout.zone_of(ends.poses[:, :2])
    return np.where(zones >= 0, zones, previous)


def _gate_open(ends: ControllerWire, zones: np.ndarray, cfg: PhysicsConfig) -> bool:
    if ends.gate_opening is None:  # no gate topic: the rule that drives the servo
        return int(np.sum(zones == LEVER)) >= cfg.min_at_lever
    return ends.gate_opening >= GATE_OPEN_FRACTION


def _ending(error: BaseException) -> str:
    if isinstance(error, KeyboardInterrupt):
        return "terminated" if type(error).__name__ == "Terminated" else "interrupted"
    if isinstance(error, SecondController):
        return "second controller"
    if isinstance(error, WireTimeout):
        return "no odometry" if str(error).startswith("odometry") else "no room"
    return "error"


def serve_episode(
    policy: WirePolicy,
    cfg: PhysicsConfig,
    wire: WireConfig,
    serve: ServeConfig = ServeConfig(),
    layout: Layout | None = None,
    audit=None,
    episode: int = 0,
    say: Callable[[str], None] = _say,
) -> ServeReport:
    """Plays one episode of `policy` on the robots behind the wire; however it ends, every
    robot gets a zero command last (said in one line by `say`).

    Args:
        layout: the room; None: wait for it on /pimbot/layout.
        audit: a `defenses.audit.AuditLog` to append every decision to, or None.
        episode: the episode number in the incentive messages.
    Returns:
        The report; `ended` says how it ended: done, or (with `problem`, the line that
        says why) no room, no odometry (for `timeout`) or second controller.
    Raises:
        KeyboardInterrupt: Ctrl-C or SIGTERM, after the stop (its `serve_report` attribute
            holds the report so far).
        Exception: anything else, after the stop (an invalid layout: InvalidParameter).
    """
    start = time.perf_counter()
    ends = ControllerWire(cfg.n_robots, wire, serve, say)
    played = _Played(cfg.n_robots)
    try:
        _play(policy, cfg, ends, serve, layout, audit, episode, played)
    except BaseException as error:
        ended = _ending(error)
        problem = str(error).splitlines()[0] if str(error) else ended
        ends.stop(problem if ended != "error" else f"error: {type(error).__name__}: {problem}")
        report = played.report(ends, time.perf_counter() - start, ended, problem)
        _finish(ends, report, episode, audit)
        if isinstance(error, WireTimeout | SecondController):
            return report
        error.serve_report = report
        raise
    ends.stop("the episode is over")
    report = played.report(ends, time.perf_counter() - start)
    _finish(ends, report, episode, audit)
    return report


def _play(policy, cfg, ends: ControllerWire, serve: ServeConfig, layout, audit, episode, played):
    n = cfg.n_robots
    layout = layout or ends.wait_layout(serve.timeout)
    if layout.num_robots != n:
        raise InvalidParameter(f"layout: a room for {layout.num_robots} robots, the run has {n}")
    ends.wait_odometry(-1, serve.timeout)
    played.zones.append(_zones(ends, layout, np.full(n, START)))
    for t in range(cfg.max_steps):
        previous = played.zones[-1]
        began = time.perf_counter()
        chosen, verdicts = _decide(policy, ends, played, episode, t, serve)
        driving = chosen != previous
        goals = np.array(
            [layout.slot(chosen[i], i) if driving[i] else (0.0, 0.0) for i in range(n)]
        )
        played.decision_ms.append(1e3 * (time.perf_counter() - began))  # the first command next
        arrived = _drive(ends, goals, driving, cfg, serve.timeout)
        _settle(ends, cfg, serve.timeout)
        now = _zones(ends, layout, previous)
        gate_open = _gate_open(ends, now, cfg)
        event = _step_event(episode, t, chosen, previous, now, gate_open, verdicts)
        event["incentives"] = played.last_incentives.tolist()
        ends.publish_status({**event, **ends.counters()})
        if audit is not None:
            audit.append("decision", **event)
        played.record(event, now, arrived | ~driving)
        if event["success"]:
            break


def _finish(ends: ControllerWire, report: ServeReport, episode: int, audit) -> None:
    """The episode's end on the status topic (with the counters) and in the audit log."""
    end = {
        "done": True,
        "episode": episode,
        "success": report.success,
        "steps": len(report.actions),
        "ended": report.ended,
    }
    try:
        ends.publish_status({**end, **ends.counters()})
        if audit is not None:
            audit.append("episode", **end, rejected=report.rejected, dropped=report.dropped)
        ends.flush()
    except Exception as error:  # noqa: BLE001 (the robots are stopped; say it, end anyway)
        print(f"serve: the end was not published: {error}", file=sys.stderr)


def _step_event(episode, t, chosen, previous, now, gate_open: bool, verdicts) -> dict:
    """One decision step as /pimbot/status and the audit log carry it."""
    return {
        "episode": episode,
        "step": t,
        "actions": chosen.tolist(),
        "zones_before": previous.tolist(),
        "zones_after": now.tolist(),
        "verdicts": dict(Counter(verdicts)),
        "rewards": er_rewards(previous, now, gate_open).tolist(),
        "gate_open": gate_open,
        "success": bool(gate_open and np.any(now == DOOR)),
    }


class _Played:
    """What an episode on the wire has done so far."""

    def __init__(self, n: int):
        self.zones: list[np.ndarray] = []
        self.sent, self.received = np.zeros((n, n)), np.zeros((n, n))
        self.last_incentives = np.zeros((n, n))
        self.events: list[dict] = []
        self.arrived: list[list[bool]] = []
        self.decision_ms: list[float] = []
        self.counts, self.rejected = Counter(), Counter()

    def record(self, event: dict, zones: np.ndarray, arrived: np.ndarray) -> None:
        self.events.append(event)
        self.zones.append(zones)
        self.arrived.append(arrived.tolist())

    def report(
        self, ends: ControllerWire, wall_s: float, ended: str = "done", problem=None
    ) -> ServeReport:
        events = self.events
        first = ends.first_ns
        return ServeReport(
            success=bool(events and events[-1]["success"]),
            actions=[e["actions"] for e in events],
            zones=[z.tolist() for z in self.zones],
            rewards=[e["rewards"] for e in events],
            gate_open=[e["gate_open"] for e in events],
            arrived=self.arrived,
            decision_ms=self.decision_ms,
            incentives_sent=self.counts["sent"],
            incentives_accepted=self.counts["accepted"],
            rejected=dict(self.rejected),
            received_totals=self.received.tolist(),
            messages=ends.node.messages(),
            sim_seconds=0.0 if first is None else max(ends.now_ns - first, 0) / 1e9,
            wall_s=wall_s,
            ended=ended,
            problem=problem,
            dropped=ends.node.dropped_counts(),
            commands_limited=dict(ends.limited),
            stops=list(ends.stops),
            type_mismatches=list(ends.type_mismatches),
        )


def _decide(policy, ends: ControllerWire, played: _Played, episode: int, t: int, serve):
    """The joint decision at step `t`, and its incentives sent and collected on the wire;
    returns (actions [N], the verdict on each incentive message)."""
    n = ends.n
    chosen, incentives = policy(observation(played.zones[-1]), played.sent, t)
    played.sent += incentives
    played.last_incentives = incentives
    played.counts["sent"] += ends.incentives.send(episode, t, incentives)
    accepted, verdicts = ends.incentives.collect(n * (n - 1), serve.incentive_timeout)
    played.received += accepted
    played.counts["accepted"] += verdicts.count("ok")
    played.rejected.update(v for v in verdicts if v != "ok")
    return chosen, verdicts


def with_attack(loaded, name: str, adversary: int):
    """`loaded` with attack `name` (default parameters) on robot `adversary` instead of the
    run's own attack (InvalidParameter naming a bad name or robot)."""
    from pimbot import attacks

    n = loaded.resolved.env.num_agents
    attack = attacks.make(name, n, adversary=adversary)
    return dataclasses.replace(loaded, resolved=dataclasses.replace(loaded.resolved, attack=attack))


def trained_policy(loaded, seed_index: int) -> WirePolicy:
    """One seed's joint decision, compiled before the robots are driven."""
    import jax

    from pimbot.robot import evaluate

    decision = evaluate.decision_function(loaded)
    seed = loaded.seeds[seed_index]
    policy = WirePolicy(
        decision, loaded.seed_state(seed_index), jax.random.fold_in(jax.random.PRNGKey(seed), 7)
    )
    n = loaded.resolved.env.num_agents
    warm = WirePolicy(decision, policy.state, jax.random.PRNGKey(0))  # its own key: no draw
    warm(observation(np.full(n, START)), np.zeros((n, n)), 0)
    return policy
