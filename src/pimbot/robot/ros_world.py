"""The MuJoCo world playing the robots on ROS 2 topics (`pimbot robot world`).

The same room, robots, noise and gate servo as `episode.Simulation`, but the robot bases
listen on the wire: each control period the world applies every robot's latest command
from `/tb3_<i>/cmd_vel` (Twist on Humble, TwistStamped on Jazzy), steps the physics and
publishes `/tb3_<i>/odom` (nav_msgs/Odometry, stamped in simulated time) and the gate's
opening on `/pimbot/gate`; the room is on `/pimbot/layout` (latched). Topic names and
types: `pimbot.robot.ros_wire`.

Pace: with `speed` = 0 the world steps as soon as every robot has a command answering the
last odometry (lockstep, as fast as the controller goes), or after `command_timeout`
wall-clock seconds without one (a base keeps its last command, as a real one does until
its own timeout); with `speed` > 0 it also waits until `control_period / speed` wall seconds
have passed (1 = real time). It steps only once every robot has been commanded (robots
stand still until a controller shows up, their odometry republished every 0.1 s), and
stops when the controller publishes its end on `/pimbot/status`, or after `timeout`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time

import numpy as np

from pimbot.errors import InvalidParameter
from pimbot.robot import ros_wire
from pimbot.robot.episode import PhysicsConfig, Simulation
from pimbot.robot.messages import cmd_vel_topic, odom_topic
from pimbot.robot.world import Layout, build_world, sample_layout

REPUBLISH_S = 0.1


@dataclasses.dataclass(frozen=True)
class WireConfig:
    """How a process meets the others on the wire."""

    distro: str = "humble"
    """ROS 2 distro whose cmd_vel type is used: humble (Twist) or jazzy (TwistStamped)."""
    domain_id: int = 0
    """DDS domain (ROS_DOMAIN_ID)."""
    speed: float = 0.0
    """World only: real-time factor; 0 = lockstep with the controller."""
    command_timeout: float = 1.0
    """World only: wall seconds a control period waits for every robot's command."""
    timeout: float = 300.0
    """Wall seconds after which the process gives up."""

    def __post_init__(self) -> None:
        ros_wire.check_distro(self.distro)
        if type(self.domain_id) is not int or not 0 <= self.domain_id <= 232:
            raise InvalidParameter(
                f"domain_id: must be an integer in [0, 232], got {self.domain_id}"
            )
        if not 0 <= self.speed < float("inf"):
            raise InvalidParameter(f"speed: must be a finite number ≥ 0, got {self.speed}")
        for name in ("command_timeout", "timeout"):
            if not getattr(self, name) > 0:
                raise InvalidParameter(f"{name}: must be a number > 0, got {getattr(self, name)}")


def layout_json(layout: Layout) -> str:
    return json.dumps(dataclasses.asdict(layout), sort_keys=True)


MAX_ROOM_M = 1000.0
"""The largest room side (m) a layout may give."""


def layout_from_json(text: str) -> Layout:
    """A `Layout` from `layout_json`'s text, checked as a room: a finite positive size, three
    zones of positive size inside it and apart, a doorway in the right wall, start poses
    inside the room (InvalidParameter naming what is wrong). The text is parsed within
    `ros_wire.bounded_json`'s size and nesting bounds."""
    try:
        raw = ros_wire.bounded_json(text)
    except ros_wire.Dropped as dropped:
        raise InvalidParameter(f"layout: not a pimbot room layout ({dropped})") from None
    try:
        fields = {f.name for f in dataclasses.fields(Layout)}
        if not isinstance(raw, dict) or set(raw) != fields:
            raise ValueError(f"fields {', '.join(sorted(fields))} expected")
        layout = Layout(
            width=_number(raw["width"]),
            height=_number(raw["height"]),
            zone_centres=tuple(_point(c, 2) for c in _items(raw["zone_centres"])),
            zone_half=_number(raw["zone_half"]),
            door_y=_number(raw["door_y"]),
            gate_direction=raw["gate_direction"],
            start_poses=tuple(_point(p, 3) for p in _items(raw["start_poses"])),
        )
    except (ValueError, TypeError, KeyError) as error:
        raise InvalidParameter(f"layout: not a pimbot room layout ({error})") from None
    problem = _room_problem(layout)
    if problem:
        raise InvalidParameter(f"layout: {problem}")
    return layout


def _number(value) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise TypeError(f"a number expected, got {value!r}"[:120])
    return float(value)


def _items(value) -> list:
    if not isinstance(value, list):
        raise TypeError(f"a list expected, got {value!r}"[:120])
    return value


def _point(value, size: int) -> tuple[float, ...]:
    items = _items(value)
    if len(items) != size:
        raise ValueError(f"{size} numbers expected, got {len(items)}")
    return tuple(_number(v) for v in items)


def _room_problem(layout: Layout) -> str | None:
    """What makes `layout` no room (None: it is one)."""
    numbers = [layout.width, layout.height, layout.zone_half, layout.door_y]
    numbers += [v for c in layout.zone_centres for v in c]
    numbers += [v for p in layout.start_poses for v in p]
    if not all(map(math.isfinite, numbers)):
        return "every number must be finite (NaN or inf given)"
    for name in ("width", "height"):
        size = getattr(layout, name)
        if not 0 < size <= MAX_ROOM_M:
            return f"{name} must be in (0, {MAX_ROOM_M:g}] m, got {size:g}"
    half_w, half_h, half = layout.width / 2, layout.height / 2, layout.zone_half
    if len(layout.zone_centres) != 3:
        return f"3 zone centres (lever, start, door) expected, got {len(layout.zone_centres)}"
    if not 0 < half <= min(half_w, half_h):
        return f"zone_half must be in (0, {min(half_w, half_h):g}] m, got {half:g}"
    names = ("lever", "start", "door")
    for name, (x, y) in zip(names, layout.zone_centres, strict=True):
        if abs(x) + half > half_w or abs(y) + half > half_h:
            return f"the {name} zone at ({x:g}, {y:g}) is not inside the room"
    for a in range(3):
        for b in range(a + 1, 3):
            (xa, ya), (xb, yb) = layout.zone_centres[a], layout.zone_centres[b]
            if abs(xa - xb) < 2 * half and abs(ya - yb) < 2 * half:
                return f"the {names[a]} and {names[b]} zones overlap"
    if not abs(layout.door_y) < half_h:
        return f"door_y must be inside the right wall (|y| < {half_h:g}), got {layout.door_y:g}"
    if type(layout.gate_direction) is not int or layout.gate_direction not in (1, -1):
        return f"gate_direction must be 1 or -1, got {layout.gate_direction!r}"
    if not layout.start_poses:
        return "no start poses"
    for i, (x, y, _) in enumerate(layout.start_poses):
        if abs(x) > half_w or abs(y) > half_h:
            return f"robot {i}'s start pose ({x:g}, {y:g}) is not inside the room"
    return None


@dataclasses.dataclass
class WorldReport:
    """What the world saw on the wire."""

    ticks: int
    sim_seconds: float
    wall_s: float
    ended: str
    """"controller done" or "timeout"."""
    messages: dict[str, int]
    answer_ms: list[float]
    """Per control period: wall ms from publishing odometry to the last robot's command."""
    final_zones: list[int]
    gate_opening: float
    dropped: dict[str, dict[str, int]] = dataclasses.field(default_factory=dict)
    """Messages dropped on the way in, by topic and reason (`ros_wire.Reader.take`)."""

    def summary(self) -> dict:
        answers = np.asarray(self.answer_ms) if self.answer_ms else np.zeros(1)
        return {
            "ticks": self.ticks,
            "sim_seconds": self.sim_seconds,
            "wall_s": self.wall_s,
            "ended": self.ended,
            "messages": self.messages,
            "answer_ms_median": float(np.median(answers)),
            "answer_ms_p95": float(np.percentile(answers, 95)),
            "final_zones": self.final_zones,
            "gate_opening": self.gate_opening,
            "dropped": self.dropped,
        }


class _WorldWire:
    """The world's endpoints: per robot a cmd_vel reader and an odom writer; the room,
    gate and status topics."""

    def __init__(self, n: int, wire: WireConfig):
        self.node = node = ros_wire.Node(wire.domain_id)
        cmd = ros_wire.cmd_vel_struct(wire.distro)
        self.commands = [
            node.reader(cmd_vel_topic(i), cmd, ros_wire.reliable_qos(), parse=_command)
            for i in range(n)
        ]
        self.odometry = [
            node.writer(odom_topic(i), ros_wire.Odometry, ros_wire.reliable_qos()) for i in range(n)
        ]
        self.layout = node.writer(ros_wire.LAYOUT_TOPIC, ros_wire.String, ros_wire.latched_qos())
        self.gate = node.writer(ros_wire.GATE_TOPIC, ros_wire.Float64, ros_wire.reliable_qos())
        self.status = node.reader(
            ros_wire.STATUS_TOPIC, ros_wire.String, ros_wire.reliable_qos(), parse=_status
        )

    def publish_state(self, sim: Simulation) -> float:
        """Odometry of every robot (the simulation's latest) and the gate; the wall time."""
        for i, writer in enumerate(self.odometry):
            writer.write(ros_wire.wire_odometry(sim.bus.latest[odom_topic(i)]))
        self.gate.write(ros_wire.Float64(float(sim.world.gate_opening())))
        return time.perf_counter()

    def take_commands(self, commands, answered, commanded) -> None:
        """Latest (linear, angular) per robot into `commands` [N, 2]; marks who answered."""
        for i, reader in enumerate(self.commands):
            for command in reader.take():
                commands[i] = command
                answered[i] = commanded[i] = True

    def controller_done(self) -> bool:
        return any(event.get("done") is True for event in self.status.take())


def _command(message) -> tuple[float, float]:
    """(linear, angular) of a cmd_vel message; a robot base drops one that is not finite."""
    linear, angular = ros_wire.command_of(message)
    if not (math.isfinite(linear) and math.isfinite(angular)):
        raise ros_wire.Dropped("not finite", f"({linear}, {angular})")
    return linear, angular


def _status(message) -> dict:
    event = ros_wire.bounded_json(message.data)
    if not isinstance(event, dict):
        raise ros_wire.Dropped("not a JSON object")
    return event


def play_world(cfg: PhysicsConfig, wire: WireConfig, rng: np.random.Generator) -> WorldReport:
    """Plays the robots of one room on the wire until the controller is done (or timeout)."""
    layout = sample_layout(rng, cfg.n_robots, cfg.randomize_layout)
    sim = Simulation(build_world(layout), cfg, rng, record=False)
    n = cfg.n_robots
    ends = _WorldWire(n, wire)
    ends.layout.write(ros_wire.String(layout_json(layout)))
    commands = np.zeros((n, 2))
    answered = np.zeros(n, bool)
    commanded = np.zeros(n, bool)
    answers, ended = [], "timeout"
    start = published = due = ends.publish_state(sim)
    answered_at = None
    pace = cfg.control_period / wire.speed if wire.speed > 0 else 0.0
    while time.perf_counter() - start < wire.timeout:
        ends.take_commands(commands, answered, commanded)
        if ends.controller_done():
            ended = "controller done"
            break
        now = time.perf_counter()
        if answered.all() and answered_at is None:
            answered_at = now
        late = now - published >= wire.command_timeout
        if commanded.all() and now >= due and (answered_at is not None or late):
            if answered_at is not None:
                answers.append(1e3 * (answered_at - published))
            sim.tick(commands[:, 0], commands[:, 1])
            answered[:], answered_at = False, None
            published = ends.publish_state(sim)
            due = max(due + pace, published - pace) if pace else published
        elif not commanded.all() and now - published >= REPUBLISH_S:
            published = due = ends.publish_state(sim)
        else:
            time.sleep(0.0002)
    return WorldReport(
        ticks=len(sim.trace["time"]),
        sim_seconds=float(sim.world.data.time),
        wall_s=time.perf_counter() - start,
        ended=ended,
        messages=ends.node.messages(),
        answer_ms=answers,
        final_zones=sim.zones().tolist(),
        gate_opening=float(sim.world.gate_opening()),
        dropped=ends.node.dropped_counts(),
    )
