"""The Reciprocator on a matrix game, tabulated per state: its batch of games and its PPO.

A matrix game's observation takes few values (its binary state code,
`exact_voi.state_codes`), so the policy and value networks need only be run on
the K = 2^obs_dim possible observations. Playing then samples every game's
actions from the per-state logits, with the randomness of the whole batch drawn
at once (`play`); and the PPO loss of
`reciprocator.ppo_loss` regroups exactly into sums per (state, action):

* the ratio r_g and its clip c_g depend only on the group g = (state, action);
  Σ_{s∈g} min(r_g A_s, c_g A_s) = min(r_g, c_g)·Σ A_s⁺ + max(r_g, c_g)·Σ A_s⁻,
  where A_s = G_s − V̂(state) carries no gradient;
* the entropy depends only on the state; the value loss Σ (V̂_k − G_s)² =
  n_k V̂_k² − 2 V̂_k Σ G_s + Σ G_s².

The per-sample work of an epoch is then a subtraction and two segment sums;
every network call and its gradient is on K rows. Same loss as the per-sample
form up to the order of floating-point summation.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax

from pimbot import nets
from pimbot.learners import exact_voi
from pimbot.rollout import Trajectory, step_metric_names


def obs_table(obs_dim: int) -> np.ndarray:
    """float32 [K, obs_dim]: the observation of every state code (its bits)."""
    codes = np.arange(2**obs_dim)
    return ((codes[:, None] >> np.arange(obs_dim)[None, :]) & 1).astype(np.float32)


def logits_table(module, policy, obs_dim: int, num_agents: int) -> jax.Array:
    """[N, K, A]: every agent's logits in every state."""
    table = jnp.broadcast_to(jnp.asarray(obs_table(obs_dim)), (num_agents, 2**obs_dim, obs_dim))
    return nets.apply_stacked(module, policy, table)


def act_from_table(logits: jax.Array):
    """A rollout `act` function sampling from precomputed per-state logits [N, K, A]."""
    agents = jnp.arange(logits.shape[0])

    def act(key, obs):
        code = exact_voi.state_codes(obs)
        return jax.random.categorical(key, logits[agents, code])

    return act


def play(env, logits: jax.Array, key: jax.Array, num_envs: int) -> Trajectory | None:
    """`num_envs` games from per-state logits [N, K, A], as `rollout` plays them without an
    attack that acts: leaves [E, T, ...]; None where the game is not tabulable (it
    declares per-step metrics).

    A matrix game's step depends on the joint action only and every episode lasts
    `max_steps` steps, so the games run on state codes through `exact_voi.game_tables`;
    the actions are inverse-CDF samples of the softmax, the uniforms of all games and
    steps drawn in one call."""
    if step_metric_names(env):
        return None
    n, steps, num_actions = env.num_agents, env.max_steps, env.num_actions
    tables = exact_voi.game_tables(env)
    place = jnp.asarray(num_actions ** np.arange(n), jnp.int32)
    next_codes = jnp.asarray(tables.next_codes)

    # inverse-CDF sampling: action = #{a < A − 1 : u > P(action ≤ a)}
    cdf = jnp.cumsum(jax.nn.softmax(logits), axis=-1)[..., :-1]  # [N, K, A − 1]

    def body(codes, u):
        below = jnp.moveaxis(cdf[:, codes], 0, 1)  # [E, N, A − 1]
        actions = jnp.sum(u[..., None] > below, axis=-1).astype(jnp.int32)
        joint = jnp.sum(actions * place, axis=-1)
        return next_codes[joint], (codes, actions, joint)

    noise = jax.random.uniform(key, (steps, num_envs, n))
    first = jnp.full((num_envs,), tables.first_code, jnp.int32)
    _, (codes, actions, joint) = jax.lax.scan(body, first, noise)
    codes, actions, joint = codes.T, jnp.swapaxes(actions, 0, 1), joint.T  # [E, T, ...]
    obs = jnp.asarray(obs_table(env.obs_dim))[codes]  # [E, T, obs_dim]
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


def ppo_update(modules, cfg, obs_dim, policy, value, opt, codes, actions, returns, valid, sign):
    """`cfg.ppo_epochs` full-batch Adam steps of the PPO loss, regrouped per state.

    Args:
        modules: (policy, value) networks; obs_dim: observation size (K = 2^obs_dim);
        codes: int [S] state codes; actions: int [N, S]; returns: [N, S] normalized
        returns; valid: bool [S]; sign: [N] (the policy term's sign per agent).
    Returns:
        (policy, value, opt).
    """
    policy_module, value_module = modules
    n = actions.shape[0]
    num_states, num_actions = 2**obs_dim, policy_module.out_dim
    table = jnp.broadcast_to(jnp.asarray(obs_table(obs_dim)), (n, num_states, obs_dim))
    mask = valid.astype(jnp.float32)
    count = jnp.maximum(mask.sum(), 1.0)
    groups = codes[None, :] * num_actions + actions  # [N, S], group g = (state, action)
    seg = jax.vmap(lambda v, g: jax.ops.segment_sum(v, g, num_segments=num_states * num_actions))

    def per_group(v):  # [N, S] -> [N, K, A]
        return seg(v * mask, groups).reshape(n, num_states, num_actions)

    def per_state(v):  # [N, S] -> [N, K]
        return jax.vmap(lambda x: jax.ops.segment_sum(x, codes, num_segments=num_states))(v * mask)

    visits = per_state(jnp.ones_like(returns))  # [N, K]
    return_sum, return_sq = per_state(returns), per_state(returns**2)
    old = jax.nn.log_softmax(nets.apply_stacked(policy_module, policy, table))  # [N, K, A]
    agents = jnp.arange(n)[:, None]

    def loss_fn(params):
        pol, val = params
        log_probs = jax.nn.log_softmax(nets.apply_stacked(policy_module, pol, table))
        values = nets.apply_stacked(value_module, val, table)[..., 0]  # [N, K]
        advantage = returns - jax.lax.stop_gradient(values)[agents, codes]  # [N, S]
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

    def epoch(carry, _):
        params, opt = carry
        updates, opt = optimizer.update(grad_fn(params), opt, params)
        return (optax.apply_updates(params, updates), opt), None

    ((policy, value), opt), _ = jax.lax.scan(
        epoch, ((policy, value), opt), None, length=cfg.ppo_epochs
    )
    return policy, value, opt
