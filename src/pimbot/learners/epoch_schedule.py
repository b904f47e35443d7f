"""Full-batch Adam epochs with a per-agent epoch count (an attack's `update_schedule`).

The Reciprocator's ordinary PPO runs `ppo_epochs` Adam steps of one loss summed over
agents, with one Adam state over the stacked parameters. Every agent's rows of the
parameters get the gradient of its own loss term only, and Adam is elementwise, so
agent i's rows evolve as if it were trained alone, except for Adam's step count, which
is shared. A schedule gives every agent its own count of epochs: here the Adam state is
kept per agent (`init`: the count too is [N]), a static `most` epochs are run, and
after epoch e only the agents with e < epochs[i] take the new parameter and optimizer
rows. An agent scheduled k epochs thus ends where the ordinary update with
`ppo_epochs = k` would have left it (up to the order of floating-point operations).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax


def init(lr: float, params) -> optax.OptState:
    """Adam states per agent of stacked parameters (leaves [N, ...], the count [N])."""
    return jax.vmap(optax.adam(lr).init)(params)


def run(grad_fn: Callable, lr: float, params, opt: optax.OptState, epochs: jax.Array, most: int):
    """`most` full-batch Adam steps of `grad_fn`, agent i keeping its first `epochs[i]`.

    Args:
        grad_fn: stacked params -> their gradient (leaves [N, ...]); opt: from `init`;
        epochs: int [N]; most: static, ≥ max(epochs).
    Returns:
        (params, opt).
    """
    optimizer = optax.adam(lr)

    def keep_rows(take, new, old):
        return jnp.where(take.reshape(take.shape + (1,) * (new.ndim - 1)), new, old)

    def epoch(carry, e):
        params, opt = carry
        updates, new_opt = jax.vmap(optimizer.update)(grad_fn(params), opt, params)
        new_params = optax.apply_updates(params, updates)
        take = e < epochs
        keep = lambda new, old: keep_rows(take, new, old)  # noqa: E731
        return (jax.tree.map(keep, new_params, params), jax.tree.map(keep, new_opt, opt)), None

    (params, opt), _ = jax.lax.scan(epoch, (params, opt), jnp.arange(most))
    return params, opt
