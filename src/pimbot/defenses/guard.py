"""`incentive_guard`: what a recipient accepts of the incentives it is sent.

Three checks, in order, on every (giver, recipient) pair of one episode:

1. clip every per-step value to the honest range [0, R_max];
2. a per-pair per-episode budget: once a giver's clipped incentives to a recipient
   this episode reach `budget_fraction · R_max · T`, the rest is cut;
3. a robust z-score of the episode's mean incentive per step against that giver's
   own recent history (median and MAD of the last `history` episodes); an
   episode scoring above `outlier_z` is dropped for that pair.

Only honest recipients run the guard (a manipulated agent's code is the
attacker's). The counts of clipped, budget-cut and dropped values are metrics.
Everything is jit/vmap-able; the history is a ring buffer in the learner state.
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp
from flax import struct

from pimbot.contracts.defense import Defense, IncentiveContext
from pimbot.contracts.params import check_int, check_number
from pimbot.envs.core import InvalidParameter

MAD_TO_SIGMA = 1.4826  # MAD of a normal distribution × this = its standard deviation


@struct.dataclass
class IncentiveGuard(Defense):
    """Clip received incentives to [0, R_max], cap them per episode, drop outliers."""

    budget_fraction: float = 1.0
    """Per giver, recipient and episode, accept at most budget_fraction · R_max · episode
    length (1.0: the most an honest giver can send, so the budget only stops dishonest ones)."""
    outlier_z: float = 8.0
    """Drop a giver's incentives for an episode when the robust z-score of their mean per
    step against the giver's own history exceeds this; 0 disables the outlier check."""
    history: int = struct.field(pytree_node=False, default=32)
    """Episodes of each giver's history kept for the outlier check."""
    min_history: int = 8
    """Episodes of history needed before outliers are judged."""
    min_scale: float = 0.1
    """Floor of the robust scale, as a fraction of R_max (a giver that always sends the
    same value would otherwise make any change an outlier)."""

    name: ClassVar[str] = "incentive_guard"
    hooks: ClassVar[tuple[str, ...]] = ("learning_incentives",)

    def validate(self, num_agents: int) -> None:
        del num_agents
        check_number("budget_fraction", self.budget_fraction, low=0.0, strict_low=True)
        check_number("outlier_z", self.outlier_z, low=0.0)
        check_number("min_scale", self.min_scale, low=0.0, strict_low=True)
        for name in ("history", "min_history"):
            check_int(name, getattr(self, name), 1)
        if self.min_history > self.history:
            raise InvalidParameter(
                f"min_history: must be ≤ history = {self.history}, got {self.min_history}"
            )

    def init_state(self, num_agents: int, policy) -> dict[str, jax.Array]:
        del policy
        return init_state(self, num_agents)

    def learning_incentives(self, state, ctx: IncentiveContext):
        return apply(self, state, ctx.accepted, ctx.valid, ctx.incentive_max, ctx.honest)


def init_state(guard: IncentiveGuard, num_agents: int) -> dict[str, jax.Array]:
    """Ring buffer of per-episode mean incentives per step [history, giver, recipient]."""
    return {
        "history": jnp.full((guard.history, num_agents, num_agents), jnp.nan, jnp.float32),
        "count": jnp.zeros((), jnp.int32),
    }


def robust_z(value: jax.Array, history: jax.Array, min_scale: float) -> jax.Array:
    """|value − median| / max(1.4826 · MAD, min_scale) per entry.

    Args:
        value: [...]; history: [H, ...] past values, NaN where not yet filled.
    """
    median = jnp.nanmedian(history, axis=0)
    mad = jnp.nanmedian(jnp.abs(history - median), axis=0)
    return jnp.abs(value - median) / jnp.maximum(MAD_TO_SIGMA * mad, min_scale)


def apply(
    guard: IncentiveGuard,
    state: dict[str, jax.Array],
    incentives: jax.Array,
    valid: jax.Array,
    incentive_max: float,
    honest: jax.Array,
) -> tuple[jax.Array, dict[str, jax.Array], dict[str, jax.Array]]:
    """The incentives honest recipients accept of one episode.

    Args:
        incentives: [T, N giver, N recipient] as sent (zero on invalid steps).
        valid: bool [T].
        incentive_max: R_max of honest incentives.
        honest: bool [N], recipients that run the guard.
    Returns:
        (accepted [T, N, N] — unchanged in the columns of recipients that do not
        guard —, new state, metrics: counts of clipped, budget-cut and dropped values).
    """
    steps = incentives.shape[0]
    mask = valid.astype(jnp.float32)[:, None, None]
    clipped = jnp.clip(incentives, 0.0, incentive_max) * mask
    budget = guard.budget_fraction * incentive_max * steps
    spent_before = jnp.cumsum(clipped, axis=0) - clipped
    budgeted = jnp.clip(budget - spent_before, 0.0, clipped)

    num_valid = jnp.maximum(mask.sum(axis=0), 1.0)  # [1, 1]
    mean_per_step = budgeted.sum(axis=0) / num_valid  # [giver, recipient]
    z = robust_z(mean_per_step, state["history"], guard.min_scale * incentive_max)
    judged = (guard.outlier_z > 0) & (state["count"] >= guard.min_history)
    outlier = judged & (z > guard.outlier_z)  # [giver, recipient]
    accepted = jnp.where(outlier[None], 0.0, budgeted)

    guarded = honest[None, None, :]
    accepted = jnp.where(guarded, accepted, incentives)
    new_state = {
        "history": jnp.roll(state["history"], 1, axis=0).at[0].set(mean_per_step),
        "count": jnp.minimum(state["count"] + 1, guard.history),
    }
    off_diagonal = 1.0 - jnp.eye(incentives.shape[1])
    counted = guarded * off_diagonal * mask
    metrics = {
        "defense/guard_clipped": jnp.sum(counted * (clipped != incentives)),
        "defense/guard_budget_cut": jnp.sum(counted * (budgeted < clipped)),
        "defense/guard_dropped": jnp.sum(
            honest[None, :] * off_diagonal * outlier * (budgeted.sum(axis=0) > 0)
        ),
    }
    return accepted, new_state, metrics
