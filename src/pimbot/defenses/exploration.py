"""`exploration_floor`: a minimum ε that received incentives cannot push below.

LIO acts (and takes its policy step) with the ε-mixed policy (1 − ε)·π + ε/|A|.
Incentives can drive the softmax π to a point mass, but not the mixing: with
the floor, every honest agent keeps ε ≥ `min_epsilon`, so each action keeps a
probability ≥ min_epsilon/|A| in training however large the incentives are.
Evaluation (ε = 0) is unchanged.
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp
from flax import struct

from pimbot.contracts.defense import Defense, EpsilonContext
from pimbot.contracts.params import check_number


@struct.dataclass
class ExplorationFloor(Defense):
    """Keep every honest agent's exploration weight ε at or above a floor."""

    min_epsilon: float = 0.2
    """The floor on ε of honest agents' acting policy (ER's schedule ends at 0.1, IPD's at 0.01)."""

    name: ClassVar[str] = "exploration_floor"
    hooks: ClassVar[tuple[str, ...]] = ("acting_epsilon",)

    def validate(self, num_agents: int) -> None:
        del num_agents
        check_number("min_epsilon", self.min_epsilon, low=0.0, high=1.0, strict_low=True)

    def acting_epsilon(self, state, ctx: EpsilonContext) -> jax.Array:
        del state
        return floored_epsilon(self, ctx.epsilon, ctx.honest)


def floored_epsilon(floor: ExplorationFloor, epsilon: jax.Array, honest: jax.Array) -> jax.Array:
    """Per-agent ε [N]: max(ε, min_epsilon) for honest agents, ε for the others."""
    return jnp.where(honest, jnp.maximum(epsilon, floor.min_epsilon), epsilon).astype(jnp.float32)
