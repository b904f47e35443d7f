"""One episode as a `lax.scan`, with incentives, and the per-episode metrics.

The scan always runs `env.max_steps` steps; steps after the episode ended are
marked invalid (`valid = False`) and are masked out of every loss and metric,
so variable-length episodes keep a static shape.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

from pimbot.contracts.attack import NO_ATTACK, Attack, Decision, attack_key
from pimbot.envs.core import Env, step_metric_names

# act(key, obs [N, obs_dim]) -> actions int32 [N]
ActFn = Callable[[jax.Array, jax.Array], jax.Array]
# give(obs [N, obs_dim], actions [N]) -> incentives [N giver, N recipient], zero diagonal.
# It gets no key, by contract: a learner that trains its incentives through the
# recipients' updates recomputes them from its parameters on the batch as played
# (`AdversaryView.emitted`, LIO's meta-gradient), which only a deterministic function of
# (obs, actions) allows. A stochastic incentive draws its noise from the learner's own key
# before the rollout (e.g. per episode, [T, N, N]) and closes `give` over it, so the same
# noise can be applied again when the incentives are recomputed (docs/extending.md).
GiveFn = Callable[[jax.Array, jax.Array], jax.Array]


@struct.dataclass
class Trajectory:
    """One episode, time-major. T = env.max_steps."""

    obs: jax.Array  # float32 [T, N, obs_dim], incentive slots filled
    actions: jax.Array  # int32 [T, N]
    env_rewards: jax.Array  # float32 [T, N], zero on invalid steps
    incentives: jax.Array  # float32 [T, N, N] (giver, recipient) emitted, zero on invalid steps
    incentive_scale: jax.Array  # float32 [T, N, N]: emitted = scale · learned + offset (attacks)
    incentive_offset: jax.Array  # float32 [T, N, N]
    valid: jax.Array  # bool [T], the step took place
    success: jax.Array  # bool [T], info["success"] of the step
    step_metrics: dict[str, jax.Array]  # per env.step_metrics name: float32 [T] or [T, N]


def fill_incentive_obs(env: Env, obs: jax.Array, given: jax.Array) -> jax.Array:
    """Writes the cumulative incentives each agent has given into its observation.

    Args:
        obs: [N, obs_dim] as returned by the env (incentive slots zero).
        given: [N, N] cumulative incentives, given[i, j] from i to j.
    Returns:
        obs with row i's last N-1 entries = given[i, j] for j != i in id order
        (unchanged when the env has no incentive slots).
    """
    if not env.incentive_obs:
        return obs
    n = env.num_agents
    others = jnp.array([[j for j in range(n) if j != i] for i in range(n)])
    given_to_others = jnp.take_along_axis(given, others, axis=1)  # [N, N-1]
    return obs.at[:, -(n - 1) :].set(given_to_others)


def decide(
    env: Env,
    key: jax.Array,
    obs: jax.Array,
    given: jax.Array,
    act: ActFn,
    give: GiveFn | None,
    attack: Attack,
    env_step: jax.Array | int,
    attack_state=None,
):
    """One joint decision as training plays it: the observation with the incentives
    given so far, the attack's actions and its emission of the learned incentives.

    Args:
        obs: [N, obs_dim] from the env; given: [N, N] incentives emitted so far this episode.
        attack_state: the attack's per-seed state ({} when it keeps none).
    Returns:
        (filled obs, actions int32 [N], incentives emitted [N, N], scale [N, N], offset [N, N]).
    """
    n = env.num_agents
    state = {} if attack_state is None else attack_state
    act_key, emit_key = jax.random.split(attack_key(key))
    obs = fill_incentive_obs(env, obs, given)
    actions = act(key, obs).astype(jnp.int32)
    at = Decision(env.idle_action, env.num_actions, jnp.asarray(env_step))
    actions = attack.act(state, act_key, actions, at)
    scale, offset = attack.emit(state, emit_key, given)
    if give is None:
        incentives = jnp.zeros((n, n), jnp.float32)
    else:
        incentives = scale * give(obs, actions) + offset
    return obs, actions, incentives, scale, offset


def rollout(
    env: Env,
    key: jax.Array,
    act: ActFn,
    give: GiveFn | None = None,
    attack: Attack = NO_ATTACK,
    env_step0: jax.Array | int = 0,
    attack_state=None,
) -> Trajectory:
    """Plays one episode from `env.reset`.

    Args:
        env: the environment.
        key: PRNG key for this episode.
        act: samples the joint action from the (filled) observations.
        give: the learned incentives after the joint action; None for no incentives.
        attack: consulted for the actions played and the incentives emitted.
        env_step0: environment steps taken in training before this episode
            (for attacks that switch on and off over time).
        attack_state: the attack's per-seed state (read-only during the episode).
    """
    n = env.num_agents
    reset_key, steps_key = jax.random.split(key)
    obs, state = env.reset(reset_key)

    def body(carry, inputs):
        state, obs, given, alive = carry
        step_key, t = inputs
        act_key, env_key = jax.random.split(step_key)
        obs, actions, incentives, scale, offset = decide(
            env, act_key, obs, given, act, give, attack, env_step0 + t, attack_state
        )
        incentives = incentives * alive
        next_obs, next_state, rewards, done, info = env.step(env_key, state, actions)
        step = Trajectory(
            obs=obs,
            actions=actions,
            env_rewards=rewards * alive,
            incentives=incentives,
            incentive_scale=scale.astype(jnp.float32),
            incentive_offset=offset.astype(jnp.float32),
            valid=alive,
            success=info["success"] & alive,
            step_metrics={
                name: jnp.where(alive, info[name], 0).astype(jnp.float32)
                for name in step_metric_names(env)
            },
        )
        return (next_state, next_obs, given + incentives, alive & ~done), step

    init = (state, obs, jnp.zeros((n, n), jnp.float32), jnp.array(True))
    steps = (jax.random.split(steps_key, env.max_steps), jnp.arange(env.max_steps))
    _, traj = jax.lax.scan(body, init, steps)
    return traj


def discounted_returns(rewards: jax.Array, gamma: float) -> jax.Array:
    """Reward-to-go G_t = Σ_{k ≥ t} γ^(k−t) r_k along axis 0.

    Args:
        rewards: [T, ...] (already zero on invalid steps).
    """
    steps = rewards.shape[0]
    t = jnp.arange(steps)
    exponent = t[None, :] - t[:, None]
    discount = jnp.where(exponent >= 0, gamma ** jnp.maximum(exponent, 0), 0.0)  # [T, T]
    return jnp.tensordot(discount.astype(rewards.dtype), rewards, axes=1)


def received(incentives: jax.Array) -> jax.Array:
    """Incentives each agent receives: [..., N giver, N recipient] -> [..., N]."""
    return incentives.sum(axis=-2)


def episode_metrics(env: Env, traj: Trajectory) -> dict[str, jax.Array]:
    """Per-episode metrics (see docs/experiments.md), then the episode sums of the
    env's declared per-step metrics (`Env.step_metrics`) under their own names."""
    env_return = traj.env_rewards.sum(axis=0)  # [N]
    got = received(traj.incentives).sum(axis=0)  # [N]
    given = traj.incentives.sum(axis=(0, 2))  # [N]
    steps = traj.valid.sum()
    success = env.episode_success(traj.success.sum(), steps, env_return)
    metrics = {
        "success": success,
        "steps": steps.astype(jnp.float32),
        "team_return": env_return.sum(),
        "return_env": env_return,
        "received": got,
        "given": given,
        "return_total": env_return + got - given,
    }
    for name, per_step in traj.step_metrics.items():
        if name in metrics:
            raise ValueError(f"step_metrics: {name!r} would replace pimbot's own metric")
        metrics[name] = per_step.sum(axis=0)
    return metrics
