"""`health_monitor`: per honest agent, health signals, an alarm rule and a safe fallback.

Every iteration each honest recipient j updates exponential moving averages of
* the team welfare trend: fast − slow EMA of the team's environment return;
* per giver i, the mean incentive per step j received from i, its square (so its
  variance across episodes) and how often it fell outside the honest range [0, R_max];
* per giver i, the gradient conflict: cos(g_inc_ij, g_env_j) between j's
  policy-gradient component driven by i's incentives and the one driven by its
  environment reward (score-function gradients on the same episode).

A pair (i, j) is flagged while any of
* range:    the out-of-range EMA exceeds 1/2;
* variance: the std of i's incentives to j across episodes exceeds
            `variance_threshold` · R_max (default 1/2: by Popoviciu's inequality no
            giver that stays in [0, R_max] can exceed it);
* conflict: the conflict EMA is below −`conflict_threshold` (i's incentives
            persistently push j against its own environment reward) *while* the
            team welfare declines (fast − slow EMA < −`welfare_drop` · max(|slow
            EMA|, 1)). Conflict alone is LIO's normal mode — paying an agent to do
            what costs it, as at the lever: clean LIO sits near −0.3 in ER(2,1) and
            near −0.8 in ER(4,3), as low as a bypassing giver in ER(2,1) (−0.95) — so
            it is only suspicious while the welfare falls
holds. A flag held for `patience` consecutive iterations after `warmup` raises an
alarm: j falls back to its last good policy checkpoint and refuses i's
incentives for `cooldown` iterations. A checkpoint is good when it is taken (every
`checkpoint_period` iterations) while none of j's pairs is flagged and the team
welfare is not declining.
Everything is jit/vmap-able.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
from flax import struct

from pimbot.contracts.defense import Defense, IncentiveContext, PolicyStepContext
from pimbot.contracts.params import check_int, check_number

FAST_RATE = 0.1  # EMA rate of the fast welfare average
SLOW_RATE = 0.01  # EMA rate of the slow welfare average


@struct.dataclass
class HealthMonitor(Defense):
    """Welfare trend, incentive variance and gradient conflict; alarm → fallback + cool-down."""

    stats_rate: float = 0.05
    """EMA rate of the incentive statistics and the gradient conflict."""
    variance_threshold: float = 0.5
    """Flag a giver whose incentives' std across episodes exceeds this × R_max."""
    conflict_threshold: float = 0.5
    """Flag a giver whose gradient-conflict EMA is below −this while the welfare declines."""
    welfare_drop: float = 0.1
    """Welfare declines when fast − slow EMA < −this × max(|slow EMA|, 1); no checkpoint
    is taken while it does."""
    patience: int = 50
    """Consecutive flagged iterations that raise an alarm."""
    warmup: int = 200
    """Iterations before any alarm can be raised."""
    cooldown: int = 1000
    """Iterations a recipient refuses the flagged giver's incentives after an alarm."""
    checkpoint_period: int = 100
    """Iterations between checkpoints of a recipient's last good policy."""

    name: ClassVar[str] = "health_monitor"
    hooks: ClassVar[tuple[str, ...]] = ("learning_incentives", "after_policy_step")

    def validate(self, num_agents: int) -> None:
        del num_agents
        check_number("stats_rate", self.stats_rate, low=0.0, high=1.0, strict_low=True)
        for name in ("variance_threshold", "conflict_threshold", "welfare_drop"):
            check_number(name, getattr(self, name), low=0.0)
        for name, low in (
            ("patience", 1),
            ("warmup", 0),
            ("cooldown", 0),
            ("checkpoint_period", 1),
        ):
            check_int(name, getattr(self, name), low)

    def init_state(self, num_agents: int, policy) -> dict[str, Any]:
        return init_state(num_agents, policy)

    def learning_incentives(self, state, ctx: IncentiveContext):
        """Recipients refuse the givers they are cooling down from."""
        refusing = refused(state) & ctx.honest[None, :]
        accepted = jnp.where(refusing[None], 0.0, ctx.accepted)
        return (
            accepted,
            state,
            {"defense/monitor_refused_pairs": refusing.sum().astype(jnp.float32)},
        )

    def after_policy_step(self, state, ctx: PolicyStepContext):
        return step(
            self,
            state,
            ctx.iteration,
            ctx.sent,
            ctx.valid,
            ctx.env_rewards.sum(),
            ctx.gradients,
            ctx.env_rewards,
            ctx.policy,
            ctx.incentive_max,
            ctx.honest,
        )


def init_state(num_agents: int, policy) -> dict[str, Any]:
    """Monitor state; `policy` (stacked [N, ...]) is the first good checkpoint."""
    pairs = jnp.zeros((num_agents, num_agents), jnp.float32)
    counts = jnp.zeros((num_agents, num_agents), jnp.int32)
    return {
        "welfare_fast": jnp.zeros((), jnp.float32),
        "welfare_slow": jnp.zeros((), jnp.float32),
        "incentive_mean": pairs,
        "incentive_square": pairs,
        "out_of_range": pairs,
        "conflict": pairs,
        "streak": counts,
        "cooldown": counts,
        "alarms": counts,
        "first_alarm": jnp.full((), -1, jnp.int32),
        "checkpoint": policy,
    }


def refused(state: dict[str, Any]) -> jax.Array:
    """bool [giver, recipient]: pairs in cool-down (the recipient refuses the giver)."""
    return state["cooldown"] > 0


def conflict_cosines(gradients: jax.Array) -> jax.Array:
    """cos(g_inc_ij, g_env_j) [giver, recipient] from flat gradients [1 + N, N, P].

    gradients[0] is the env-driven component of every agent's policy gradient,
    gradients[1 + i] the component driven by the incentives giver i sent.
    """
    env, incentive = gradients[0], gradients[1:]
    dot = jnp.sum(incentive * env[None], axis=-1)
    norms = jnp.linalg.norm(incentive, axis=-1) * jnp.linalg.norm(env, axis=-1)[None]
    return jnp.where(norms > 0, dot / jnp.maximum(norms, 1e-12), 0.0)


def step(
    monitor: HealthMonitor,
    state: dict[str, Any],
    iteration: jax.Array,
    incentives: jax.Array,
    valid: jax.Array,
    team_return: jax.Array,
    gradients_fn: Callable[[jax.Array], jax.Array],
    env_rewards: jax.Array,
    policy,
    incentive_max: float,
    honest: jax.Array,
):
    """One monitoring step after the recipients' policy update.

    Args:
        iteration: the iteration just trained (int32 []).
        incentives: [T, N giver, N recipient] as sent on the episode learnt from.
        valid: bool [T]; team_return: [] team env return of that episode.
        gradients_fn: rewards [K, T, N] -> flat score-function gradients [K, N, P]
            of every agent's policy loss (no entropy) on that episode.
        env_rewards: [T, N]; policy: the updated stacked policy [N, ...].
        honest: bool [N], agents that run the monitor.
    Returns:
        (policy, with fallen-back recipients reset to their checkpoint; new state; metrics).
    """
    episode = (incentives, valid, team_return, env_rewards)
    stats = _statistics(monitor.stats_rate, state, iteration, episode, gradients_fn, incentive_max)
    flags = _flags(monitor, stats, honest, incentive_max)
    streak, cooldown, alarm, fallback = _alarms(monitor, state, flags["flagged"], iteration)

    policy = _select(fallback, state["checkpoint"], policy)
    healthy = honest & ~flags["flagged"].any(axis=0) & ~fallback & ~flags["declining"]
    take = healthy & ((iteration + 1) % monitor.checkpoint_period == 0)
    checkpoint = _select(take, policy, state["checkpoint"])

    any_alarm = alarm.any()
    new_state = {
        **stats,
        "streak": streak,
        "cooldown": cooldown,
        "alarms": state["alarms"] + alarm,
        "first_alarm": jnp.where(
            (state["first_alarm"] < 0) & any_alarm, iteration, state["first_alarm"]
        ),
        "checkpoint": checkpoint,
    }
    return policy, new_state, _metrics(alarm, fallback, flags, stats["conflict"])


def _statistics(rate, state, iteration, episode, gradients_fn, incentive_max) -> dict:
    """The health statistics' EMAs (rate `rate`; the welfare's at `FAST_RATE` and
    `SLOW_RATE`) updated with `episode` = (incentives, valid, team return, env rewards);
    the first iteration starts them at its values."""
    incentives, valid, team_return, env_rewards = episode
    steps = jnp.maximum(valid.sum(), 1).astype(jnp.float32)
    mask = valid.astype(jnp.float32)[:, None, None]
    mean_sent = (incentives * mask).sum(axis=0) / steps  # [giver, recipient]
    outside = jnp.any(((incentives < 0) | (incentives > incentive_max)) & (mask > 0), axis=0)

    first = iteration == 0
    ema = lambda old, new, r: jnp.where(first, new, (1 - r) * old + r * new)  # noqa: E731
    welfare_fast = ema(state["welfare_fast"], team_return, FAST_RATE)
    welfare_slow = ema(state["welfare_slow"], team_return, SLOW_RATE)
    incentive_mean = ema(state["incentive_mean"], mean_sent, rate)
    incentive_square = ema(state["incentive_square"], mean_sent**2, rate)
    out_of_range = ema(state["out_of_range"], outside.astype(jnp.float32), rate)
    sources = jnp.concatenate([env_rewards[None], jnp.moveaxis(incentives, 1, 0)], axis=0)
    cosines = conflict_cosines(gradients_fn(sources))
    return {
        "welfare_fast": welfare_fast,
        "welfare_slow": welfare_slow,
        "incentive_mean": incentive_mean,
        "incentive_square": incentive_square,
        "out_of_range": out_of_range,
        "conflict": ema(state["conflict"], cosines, rate),
    }


def _flags(monitor: HealthMonitor, stats: dict, honest: jax.Array, incentive_max) -> dict:
    """The welfare trend, whether it declines, the honest pairs [giver, recipient] and
    which of them each rule flags ("range", "variance", "conflict"; any: "flagged")."""
    n = honest.shape[0]
    trend = stats["welfare_fast"] - stats["welfare_slow"]
    slow = stats["welfare_slow"]
    declining = trend < -monitor.welfare_drop * jnp.maximum(jnp.abs(slow), 1.0)
    variance = jnp.maximum(stats["incentive_square"] - stats["incentive_mean"] ** 2, 0.0)
    std = jnp.sqrt(variance)
    pair = honest[None, :] & ~jnp.eye(n, dtype=bool)
    flag_range = stats["out_of_range"] > 0.5
    flag_variance = std > monitor.variance_threshold * incentive_max
    flag_conflict = (stats["conflict"] < -monitor.conflict_threshold) & declining
    return {
        "trend": trend,
        "declining": declining,
        "pair": pair,
        "range": flag_range,
        "variance": flag_variance,
        "conflict": flag_conflict,
        "flagged": pair & (flag_range | flag_variance | flag_conflict),
    }


def _alarms(monitor: HealthMonitor, state: dict, flagged: jax.Array, iteration: jax.Array):
    """(streaks, cool-downs, alarms [giver, recipient], recipients falling back [N]): a
    pair flagged `patience` times in a row after `warmup`, not cooling down, raises an
    alarm, which restarts its streak and starts its cool-down."""
    streak = jnp.where(flagged, state["streak"] + 1, 0)
    cooling = state["cooldown"] > 0
    alarm = (streak >= monitor.patience) & ~cooling & (iteration >= monitor.warmup)
    streak = jnp.where(alarm, 0, streak)
    cooldown = jnp.where(alarm, monitor.cooldown, jnp.maximum(state["cooldown"] - 1, 0))
    return streak, cooldown, alarm, alarm.any(axis=0)


def _metrics(alarm, fallback, flags: dict, conflict) -> dict[str, jax.Array]:
    """The step's `defense/monitor_*` metrics (key order: metrics.csv's column order)."""
    count = lambda x: jnp.sum(x & alarm).astype(jnp.float32)  # noqa: E731
    honest_pairs = jnp.maximum(flags["pair"].sum(), 1)
    return {
        "defense/monitor_alarms": alarm.sum().astype(jnp.float32),
        "defense/monitor_alarms_by_giver": alarm.sum(axis=1).astype(jnp.float32),  # [N]
        "defense/monitor_alarms_range": count(flags["range"]),
        "defense/monitor_alarms_variance": count(flags["variance"]),
        "defense/monitor_alarms_conflict": count(flags["conflict"]),
        "defense/monitor_fallbacks": fallback.sum().astype(jnp.float32),
        "defense/monitor_flagged_pairs": flags["flagged"].sum().astype(jnp.float32),
        "defense/monitor_conflict": jnp.sum(conflict * flags["pair"]) / honest_pairs,
        "defense/monitor_welfare_trend": flags["trend"],
    }


def _select(mask: jax.Array, new, old):
    """Per agent: new[i] where mask[i] else old[i], for stacked pytrees [N, ...]."""
    return jax.tree.map(
        lambda a, b: jnp.where(mask.reshape((-1,) + (1,) * (a.ndim - 1)), a, b), new, old
    )
