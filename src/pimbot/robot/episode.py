"""One Escape Room episode in physics: decisions, driving, and the ER rules on zones.

Per decision step t (at most `max_steps`, as in the abstract ER):
  1. every robot's position is the zone it stands in (a robot in no zone keeps
     the zone it was last in); the observation has the abstract env's layout;
  2. the policy picks lever / start / door for every robot;
  3. a robot whose choice differs from its zone drives to its own slot in the
     chosen zone (go-to-goal on its noisy odometry, Twist on /tb3_<i>/cmd_vel)
     until every driving robot has arrived or `decision_time_limit` has passed;
     then all robots hold still for `settle_time`;
  4. the ER rules apply to the zones the robots are now in: +10 to a robot in
     the door zone while the gate is open, else 0 if its zone did not change,
     else −1; success when the gate is open with a robot in the door zone.
The gate servo opens the gate whenever at least M robots are in the lever zone,
at every control tick, whatever the policy chose.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Protocol

import mujoco
import numpy as np

from pimbot.robot import controller as ctl
from pimbot.robot.messages import (
    Bus,
    Odometry,
    Pose,
    Quaternion,
    Twist,
    Vector3,
    cmd_vel_topic,
    odom_topic,
)
from pimbot.robot.world import World, build_world, sample_layout

LEVER, START, DOOR = 0, 1, 2
GATE_OPEN_FRACTION = 0.9  # the gate counts as open past 90 % of its travel


@dataclasses.dataclass(frozen=True)
class PhysicsConfig:
    """How an ER(N, M) episode is played in physics."""

    n_robots: int = 2
    """N."""
    min_at_lever: int = 1
    """M: robots in the lever zone that hold the gate open."""
    max_steps: int = 5
    """Decision steps per episode (the abstract ER horizon)."""
    decision_time_limit: float = 40.0
    """Simulated seconds a decision step may take to drive before the rules apply."""
    settle_time: float = 1.0
    """Simulated seconds all robots hold still before the rules apply (the gate moves)."""
    control_period: float = 0.05
    """Seconds between controller ticks (20 Hz, TurtleBot3's usual cmd_vel rate)."""
    odom_noise_position: float = 0.01
    """Standard deviation (m) of the Gaussian noise on odometry x and y."""
    odom_noise_yaw: float = 0.02
    """Standard deviation (rad) of the Gaussian noise on odometry yaw."""
    actuation_noise: float = 0.05
    """Standard deviation of the multiplicative noise on each commanded wheel speed."""
    randomize_layout: bool = True
    """Randomize room size and zone positions per episode (else the nominal room)."""
    controller: ctl.ControllerConfig = ctl.ControllerConfig()

    def __post_init__(self) -> None:
        from pimbot.envs.core import InvalidParameter

        if not 1 <= self.min_at_lever < self.n_robots:
            raise InvalidParameter(
                f"min_at_lever: must satisfy 1 ≤ M < N = {self.n_robots}, got {self.min_at_lever}"
            )
        for name in ("decision_time_limit", "control_period"):
            if not getattr(self, name) > 0:
                raise InvalidParameter(f"{name}: must be a number > 0, got {getattr(self, name)}")
        for name in ("settle_time", "odom_noise_position", "odom_noise_yaw", "actuation_noise"):
            if not getattr(self, name) >= 0:
                raise InvalidParameter(f"{name}: must be a number ≥ 0, got {getattr(self, name)}")


class Policy(Protocol):
    """Chooses every robot's zone from the abstract observations."""

    def start_episode(self) -> None: ...

    def __call__(self, obs: np.ndarray, t: int) -> np.ndarray:
        """obs float32 [N, obs_dim] (incentive slots zero) -> actions int [N]."""
        ...


@dataclasses.dataclass
class EpisodeResult:
    """What happened in one physics episode (T = decision steps taken)."""

    actions: np.ndarray  # int [T, N]
    positions: np.ndarray  # int [T + 1, N], zones before the first and after every step
    rewards: np.ndarray  # float [T, N]
    gate_open: np.ndarray  # bool [T]
    arrived: np.ndarray  # bool [T, N], driving robots that reached their slot in time
    decision_seconds: np.ndarray  # float [T], simulated time each step took
    success: bool
    physics_steps: int
    world: World
    bus: Bus
    trace: dict[str, np.ndarray]  # per tick: "time" [K], "poses" [K, N, 3], "gate" [K]

    @property
    def steps(self) -> int:
        return int(self.actions.shape[0])


def observation(positions: np.ndarray, num_positions: int = 3) -> np.ndarray:
    """The abstract ER observation of every agent, incentive slots zero: [N, 3N + N − 1].

    Row i: one-hot of agent i's position, then every other agent's in id order.
    """
    n = len(positions)
    one_hot = np.eye(num_positions, dtype=np.float32)[positions]
    rows = [
        np.concatenate([one_hot[i]] + [one_hot[j] for j in range(n) if j != i]) for i in range(n)
    ]
    return np.concatenate([np.stack(rows), np.zeros((n, n - 1), np.float32)], axis=1)


def er_rewards(previous: np.ndarray, now: np.ndarray, gate_open: bool) -> np.ndarray:
    """The ER rules on zones: +10 in the door zone with the gate open, 0 stayed, −1 moved."""
    return np.where(gate_open & (now == DOOR), 10.0, np.where(now == previous, 0.0, -1.0))


class Simulation:
    """The world, the bus and the control tick shared by driving and settling."""

    def __init__(self, world: World, cfg: PhysicsConfig, rng: np.random.Generator, record):
        self.world, self.cfg, self.rng = world, cfg, rng
        self.bus = Bus(record=record)
        self.substeps = max(1, round(cfg.control_period / world.model.opt.timestep))
        self.steps = 0
        self.trace: dict[str, list] = {"time": [], "poses": [], "gate": []}
        self._publish_odometry()

    @property
    def stamp_ns(self) -> int:
        return int(round(self.world.data.time * 1e9))

    def zones(self) -> np.ndarray:
        return self.world.layout.zone_of(self.world.poses()[:, :2])

    def _publish_odometry(self) -> None:
        poses, velocities = self.world.poses(), self.world.body_velocities()
        n = self.world.num_robots
        noise_xy = self.rng.normal(0.0, self.cfg.odom_noise_position, (n, 2))
        noise_yaw = self.rng.normal(0.0, self.cfg.odom_noise_yaw, n)
        for i in range(n):
            message = Odometry(
                stamp_ns=self.stamp_ns,
                frame_id="odom",
                child_frame_id=f"tb3_{i}/base_footprint",
                pose=Pose(
                    Vector3(poses[i, 0] + noise_xy[i, 0], poses[i, 1] + noise_xy[i, 1], 0.0),
                    Quaternion.from_yaw(poses[i, 2] + noise_yaw[i]),
                ),
                twist=Twist(Vector3(velocities[i, 0]), Vector3(z=velocities[i, 1])),
                position_variance=self.cfg.odom_noise_position**2,
            )
            self.bus.publish(self.stamp_ns, odom_topic(i), message)

    def odometry_poses(self) -> np.ndarray:
        """(x, y, θ) [N, 3] from the latest /tb3_<i>/odom messages."""
        out = np.empty((self.world.num_robots, 3))
        for i in range(self.world.num_robots):
            odom = self.bus.latest[odom_topic(i)]
            out[i] = odom.pose.position.x, odom.pose.position.y, odom.pose.orientation.yaw()
        return out

    def tick(self, linear: np.ndarray, angular: np.ndarray) -> None:
        """Publishes the commands, runs one control period of physics, publishes odometry."""
        world, cfg = self.world, self.cfg
        n = world.num_robots
        for i in range(n):
            twist = Twist(Vector3(float(linear[i])), Vector3(z=float(angular[i])))
            self.bus.publish(self.stamp_ns, cmd_vel_topic(i), twist)
        # The robot base: wheel speeds from the latest cmd_vel, with actuation noise.
        commands = [self.bus.latest[cmd_vel_topic(i)] for i in range(n)]
        wheels = ctl.wheel_speeds([c.linear.x for c in commands], [c.angular.z for c in commands])
        wheels = wheels * (1.0 + self.rng.normal(0.0, cfg.actuation_noise, wheels.shape))
        world.data.ctrl[world.wheel_ctrl] = wheels
        at_lever = int(np.sum(self.zones() == LEVER))
        world.data.ctrl[world.gate_ctrl] = (
            world.gate_open_target if at_lever >= cfg.min_at_lever else 0.0
        )
        mujoco.mj_step(world.model, world.data, nstep=self.substeps)
        self.steps += self.substeps
        self.trace["time"].append(world.data.time)
        self.trace["poses"].append(world.poses())
        self.trace["gate"].append(world.gate_opening())
        self._publish_odometry()


def run_episode(
    policy: Policy | Callable[[np.ndarray, int], np.ndarray],
    cfg: PhysicsConfig,
    rng: np.random.Generator,
    record: bool = False,
) -> EpisodeResult:
    """Plays one episode: a fresh (randomized) room, robots at random poses in the start zone.

    Args:
        policy: chooses zones from observations (see `Policy`).
        cfg: episode settings.
        rng: the episode's randomness (layout, start poses, noise).
        record: keep every bus message (for a rosbag).
    """
    layout = sample_layout(rng, cfg.n_robots, cfg.randomize_layout)
    world = build_world(layout)
    sim = Simulation(world, cfg, rng, record)
    if hasattr(policy, "start_episode"):
        policy.start_episode()
    n = cfg.n_robots
    positions = [np.full(n, START)]
    actions, rewards, gates, arrivals, durations = [], [], [], [], []
    success = False
    settle_ticks = max(1, round(cfg.settle_time / cfg.control_period))
    progress = ctl.Progress(n)
    for t in range(cfg.max_steps):
        previous = positions[-1]
        chosen = np.asarray(policy(observation(previous), t), np.int64)
        driving = chosen != previous
        goals = np.array(
            [layout.slot(chosen[i], i) if driving[i] else (0.0, 0.0) for i in range(n)]
        )
        started = world.data.time
        arrived = drive(sim, goals, driving, progress)
        for _ in range(settle_ticks):
            sim.tick(np.zeros(n), np.zeros(n))
        zones = sim.zones()
        now = np.where(zones >= 0, zones, previous)
        gate_open = world.gate_opening() >= GATE_OPEN_FRACTION
        actions.append(chosen)
        positions.append(now)
        rewards.append(er_rewards(previous, now, gate_open))
        gates.append(gate_open)
        arrivals.append(arrived | ~driving)
        durations.append(world.data.time - started)
        if gate_open and np.any(now == DOOR):
            success = True
            break
    return EpisodeResult(
        actions=np.array(actions),
        positions=np.array(positions),
        rewards=np.array(rewards),
        gate_open=np.array(gates),
        arrived=np.array(arrivals),
        decision_seconds=np.array(durations),
        success=success,
        physics_steps=sim.steps,
        world=world,
        bus=sim.bus,
        trace={k: np.array(v) for k, v in sim.trace.items()},
    )


def drive(sim: Simulation, goals: np.ndarray, driving: np.ndarray, progress) -> np.ndarray:
    """Drives the robots of `driving` to their `goals` (`ctl.go_to_goal` on odometry, one
    control period a tick) until all have arrived or the decision's time is up; returns
    which arrived (bool [N]). `progress`: the decision's `ctl.Progress`, restarted here."""
    world, cfg = sim.world, sim.cfg
    started = world.data.time
    active = driving.copy()
    arrived = np.zeros(len(driving), bool)
    progress.reset(started)
    while active.any() and world.data.time - started < cfg.decision_time_limit:
        odometry = sim.odometry_poses()
        distance = np.linalg.norm(goals - odometry[:, :2], axis=1)
        detour = progress.update(world.data.time, distance)
        linear, angular, reached = ctl.go_to_goal(odometry, goals, active, cfg.controller, detour)
        arrived |= reached & active
        active &= ~reached
        sim.tick(linear, angular)
    return arrived


@dataclasses.dataclass
class ScriptedPolicy:
    """Plays a fixed sequence of joint actions (row t at decision t; the last row repeats)."""

    script: np.ndarray  # int [T, N]

    def start_episode(self) -> None:
        pass

    def __call__(self, obs: np.ndarray, t: int) -> np.ndarray:
        del obs
        script = np.atleast_2d(self.script)
        return script[min(t, len(script) - 1)]
