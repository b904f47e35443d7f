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


def layout_from_json(text: str) -> Layout:
    """A `Layout` from `layout_json`'s text (InvalidParameter naming what is wrong)."""
    try:
        raw = json.loads(text)
        fields = {f.name for f in dataclasses.fields(Layout)}
        if not isinstance(raw, dict) or set(raw) != fields:
            raise ValueError(f"fields {', '.join(sorted(fields))} expected")
        return Layout(
            width=float(raw["width"]),
            height=float(raw["height"]),
            zone_centres=tuple(tuple(map(float, c)) for c in raw["zone_centres"]),
            zone_half=float(raw["zone_half"]),
            door_y=float(raw["door_y"]),
            gate_direction=int(raw["gate_direction"]),
            start_poses=tuple(tuple(map(float, p)) for p in raw["start_poses"]),
        )
    except (ValueError, TypeError, KeyError) as error:
        raise InvalidParameter(f"layout: not a pimbot room layout ({error})") from None


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
        }


class _WorldWire:
    """The world's endpoints: per robot a cmd_vel reader and an odom writer; the room,
    gate and status topics."""

    def __init__(self, n: int, wire: WireConfig):
        self.node = node = ros_wire.Node(wire.domain_id)
        cmd = ros_wire.cmd_vel_struct(wire.distro)
        self.commands = [
            node.reader(cmd_vel_topic(i), cmd, ros_wire.reliable_qos()) for i in range(n)
        ]
        self.odometry = [
            node.writer(odom_topic(i), ros_wire.Odometry, ros_wire.reliable_qos()) for i in range(n)
        ]
        self.layout = node.writer(ros_wire.LAYOUT_TOPIC, ros_wire.String, ros_wire.latched_qos())
        self.gate = node.writer(ros_wire.GATE_TOPIC, ros_wire.Float64, ros_wire.reliable_qos())
        self.status = node.reader(ros_wire.STATUS_TOPIC, ros_wire.String, ros_wire.reliable_qos())

    def publish_state(self, sim: Simulation) -> float:
        """Odometry of every robot (the simulation's latest) and the gate; the wall time."""
        for i, writer in enumerate(self.odometry):
            writer.write(ros_wire.wire_odometry(sim.bus.latest[odom_topic(i)]))
        self.gate.write(ros_wire.Float64(float(sim.world.gate_opening())))
        return time.perf_counter()

    def take_commands(self, commands, answered, commanded) -> None:
        """Latest (linear, angular) per robot into `commands` [N, 2]; marks who answered."""
        for i, reader in enumerate(self.commands):
            for message in reader.take():
                commands[i] = ros_wire.command_of(message)
                answered[i] = commanded[i] = True

    def controller_done(self) -> bool:
        for message in self.status.take():
            try:
                if json.loads(message.data).get("done"):
                    return True
            except (ValueError, AttributeError):
                continue
        return False


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
    )
