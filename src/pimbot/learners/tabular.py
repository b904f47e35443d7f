"""The Reciprocator on a matrix game, tabulated per state: its batch of games and its PPO.

A matrix game's observation takes few values (its reachable states,
`exact_voi.game_tables`), so the policy and value networks need only be run on
those K observations. Playing then samples every game's
actions from the per-state logits, with the randomness of the whole batch drawn
at once (`play`); and the PPO loss of
`reciprocator.ppo_loss` regroups exactly into sums per (state, action):

* the ratio r_g and its clip c_g depend only on the group g = (state, action);
  Σ_{s∈g} min(r_g A_s, c_g A_s) = min(r_g, c_g)·Σ A_s⁺ + max(r_g, c_g)·Σ A_s⁻,
  where A_s = G_s − V̂(state) carries no gradient;
* the entropy depends only on the state; the value loss Σ (V̂_k − G_s)² =
  n_k V̂_k² − 2 V̂_k Σ G_s + Σ G_s².

The per-sample work of an epoch is then a subtraction and small matrix products
with the one-hot states (no gathers or scatters, which are slow under the seed
vmap); every network call and its gradient is on K rows. Same loss as the per-sample
form up to the order of floating-point summation.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax

from pimbot import nets
from pimbot.contracts.rollout import Trajectory, step_metric_names
from pimbot.learners import epoch_schedule, exact_voi


def logits_table(module, policy, tables: exact_voi.GameTables, num_agents: int) -> jax.Array:
    """[N, K, A]: every agent's logits in every reachable state."""
    obs = jnp.asarray(tables.state_obs)
    return nets.apply_stacked(module, policy, jnp.broadcast_to(obs, (num_agents,) + obs.shape))


def act_from_table(logits: jax.Array, tables: exact_voi.GameTables):
    """A rollout `act` function sampling from per-state logits [N, K, A]."""

    def act(key, obs):
        per_state = jnp.einsum("k,nka->na", exact_voi.state_one_hot(obs, tables), logits)
        return jax.random.categorical(key, per_state)

    return act


def play(env, logits: jax.Array, key: jax.Array, num_envs: int) -> Trajectory | None:
    """`num_envs` games from per-state logits [N, K, A], as `rollout` plays them without an
    attack that acts: leaves [E, T, ...]; None where the game is not tabulable (it
    declares per-step metrics).

    A matrix game's step depends on the joint action only and every episode lasts
    `max_steps` steps, so the games run on dense states through `exact_voi.game_tables`;
    the actions are inverse-CDF samples of the softmax, the uniforms of all games and
    steps drawn in one call."""
    if step_metric_names(env):
        return None
    n, steps, num_actions = env.num_agents, env.max_steps, env.num_actions
    tables = exact_voi.game_tables(env)
    next_states = jnp.asarray(tables.next_states)
    # inverse-CDF sampling: action = #{a < A − 1 : u > P(action ≤ a)}
    cdf = jnp.cumsum(jax.nn.softmax(logits), axis=-1)[..., :-1]  # [N, K, A − 1]

    def body(states, u):
        below = jnp.moveaxis(cdf[:, states], 0, 1)  # [E, N, A − 1]
        actions = jnp.sum(u[..., None] > below, axis=-1).astype(jnp.int32)
        joint = exact_voi.joint_index(actions, num_actions)
        return next_states[joint], (states, actions, joint)

    noise = jax.random.uniform(key, (steps, num_envs, n))
    first = jnp.full((num_envs,), tables.first_state, jnp.int32)
    _, (states, actions, joint) = jax.lax.scan(body, first, noise)
    states, actions, joint = states.T, jnp.swapaxes(actions, 0, 1), joint.T  # [E, T, ...]
    obs = jnp.asarray(tables.state_obs)[states]  # [E, T, obs_dim]
    zeros = jnp.zeros((num_envs, steps, n, n), jnp.float32)
    return Trajectory(
        obs=jnp.broadcast_to(obs[:, :, None, :], (num_envs, steps, n, env.obs_dim)),
        actions=actions,
        env_rewards=jnp.asarray(tables.rewards)[joint],
        incentives=zeros,
        incentive_scale=jnp.ones_like(zeros),
        incentive_offset=zeros,
        valid=jnp.ones((num_envs, steps), bool),
        success=jnp.asarray(tables.success)[joint],
        step_metrics={},
    )


def ppo_update(
    modules, cfg, tables, policy, value, opt, states, actions, returns, valid, sign, schedule=None
):
    """`cfg.ppo_epochs` full-batch Adam steps of the PPO loss, regrouped per state.

    Args:
        modules: (policy, value) networks; tables: the game's `exact_voi.GameTables`;
        states: float [S, K] one-hot dense states; actions: int [N, S]; returns: [N, S]
        normalized returns; valid: bool [S]; sign: [N] (the policy term's sign per agent);
        schedule: an attack's `UpdateSchedule` (per-agent epochs; `opt` then holds Adam
        states per agent, `epoch_schedule.init`), or None: `ppo_epochs` for all.
    Returns:
        (policy, value, opt).
    """
    policy_module, value_module = modules
    n = actions.shape[0]
    obs = jnp.asarray(tables.state_obs)
    table = jnp.broadcast_to(obs, (n,) + obs.shape)
    mask = valid.astype(jnp.float32)
    count = jnp.maximum(mask.sum(), 1.0)
    states = states * mask[:, None]  # [S, K]
    taken = jax.nn.one_hot(actions, policy_module.out_dim, dtype=jnp.float32)  # [N, S, A]

    def per_group(v):  # [N, S] -> [N, K, A]: sums over the valid samples of each group
        return jnp.einsum("sk,nsa->nka", states, taken * v[..., None])

    visits = jnp.sum(states, axis=0)  # [K]
    return_sum = jnp.einsum("sk,ns->nk", states, returns)
    return_sq = jnp.einsum("sk,ns->nk", states, returns**2)
    old = jax.nn.log_softmax(nets.apply_stacked(policy_module, policy, table))  # [N, K, A]

    def loss_fn(params):
        pol, val = params
        log_probs = jax.nn.log_softmax(nets.apply_stacked(policy_module, pol, table))
        values = nets.apply_stacked(value_module, val, table)[..., 0]  # [N, K]
        at_sample = jnp.einsum("sk,nk->ns", states, jax.lax.stop_gradient(values))
        advantage = returns - at_sample  # [N, S] (invalid samples carry no weight)
        positive = per_group(jnp.maximum(advantage, 0.0))
        negative = per_group(jnp.minimum(advantage, 0.0))
        ratio = jnp.exp(log_probs - old)
        clipped = jnp.clip(ratio, 1.0 - cfg.clip, 1.0 + cfg.clip)
        surrogate = jnp.minimum(ratio, clipped) * positive + jnp.maximum(ratio, clipped) * negative
        entropy = -jnp.sum(jnp.exp(log_probs) * log_probs, axis=-1)  # [N, K]
        policy_loss = -(surrogate.sum((1, 2)) + cfg.entropy_coef * (visits * entropy).sum(1))
        value_loss = (visits * values**2 - 2 * values * return_sum + return_sq).sum(1)
        return jnp.sum(sign * policy_loss + cfg.value_coef * value_loss) / count

    optimizer = optax.adam(cfg.lr)
    grad_fn = jax.grad(loss_fn)
    if schedule is not None:
        (policy, value), opt = epoch_schedule.run(
            grad_fn, cfg.lr, (policy, value), opt, schedule.epochs, schedule.most_epochs
        )
        return policy, value, opt

    def epoch(carry, _):
        params, opt = carry
        updates, opt = optimizer.update(grad_fn(params), opt, params)
        return (optax.apply_updates(params, updates), opt), None

    ((policy, value), opt), _ = jax.lax.scan(
        epoch, ((policy, value), opt), None, length=cfg.ppo_epochs
    )
    return policy, value, opt
