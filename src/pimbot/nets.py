"""Policy and incentive MLPs, with parameters stacked along a leading agent axis.

Every agent owns its own network; the N copies are stored as one pytree whose
leaves have a leading axis of size N, so all agents run in one vmapped call.
Kernels use Glorot-uniform initialisation and zero biases, as TensorFlow 1's
`tf.layers.dense` did in the original LIO code.
"""

from __future__ import annotations

from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp


class MLP(nn.Module):
    """ReLU hidden layers and a linear output layer."""

    hidden: Sequence[int]
    out_dim: int
    out_bias: bool = True

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        init = nn.initializers.glorot_uniform()
        for width in self.hidden:
            x = nn.relu(nn.Dense(width, kernel_init=init)(x))
        return nn.Dense(self.out_dim, use_bias=self.out_bias, kernel_init=init)(x)


def init_stacked(module: nn.Module, key: jax.Array, num_agents: int, in_dim: int):
    """Parameters of `num_agents` independent copies of `module`, stacked on axis 0."""
    keys = jax.random.split(key, num_agents)
    dummy = jnp.zeros((in_dim,), jnp.float32)
    return jax.vmap(lambda k: module.init(k, dummy))(keys)


def apply_stacked(module: nn.Module, params, x: jax.Array) -> jax.Array:
    """Applies agent i's network to x[i]: x [N, ..., in_dim] -> [N, ..., out_dim]."""
    return jax.vmap(module.apply)(params, x)


def policy_module(hidden: Sequence[int], num_actions: int) -> MLP:
    """The softmax policy's logit network."""
    return MLP(tuple(hidden), num_actions)


def incentive_module(hidden: Sequence[int], num_agents: int) -> MLP:
    """The incentive network: one pre-sigmoid output per agent, no output bias (as LIO)."""
    return MLP(tuple(hidden), num_agents, out_bias=False)


def mixed_log_probs(logits: jax.Array, epsilon: jax.Array | float) -> jax.Array:
    """log of the ε-mixed distribution (1 − ε)·softmax(logits) + ε/|A|, stably.

    Args:
        logits: [..., A].
        epsilon: exploration weight in [0, 1].
    Returns:
        [..., A] log-probabilities.
    """
    num_actions = logits.shape[-1]
    log_softmax = jax.nn.log_softmax(logits)
    return jnp.logaddexp(jnp.log1p(-epsilon) + log_softmax, jnp.log(epsilon / num_actions))
