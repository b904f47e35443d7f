"""The policy-gradient baseline (`pg`): REINFORCE on environment reward only.

Each agent updates its own softmax policy with one SGD step per iteration on
the episode it just played: loss = −Σ_t log π_ε(a_t|o_t)·G_t − c_ent·Σ_t H(π_ε(o_t)),
summed over time (no mean, no baseline, no normalisation), as the original.
The loss and the step are shared with LIO, whose recipients take the same step
on env + received-incentive rewards.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import optax
from flax import struct

from pimbot import nets
from pimbot.contracts import learner_kit as kit
from pimbot.contracts.attack import NO_ATTACK, Attack, Outcome, attack_key
from pimbot.contracts.defense import NO_DEFENSE, Defenses
from pimbot.contracts.learner import Actor
from pimbot.contracts.rollout import Trajectory, discounted_returns, episode_metrics, rollout
from pimbot.envs.core import Env, TracedFields


@dataclasses.dataclass(frozen=True)
class PGConfig(TracedFields):
    """Hyperparameters of the policy-gradient baseline (defaults: the original ER column;
    other games declare the IPD column at their registration). The numbers in
    `traced_fields` are traced arguments of the compiled program; the ε schedule and
    `lr_policy` stay structure (as LIO's, whose policy step this is)."""

    traced_fields: ClassVar[tuple[str, ...]] = ("entropy_coef", "gamma")

    policy_hidden: tuple[int, ...] = (64, 32)
    """Hidden layer widths of the policy MLP."""
    lr_policy: float = 1e-3
    """SGD learning rate of the policy step."""
    entropy_coef: float = 0.01
    """Weight of the entropy bonus."""
    gamma: float = 0.99
    """Discount factor."""
    epsilon_start: float = 1.0
    """Initial exploration weight ε (acting with (1 − ε)π + ε/|A|)."""
    epsilon_end: float = 0.1
    """Final ε."""
    epsilon_decay_iters: int = 1000
    """Iterations over which ε decays linearly."""

    RANGES: ClassVar[dict] = {
        "gamma": (0.0, 1.0),
        "epsilon_start": (0.0, 1.0),
        "epsilon_end": (0.0, 1.0),
    }
    """Checked ranges (low, high) of the fields; the others are ≥ 0 (`check_fields`)."""


@struct.dataclass
class PGState:
    policy: dict  # stacked policy parameters, leaves [N, ...]
    attack_state: Any  # the attack's own state, else an empty dict
    defense_state: tuple  # each defense's own state, in order
    key: jax.Array
    iteration: jax.Array  # int32 []
    env_steps: jax.Array  # int32 [], environment steps taken in training


epsilon_at = kit.epsilon_schedule
"""Linear ε schedule: start → end over `decay_iters` iterations, then constant."""
act_fn = kit.sampling_act
"""A rollout `act` function sampling every agent's action from its ε-mixed policy (ε []
or [N]: an exploration floor on some agents)."""
evaluate_actor = kit.evaluate_actor
"""Per-episode metrics of `episodes` episodes of an `Actor`, the attack acting as in
training (LIO's and the Reciprocator's evaluation too)."""


def reinforce_loss(
    policy_params,
    module: nets.MLP,
    obs: jax.Array,
    actions: jax.Array,
    returns: jax.Array,
    valid: jax.Array,
    epsilon: jax.Array,
    entropy_coef: float,
) -> jax.Array:
    """One agent's policy loss on one episode (sums over time, invalid steps masked).

    Args:
        policy_params: this agent's policy parameters.
        obs: [T, obs_dim]; actions: int [T]; returns: [T] reward-to-go; valid: bool [T].
        epsilon: the exploration weight the episode was played with.
    """
    log_probs = nets.mixed_log_probs(module.apply(policy_params, obs), epsilon)  # [T, A]
    taken = jnp.take_along_axis(log_probs, actions[:, None], axis=1)[:, 0]
    entropy = -jnp.sum(jnp.exp(log_probs) * log_probs, axis=1)
    mask = valid.astype(jnp.float32)
    return -jnp.sum(mask * taken * returns) - entropy_coef * jnp.sum(mask * entropy)


def policy_step(
    module: nets.MLP,
    policy,
    traj: Trajectory,
    rewards: jax.Array,
    epsilon: jax.Array,
    lr: float,
    gamma: float,
    entropy_coef: float,
    sign: jax.Array | float = 1.0,
):
    """Every agent's one-step policy-gradient update, differentiable in `rewards`.

    Args:
        policy: stacked policy parameters [N, ...].
        traj: the episode the step learns from.
        rewards: [T, N] the reward each agent learns from (zero on invalid steps).
        sign: [N] or scalar; +1 ascends the return, −1 descends it.
    Returns:
        The updated stacked policy parameters.
    """
    returns = discounted_returns(rewards, gamma)  # [T, N]
    grad_fn = jax.grad(reinforce_loss)
    per_agent_epsilon = 0 if jnp.ndim(epsilon) else None  # [N] with an exploration floor
    grads = jax.vmap(grad_fn, in_axes=(0, None, 1, 1, 1, None, per_agent_epsilon, None))(
        policy, module, traj.obs, traj.actions, returns, traj.valid, epsilon, entropy_coef
    )
    sign = jnp.broadcast_to(jnp.asarray(sign, jnp.float32), (traj.actions.shape[1],))
    grads = kit.per_agent(grads, sign)
    optimizer = optax.sgd(lr)
    updates, _ = optimizer.update(grads, optimizer.init(policy))
    return optax.apply_updates(policy, updates)


def init(
    key: jax.Array,
    env: Env,
    cfg: PGConfig,
    attack: Attack = NO_ATTACK,
    defenses: Defenses = NO_DEFENSE,
) -> PGState:
    module = nets.policy_module(cfg.policy_hidden, env.num_actions)
    init_key, key = jax.random.split(key)
    policy = nets.init_stacked(module, init_key, env.num_agents, env.obs_dim)
    return PGState(policy=policy, **kit.hook_fields(key, env.num_agents, attack, defenses, policy))


def update(
    state: PGState,
    env: Env,
    cfg: PGConfig,
    attack: Attack = NO_ATTACK,
    defenses: Defenses = NO_DEFENSE,
) -> tuple[PGState, dict[str, jax.Array]]:
    """One training iteration: play an episode, take one policy step per agent."""
    module = nets.policy_module(cfg.policy_hidden, env.num_actions)
    key, episode_key = jax.random.split(state.key)
    schedule_epsilon = epsilon_at(
        state.iteration, cfg.epsilon_start, cfg.epsilon_end, cfg.epsilon_decay_iters
    )
    # 1. exploration (defense hook: acting_epsilon)
    epsilon = kit.acting_epsilon(
        defenses, state.defense_state, attack, env.num_agents, schedule_epsilon
    )
    # 2. play an episode (attack hooks: act)
    act = act_fn(module, state.policy, epsilon)
    traj = rollout(env, episode_key, act, None, attack, state.env_steps, state.attack_state)
    # 3. every agent's policy step on env reward (attack hook: policy_sign)
    policy = policy_step(
        module,
        state.policy,
        traj,
        traj.env_rewards,
        epsilon,
        cfg.lr_policy,
        cfg.gamma,
        cfg.entropy_coef,
        sign=attack.policy_sign(state.attack_state, env.num_agents),
    )
    success = episode_metrics(env, traj)["success"]
    env_steps = state.env_steps + traj.valid.sum()
    metrics = {"train/epsilon": schedule_epsilon, "train/success": success}

    # 4. a learning attack replaces the adversary's update (attack hook: adversary_step);
    #    it sees the episode just played, at the schedule's ε (it runs no defense)
    def view():
        return kit.adversary_view(
            attack, module, policy, traj, schedule_epsilon, success, cfg.gamma, state.iteration
        )

    policy, _, attack_state, attack_metrics = kit.adversary_step(
        attack, state.attack_state, state.key, view, policy
    )
    metrics.update(attack_metrics)
    # 5. the attack's own state (attack hook: observe)
    attack_state = attack.observe(
        attack_state, attack_key(episode_key), Outcome(success, state.iteration, env_steps)
    )
    new_state = PGState(
        policy=policy,
        attack_state=attack_state,
        defense_state=state.defense_state,
        key=key,
        iteration=state.iteration + 1,
        env_steps=env_steps,
    )
    return new_state, metrics


def acting(env: Env, cfg: PGConfig, state: PGState) -> Actor:
    """The trained policy at ε = 0 (actions sampled)."""
    module = nets.policy_module(cfg.policy_hidden, env.num_actions)
    return Actor(act_fn(module, state.policy, jnp.float32(0.0)))


def evaluate(
    key: jax.Array,
    state: PGState,
    env: Env,
    cfg: PGConfig,
    episodes: int,
    attack: Attack = NO_ATTACK,
):
    """Per-episode metrics [episodes, ...] of evaluation episodes (ε = 0, actions sampled)."""
    return evaluate_actor(key, env, acting(env, cfg, state), episodes, attack, state)
