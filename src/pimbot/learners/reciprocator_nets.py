"""The Reciprocator's policy and value networks: what they see, their policy head, their init.

Three choices, each a config field (`ReciprocatorConfig`), the first value pimbot's
general agent and the second the original IPD agent's (johnlyzhou/reciprocator,
`src/agents/matrix_games/matrix_components.py`, `src/environments/ipd.py`):

* `net_input`: "observation" (the environment's observation) or "previous_actions"
  (matrix games: every agent's previous action as a number in id order, (−1, 0, …, 0)
  at the first step; the original's IPD state, 2 numbers, (−1, 0) at reset);
* `policy_head`: "softmax" (one logit per action) or "sigmoid" (two actions: one
  logit z with p(action 1) = σ(z), the original's Bernoulli actor; returned as the
  logits [0, z], so every consumer still takes a softmax);
* `net_init`: "glorot" (flax's Glorot-uniform kernels, zero biases) or
  "fan_in_uniform" (kernels and biases uniform in ±1/√fan_in, PyTorch's `nn.Linear`
  default, which the original uses).

With the first values the networks are `nets.MLP` itself, drawn as before.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from flax import linen as nn

from pimbot import nets
from pimbot.learners import exact_voi

NET_INPUTS = ("observation", "previous_actions")
POLICY_HEADS = ("softmax", "sigmoid")
NET_INITS = ("glorot", "fan_in_uniform")


class EncodedNet(nn.Module):
    """`nets.MLP` on a matrix game's state encoded as a fixed row per reachable state,
    optionally with the one-logit (sigmoid) head."""

    hidden: Sequence[int]
    out_dim: int
    """Outputs: the number of actions (policy) or 1 (value)."""
    sigmoid_head: bool = False
    """Two actions from one logit z: outputs [0, z]."""
    codes: tuple[int, ...] | None = None
    """The reachable states' codes (`exact_voi.GameTables.states`); None: no encoding."""
    rows: tuple[tuple[float, ...], ...] | None = None
    """The network input of each reachable state, in the order of `codes`."""

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        x = obs
        if self.codes is not None:
            state = exact_voi.row_codes(obs)[..., None] == jnp.asarray(self.codes, jnp.int32)
            x = state.astype(jnp.float32) @ jnp.asarray(self.rows, jnp.float32)
        if self.sigmoid_head:
            z = nets.MLP(tuple(self.hidden), 1)(x)
            return jnp.concatenate([jnp.zeros_like(z), z], axis=-1)
        return nets.MLP(tuple(self.hidden), self.out_dim)(x)


def modules(
    env, hidden: Sequence[int], net_input: str, policy_head: str
) -> tuple[nn.Module, nn.Module]:
    """(policy, value) modules; the general choices give `nets.MLP` unchanged."""
    if net_input == "observation" and policy_head == "softmax":
        return nets.policy_module(hidden, env.num_actions), nets.MLP(tuple(hidden), 1)
    codes = rows = None
    if net_input == "previous_actions":
        tables = exact_voi.game_tables(env)
        codes = tuple(int(c) for c in tables.states)
        rows = tuple(tuple(float(v) for v in row) for row in previous_actions_rows(tables))
    return (
        EncodedNet(tuple(hidden), env.num_actions, policy_head == "sigmoid", codes, rows),
        EncodedNet(tuple(hidden), 1, False, codes, rows),
    )


def previous_actions_rows(tables: exact_voi.GameTables) -> np.ndarray:
    """float32 [K, N]: each reachable state's previous joint action, (−1, 0, …, 0) for the
    first state (the original IPD agent's state vector, generalized to N agents)."""
    joints = exact_voi.joint_actions(tables.rewards.shape[1], tables.alternative.shape[2])
    rows = np.zeros((len(tables.states), joints.shape[1]), np.float32)
    rows[tables.next_states] = joints
    rows[tables.first_state] = 0.0
    rows[tables.first_state, 0] = -1.0
    return rows


def fan_in_uniform(key: jax.Array, params):
    """Redraws every Dense layer of stacked parameters (leaves [N, ...]): kernel [N, in,
    out] and bias [N, out] uniform in ±1/√in (PyTorch's `nn.Linear` default)."""
    count = [0]

    def redraw(tree):
        if isinstance(tree, dict) and "kernel" in tree:
            count[0] += 1
            bound = 1.0 / np.sqrt(tree["kernel"].shape[-2])
            k_key, b_key = jax.random.split(jax.random.fold_in(key, count[0]))
            out = dict(tree)
            out["kernel"] = jax.random.uniform(
                k_key, tree["kernel"].shape, tree["kernel"].dtype, -bound, bound
            )
            if "bias" in tree:
                out["bias"] = jax.random.uniform(
                    b_key, tree["bias"].shape, tree["bias"].dtype, -bound, bound
                )
            return out
        if isinstance(tree, dict):
            return {name: redraw(sub) for name, sub in sorted(tree.items())}
        return tree

    return redraw(params)


def init_params(module: nn.Module, key: jax.Array, num_agents: int, in_dim: int, net_init: str):
    """Stacked parameters of `num_agents` copies of `module` under `net_init`."""
    params = nets.init_stacked(module, key, num_agents, in_dim)
    if net_init == "fan_in_uniform":
        params = fan_in_uniform(jax.random.fold_in(key, 1), params)
    return params
