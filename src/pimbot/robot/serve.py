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
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections import Counter

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
from pimbot.robot.ros_world import WireConfig, layout_from_json
from pimbot.robot.world import Layout

RESEND_S = 0.25
"""Wall seconds without fresh odometry after which the last commands are sent again."""


class WireTimeout(InvalidParameter):
    """Nothing came on a topic the controller waits for (one line, names the topic)."""


@dataclasses.dataclass(frozen=True)
class ServeConfig:
    """The controller's own settings."""

    authenticated: bool = False
    """Sign incentive messages (HMAC-SHA256, per-pair keys) and verify them on receipt."""
    odometry_timeout: float = 10.0
    """Wall seconds without fresh odometry from every robot before giving up."""
    layout_timeout: float = 60.0
    """Wall seconds to wait for the room on /pimbot/layout."""
    incentive_timeout: float = 2.0
    """Wall seconds a decision waits for its incentive messages to come back."""


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
    """Rejected incentive messages by reason."""
    received_totals: list[list[float]]
    """[giver][recipient] incentive accepted by the recipients over the episode."""
    messages: dict[str, int]
    sim_seconds: float
    wall_s: float

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


class IncentiveLink:
    """The incentive topics of every robot: signing senders and verifying receivers."""

    def __init__(self, node: ros_wire.Node, n: int, authenticated: bool):
        self.n, self.authenticated = n, authenticated
        topics = [ros_wire.incentive_topic(j) for j in range(n)]
        qos = ros_wire.reliable_qos(depth=64)
        self.writers = [node.writer(t, ros_wire.String, qos) for t in topics]
        self.readers = [node.reader(t, ros_wire.String, qos) for t in topics]
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
        for `expected` messages or `timeout` wall seconds."""
        accepted, verdicts = np.zeros((self.n, self.n)), []
        deadline = time.perf_counter() + timeout
        while len(verdicts) < expected and time.perf_counter() < deadline:
            for j, reader in enumerate(self.readers):
                for sample in reader.take():
                    message = _parse_incentive(sample.data)
                    reason = self._verdict(j, message)
                    verdicts.append(reason)
                    if reason == "ok":
                        accepted[message.giver, j] += message.value
            time.sleep(0.0005)
        return accepted, verdicts

    def _verdict(self, recipient: int, message) -> str:
        if self.receivers is not None:
            return self.receivers[recipient].receive(message).reason
        if not isinstance(message, channel.IncentiveMessage):
            return "malformed message"
        ok = message.recipient == recipient and message.giver != recipient
        return "ok" if ok and math.isfinite(message.value) else "malformed message"


def _parse_incentive(text: str):
    try:
        raw = json.loads(text)
        names = [f.name for f in dataclasses.fields(channel.IncentiveMessage)]
        return channel.IncentiveMessage(**{k: raw[k] for k in names})
    except (ValueError, TypeError, KeyError):
        return None


class ControllerWire:
    """The controller's endpoints and the latest odometry of every robot."""

    def __init__(self, n: int, wire: WireConfig, authenticated: bool):
        self.n, self.distro = n, wire.distro
        self.node = node = ros_wire.Node(wire.domain_id)
        cmd = ros_wire.cmd_vel_struct(wire.distro)
        self.commands = [
            node.writer(cmd_vel_topic(i), cmd, ros_wire.reliable_qos()) for i in range(n)
        ]
        self.odometry = [
            node.reader(odom_topic(i), ros_wire.Odometry, ros_wire.sensor_qos()) for i in range(n)
        ]
        self.layout = node.reader(ros_wire.LAYOUT_TOPIC, ros_wire.String, ros_wire.latched_qos())
        self.gate = node.reader(ros_wire.GATE_TOPIC, ros_wire.Float64, ros_wire.sensor_qos())
        self.status = node.writer(ros_wire.STATUS_TOPIC, ros_wire.String, ros_wire.reliable_qos())
        self.incentives = IncentiveLink(node, n, authenticated)
        self.poses = np.zeros((n, 3))
        self.stamps = np.full(n, -1, np.int64)
        self.gate_opening: float | None = None
        self.last_command: tuple[np.ndarray, np.ndarray] | None = None

    def poll(self) -> None:
        for i, reader in enumerate(self.odometry):
            for message in reader.take():
                stamp = ros_wire.time_ns(message.header.stamp)
                if stamp >= self.stamps[i]:
                    self.stamps[i], self.poses[i] = stamp, ros_wire.planar_pose(message)
        for message in self.gate.take():
            self.gate_opening = message.data

    @property
    def now_ns(self) -> int:
        return int(self.stamps.min())

    def wait_odometry(self, after_ns: int, timeout: float) -> None:
        """Waits until every robot's odometry is newer than `after_ns` (WireTimeout else),
        sending the last commands again every `RESEND_S` meanwhile (as a ROS controller
        publishing on a timer would: a command sent before the robot's reader was matched
        is lost)."""
        now = time.perf_counter()
        deadline, resend = now + timeout, now + RESEND_S
        while True:
            self.poll()
            if self.now_ns > after_ns:
                return
            now = time.perf_counter()
            if now > resend and self.last_command is not None:
                self.command(*self.last_command)
                resend = now + RESEND_S
            if now > deadline:
                stale = [odom_topic(i) for i in np.flatnonzero(self.stamps <= after_ns)]
                raise WireTimeout(
                    f"odometry: nothing new on {', '.join(stale)} for {timeout:g} s "
                    f"(domain {self.node.participant.domain_id}, is a robot or "
                    "`pimbot robot world` running?)"
                )
            time.sleep(0.0002)

    def wait_layout(self, timeout: float) -> Layout:
        deadline = time.perf_counter() + timeout
        while time.perf_counter() < deadline:
            for message in self.layout.take():
                return layout_from_json(message.data)
            time.sleep(0.01)
        raise WireTimeout(f"layout: nothing on {ros_wire.LAYOUT_TOPIC} for {timeout:g} s")

    def command(self, linear: np.ndarray, angular: np.ndarray) -> None:
        at = self.now_ns
        self.last_command = (linear, angular)
        for i, writer in enumerate(self.commands):
            writer.write(ros_wire.wire_cmd_vel(self.distro, linear[i], angular[i], at, i))

    def publish_status(self, event: dict) -> None:
        self.status.write(ros_wire.String(json.dumps(event, sort_keys=True)))

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


def serve_episode(
    policy: WirePolicy,
    cfg: PhysicsConfig,
    wire: WireConfig,
    serve: ServeConfig = ServeConfig(),
    layout: Layout | None = None,
    audit=None,
    episode: int = 0,
) -> ServeReport:
    """Plays one episode of `policy` on the robots behind the wire.

    Args:
        layout: the room; None: wait for it on /pimbot/layout.
        audit: a `defenses.audit.AuditLog` to append every decision to, or None.
        episode: the episode number in the incentive messages.
    Raises:
        WireTimeout: no room or no odometry in time (one line).
    """
    start = time.perf_counter()
    n = cfg.n_robots
    ends = ControllerWire(n, wire, serve.authenticated)
    layout = layout or ends.wait_layout(serve.layout_timeout)
    if layout.num_robots != n:
        raise InvalidParameter(f"layout: a room for {layout.num_robots} robots, the run has {n}")
    ends.wait_odometry(-1, serve.odometry_timeout)
    played = _Played(n, _zones(ends, layout, np.full(n, START)))
    for t in range(cfg.max_steps):
        previous = played.zones[-1]
        began = time.perf_counter()
        chosen, verdicts = _decide(policy, ends, played, episode, t, serve)
        driving = chosen != previous
        goals = np.array(
            [layout.slot(chosen[i], i) if driving[i] else (0.0, 0.0) for i in range(n)]
        )
        played.decision_ms.append(1e3 * (time.perf_counter() - began))  # the first command next
        arrived = _drive(ends, goals, driving, cfg, serve.odometry_timeout)
        _settle(ends, cfg, serve.odometry_timeout)
        now = _zones(ends, layout, previous)
        gate_open = _gate_open(ends, now, cfg)
        event = _step_event(episode, t, chosen, previous, now, gate_open, verdicts)
        event["incentives"] = played.last_incentives.tolist()
        ends.publish_status(event)
        if audit is not None:
            audit.append("decision", **event)
        played.record(event, now, arrived | ~driving)
        if event["success"]:
            break
    report = played.report(ends, time.perf_counter() - start)
    end = {
        "done": True,
        "episode": episode,
        "success": report.success,
        "steps": len(report.actions),
    }
    ends.publish_status(end)
    if audit is not None:
        audit.append("episode", **end, rejected=report.rejected)
    ends.flush()
    return report


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

    def __init__(self, n: int, zones: np.ndarray):
        self.zones = [zones]
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

    def report(self, ends: ControllerWire, wall_s: float) -> ServeReport:
        events = self.events
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
            sim_seconds=ends.now_ns / 1e9,
            wall_s=wall_s,
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
