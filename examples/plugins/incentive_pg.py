"""`incentive_pg`: REINFORCE agents that also pay each other learned incentives (a plugin).

Every agent i has a softmax policy θ_i and an incentive function η_i: after each joint
action it gives agent j ≠ i  u_ij = R_max · sigmoid(η_i(o_i, a))_j  (its own observation and
the joint action one-hot). Each iteration plays one episode τ, then
  1. every recipient takes one SGD step on its REINFORCE loss −Σ_t log π_ε(a_t|o_t)·G_t,
     G the return of env reward plus the incentives it accepts;
  2. every giver ascends its own env return through the recipients' step: with θ̂(u) the
     step the recipients would take on env reward + what u gives them,
         J_i(η) = Σ_{j≠i} Σ_t log π_θ̂j(u(η))(a_t^j | o_t^j) · G_t^{i, env}
                  − c · Σ_t γ^t Σ_j u_ij,t            (one Adam step on η_i)
     on the same episode τ: LIO's idea (Yang et al. 2020) with one rollout, not two.
docs/extending.md, "A learner that pays incentives", is written alongside this file.
Hook points: attack `act`, `emit` (in `rollout`), `learning_rewards`, `policy_sign`,
`adversary_step`, `observe`; defense `acting_epsilon`, `learning_incentives`,
`after_policy_step`.

    pimbot train escape_room-v0 --plugin examples/plugins/incentive_pg.py \
        --learner incentive_pg --seeds 3 --iterations 3000 --out runs/ipg
"""

from __future__ import annotations

import dataclasses
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
    agent_row,
    attack_key,
    discounted_returns,
    episode_metrics,
    nets,
    received,
    register_learner,
    rollout,
)
from pimbot.contracts.plugin_api import learner_kit as kit


@dataclasses.dataclass(frozen=True)
class IPGConfig:
    """Hyperparameters of `incentive_pg` (`--hp NAME=VALUE`)."""

    policy_hidden: tuple[int, ...] = (32,)
    """Hidden layer widths of every agent's policy."""
    incentive_hidden: tuple[int, ...] = (16,)
    """Hidden layer widths of every agent's incentive function."""
    lr_policy: float = 1e-2
    """SGD learning rate of the policy step (and of the step the givers model)."""
    lr_incentive: float = 1e-3
    """Adam learning rate of the incentive step."""
    incentive_max: float = 2.0
    """R_max: the most one agent gives another in one step."""
    cost: float = 0.01
    """c: what each unit given costs the giver's objective (discounted)."""
    gamma: float = 0.99
    """Discount factor."""
    epsilon_start: float = 0.5
    """Initial exploration weight ε (acting with (1 − ε)π + ε/|A|)."""
    epsilon_end: float = 0.05
    """Final ε."""
    epsilon_decay_iters: int = 1000
    """Iterations over which ε decays linearly."""

    RANGES: ClassVar[dict] = {k: (0.0, 1.0) for k in ("gamma", "epsilon_start", "epsilon_end")}
    """Checked ranges (low, high); the other numbers must be ≥ 0, widths ≥ 1."""


@struct.dataclass
class IPGState:
    policy: Any  # stacked θ, leaves [N, ...]
    incentive: Any  # stacked η, leaves [N, ...]
    incentive_opt: Any  # Adam state of η (elementwise, so one per giver)
    attack_state: Any  # the fields below: kit.hook_fields
    defense_state: tuple
    key: jax.Array
    iteration: jax.Array
    env_steps: jax.Array


NAME = "incentive_pg"


def networks(env, cfg: IPGConfig) -> tuple[nets.MLP, nets.MLP]:
    policy_net = nets.policy_module(cfg.policy_hidden, env.num_actions)
    return policy_net, nets.incentive_module(cfg.incentive_hidden, env.num_agents)


def gives(incentive_net, eta_i, obs_i, actions, giver, cfg, num_actions):
    """What giver i gives every agent, [..., N] (0 to itself): obs_i [..., obs_dim], the
    joint actions [..., N]. Deterministic, as `give` must be (no key)."""
    joint = jax.nn.one_hot(actions, num_actions).reshape(actions.shape[:-1] + (-1,))
    out = jax.nn.sigmoid(incentive_net.apply(eta_i, jnp.concatenate([obs_i, joint], -1)))
    return cfg.incentive_max * out * (1.0 - jax.nn.one_hot(giver, actions.shape[-1]))


def incentives(incentive_net, eta, obs, actions, cfg, num_actions):
    """Every giver's incentives [..., N giver, N recipient]: obs [..., N, obs_dim]."""
    every = jax.vmap(gives, in_axes=(None, 0, -2, None, 0, None, None), out_axes=-2)
    n = actions.shape[-1]
    return every(incentive_net, eta, obs, actions, jnp.arange(n), cfg, num_actions)


def policy_grads(policy_net, policy, traj, rewards, epsilon, gamma):
    """Every agent's REINFORCE gradient on `traj` for its rewards [T, N] (stacked)."""
    returns = discounted_returns(rewards * traj.valid[:, None], gamma)

    def loss(p):
        return -jnp.sum(kit.taken_log_probs(policy_net, p, traj, epsilon) * returns)

    return jax.grad(loss)(policy)


def init(key, env, cfg: IPGConfig, attack=NO_ATTACK, defenses=NO_DEFENSE):
    policy_net, incentive_net = networks(env, cfg)
    policy_key, incentive_key, key = jax.random.split(key, 3)
    n = env.num_agents
    policy = nets.init_stacked(policy_net, policy_key, n, env.obs_dim)
    in_dim = env.obs_dim + n * env.num_actions
    incentive = nets.init_stacked(incentive_net, incentive_key, n, in_dim)
    return IPGState(
        policy=policy,
        incentive=incentive,
        incentive_opt=optax.adam(cfg.lr_incentive).init(incentive),
        **kit.hook_fields(key, n, attack, defenses, policy, incentive),
    )


def update(state: IPGState, env, cfg: IPGConfig, attack=NO_ATTACK, defenses=NO_DEFENSE):
    """One iteration: play τ, the recipients' step, the givers' step."""
    (policy_net, incentive_net), n, a = networks(env, cfg), env.num_agents, attack.adversary
    key, episode_key = jax.random.split(state.key)
    schedule = kit.epsilon_schedule(
        state.iteration, cfg.epsilon_start, cfg.epsilon_end, cfg.epsilon_decay_iters
    )
    # 1. exploration (defense hook: acting_epsilon)
    epsilon = kit.acting_epsilon(defenses, state.defense_state, attack, n, schedule)
    # 2. play τ; every giver's incentives after each joint action (attack hooks: act, emit)
    act = kit.sampling_act(policy_net, state.policy, epsilon)

    def give(obs, actions):
        return incentives(incentive_net, state.incentive, obs, actions, cfg, env.num_actions)

    traj = rollout(env, episode_key, act, give, attack, state.env_steps, state.attack_state)
    # 3. the recipients' step on env reward + what they accept (defense hook:
    #    learning_incentives; attack hooks: learning_rewards, policy_sign)
    accepted, defense_state, defense_metrics = kit.accepted_incentives(
        defenses, state.defense_state, attack, traj, cfg.incentive_max
    )
    rewards = attack.learning_rewards(state.attack_state, traj.env_rewards, received(accepted))
    grads = policy_grads(policy_net, state.policy, traj, rewards, epsilon, cfg.gamma)
    sign = attack.policy_sign(state.attack_state, n)
    sgd = optax.sgd(cfg.lr_policy)
    policy, _ = kit.signed_step(sgd, grads, sgd.init(state.policy), state.policy, sign)
    # 4. the defenses' look at the step just taken (defense hook: after_policy_step)
    gradients = kit.reinforce_gradients(policy_net, state.policy, traj, epsilon, cfg.gamma)
    policy, defense_state, monitor_metrics = kit.after_policy_step(
        defenses, defense_state, attack, policy, state.iteration, traj, gradients,
        cfg.incentive_max,
    )  # fmt: skip

    # 5. the givers' step through the step they model every recipient taking: the
    #    ordinary one, on env reward + what they are sent (no defense, sign +1)
    def recipients_log_probs(sent):  # [T, N, N] -> log π_θ̂j(a_t^j | o_t^j) [T, N]
        model_rewards = traj.env_rewards + received(sent)
        model = policy_grads(policy_net, state.policy, traj, model_rewards, epsilon, cfg.gamma)
        new = jax.tree.map(lambda p, g: p - cfg.lr_policy * g, state.policy, model)
        return kit.taken_log_probs(policy_net, new, traj, epsilon)

    def sent_by(eta):  # what every giver sent on τ, recomputed from η
        learned = incentives(incentive_net, eta, traj.obs, traj.actions, cfg, env.num_actions)
        return (learned * traj.incentive_scale + traj.incentive_offset) * traj.valid[:, None, None]

    def objectives(eta):  # J_i(η) for every giver i, [N]
        sent = sent_by(eta)
        env_returns = discounted_returns(traj.env_rewards, cfg.gamma) * traj.valid[:, None]
        others = 1.0 - jnp.eye(n)  # [giver, recipient]
        gain = jnp.einsum("tj,ti,ij->i", recipients_log_probs(sent), env_returns, others)
        discount = cfg.gamma ** jnp.arange(traj.valid.shape[0])
        return gain - cfg.cost * jnp.einsum("t,tij->i", discount, sent)

    own_grads = jax.jacrev(objectives)(state.incentive)  # leaves [giver, N, ...]: take row i
    ascent = jax.tree.map(lambda g: -g[jnp.arange(n), jnp.arange(n)], own_grads)
    steps, incentive_opt = optax.adam(cfg.lr_incentive).update(ascent, state.incentive_opt)
    incentive = optax.apply_updates(state.incentive, steps)
    # 6. a learning attack's step replaces the adversary's (attack hook: adversary_step)
    success = episode_metrics(env, traj)["success"]

    def view():
        channel = kit.incentive_channel(
            attack, state.incentive, traj,
            lambda eta_a, t: gives(incentive_net, eta_a, t.obs[:, a], t.actions, a, cfg,
                                   env.num_actions),
            recipients_log_probs,
        )  # fmt: skip
        return kit.adversary_view(
            attack, policy_net, policy, traj, schedule, success, cfg.gamma, state.iteration,
            channel,
        )  # fmt: skip

    policy, incentive, attack_state, attack_metrics = kit.adversary_step(
        attack, state.attack_state, state.key, view, policy, incentive
    )
    # 7. the attack's own state (attack hook: observe)
    env_steps = state.env_steps + traj.valid.sum()
    outcome = Outcome(success, state.iteration, env_steps)
    attack_state = attack.observe(attack_state, attack_key(episode_key), outcome)
    given = traj.incentives.sum(axis=(0, 2))
    metrics = {"train/success": success, "train/epsilon": schedule, "train/given": given}
    new_state = IPGState(
        policy, incentive, incentive_opt, attack_state, defense_state, key,
        state.iteration + 1, env_steps,
    )  # fmt: skip
    return new_state, metrics | defense_metrics | monitor_metrics | attack_metrics


def acting(env, cfg: IPGConfig, state: IPGState) -> Actor:
    """The trained policies at ε = 0 (actions sampled) and the learned incentives."""
    policy_net, incentive_net = networks(env, cfg)

    def give(obs, actions):
        return incentives(incentive_net, state.incentive, obs, actions, cfg, env.num_actions)

    return Actor(kit.sampling_act(policy_net, state.policy, jnp.float32(0.0)), give)


def evaluate(key, state: IPGState, env, cfg: IPGConfig, episodes: int, attack=NO_ATTACK):
    """Per-episode metrics [episodes, ...] at ε = 0, the attack acting as in training."""
    return kit.evaluate_actor(key, env, acting(env, cfg, state), episodes, attack, state)


register_learner(
    LearnerDef(
        NAME,
        "REINFORCE agents paying learned incentives, one-rollout LIO-style giver step (plugin)",
        IPGConfig, init, update, evaluate, acting,
        attack_hooks=("act", "emit", "learning_rewards", "policy_sign", "adversary_step",
                      "observe"),
        defense_hooks=("acting_epsilon", "learning_incentives", "after_policy_step"),
        has_incentives=True,
    )
)  # fmt: skip


def export_policy(env, cfg: IPGConfig, state: IPGState, agent: int):
    """Agent `agent`'s logits(obs [B, obs_dim]) for `pimbot export`."""
    return kit.agent_function(networks(env, cfg)[0], state.policy, agent)


def export_incentive(env, cfg: IPGConfig, state: IPGState, agent: int):
    """What agent `agent` gives, give(obs [B, obs_dim], actions [B, N]) -> [B, N]."""
    eta_i = agent_row(state.incentive, agent)
    net = networks(env, cfg)[1]
    return lambda obs, actions: gives(net, eta_i, obs, actions, agent, cfg, env.num_actions)


def _register_export():
    """`pimbot export` of this learner's runs (pimbot.robot sits above the contracts)."""
    from pimbot.robot.exportable import PolicyExport, register_export

    register_export(acting, PolicyExport(export_policy, export_incentive))


_register_export()
