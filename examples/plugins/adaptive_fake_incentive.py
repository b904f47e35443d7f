"""`adaptive_fake_incentive`: a fake incentive that grows each time the team succeeds.

The adversary sends C to every other agent every step (as `fake_incentive`), but C
lives in its per-seed state: after every iteration the team's running success (an
exponential average) is updated, and each time it exceeds `threshold`, C grows by
`factor` (up to `max_amount`) and the running success restarts from 0, so the next
growth has to be earned again. Hooks: `emit` (what is sent), `observe` (the state).

    pimbot attacks --plugin examples/plugins/adaptive_fake_incentive.py
    pimbot train escape_room-v0 --plugin examples/plugins/adaptive_fake_incentive.py \
        --attack adaptive_fake_incentive --ap factor=2 --ap threshold=0.5 --out runs/adaptive
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
from flax import struct

from pimbot.attacks import Attack, register
from pimbot.contracts.attack import Outcome
from pimbot.contracts.params import check_number


@register
@struct.dataclass
class AdaptiveFakeIncentive(Attack):
    """Fake incentive C that grows by a factor each time the team's running success is high."""

    amount: float = 10.0
    """C at the start, sent per step to every other agent."""
    factor: float = 2.0
    """C ← min(factor · C, max_amount) each time the running success exceeds the threshold."""
    threshold: float = 0.8
    """Running team success above which C grows."""
    smoothing: float = 0.1
    """Weight of the latest iteration in the running success (exponential average)."""
    max_amount: float = 1000.0
    """C never grows beyond this."""

    name: ClassVar[str] = "adaptive_fake_incentive"
    lever: ClassVar[str] = "incentive"
    hooks: ClassVar[tuple[str, ...]] = ("emit", "observe")

    def validate(self, num_agents: int) -> None:
        super().validate(num_agents)
        check_number("amount", self.amount)
        check_number("factor", self.factor, low=1.0)
        check_number("threshold", self.threshold, low=0.0, high=1.0)
        check_number("smoothing", self.smoothing, low=0.0, high=1.0, strict_low=True)
        check_number("max_amount", self.max_amount)

    def init_state(self, key, num_agents, adversary):
        del key, num_agents, adversary
        amount = jnp.asarray(self.amount, jnp.float32)
        return {"amount": amount, "running_success": jnp.zeros((), jnp.float32)}

    def emit(self, state, key, given_so_far):
        del key
        n = given_so_far.shape[0]
        is_adv = self.is_adversary(n)[:, None]
        scale = jnp.broadcast_to(jnp.where(is_adv, 0.0, 1.0), (n, n))
        offset = jnp.where(is_adv, state["amount"] * (1.0 - jnp.eye(n)), 0.0)
        return scale, offset

    def observe(self, state, key, outcome: Outcome):
        del key
        running = (1 - self.smoothing) * state["running_success"]
        running = running + self.smoothing * outcome.success
        high = running > self.threshold
        grown = jnp.minimum(state["amount"] * self.factor, self.max_amount)
        return {
            "amount": jnp.where(high, grown, state["amount"]).astype(jnp.float32),
            "running_success": jnp.where(high, 0.0, running).astype(jnp.float32),
        }
