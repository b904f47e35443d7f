"""`per_giver_cap`: a recipient accepts at most `cap` from any one giver in any one step.

Hook: `learning_incentives`, what the recipients learn from. Every (step, giver,
recipient) value is cut to `cap` before the recipient's policy step; the incentives
as sent (and what the givers learn) are unchanged. Only honest recipients run it:
the adversary's own code is the attacker's. The number of values cut per
iteration is the metrics.csv column `defense/cap_cut`.

    pimbot defenses --plugin examples/plugins/per_giver_cap.py
    pimbot train escape_room-v0 --plugin examples/plugins/per_giver_cap.py \
        --attack fake_incentive --defense per_giver_cap --defense-param per_giver_cap.cap=1 \
        --out runs/capped
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
from flax import struct

from pimbot.contracts.defense import Defense, IncentiveContext, register
from pimbot.contracts.params import check_number


@register
@struct.dataclass
class PerGiverCap(Defense):
    """Cap what a recipient accepts from any one giver per step."""

    cap: float = 1.0
    """The most a recipient accepts from one giver in one step."""

    name: ClassVar[str] = "per_giver_cap"
    hooks: ClassVar[tuple[str, ...]] = ("learning_incentives",)

    def validate(self, num_agents: int) -> None:
        del num_agents
        check_number("cap", self.cap, low=0.0)

    def learning_incentives(self, state, ctx: IncentiveContext):
        """(accepted [T, N giver, N recipient], state, metrics)."""
        guarded = ctx.honest[None, None, :]  # by recipient
        accepted = jnp.where(guarded, jnp.minimum(ctx.accepted, self.cap), ctx.accepted)
        cut = jnp.sum((accepted < ctx.accepted) * ctx.valid[:, None, None])
        return accepted, state, {"defense/cap_cut": cut.astype(jnp.float32)}
