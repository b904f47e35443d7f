"""`epsilon_random`: the adversary plays a uniformly random action with probability ε.

Hook: `act`, the joint action actually played. The learner's own actions are
sampled first; at the adversary's entry a coin with P(heads) = ε replaces its
action by one drawn uniformly from the env's actions. Both draws use the hook's
own key (derived from the learner's key without consuming it), so ε = 0 plays
exactly the clean run. Everything the others model of the adversary, and its own
learning, stays the ordinary learner's: only what it does in the env changes.

    pimbot attacks --plugin examples/plugins/epsilon_random.py
    pimbot train escape_room-v0 --plugin examples/plugins/epsilon_random.py \
        --attack epsilon_random --ap epsilon=0.3 --out runs/eps
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp
from flax import struct

from pimbot.attacks import Attack, register
from pimbot.contracts.params import check_number


@register
@struct.dataclass
class EpsilonRandom(Attack):
    """ε-random adversary: with probability ε it plays a uniformly random action."""

    epsilon: float = 0.1
    """Probability of a uniformly random action at each step."""

    name: ClassVar[str] = "epsilon_random"
    lever: ClassVar[str] = "policy"
    hooks: ClassVar[tuple[str, ...]] = ("act",)

    def validate(self, num_agents: int) -> None:
        super().validate(num_agents)
        check_number("epsilon", self.epsilon, low=0.0, high=1.0)

    def act(self, state, key, actions, at):
        del state
        coin_key, action_key = jax.random.split(key)
        random_action = jax.random.randint(action_key, (), 0, at.num_actions, actions.dtype)
        randomised = jax.random.uniform(coin_key) < self.epsilon
        replace = self.is_adversary(actions.shape[0]) & randomised
        return jnp.where(replace, random_action, actions).astype(actions.dtype)
