"""The go-to-goal unicycle controller and the differential-drive wheel mapping.

Each robot turns toward its goal in place while the heading error is large,
then drives with a forward speed proportional to the distance (saturated at the
TurtleBot3 limits) while correcting its heading. Robots pass each other by the
right-hand rule: a close robot pushes the desired heading away from it and, when
it is ahead, to the right, and slows this one down, so two robots meeting
head-on both keep right and pass.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from pimbot.robot.world import MAX_ANGULAR, MAX_LINEAR, WHEEL_RADIUS, WHEEL_SEPARATION


@dataclasses.dataclass(frozen=True)
class ControllerConfig:
    """Gains and tolerances of the go-to-goal controller."""

    gain_distance: float = 0.8
    """Forward speed per metre of distance to the goal (1/s), before saturation."""
    gain_heading: float = 3.0
    """Yaw rate per radian of heading error (1/s), before saturation."""
    arrive_tolerance: float = 0.04
    """Distance (m) at which the robot counts as arrived and stops."""
    turn_in_place: float = 0.6
    """Heading error (rad) above which the robot only turns."""
    avoid_range: float = 0.6
    """Centre distance (m) under which other robots push this one's heading away."""
    avoid_gain: float = 1.5
    """Weight of the push away from (and to the right of) a robot at contact distance."""
    avoid_cone: float = 0.6
    """Half-angle (rad) of the cone ahead in which a close robot slows this one down."""
    back_off_gap: float = 0.2
    """Centre distance (m) to a robot ahead under which this one reverses (it is wedged)."""
    back_off_speed: float = 0.05
    """Reversing speed (m/s) when wedged."""


def safe_command(linear, angular) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """Every command that leaves a controller, made safe: a robot whose linear or angular
    velocity is not finite gets (0, 0), and every other velocity is clamped to the
    TurtleBot3 Burger's limits (±`MAX_LINEAR` m/s, ±`MAX_ANGULAR` rad/s). Returns (linear
    [N], angular [N], {"not finite": robots stopped, "beyond the limits": robots clamped}).
    """
    linear = np.array(linear, dtype=float, ndmin=1)
    angular = np.array(angular, dtype=float, ndmin=1)
    finite = np.isfinite(linear) & np.isfinite(angular)
    linear, angular = np.where(finite, linear, 0.0), np.where(finite, angular, 0.0)
    beyond = (np.abs(linear) > MAX_LINEAR) | (np.abs(angular) > MAX_ANGULAR)
    linear = np.clip(linear, -MAX_LINEAR, MAX_LINEAR)
    angular = np.clip(angular, -MAX_ANGULAR, MAX_ANGULAR)
    counts = {"not finite": int((~finite).sum()), "beyond the limits": int(beyond.sum())}
    return linear, angular, counts


def wrap_angle(angle):
    """Wraps to (−π, π]."""
    return (np.asarray(angle) + math.pi) % (2 * math.pi) - math.pi


def wheel_speeds(linear: np.ndarray, angular: np.ndarray) -> np.ndarray:
    """Twist (v m/s, ω rad/s) per robot -> (left, right) wheel speeds in rad/s: [N, 2].

    Wheel speeds above the motor limit are scaled down together, keeping the
    ratio (the path's curvature).
    """
    linear, angular = np.asarray(linear, float), np.asarray(angular, float)
    half = WHEEL_SEPARATION / 2
    wheels = np.stack([linear - angular * half, linear + angular * half], axis=-1) / WHEEL_RADIUS
    limit = MAX_LINEAR / WHEEL_RADIUS
    peak = np.max(np.abs(wheels), axis=-1, keepdims=True)
    return wheels * np.minimum(1.0, limit / np.maximum(peak, 1e-12))


def body_twist(wheels: np.ndarray) -> np.ndarray:
    """(left, right) wheel speeds rad/s [N, 2] -> (v, ω) [N, 2]: the forward kinematics."""
    left, right = wheels[..., 0], wheels[..., 1]
    return np.stack(
        [WHEEL_RADIUS * (left + right) / 2, WHEEL_RADIUS * (right - left) / WHEEL_SEPARATION],
        axis=-1,
    )


def go_to_goal(
    poses: np.ndarray,
    goals: np.ndarray,
    active: np.ndarray,
    cfg: ControllerConfig,
    detour: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Twist commands toward the goals.

    The desired heading follows the goal direction plus, for every robot
    within `avoid_range`, a push away from it and, if it is ahead, a push to
    the right (so robots meeting head-on both keep right and pass).

    Args:
        poses: [N, 3] (x, y, θ) as the robots estimate them (odometry).
        goals: [N, 2] goal points.
        active: bool [N], robots that are driving (the others hold still).
        detour: bool [N] or None; robots that go round parked robots on the side away
            from their goal (the way out when the goal side is a dead end, see `Progress`).
    Returns:
        (linear [N] m/s, angular [N] rad/s, arrived bool [N]).
    """
    delta = goals - poses[:, :2]
    distance = np.linalg.norm(delta, axis=1)
    arrived = distance <= cfg.arrive_tolerance
    direction = delta / np.maximum(distance, 1e-9)[:, None]
    moving = active & ~arrived
    field = direction.copy()
    slow = np.ones(len(poses))
    backing = np.zeros(len(poses), bool)
    for i in np.flatnonzero(moving):
        flip = detour is not None and bool(detour[i])
        avoided = _avoidance(i, poses, distance[i], direction[i], moving, cfg, flip)
        if avoided is None:
            continue
        push, closest = avoided
        field[i] += cfg.avoid_gain * push
        if closest is not None:
            slow[i] = np.clip((closest - 0.23) / 0.15, 0.0, 1.0)
            backing[i] = closest < cfg.back_off_gap
    heading = np.arctan2(field[:, 1], field[:, 0])
    error = wrap_angle(heading - poses[:, 2])
    angular = np.clip(cfg.gain_heading * error, -MAX_ANGULAR, MAX_ANGULAR)
    linear = np.clip(cfg.gain_distance * distance * np.cos(error), 0.0, MAX_LINEAR) * slow
    linear = np.where(np.abs(error) > cfg.turn_in_place, 0.0, linear)
    # Wedged against a robot ahead: reverse slowly while turning away.
    linear = np.where(backing, -cfg.back_off_speed, linear)
    return np.where(moving, linear, 0.0), np.where(moving, angular, 0.0), arrived


def _avoidance(i, poses, distance, direction, moving, cfg: ControllerConfig, flip: bool):
    """(The push [2] on moving robot `i`'s desired heading from the robots near it, the
    centre distance to the closest one in its cone ahead or None), or None when no robot
    is near. `distance`, `direction`: to its goal; `flip`: it detours (`go_to_goal`)."""
    others = np.flatnonzero(np.arange(len(poses)) != i)
    rel = poses[others, :2] - poses[i, :2]
    gap = np.linalg.norm(rel, axis=1)
    # Robots beyond this one's goal are no obstacle on the way there.
    near = (gap < cfg.avoid_range) & (gap < distance + 0.25)
    if not near.any():
        return None
    others, rel, gap = others[near], rel[near], gap[near]
    bearing = wrap_angle(np.arctan2(rel[:, 1], rel[:, 0]) - poses[i, 2])
    weight = np.clip((cfg.avoid_range - gap) / (cfg.avoid_range - 0.22), 0.0, 1.0)
    # How much each robot lies on the way to the goal (not on the current heading,
    # so that the field around a parked robot does not turn with this robot).
    ahead = np.maximum((rel / gap[:, None]) @ direction, 0.0)
    away = -rel / gap[:, None]
    # Around a parked robot on the goal's side (its left side on a tie); past a
    # driving one on the right.
    around = np.stack([-away[:, 1], away[:, 0]], axis=1)
    side = np.where(around @ direction >= -0.2, 1.0, -1.0)
    if flip:
        side = -side
    around *= side[:, None]
    keep_right = np.array([direction[1], -direction[0]])
    tangent = np.where(moving[others][:, None], keep_right, around)
    push = weight[:, None] * (np.where(moving[others], 1.0, 0.5)[:, None] * away)
    push += (weight * ahead)[:, None] * tangent
    blocking = np.abs(bearing) < cfg.avoid_cone
    return push.sum(axis=0), (gap[blocking].min() if blocking.any() else None)


@dataclasses.dataclass
class Progress:
    """Stall detection: a driving robot whose distance to its goal has not shrunk by
    `min_gain` within `window` seconds takes the detour side for the next window."""

    num_robots: int
    window: float = 5.0
    min_gain: float = 0.05

    def __post_init__(self) -> None:
        self.best = np.full(self.num_robots, np.inf)
        self.since = np.zeros(self.num_robots)
        self.detour = np.zeros(self.num_robots, bool)

    def reset(self, now: float) -> None:
        self.best[:] = np.inf
        self.since[:] = now
        self.detour[:] = False

    def update(self, now: float, distance: np.ndarray) -> np.ndarray:
        """Feeds the current distances; returns the detour flags to use."""
        improved = distance < self.best - self.min_gain
        self.best = np.where(improved, distance, self.best)
        self.since = np.where(improved, now, self.since)
        stalled = now - self.since > self.window
        self.detour = np.where(stalled, ~self.detour, self.detour)
        self.since = np.where(stalled, now, self.since)
        self.best = np.where(stalled, distance, self.best)
        return self.detour
