"""Strategy manipulations of one agent (the adversary), as frozen configs with hooks.

A learner consults its attack at a few named points; an attack overrides only
the hooks of its lever (spec/attacks.md):

* `act`              — the joint action actually played (bypass);
* `emit`             — the incentives actually emitted: returns a per-giver
                       scale of the learned incentives and a constant offset
                       (fake incentive, ADMO's budget);
* `learning_rewards` — the reward the adversary's own policy step uses (self-centered);
* `policy_sign`      — +1 ascends, −1 descends, 0 freezes an agent's actual
                       policy step (reverse; ADMO, which updates the adversary itself).

Everything the other agents *model* of the adversary (LIO's meta-gradient
through every recipient's update) stays the ordinary learner: only the
adversary's actual behaviour changes. No learner is copied per attack.
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import jax
import jax.numpy as jnp


@dataclasses.dataclass(frozen=True)
class Attack:
    """No manipulation; the base of every attack (all hooks are the identity)."""

    adversary: int = 0
    """Index of the manipulated agent."""

    name: ClassVar[str] = "none"
    lever: ClassVar[str] = "none"
    needs_incentives: ClassVar[bool] = False
    """True when the attack only makes sense for a learner with an incentive channel."""

    def validate(self, num_agents: int) -> None:
        """Raises InvalidParameter naming the bad field."""
        from pimbot.envs.core import InvalidParameter

        if isinstance(self.adversary, bool) or not isinstance(self.adversary, int):
            raise InvalidParameter(f"adversary: must be an integer, got {self.adversary!r}")
        if not 0 <= self.adversary < num_agents:
            raise InvalidParameter(
                f"adversary: must be an agent index in [0, {num_agents - 1}], got {self.adversary}"
            )

    def is_adversary(self, num_agents: int) -> jax.Array:
        """bool [N], True at the adversary."""
        return jnp.arange(num_agents) == self.adversary

    def act(self, actions: jax.Array, idle_action: int, env_step: jax.Array) -> jax.Array:
        """The joint action played. `env_step`: environment steps taken so far in training."""
        del idle_action, env_step
        return actions

    def emit(self, num_agents: int, given_so_far: jax.Array) -> tuple[jax.Array, jax.Array]:
        """(scale [N], offset [N, N]): emitted[i, j] = scale[i] · learned[i, j] + offset[i, j].

        Args:
            given_so_far: [N, N] incentives emitted earlier in this episode.
        """
        del given_so_far
        return jnp.ones((num_agents,)), jnp.zeros((num_agents, num_agents))

    def learning_rewards(self, env_rewards: jax.Array, received: jax.Array) -> jax.Array:
        """[T, N] rewards of every agent's actual policy step (env + received by default)."""
        return env_rewards + received

    def policy_sign(self, num_agents: int) -> jax.Array:
        """[N] sign of every agent's actual policy step."""
        return jnp.ones((num_agents,))


@dataclasses.dataclass(frozen=True)
class SelfCentered(Attack):
    """Partial communication: the adversary's own policy step ignores incentives received.

    It still gives incentives and still trains its incentive function.
    """

    name: ClassVar[str] = "self_centered"
    lever: ClassVar[str] = "incentive"
    needs_incentives: ClassVar[bool] = True

    def learning_rewards(self, env_rewards, received):
        is_adv = self.is_adversary(env_rewards.shape[-1])
        return env_rewards + jnp.where(is_adv, 0.0, received)


@dataclasses.dataclass(frozen=True)
class FakeIncentive(Attack):
    """The adversary emits a constant C to every other agent every step, ignoring [0, R_max]."""

    amount: float = 50.0
    """C, the fake incentive per step and recipient (paper: 50; original code: 10)."""

    name: ClassVar[str] = "fake_incentive"
    lever: ClassVar[str] = "incentive"
    needs_incentives: ClassVar[bool] = True

    def validate(self, num_agents: int) -> None:
        super().validate(num_agents)
        _check_number("amount", self.amount)

    def emit(self, num_agents, given_so_far):
        del given_so_far
        is_adv = self.is_adversary(num_agents)
        scale = jnp.where(is_adv, 0.0, 1.0)
        others = 1.0 - jnp.eye(num_agents)
        offset = jnp.where(is_adv[:, None], self.amount * others, 0.0)
        return scale, offset


@dataclasses.dataclass(frozen=True)
class Bypass(Attack):
    """No-op: the adversary always takes the environment's idle action.

    With `toggle_period` K it alternates K environment steps of bypass and K of
    normal play (the original "toggle", K = 1000). It keeps giving and learning
    incentives.
    """

    toggle_period: int = 0
    """K > 0: alternate bypass and normal play every K environment steps; 0: always bypass."""

    name: ClassVar[str] = "bypass"
    lever: ClassVar[str] = "policy"

    def validate(self, num_agents: int) -> None:
        from pimbot.envs.core import InvalidParameter

        super().validate(num_agents)
        if isinstance(self.toggle_period, bool) or not isinstance(self.toggle_period, int):
            raise InvalidParameter(
                f"toggle_period: must be an integer ≥ 0, got {self.toggle_period!r}"
            )
        if self.toggle_period < 0:
            raise InvalidParameter(
                f"toggle_period: must be an integer ≥ 0, got {self.toggle_period}"
            )

    def active(self, env_step: jax.Array) -> jax.Array:
        if self.toggle_period == 0:
            return jnp.array(True)
        return (env_step // self.toggle_period) % 2 == 0

    def act(self, actions, idle_action, env_step):
        bypassing = self.is_adversary(actions.shape[0]) & self.active(env_step)
        return jnp.where(bypassing, idle_action, actions).astype(actions.dtype)


@dataclasses.dataclass(frozen=True)
class Reverse(Attack):
    """Reward flip: the adversary's actual policy step descends its own return.

    The sign of its whole policy loss, entropy term included, is flipped; the
    others still model it as ascending.
    """

    name: ClassVar[str] = "reverse"
    lever: ClassVar[str] = "policy"

    def policy_sign(self, num_agents):
        return jnp.where(self.is_adversary(num_agents), -1.0, 1.0)


def _check_number(name: str, value) -> None:
    from pimbot.envs.core import InvalidParameter

    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InvalidParameter(f"{name}: must be a number, got {value!r}")
    if not math.isfinite(value):
        raise InvalidParameter(f"{name}: must be a finite number, got {value!r}")
