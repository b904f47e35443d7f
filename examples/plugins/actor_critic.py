"""`actor_critic`: independent advantage actor-critic, a learner written as a plugin.

Every agent has its own softmax actor π and value critic V (two MLPs, nothing shared, no
incentive channel). Each iteration plays one episode with the ε-mixed actors and takes one
Adam step per agent on
    actor:  −Σ_t A_t · log π_ε(a_t | o_t) − c_ent · Σ_t H(π_ε(· | o_t))
    critic: ½ Σ_t (V(o_t) − G_t)², with the target G_t = A_t + V(o_t) held fixed
where A_t is the GAE(γ, λ) advantage of the agent's own reward (Schulman et al. 2016,
"High-Dimensional Continuous Control Using Generalized Advantage Estimation"); the episode's
last step bootstraps from 0. Hook points it calls (docs/extending.md, "(e) A learner"):
attack `act` (in `rollout`), `learning_rewards`, `policy_sign`, `adversary_step`,
`observe`; defense `acting_epsilon`. An attack at `emit` is refused (no channel).

    pimbot learners --plugin examples/plugins/actor_critic.py
    pimbot train escape_room-v0 --plugin examples/plugins/actor_critic.py \
        --learner actor_critic --seeds 3 --iterations 2000 --out runs/ac
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import optax
from flax import struct

from pimbot.contracts.plugin_api import (
    NO_ATTACK,
    NO_DEFENSE,
    Actor,
    LearnerDef,
    Outcome,
    attack_key,
    episode_metrics,
    nets,
    register_learner,
    rollout,
)
from pimbot.contracts.plugin_api import learner_kit as kit


@dataclasses.dataclass(frozen=True)
class ACConfig:
    """Hyperparameters of the independent actor-critic (`--hp NAME=VALUE`)."""

    actor_hidden: tuple[int, ...] = (32,)
    """Hidden layer widths of every agent's actor."""
    critic_hidden: tuple[int, ...] = (32,)
    """Hidden layer widths of every agent's critic."""
    lr_actor: float = 1e-3
    """Adam learning rate of the actor."""
    lr_critic: float = 1e-2
    """Adam learning rate of the critic."""
    entropy_coef: float = 0.01
    """Weight of the entropy bonus."""
    gamma: float = 0.99
    """Discount factor."""
    gae_lambda: float = 0.95
    """λ of the advantage (0: one-step TD error, 1: return minus value)."""
    epsilon_start: float = 0.5
    """Initial exploration weight ε (acting with (1 − ε)π + ε/|A|)."""
    epsilon_end: float = 0.05
    """Final ε."""
    epsilon_decay_iters: int = 1000
    """Iterations over which ε decays linearly."""

    RANGES: ClassVar[dict] = {
        k: (0.0, 1.0) for k in ("gamma", "gae_lambda", "epsilon_start", "epsilon_end")
    }
    """Checked ranges (low, high); the other numbers must be ≥ 0, widths ≥ 1."""


@struct.dataclass
class ACState:
    actor: Any  # stacked actor parameters, leaves [N, ...]
    critic: Any  # stacked critic parameters, leaves [N, ...]
    actor_opt: Any  # Adam states (elementwise, so one per agent)
    critic_opt: Any
    attack_state: Any  # the attack's own per-seed state (these five: kit.hook_fields)
    defense_state: tuple  # each defense's own state, in order
    key: jax.Array
    iteration: jax.Array  # int32 []
    env_steps: jax.Array  # int32 [], environment steps taken in training


NAME = "actor_critic"
OWN = f"learner/{NAME}/"
"""Namespace of the learner's own metrics (the report's sweep section tabulates them)."""


def networks(env, cfg: ACConfig) -> tuple[nets.MLP, nets.MLP]:
    return nets.policy_module(cfg.actor_hidden, env.num_actions), nets.MLP(cfg.critic_hidden, 1)


def advantages(rewards, values, valid, gamma, lam):
    """GAE of one agent: rewards, values [T] (zero after the episode), valid bool [T]."""
    next_values = jnp.append(values[1:] * valid[1:], 0.0)
    deltas = (rewards + gamma * next_values - values) * valid

    def back(later, delta):
        now = delta + gamma * lam * later
        return now, now

    return jax.lax.scan(back, jnp.float32(0.0), deltas, reverse=True)[1]


def agent_loss(nets_, cfg, actor, critic, obs, actions, rewards, valid, epsilon):
    """One agent's (actor + critic loss, critic loss) on one episode: obs [T, obs_dim],
    actions, rewards, valid [T]; epsilon []."""
    actor_net, critic_net = nets_
    values = critic_net.apply(critic, obs)[:, 0] * valid
    adv = advantages(rewards, jax.lax.stop_gradient(values), valid, cfg.gamma, cfg.gae_lambda)
    log_probs = nets.mixed_log_probs(actor_net.apply(actor, obs), epsilon)  # [T, A]
    taken = jnp.take_along_axis(log_probs, actions[:, None], axis=1)[:, 0]
    entropy = -jnp.sum(jnp.exp(log_probs) * log_probs, axis=1)
    actor_loss = -jnp.sum(valid * (adv * taken + cfg.entropy_coef * entropy))
    critic_loss = 0.5 * jnp.sum(valid * jnp.square(values - jax.lax.stop_gradient(adv + values)))
    return actor_loss + critic_loss, critic_loss


def init(key, env, cfg: ACConfig, attack=NO_ATTACK, defenses=NO_DEFENSE):
    actor_net, critic_net = networks(env, cfg)
    actor_key, critic_key, key = jax.random.split(key, 3)
    actor = nets.init_stacked(actor_net, actor_key, env.num_agents, env.obs_dim)
    critic = nets.init_stacked(critic_net, critic_key, env.num_agents, env.obs_dim)
    return ACState(
        actor=actor,
        critic=critic,
        actor_opt=optax.adam(cfg.lr_actor).init(actor),
        critic_opt=optax.adam(cfg.lr_critic).init(critic),
        **kit.hook_fields(key, env.num_agents, attack, defenses, actor),
    )


def update(state: ACState, env, cfg: ACConfig, attack=NO_ATTACK, defenses=NO_DEFENSE):
    """One iteration: play an episode, take every agent's actor and critic step."""
    nets_, n = networks(env, cfg), env.num_agents
    key, episode_key = jax.random.split(state.key)
    schedule = kit.epsilon_schedule(
        state.iteration, cfg.epsilon_start, cfg.epsilon_end, cfg.epsilon_decay_iters
    )
    # 1. exploration (defense hook: acting_epsilon; the adversary runs no defense)
    epsilon = kit.acting_epsilon(defenses, state.defense_state, attack, n, schedule)
    epsilon = jnp.broadcast_to(epsilon, (n,))
    # 2. play an episode (attack hook: act, consulted by rollout at every step)
    act = kit.sampling_act(nets_[0], state.actor, epsilon)
    traj = rollout(env, episode_key, act, None, attack, state.env_steps, state.attack_state)
    # 3. the rewards each agent learns from (attack hook: learning_rewards; none received)
    received = jnp.zeros_like(traj.env_rewards)
    rewards = attack.learning_rewards(state.attack_state, traj.env_rewards, received)
    # 4. every agent's Adam steps; the actor's times its sign (attack hook: policy_sign)
    grad_fn = jax.grad(functools.partial(agent_loss, nets_, cfg), argnums=(0, 1), has_aux=True)
    (actor_grads, critic_grads), critic_loss = jax.vmap(grad_fn, (0, 0, 1, 1, 1, None, 0))(
        state.actor, state.critic, traj.obs, traj.actions, rewards, traj.valid, epsilon
    )
    sign = attack.policy_sign(state.attack_state, n)
    adam = optax.adam(cfg.lr_actor)
    actor, actor_opt = kit.signed_step(adam, actor_grads, state.actor_opt, state.actor, sign)
    steps, critic_opt = optax.adam(cfg.lr_critic).update(critic_grads, state.critic_opt)
    critic = optax.apply_updates(state.critic, steps)
    success = episode_metrics(env, traj)["success"]
    env_steps = state.env_steps + traj.valid.sum()
    metrics = {"train/success": success, "train/epsilon": schedule}
    metrics |= {"train/acting_epsilon": epsilon, OWN + "critic_loss": critic_loss.mean()}

    # 5. a learning attack moves the adversary's actor (attack hook: adversary_step); it
    #    sees the episode just played (ω = θ_a, r = env reward), no incentive channel
    def view():
        return kit.adversary_view(
            attack, nets_[0], actor, traj, epsilon, success, cfg.gamma, state.iteration
        )

    actor, _, attack_state, attack_metrics = kit.adversary_step(
        attack, state.attack_state, state.key, view, actor
    )
    metrics |= attack_metrics
    # 6. the attack's own state (attack hook: observe)
    outcome = Outcome(success, state.iteration, env_steps)
    attack_state = attack.observe(attack_state, attack_key(episode_key), outcome)
    new_state = ACState(
        actor, critic, actor_opt, critic_opt, attack_state, state.defense_state, key,
        state.iteration + 1, env_steps,
    )  # fmt: skip
    return new_state, metrics


def acting(env, cfg: ACConfig, state: ACState) -> Actor:
    """The trained actors at ε = 0 (actions sampled)."""
    return Actor(kit.sampling_act(networks(env, cfg)[0], state.actor, jnp.float32(0.0)))


def evaluate(key, state: ACState, env, cfg: ACConfig, episodes: int, attack=NO_ATTACK):
    """Per-episode metrics [episodes, ...] at ε = 0, the attack acting as in training."""
    return kit.evaluate_actor(key, env, acting(env, cfg, state), episodes, attack, state)


register_learner(
    LearnerDef(
        NAME,
        "independent advantage actor-critic (GAE) on own reward, no incentives (plugin)",
        ACConfig, init, update, evaluate, acting,
        attack_hooks=("act", "learning_rewards", "policy_sign", "adversary_step", "observe"),
        defense_hooks=("acting_epsilon",),
        env_defaults={"escape_room-v0": {"lr_actor": 3e-3, "epsilon_decay_iters": 500}},
    )
)  # fmt: skip
