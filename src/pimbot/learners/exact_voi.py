"""Exact value of influence on matrix games (the original Reciprocator's IPD agent).

In a matrix game every reward is a known function of the joint action, so the
value of influence needs no learned models (spec/reciprocators.md; the
original's `MatrixVOI`):

    VoI(j → i, t) = r_i(a_t) − Σ_{a'} p̂_j(a' | s_t) · r_i(a', a_{−j, t}),

where p̂_j(· | s) is agent j's empirical action frequency in state s over the
last `history` batches, refreshed every `refit_period` iterations (the
original: the last 1 batch, every 3). The VoI is the reward term only, as in
the original's matrix agent (it argues that the future values cancel).

States are the codes Σ_d obs_d·2^d of the (binary, shared) observation; a
state not visited in the stored batches keeps its previous estimate, uniform at
the start (the original starts at p = 0.5, and would produce NaN there).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from pimbot.envs.core import InvalidParameter
from pimbot.envs.matrix_games import MatrixGame

MAX_OBS_BITS = 16
"""Largest observation size whose state codes are tabulated (2^16 states)."""


@struct.dataclass
class ActionFrequencies:
    probs: jax.Array  # float32 [K, N, A]: p̂_j(a | s), the estimate in use
    counts: jax.Array  # float32 [H, K, N, A]: per stored batch, visits of (s, j, a)


def check_env(env) -> None:
    """Exact VoI needs a matrix game: rewards a function of the joint action only."""
    if not isinstance(env, MatrixGame):
        raise InvalidParameter(
            f"voi: 'exact' needs a matrix game (rewards a known function of the joint "
            f"action), got {type(env).__name__}; use voi='learned'"
        )
    if env.obs_dim > MAX_OBS_BITS:
        raise InvalidParameter(
            f"voi: 'exact' tabulates 2^obs_dim states, obs_dim {env.obs_dim} > {MAX_OBS_BITS}"
        )


@dataclasses.dataclass(frozen=True)
class GameTables:
    """A matrix game's rules as tables over the joint action j = Σ_k a_k A^k."""

    rewards: np.ndarray  # float32 [A^N, N]
    next_codes: np.ndarray  # int32 [A^N]: state code of the observation after the step
    success: np.ndarray  # bool [A^N]
    first_code: int  # state code of the first observation


def joint_actions(num_agents: int, num_actions: int) -> np.ndarray:
    """int32 [A^N, N]: joint action j's per-agent actions (agent k is digit k of j)."""
    index = np.arange(num_actions**num_agents)
    return ((index[:, None] // num_actions ** np.arange(num_agents)) % num_actions).astype(np.int32)


def game_tables(env: MatrixGame) -> GameTables:
    """Tabulates `env.step` over every joint action (a matrix game's step depends on the
    joint action only), at trace time."""
    joints = joint_actions(env.num_agents, env.num_actions)
    key = jax.random.PRNGKey(0)  # matrix games are deterministic
    with jax.ensure_compile_time_eval():
        obs, state = env.reset(key)
        next_obs, _, rewards, _, info = jax.vmap(env.step, in_axes=(None, None, 0))(
            key, state, jnp.asarray(joints)
        )
        return GameTables(
            rewards=np.asarray(rewards, np.float32),
            next_codes=np.asarray(state_codes(next_obs), np.int32),
            success=np.asarray(info["success"], bool),
            first_code=int(state_codes(obs)),
        )


def state_codes(obs: jax.Array) -> jax.Array:
    """int32 [...] state code of agent 0's binary observation: obs [..., N, obs_dim]."""
    bits = jnp.round(obs[..., 0, :]).astype(jnp.int32)
    return jnp.sum(bits << jnp.arange(obs.shape[-1], dtype=jnp.int32), axis=-1)


def init_frequencies(env, history: int) -> ActionFrequencies:
    states, n, a = 2**env.obs_dim, env.num_agents, env.num_actions
    return ActionFrequencies(
        probs=jnp.full((states, n, a), 1.0 / a, jnp.float32),
        counts=jnp.zeros((history, states, n, a), jnp.float32),
    )


def store_and_refit(
    freqs: ActionFrequencies,
    codes: jax.Array,
    actions: jax.Array,
    valid: jax.Array,
    slot: jax.Array,
    due: jax.Array,
) -> ActionFrequencies:
    """Stores this batch's visits in ring slot `slot`; when `due`, re-estimates p̂.

    Args:
        codes: int [S] state codes; actions: int [S, N]; valid: bool [S].
    """
    num_states, _, num_actions = freqs.probs.shape
    one_hot = jax.nn.one_hot(actions, num_actions, dtype=jnp.float32) * valid[:, None, None]
    batch = jax.ops.segment_sum(one_hot, codes, num_segments=num_states)  # [K, N, A]
    counts = freqs.counts.at[slot].set(batch)
    total = counts.sum(axis=0)
    visits = total.sum(axis=-1, keepdims=True)
    estimate = jnp.where(visits > 0, total / jnp.maximum(visits, 1.0), freqs.probs)
    return ActionFrequencies(probs=jnp.where(due, estimate, freqs.probs), counts=counts)


def value_of_influence(
    probs: jax.Array, rewards: np.ndarray, codes: jax.Array, actions: jax.Array
) -> jax.Array:
    """VoI(j → i) for every ordered pair, zero on the diagonal.

    Args:
        probs: [K, N, A] p̂; rewards: [A^N, N] (`GameTables.rewards`); codes: int [...];
        actions: int [..., N].
    Returns:
        [..., N influencer j, N influenced i].
    """
    num_states, n, a = probs.shape
    place = jnp.asarray(a ** np.arange(n), jnp.int32)  # [N]
    joint = jnp.sum(actions * place, axis=-1)  # [...]
    rewards = jnp.asarray(rewards)
    actual = rewards[joint]  # [..., N i]
    # joint index with agent j's action replaced by a': [..., N j, A a']
    swapped = (joint[..., None, None] - (actions * place)[..., :, None]) + (
        place[:, None] * jnp.arange(a, dtype=jnp.int32)[None, :]
    )
    alternative = rewards[swapped]  # [..., N j, A, N i]
    p = probs[codes]  # [..., N j, A]
    baseline = jnp.sum(p[..., None] * alternative, axis=-2)  # [..., N j, N i]
    voi = actual[..., None, :] - baseline
    return voi * (1.0 - jnp.eye(n, dtype=voi.dtype))
