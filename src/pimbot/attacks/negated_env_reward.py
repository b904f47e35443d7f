"""`negated_env_reward` — the adversary learns on its env reward negated, otherwise ordinary.

This is what the published PIMbot code's Stag Hunt "ADMO" does to the adversary
(`lio/alg/train_lio_staghunt_admo.py` of UCR-Intelligent-Robotics-Lab/greedy_agent,
`run_episode`: in its "adversarial" mode the adversary's env reward is negated as each
step is recorded, before anything learns from it; docs/attacks.md). The paper's ADMO
(`admo`, Alg. 1) is a different attack: a loss of its own with a budget and a reference
policy. Here the adversary

* takes LIO's ordinary policy step on −r_env + incentives received (`learning_rewards`;
  against the Reciprocator, −r_env + its reciprocal reward);
* takes LIO's ordinary incentive step — Adam ascent on its surrogate through the
  recipients' updates, then Adam descent on its cost — with −r_env in place of its env
  return on τ̂ (`adversary_step`; the meta-gradient is the learner's own second-order
  pass, `AdversaryView.meta_pullback`). Adam is elementwise, so the attack's own Adam
  states for the adversary's row behave as the adversary's row of the learner's.

What it leaves as in the code: the others learn from the env as it is and model the
adversary as the ordinary learner; evaluation episodes score true env rewards (the code's
`evaluate.test_staghunt` plays its own episodes, where nothing is negated).

Differences to the code, each named:
* the code's script also runs its ADMO scheduler of extra ordinary steps (`admo_code`,
  `AdaptiveMOController.step`) on top of the negation; this attack isolates the negation;
* in the code the other givers' model of the adversary's update reads the same
  negated buffer; here they model the ordinary learner (the attack contract);
* the cost term of the adversary's incentive step is measured on τ̂ (LIO: on τ) and
  on the emitted incentives (LIO: the raw sigmoid outputs; Adam is scale-invariant);
* N ≥ 3 with LIO's "shared" incentive updates: the adversary's step moves only its
  own η_a (as `admo_code`).
`lr_incentive`, `lr_cost` must equal the learner's (defaults: LIO's Stag Hunt column,
the original `config_staghunt_lio.py`).
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp
import optax
from flax import struct

from pimbot.contracts.attack import AdversaryView, AgentParams, Attack, agent_row, incentive_channel
from pimbot.contracts.params import check_number
from pimbot.contracts.rollout import discounted_returns


def negated_for(attack: Attack, env_rewards: jax.Array) -> jax.Array:
    """[..., N] env rewards with the adversary's column negated, the others' as they are."""
    return jnp.where(attack.is_adversary(env_rewards.shape[-1]), -env_rewards, env_rewards)


@struct.dataclass
class NegatedEnvReward(Attack):
    """The code's Stag Hunt ADMO: the adversary's own learning sees −r_env; nothing else."""

    lr_incentive: float = 1e-3
    """The learner's Adam rate of the incentive (meta-gradient) step (LIO: 1e-3)."""
    lr_cost: float = 1e-4
    """The learner's Adam rate of the separate cost step (LIO Stag Hunt: 1e-4; 0: no move)."""

    name: ClassVar[str] = "negated_env_reward"
    lever: ClassVar[str] = "reward (the adversary's own learning)"
    hooks: ClassVar[tuple[str, ...]] = ("learning_rewards", "adversary_step")

    def validate(self, num_agents: int) -> None:
        super().validate(num_agents)
        for name in ("lr_incentive", "lr_cost"):
            check_number(name, getattr(self, name), low=0.0)

    def optimizers(self) -> tuple[optax.GradientTransformation, optax.GradientTransformation]:
        """(meta-gradient Adam, cost Adam), as LIO's."""
        return optax.adam(self.lr_incentive), optax.adam(self.lr_cost)

    def init_state(self, key, num_agents, adversary: AgentParams):
        """The Adam states of the adversary's incentive steps ({} without an incentive
        channel: the Reciprocator has no η)."""
        del key, num_agents
        if not jax.tree.leaves(adversary.incentive):
            return {}
        meta, cost = self.optimizers()
        return {
            "meta_opt": meta.init(adversary.incentive),
            "cost_opt": cost.init(adversary.incentive),
        }

    def learning_rewards(self, state, env_rewards, received):
        del state
        return negated_for(self, env_rewards) + received

    def adversary_step(self, state, key, view: AdversaryView):
        del key
        theta_a = agent_row(view.policy, self.adversary)  # its ordinary step on −r_env
        if not incentive_channel(view, self.name):
            return AgentParams(theta_a, {}), state, {}
        eta_a, state = incentive_step(self, state, view)
        return AgentParams(theta_a, eta_a), state, {}


def incentive_step(attack: NegatedEnvReward, state, view: AdversaryView):
    """LIO's ordinary incentive step of the adversary, its env return on τ̂ negated.

    Returns:
        (η_a', new Adam states).
    """
    a = attack.adversary
    n = view.env_rewards.shape[-1]
    eta_a = agent_row(view.incentive, a)
    valid = view.valid.astype(jnp.float32)
    own_returns = discounted_returns(-view.env_rewards[..., a], view.gamma) * valid
    cotangent = own_returns[..., None] * (jnp.arange(n) != a).astype(jnp.float32)
    ascent = jax.tree.map(lambda g: -g[0], view.meta_pullback(cotangent[None]))
    meta, cost = attack.optimizers()
    updates, meta_opt = meta.update(ascent, state["meta_opt"])
    eta_a = optax.apply_updates(eta_a, updates)
    discount = view.gamma ** jnp.arange(valid.shape[-1]) * valid
    before = agent_row(view.incentive, a)

    def spent(eta):  # Σ_t γ^t Σ_j of what a emits on τ̂, at η of the iteration's start
        return jnp.sum(discount * view.emitted(eta)[..., a, :].sum(-1))

    cost_updates, cost_opt = cost.update(jax.grad(spent)(before), state["cost_opt"])
    return optax.apply_updates(eta_a, cost_updates), {"meta_opt": meta_opt, "cost_opt": cost_opt}
