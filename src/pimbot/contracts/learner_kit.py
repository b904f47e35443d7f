"""What every learner writes around its algorithm, written once (docs/extending.md).

    from pimbot.contracts.plugin_api import learner_kit as kit

A learner consults the attack and the defenses at their hook points itself
(`pimbot.contracts.learner`); most of that is the same in every learner: the attack's
and the defenses' state in `init`, the ε the defenses let each agent act with, the
incentives they let the recipients accept, the look they take after the policy step,
the sign an attack puts on a policy step, the view a learning attack needs and its step,
evaluation through `rollout`, and each agent's network for export. Each is one function
here; `pimbot.learners.pg` and the two example learners (`examples/plugins/`) use them,
and what stays in a learner's `update` is its algorithm, its hook points named in place.

Every function is pure and traceable (no Python branch on a traced number); stacked
parameters have leaves [N, ...], one row per agent.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax

from pimbot import nets
from pimbot.contracts import defense
from pimbot.contracts.attack import (
    AdversaryView,
    AgentParams,
    Attack,
    agent_row,
    attack_key,
    with_agent_row,
)
from pimbot.contracts.learner import Actor
from pimbot.contracts.rollout import (
    ActFn,
    Trajectory,
    discounted_returns,
    episode_metrics,
    received,
    rollout,
)
from pimbot.envs.core import Env

# --- init ------------------------------------------------------------------------------


def hook_fields(key, num_agents: int, attack: Attack, defenses, policy, incentive=None) -> dict:
    """The state fields the runner and the hooks read, at the start of a run: `attack_state`
    (`attack.init_state` given the adversary's actual rows of `policy` and `incentive`),
    `defense_state`, `key` (the learner's, after its own draws: the attack's key is derived
    from it, never consumed), `iteration` and `env_steps` (0).

    `LearnerState(policy=..., **hook_fields(key, N, attack, defenses, policy))`.
    """
    a = attack.adversary
    own = AgentParams(agent_row(policy, a), {} if incentive is None else agent_row(incentive, a))
    zero = jnp.zeros((), jnp.int32)
    return {
        "attack_state": attack.init_state(attack_key(key), num_agents, own),
        "defense_state": defense.init_states(defenses, num_agents, policy),
        "key": key,
        "iteration": zero,
        "env_steps": zero,
    }


# --- acting ----------------------------------------------------------------------------


def epsilon_schedule(iteration: jax.Array, start: float, end: float, decay_iters: int):
    """Linear ε schedule: `start` → `end` over `decay_iters` iterations, then constant."""
    frac = jnp.minimum(iteration / max(decay_iters, 1), 1.0)
    return jnp.asarray(start + (end - start) * frac, jnp.float32)


def acting_epsilon(defenses, defense_state: tuple, attack: Attack, num_agents: int, schedule):
    """The ε each agent acts and learns with (defense hook `acting_epsilon`, folded over
    the defenses; the adversary runs none): `schedule` [] where no defense changes it, else
    [N]."""
    ctx = defense.EpsilonContext(schedule, defense.honest_agents(attack, num_agents))
    return defense.acting_epsilon(defenses, defense_state, ctx)


def sampling_act(module, policy, epsilon) -> ActFn:
    """rollout's `act(key, obs [N, obs_dim]) -> actions [N]`: every agent samples from its
    ε-mixed softmax policy `module` (stacked `policy`); ε is [] or [N]."""
    if jnp.ndim(epsilon):
        epsilon = epsilon[:, None]

    def act(key, obs):
        logits = nets.apply_stacked(module, policy, obs)
        return jax.random.categorical(key, nets.mixed_log_probs(logits, epsilon))

    return act


def taken_log_probs(module, policy, traj: Trajectory, epsilon) -> jax.Array:
    """log π_ε(a_t^j | o_t^j) [T, N] of every agent's actions in `traj` under the stacked
    softmax `policy` (ε [] or [N]; 0 for the plain softmax), zero on invalid steps."""
    logits = jax.vmap(module.apply, in_axes=(0, 1), out_axes=1)(policy, traj.obs)  # [T, N, A]
    epsilon = epsilon[:, None] if jnp.ndim(epsilon) else epsilon
    taken = jnp.take_along_axis(nets.mixed_log_probs(logits, epsilon), traj.actions[..., None], -1)
    return taken[..., 0] * traj.valid[:, None]


# --- the policy step -------------------------------------------------------------------


def per_agent(tree, factors: jax.Array):
    """`tree` (leaves [N, ...]) with agent i's row times `factors[i]`."""
    return jax.tree.map(lambda x: x * factors.reshape((-1,) + (1,) * (x.ndim - 1)), tree)


def signed_step(optimizer: optax.GradientTransformation, grads, opt_state, params, sign):
    """One optimizer step of every agent's stacked `params`, agent i's *step* times
    `sign[i]` (attack hook `policy_sign`: +1 ascend as usual, −1 reverse, 0 freeze). The
    step is signed, not the gradient, so that an optimizer's momentum never moves a frozen
    agent. Returns (params, opt_state)."""
    updates, opt_state = optimizer.update(grads, opt_state, params)
    return optax.apply_updates(params, per_agent(updates, sign)), opt_state


# --- the incentives recipients learn from, and the look after the step ---------------------


def accepted_incentives(defenses, defense_state: tuple, attack: Attack, traj, incentive_max):
    """What the recipients learn from (defense hook `learning_incentives`, folded): the
    incentives sent in `traj`, masked to its valid steps, after each defense.

    Returns:
        (accepted [T, N giver, N recipient], the defenses' states, their metrics).
    """
    n = traj.actions.shape[-1]
    ctx = defense.IncentiveContext(
        traj.incentives * traj.valid[:, None, None],
        traj.incentives,
        traj.valid,
        incentive_max,
        defense.honest_agents(attack, n),
    )
    return defense.learning_incentives(defenses, defense_state, ctx)


def reinforce_gradients(module, policy, traj: Trajectory, epsilon, gamma: float):
    """`PolicyStepContext.gradients`: rewards [K, T, N] -> flat score-function gradients
    [K, N, P] of every agent's REINFORCE loss −Σ_t log π_ε(a_t|o_t)·G_t on `traj` (no
    entropy), one per reward source (the health monitor splits a step into env- and
    incentive-driven parts with it)."""

    def flat(source):
        returns = discounted_returns(source, gamma) * traj.valid[:, None]

        def loss(p):
            return -jnp.sum(taken_log_probs(module, p, traj, epsilon) * returns)

        grads = jax.grad(loss)(policy)  # each agent's loss depends on its row only
        return jnp.concatenate([g.reshape(g.shape[0], -1) for g in jax.tree.leaves(grads)], 1)

    return jax.vmap(flat)


def after_policy_step(
    defenses,
    defense_state: tuple,
    attack: Attack,
    policy,
    iteration,
    traj: Trajectory,
    gradients: Callable[[jax.Array], jax.Array],
    incentive_max: float = 0.0,
):
    """The defenses' look at the policy step just taken (defense hook `after_policy_step`,
    folded): `policy` is the stacked policy after it, `traj` the episode learnt from,
    `gradients` as `reinforce_gradients` gives it. Returns (policy, states, metrics)."""
    n = traj.actions.shape[-1]
    ctx = defense.PolicyStepContext(
        policy,
        iteration,
        traj.incentives,
        traj.valid,
        traj.env_rewards,
        gradients,
        incentive_max,
        defense.honest_agents(attack, n),
    )
    return defense.after_policy_step(defenses, defense_state, ctx)


# --- a learning attack (ADMO) ------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class IncentiveChannel:
    """The incentive part of an `AdversaryView`: all three set together (ADMO refuses a
    view with `incentive` and without the other two)."""

    incentive: Any
    """Every giver's stacked incentive parameters η [N, ...] (the adversary's row unmoved)."""
    emitted: Callable[[Any], jax.Array]
    """η_a -> [T, N, N] incentives on the judged episode, the adversary's row recomputed."""
    meta_pullback: Callable[[jax.Array], Any]
    """cotangents [K, T, N] on the recipients' log-probabilities -> [K, ...] in η_a."""


def incentive_channel(
    attack: Attack,
    incentive,
    traj: Trajectory,
    learned_row: Callable[[Any, Trajectory], jax.Array],
    recipients_log_probs: Callable[[jax.Array], jax.Array],
) -> IncentiveChannel:
    """The `emitted` and `meta_pullback` a learning attack reads, from two functions of the
    learner's:

    * `learned_row(η_a, traj) -> [T, N]`: what the adversary's own incentive function (at
      η_a) gives each agent at every step of `traj`, before the attack's `emit` (its recorded
      scale and offset are applied here, as during the episode);
    * `recipients_log_probs(incentives [T, N, N]) -> [T, N]`: every recipient's
      log-probabilities of the judged actions after its policy step on env reward plus what
      it receives of `incentives` (the step the givers model; differentiable).

    `meta_pullback` is then the reverse pass of η_a ↦ `recipients_log_probs(emitted(η_a))`,
    batched over the cotangents.
    """
    a = attack.adversary

    def emitted(eta_a):
        row = learned_row(eta_a, traj) * traj.incentive_scale[:, a] + traj.incentive_offset[:, a]
        return traj.incentives.at[:, a].set(row * traj.valid[:, None])

    eta_a = agent_row(incentive, a)

    def meta_pullback(cotangents):
        _, pull = jax.vjp(lambda eta: recipients_log_probs(emitted(eta)), eta_a)
        return jax.vmap(lambda c: pull(c)[0])(cotangents)

    return IncentiveChannel(incentive, emitted, meta_pullback)


def adversary_view(
    attack: Attack,
    module,
    policy,
    traj: Trajectory,
    epsilon,
    success,
    gamma: float,
    iteration,
    channel: IncentiveChannel | None = None,
) -> AdversaryView:
    """What a learning attack sees of one episode `traj`, judged and learnt from: θ_a is
    the adversary's row of the stacked softmax `policy` (`module`), its log-probabilities
    under the ε it acted with (`epsilon` [] or [N]: the schedule's, since it runs no
    defense), r = env reward, what it received of the incentives sent. Without a `channel`
    the incentive fields are None and `emission_scales` is ()."""
    a = attack.adversary
    eps = epsilon[a] if jnp.ndim(epsilon) else epsilon

    def log_probs(theta_a):  # [T], as the adversary played them
        logits = module.apply(theta_a, traj.obs[:, a])
        taken = jnp.take_along_axis(
            nets.mixed_log_probs(logits, eps), traj.actions[:, a, None], axis=1
        )
        return taken[:, 0] * traj.valid

    with_channel = channel is not None
    return AdversaryView(
        policy=policy,  # the adversary's row unmoved: its policy sign was 0
        incentive=channel.incentive if with_channel else None,
        log_probs=log_probs,
        env_rewards=traj.env_rewards,
        valid=traj.valid,
        emitted=channel.emitted if with_channel else None,
        meta_pullback=channel.meta_pullback if with_channel else None,
        received=(
            received(traj.incentives)[:, a]
            if with_channel
            else jnp.zeros(traj.valid.shape, jnp.float32)
        ),
        received_valid=traj.valid,
        emission_scales=((traj.incentive_scale, traj.valid),) if with_channel else (),
        success=success,
        gamma=gamma,
        iteration=iteration,
    )


def adversary_step(attack: Attack, attack_state, key, view: Callable[[], AdversaryView], policy,
                   incentive=None):  # fmt: skip
    """A learning attack's step (attack hook `adversary_step`, where the attack lists it):
    `view()` is built only then; the adversary's rows of `policy` (and `incentive`) are
    replaced by what the attack returns. `key` is the learner's (the attack's is derived).

    Returns:
        (policy, incentive, attack_state, the attack's metrics); as given, and {}, where
        the attack does not learn.
    """
    if "adversary_step" not in attack.hooks:
        return policy, incentive, attack_state, {}
    own, attack_state, metrics = attack.adversary_step(attack_state, attack_key(key), view())
    policy = with_agent_row(policy, attack.adversary, own.policy)
    if incentive is not None:
        incentive = with_agent_row(incentive, attack.adversary, own.incentive)
    return policy, incentive, attack_state, metrics


# --- evaluation, acting and export ---------------------------------------------------------


def evaluate_actor(key, env: Env, actor: Actor, episodes: int, attack: Attack, state):
    """`evaluate`'s per-episode metrics [episodes, ...]: `episodes` episodes of `actor` (the
    learner's `acting`, ε = 0) through `rollout`, the attack acting as in training (`state`
    carries its `env_steps` and `attack_state`)."""
    trajs = jax.vmap(
        lambda k: rollout(
            env, k, actor.act, actor.give, attack, state.env_steps, state.attack_state
        )
    )(jax.random.split(key, episodes))
    return jax.vmap(lambda t: episode_metrics(env, t))(trajs)


def agent_function(module, stacked, agent: int) -> Callable[..., jax.Array]:
    """Agent `agent`'s network alone, with its trained row of `stacked`: what an export
    (`pimbot.robot.exportable.PolicyExport`) returns for one agent."""
    params = agent_row(stacked, agent)
    return lambda *inputs: module.apply(params, *inputs)
