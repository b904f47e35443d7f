"""Strategy manipulations of one agent (the adversary): frozen pytree configs with hooks.

Each overrides only the hooks of its lever (docs/attacks.md; the hook points
are defined in `pimbot.contracts.attack`):

* `self_centered`  — `learning_rewards`: the adversary's policy step ignores what it receives;
* `fake_incentive` — `emit`: it sends a constant C instead of its learned incentives;
* `bypass`         — `act`: it takes the idle action (always, or toggled every K steps);
* `reverse`        — `policy_sign`: its policy step descends its own return.
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
from flax import struct

from pimbot.contracts.attack import Attack
from pimbot.contracts.params import check_int, check_number


@struct.dataclass
class SelfCentered(Attack):
    """Partial communication: the adversary's own policy step ignores incentives received.

    It still gives incentives and still trains its incentive function. Against a
    Reciprocator the "received" part is its reciprocal reward: it learns as a naive learner.
    """

    name: ClassVar[str] = "self_centered"
    lever: ClassVar[str] = "incentive"
    hooks: ClassVar[tuple[str, ...]] = ("learning_rewards",)

    def learning_rewards(self, state, env_rewards, received):
        del state
        is_adv = self.is_adversary(env_rewards.shape[-1])
        return env_rewards + jnp.where(is_adv, 0.0, received)


@struct.dataclass
class FakeIncentive(Attack):
    """The adversary emits a constant C to every other agent every step, ignoring [0, R_max]."""

    amount: float = 50.0
    """C, the fake incentive per step and recipient (paper: 50; original code: 10)."""

    name: ClassVar[str] = "fake_incentive"
    lever: ClassVar[str] = "incentive"
    hooks: ClassVar[tuple[str, ...]] = ("emit",)

    def validate(self, num_agents: int) -> None:
        super().validate(num_agents)
        check_number("amount", self.amount)

    def emit(self, state, key, given_so_far):
        del state, key
        n = given_so_far.shape[0]
        is_adv = self.is_adversary(n)[:, None]
        scale = jnp.broadcast_to(jnp.where(is_adv, 0.0, 1.0), (n, n))
        offset = jnp.where(is_adv, self.amount * (1.0 - jnp.eye(n)), 0.0)
        return scale, offset


@struct.dataclass
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
    hooks: ClassVar[tuple[str, ...]] = ("act",)

    def validate(self, num_agents: int) -> None:
        super().validate(num_agents)
        check_int("toggle_period", self.toggle_period, 0)

    def bypassing(self, env_step):
        """bool []: whether the bypass is on at `env_step`."""
        period = self.toggle_period
        return (period == 0) | ((env_step // jnp.maximum(period, 1)) % 2 == 0)

    def act(self, state, key, actions, at):
        del state, key
        bypassing = self.is_adversary(actions.shape[0]) & self.bypassing(at.env_step)
        return jnp.where(bypassing, at.idle_action, actions).astype(actions.dtype)


@struct.dataclass
class Reverse(Attack):
    """Reward flip: the adversary's actual policy step descends its own return.

    The sign of its whole policy loss, entropy term included, is flipped; the
    others still model it as ascending.
    """

    name: ClassVar[str] = "reverse"
    lever: ClassVar[str] = "policy"
    hooks: ClassVar[tuple[str, ...]] = ("policy_sign",)

    def policy_sign(self, state, num_agents):
        del state
        return jnp.where(self.is_adversary(num_agents), -1.0, 1.0)
