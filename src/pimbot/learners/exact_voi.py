"""Exact value of influence on matrix games (the original Reciprocator's IPD agent).

In a matrix game every reward is a known function of the joint action, so the
value of influence needs no learned models (docs/reciprocators.md; the
original's `MatrixVOI`):

    VoI(j → i, t) = r_i(a_t) − Σ_{a'} p̂_j(a' | s_t) · r_i(a', a_{−j, t}),

where p̂_j(· | s) is agent j's empirical action frequency in state s over the
last `history` batches, refreshed every `refit_period` iterations (the
original: the last 1 batch, every 3). The VoI is the reward term only, as in
the original's matrix agent (it argues that the future values cancel).

States are the reachable values of the (binary, shared) observation, found by
tabulating the game (`game_tables`) and indexed densely; per-sample work uses
one-hot states and small matrix products rather than gathers and scatters (fast
under the seed vmap). A state not visited in the stored batches keeps its
previous estimate, uniform at the start (the original starts at p = 0.5, and
would produce NaN there).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from pimbot.envs.core import InvalidParameter
from pimbot.envs.matrix_games import MatrixGame

MAX_OBS_BITS = 30
"""Largest observation size whose state codes fit an int32."""


@struct.dataclass
class ActionFrequencies:
    probs: jax.Array  # float32 [K, N, A]: p̂_j(a | s) per reachable state, the estimate in use
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
            f"voi: 'exact' codes observations as integers, obs_dim {env.obs_dim} > {MAX_OBS_BITS}"
        )


@dataclasses.dataclass(frozen=True)
class GameTables:
    """A matrix game's rules as tables over its reachable states (dense index k, in the
    order of their codes) and the joint action j = Σ_m a_m A^m."""

    states: np.ndarray  # int32 [K]: the reachable state codes, sorted
    state_obs: np.ndarray  # float32 [K, obs_dim]: each state's observation
    first_state: int  # dense index of the first observation
    next_states: np.ndarray  # int32 [J]: dense state after joint action j
    rewards: np.ndarray  # float32 [J, N]
    success: np.ndarray  # bool [J]
    alternative: np.ndarray  # float32 [J, N m, A a', N i]: r_i with agent m's action := a'


def joint_actions(num_agents: int, num_actions: int) -> np.ndarray:
    """int32 [A^N, N]: joint action j's per-agent actions (agent m is digit m of j)."""
    index = np.arange(num_actions**num_agents)
    return ((index[:, None] // num_actions ** np.arange(num_agents)) % num_actions).astype(np.int32)


def game_tables(env: MatrixGame) -> GameTables:
    """Tabulates `env.step` over every joint action (a matrix game's step depends on the
    joint action only), at trace time. A program's init, update and evaluation each ask
    for the tables: they are made once per env and process (one small compiled call),
    and their arrays are read-only."""
    try:
        return _cached_tables(env)
    except TypeError:  # an unhashable env (a plugin's): tabulated on every call
        return _tabulate(env)


@functools.lru_cache(maxsize=64)
def _cached_tables(env: MatrixGame) -> GameTables:
    return _tabulate(env)


def _play_every_joint_action(env: MatrixGame, joints: jax.Array):
    key = jax.random.PRNGKey(0)  # matrix games are deterministic
    obs, state = env.reset(key)
    next_obs, _, rewards, _, info = jax.vmap(env.step, in_axes=(None, None, 0))(key, state, joints)
    return state_codes(obs), state_codes(next_obs), obs[0], next_obs[:, 0], rewards, info


def _tabulate(env: MatrixGame) -> GameTables:
    n, a = env.num_agents, env.num_actions
    joints = joint_actions(n, a)
    with jax.ensure_compile_time_eval():  # may be called while a program is traced
        played = jax.jit(functools.partial(_play_every_joint_action, env))(jnp.asarray(joints))
    first, after, first_obs, after_obs, rewards, info = jax.device_get(played)  # numpy
    first, rewards = int(first), np.asarray(rewards, np.float32)
    success = np.asarray(info["success"], bool)
    states = np.unique(np.append(after, first)).astype(np.int32)
    state_obs = np.zeros((len(states), env.obs_dim), np.float32)
    state_obs[np.searchsorted(states, after)] = after_obs
    state_obs[np.searchsorted(states, first)] = first_obs
    place = a ** np.arange(n)
    swapped = (
        np.arange(len(joints))[:, None, None]
        - (joints * place)[:, :, None]
        + place[None, :, None] * np.arange(a)[None, None, :]
    )  # [J, N m, A]
    tables = GameTables(
        states=states,
        state_obs=state_obs,
        first_state=int(np.searchsorted(states, first)),
        next_states=np.searchsorted(states, after).astype(np.int32),
        rewards=rewards,
        success=success,
        alternative=rewards[swapped],
    )
    for field in dataclasses.fields(tables):  # shared between callers: never written
        value = getattr(tables, field.name)
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
    return tables


def row_codes(obs: jax.Array) -> jax.Array:
    """int32 [...] state code Σ_d obs_d 2^d of one agent's binary observation [..., obs_dim]."""
    bits = jnp.round(obs).astype(jnp.int32)
    return jnp.sum(bits << jnp.arange(obs.shape[-1], dtype=jnp.int32), axis=-1)


def state_codes(obs: jax.Array) -> jax.Array:
    """int32 [...] state code of agent 0's binary observation [..., N, obs_dim]."""
    return row_codes(obs[..., 0, :])


def state_one_hot(obs: jax.Array, tables: GameTables) -> jax.Array:
    """float32 [..., K]: the one-hot dense state of observations [..., N, obs_dim]."""
    codes = state_codes(obs)
    return (codes[..., None] == jnp.asarray(tables.states)).astype(jnp.float32)


def joint_index(actions: jax.Array, num_actions: int) -> jax.Array:
    """int32 [...]: joint action index of actions int [..., N]."""
    place = jnp.asarray(num_actions ** np.arange(actions.shape[-1]), jnp.int32)
    return jnp.sum(actions * place, axis=-1)


def init_frequencies(env, history: int) -> ActionFrequencies:
    states, n, a = len(game_tables(env).states), env.num_agents, env.num_actions
    return ActionFrequencies(
        probs=jnp.full((states, n, a), 1.0 / a, jnp.float32),
        counts=jnp.zeros((history, states, n, a), jnp.float32),
    )


def store_and_refit(
    freqs: ActionFrequencies,
    states: jax.Array,
    actions: jax.Array,
    valid: jax.Array,
    slot: jax.Array,
    due: jax.Array,
) -> ActionFrequencies:
    """Stores this batch's visits in ring slot `slot`; when `due`, re-estimates p̂.

    Args:
        states: float [S, K] one-hot dense states; actions: int [S, N]; valid: bool [S].
    """
    num_actions = freqs.probs.shape[-1]
    one_hot = jax.nn.one_hot(actions, num_actions, dtype=jnp.float32) * valid[:, None, None]
    batch = jnp.einsum("sk,sna->kna", states, one_hot)  # [K, N, A]
    counts = freqs.counts.at[slot].set(batch)
    total = counts.sum(axis=0)
    visits = total.sum(axis=-1, keepdims=True)
    estimate = jnp.where(visits > 0, total / jnp.maximum(visits, 1.0), freqs.probs)
    return ActionFrequencies(probs=jnp.where(due, estimate, freqs.probs), counts=counts)


def value_of_influence(
    probs: jax.Array, tables: GameTables, states: jax.Array, actions: jax.Array
) -> jax.Array:
    """VoI(j → i) for every ordered pair, zero on the diagonal.

    Args:
        probs: [K, N, A] p̂; states: float [..., K] one-hot dense states; actions: int [..., N].
    Returns:
        [..., N influencer j, N influenced i].
    """
    num_states, n, a = probs.shape
    joint = joint_index(actions, a)
    actual = jnp.asarray(tables.rewards)[joint]  # [..., N i]
    alternative = jnp.asarray(tables.alternative)[joint]  # [..., N j, A, N i]
    p = (states @ probs.reshape(num_states, n * a)).reshape(states.shape[:-1] + (n, a))
    baseline = jnp.einsum("...ja,...jai->...ji", p, alternative)
    voi = actual[..., None, :] - baseline
    return voi * (1.0 - jnp.eye(n, dtype=voi.dtype))
