"""`admo_code` — the published PIMbot code's "ADMO": a scheduler of extra ordinary steps.

The paper's ADMO (`admo`, docs/attacks.md) trains the adversary with its own loss,
AdamW, clipping, a reference policy and a budget. The public code behind the paper
does something else (docs/attacks.md, "`admo_code` — what the published code's "ADMO"
does"; facts read from `lio/alg/train_lio_er_admo.py` of UCR-Intelligent-Robotics-Lab/
greedy_agent). Once per iteration, after every agent's ordinary update:

1. two scalars on the episode: the adversary's discounted returns gap
   g_inc = Σ_t γ^t (r_t^a − mean_{j≠a} r_t^j) − β·Σ_t γ^t |given by a|, and
   g_pol = −s·Σ_t γ^t Σ_j r_t^j (r = env reward + incentives received; s = +1 in the
   code's "adversarial" mode = our `disrupt`, −1 "constructive" = `stealthy`), each
   clipped to [−1, 1];
2. the paper's KKT system on the 1×2 "gradient" G = [g_inc g_pol], regularised:
   (M + 1e-6·I)·[α̂; λ] = [−Q c; 1 − eᵀc], Q = GᵀG, with fixed bounds c = (0.1, 0.1);
   α = max(α̂ + c, c) / Σ (non-finite: ½, ½) — not the paper's clip to the segment;
3. the weights become *ordinary* update steps of the adversary:
   max(1, round(3·α2)) extra policy steps and max(1, round(3·α1)) extra incentive
   steps (LIO's own policy-gradient and incentive updates). No loss of its own, no
   AdamW, clipping, reference term or budget (the code's EMAs, λ_d and budget change
   nothing it does).

In the code every extra policy step first copies the adversary's main parameters to
the ones it steps (`update` starts with `copy_main_to_prime`), so however many are
scheduled, the policy moves by exactly one extra ordinary step. Here: the adversary's
policy sign is 2 — its ordinary step plus that one extra step; the scheduled count is
logged as `admo/policy_steps`. The extra incentive steps do compound (each is an Adam
step from where the last left η_a): the adversary takes its ordinary incentive step
(Adam on its meta-gradient, then Adam on its cost, as LIO) and then that many more,
with its own Adam states (Adam is elementwise, so a row of LIO's stacked Adam behaves
as this one).

Written against the attack contract (`AdversaryView`), which shows LIO's τ̂ and the
second-order pullback at the iteration's start; differences to the code, all of the
order of one learning-rate step or of one episode's sampling:
* the scalars are measured on τ̂ (the code: on τ, the episode before the update);
* the extra policy step's gradient is taken at θ on τ (the code: at θ̂ on τ), and τ̂
  is played after it (the code: before);
* every extra incentive step reuses the meta-gradient at (θ, η) of the iteration's
  start (the code recomputes it at θ̂ and the η of the previous step), and the cost
  term is measured on τ̂ (the code: τ);
* N ≥ 3 with LIO's "shared" incentive updates: the adversary's steps move only its
  own η_a (the code's optimizer also moves the other givers' η and, in the extra
  steps, the recipients' current θ, which then persist).
`lr_incentive`, `lr_cost` must equal the learner's (defaults: LIO's Escape Room column;
the IPD column has lr_cost 0).

Against the Reciprocator (`reciprocators/admo.py` of the code) the same two scalars
are computed from env rewards only (no incentives, so no cost term), and before every
PPO update (`update_schedule`, on the batch that update learns from) α sets the
adversary's PPO epochs to max(1, round(2·α1·K)) and its reciprocal weight to 2·α2·w,
where K and w are the learner's own (the code's K 10, w 5: round(20·α1) and 10·α2;
at α = (½, ½) the adversary's update is the ordinary one). The other agents keep
their ordinary update; the adversary's policy step keeps its sign 1 and it takes no
further step (`adversary_step` leaves it where PPO left it). Differences to the code:
the scalars are per-episode means over the batch (the code: its one episode) with the
learner's γ (the code: 0.99), and our PPO is full-batch with the learner's Adam.

Which learner it runs on is told by its state: without an incentive channel (the
Reciprocator's `AgentParams` carry no η) it holds a marker instead of Adam states. It lists
`policy_sign`, `adversary_step` and `update_schedule`, so a learner without an epoch
schedule (PG) refuses it by name; LIO has every hook point listed but no epochs, and
this attack's LIO path acts through the other two.
"""

from __future__ import annotations

from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import optax
from flax import struct

from pimbot.attacks.signed_modes import TracedSign, with_traced_sign
from pimbot.contracts.attack import (
    AdversaryView,
    AgentParams,
    Attack,
    UpdateSchedule,
    agent_row,
    incentive_channel,
)
from pimbot.contracts.params import check_int, check_number
from pimbot.contracts.rollout import discounted_returns, received
from pimbot.envs.core import InvalidParameter

CODE_MODES = {"disrupt": 1.0, "stealthy": -1.0}
"""Our mode names -> the code's `mode` sign (+1 "adversarial", −1 "constructive")."""

RIDGE = 1e-6
"""The code's regulariser of the KKT matrix (M + 1e-6·I)."""


def code_weights(g_inc: jax.Array, g_pol: jax.Array, bounds: jax.Array) -> jax.Array:
    """α [2] from the two clipped scalars, as the code solves them.

    (M + δI)·[x; λ] = [−Q c; 1 − c1 − c2] with Q = ggᵀ, g = (g_inc, g_pol), δ = 1e-6,
    eliminated by hand to a well-conditioned 2×2 system (the 3×3 one is nearly
    singular whenever g_inc ≈ g_pol, e.g. both clipped to ±1); then
    α = max(x + c, c) / Σ, and (½, ½) where that is not finite.
    """
    q11, q12, q22 = g_inc * g_inc, g_inc * g_pol, g_pol * g_pol
    c1, c2 = bounds[0], bounds[1]
    b1, b2 = -(q11 * c1 + q12 * c2), -(q12 * c1 + q22 * c2)
    rest = 1.0 - c1 - c2
    d = RIDGE
    # rows: (1) − (2) of the system, and (2) with λ = (rest − x1 − x2)/δ from (3), × δ
    a11, a12, r1 = q11 - q12 + d, -(q22 - q12 + d), b1 - b2
    a21, a22, r2 = 1.0 - d * q12, 1.0 - d * (q22 + d), rest - d * b2
    det = a11 * a22 - a12 * a21
    x1 = (r1 * a22 - a12 * r2) / det
    x2 = (a11 * r2 - a21 * r1) / det
    alpha = jnp.maximum(jnp.stack([x1, x2]) + bounds, bounds)
    alpha = alpha / alpha.sum()
    return jnp.where(jnp.all(jnp.isfinite(alpha)), alpha, jnp.full((2,), 0.5)).astype(jnp.float32)


def scheduled_steps(weight: jax.Array, most: int) -> jax.Array:
    """max(1, round(weight · most)), rounding half to even as Python's `round`."""
    return jnp.maximum(1, jnp.round(weight * most)).astype(jnp.int32)


@struct.dataclass
class ADMOCode(Attack):
    """The published code's ADMO: KKT weights of two scalars schedule extra ordinary steps."""

    mode: str = struct.field(pytree_node=False, default="disrupt")
    """"disrupt" (the code's default "adversarial", s = +1) or "stealthy" ("constructive")."""
    c1: float = 0.1
    """Fixed lower bound of α1 (the code's; it never adapts)."""
    c2: float = 0.1
    """Fixed lower bound of α2."""
    beta_cost: float = 0.01
    """β: weight of the discounted incentives the adversary gave in g_inc."""
    clip: float = 1.0
    """Both scalars are clipped to [−clip, clip] (the code's max_grad_norm)."""
    max_policy_steps: int = struct.field(pytree_node=False, default=3)
    """Extra policy steps scheduled: max(1, round(α2 · this)) (logged; one takes effect)."""
    max_incentive_steps: int = struct.field(pytree_node=False, default=3)
    """Extra incentive steps taken: max(1, round(α1 · this))."""
    lr_incentive: float = 1e-3
    """The learner's Adam rate of the incentive (meta-gradient) step (LIO ER and IPD: 1e-3)."""
    lr_cost: float = 1e-4
    """The learner's Adam rate of the separate cost step (LIO ER: 1e-4; IPD: 0)."""

    name: ClassVar[str] = "admo_code"
    lever: ClassVar[str] = "incentive + policy (extra ordinary steps)"
    hooks: ClassVar[tuple[str, ...]] = ("policy_sign", "adversary_step", "update_schedule")
    """LIO: `policy_sign` and `adversary_step`; Reciprocator: `update_schedule`."""

    def validate(self, num_agents: int) -> None:
        super().validate(num_agents)
        if self.mode not in CODE_MODES:
            raise InvalidParameter(
                f"mode: unknown admo_code mode {self.mode!r}; allowed: {', '.join(CODE_MODES)}"
            )
        for name in ("c1", "c2"):
            check_number(name, getattr(self, name), 0.0, 0.5)
        for name in ("beta_cost", "lr_incentive", "lr_cost"):
            check_number(name, getattr(self, name), low=0.0)
        check_number("clip", self.clip, low=0.0, strict_low=True)
        check_int("max_policy_steps", self.max_policy_steps, 1)
        check_int("max_incentive_steps", self.max_incentive_steps, 1)

    @property
    def sign(self) -> Any:
        """s of g_pol: the code's sign of the mode (`CODE_MODES`)."""
        return CODE_MODES[self.mode]

    def program_form(self) -> ProgramADMOCode:
        """ADMOCode with its mode's sign traced: stealthy and disrupt runs share a program."""
        return with_traced_sign(self, ProgramADMOCode, "disrupt")

    def optimizers(self) -> tuple[optax.GradientTransformation, optax.GradientTransformation]:
        """(meta-gradient Adam, cost Adam), as LIO's."""
        return optax.adam(self.lr_incentive), optax.adam(self.lr_cost)

    def init_state(self, key, num_agents, adversary: AgentParams):
        """LIO: the Adam states of the incentive steps; without an incentive channel (the
        Reciprocator) only the marker of the PPO schedule (`schedules_ppo`)."""
        del key, num_agents
        if not jax.tree.leaves(adversary.incentive):
            return {PPO_MARKER: jnp.ones((), bool)}
        meta, cost = self.optimizers()
        return {
            "meta_opt": meta.init(adversary.incentive),
            "cost_opt": cost.init(adversary.incentive),
        }

    def policy_sign(self, state, num_agents):
        """LIO: 2 for the adversary, its ordinary policy step plus the code's one extra
        step; the Reciprocator: 1 for everyone (its schedule is the PPO epochs)."""
        if schedules_ppo(state):
            return jnp.ones((num_agents,))
        return 1.0 + self.is_adversary(num_agents).astype(jnp.float32)

    def adversary_step(self, state, key, view):
        del key
        if not incentive_channel(view, self.name):  # the Reciprocator: PPO took the step
            return AgentParams(agent_row(view.policy, self.adversary), {}), state, {}
        return step(self, state, view)

    def update_schedule(self, state, key, view, ordinary_epochs):
        del state, key
        return ppo_schedule(self, view, ordinary_epochs)


PPO_MARKER = "schedules_ppo"
"""Key of the Reciprocator's state: its presence (static) says the schedule is PPO's."""


def schedules_ppo(state) -> bool:
    """Whether the state is the Reciprocator's (static: the keys of the state's dict)."""
    return PPO_MARKER in state


def signals(attack: ADMOCode, view: AdversaryView, given: jax.Array) -> jax.Array:
    """(returns gap, team welfare, incentive cost) [3] of the adversary, per episode.

    Args:
        given: [B..., T, N, N] incentives emitted on the judged batch (zero on invalid steps).
    """
    a = attack.adversary
    n = view.env_rewards.shape[-1]
    valid = view.valid.astype(jnp.float32)
    episodes = valid.size // valid.shape[-1]
    discount = view.gamma ** jnp.arange(valid.shape[-1]) * valid
    total = view.env_rewards + received(given)
    others = (jnp.arange(n) != a).astype(jnp.float32)
    gap = total[..., a] - (total * others).sum(-1) / (n - 1)
    welfare = total.sum(-1)
    cost = jnp.abs(given[..., a, :].sum(-1))
    return jnp.stack([jnp.sum(discount * v) for v in (gap, welfare, cost)]) / episodes


def step(attack: ADMOCode, state, view: AdversaryView):
    """The adversary's ordinary incentive step and its scheduled extra ones.

    Returns:
        (new ω, new state, `admo/*` metrics).
    """
    a = attack.adversary
    n = view.env_rewards.shape[-1]
    theta_a = jax.tree.map(lambda x: x[a], view.policy)
    eta_a = jax.tree.map(lambda x: x[a], view.incentive)
    valid = view.valid.astype(jnp.float32)
    discount = view.gamma ** jnp.arange(valid.shape[-1]) * valid

    def cost(eta):  # Σ_t γ^t Σ_j of what a emits; Adam is invariant to its R_max scale
        return jnp.sum(discount * view.emitted(eta)[..., a, :].sum(-1))

    given = view.emitted(eta_a) * view.valid[..., None, None]
    gap, welfare, spent = signals(attack, view, given)
    g_inc = jnp.clip(gap - attack.beta_cost * spent, -attack.clip, attack.clip)
    g_pol = jnp.clip(-attack.sign * welfare, -attack.clip, attack.clip)
    alpha = code_weights(g_inc, g_pol, jnp.stack([attack.c1, attack.c2]).astype(jnp.float32))
    policy_steps = scheduled_steps(alpha[1], attack.max_policy_steps)
    incentive_steps = scheduled_steps(alpha[0], attack.max_incentive_steps)

    # the giver's own surrogate J_a on τ̂ through the recipients' updates (LIO's step 5)
    env_returns = discounted_returns(view.env_rewards[..., a], view.gamma) * valid
    cotangent = env_returns[..., None] * (jnp.arange(n) != a).astype(jnp.float32)
    meta_grad = jax.tree.map(lambda g: -g[0], view.meta_pullback(cotangent[None]))  # ascent
    cost_grad = jax.grad(cost)(eta_a)
    meta, cost_opt_fn = attack.optimizers()

    def incentive_step(i, carry):
        eta, meta_opt, cost_opt = carry
        updates, new_meta = meta.update(meta_grad, meta_opt)
        moved = optax.apply_updates(eta, updates)
        cost_updates, new_cost = cost_opt_fn.update(cost_grad, cost_opt)
        moved = optax.apply_updates(moved, cost_updates)
        take = i <= incentive_steps  # step 0 is the ordinary one
        keep = lambda new, old: jnp.where(take, new, old)  # noqa: E731
        return (
            jax.tree.map(keep, moved, eta),
            jax.tree.map(keep, new_meta, meta_opt),
            jax.tree.map(keep, new_cost, cost_opt),
        )

    eta_new, meta_opt, cost_opt = jax.lax.fori_loop(
        0,
        attack.max_incentive_steps + 1,
        incentive_step,
        (eta_a, state["meta_opt"], state["cost_opt"]),
    )
    metrics = {
        "admo/alpha_1": alpha[0],
        "admo/alpha_2": alpha[1],
        "admo/returns_gap": gap,
        "admo/team_welfare": welfare,
        "admo/inc_cost": spent,
        "admo/policy_steps": policy_steps.astype(jnp.float32),
        "admo/incentive_steps": incentive_steps.astype(jnp.float32),
    }
    new_state = {"meta_opt": meta_opt, "cost_opt": cost_opt}
    return AgentParams(theta_a, eta_new), new_state, metrics


def ppo_schedule(attack: ADMOCode, view: AdversaryView, ordinary_epochs: int) -> UpdateSchedule:
    """The Reciprocator's schedule: the adversary's PPO epochs and reciprocal-weight scale
    from α of the scalars on the batch's env rewards; everyone else's ordinary update."""
    a = attack.adversary
    n = view.env_rewards.shape[-1]
    no_incentives = jnp.zeros(view.env_rewards.shape + (n,), jnp.float32)
    gap, welfare, _ = signals(attack, view, no_incentives)
    g_inc = jnp.clip(gap, -attack.clip, attack.clip)
    g_pol = jnp.clip(-attack.sign * welfare, -attack.clip, attack.clip)
    alpha = code_weights(g_inc, g_pol, jnp.stack([attack.c1, attack.c2]).astype(jnp.float32))
    most = 2 * ordinary_epochs
    adversary = attack.is_adversary(n)
    epochs = jnp.where(adversary, scheduled_steps(alpha[0], most), ordinary_epochs)
    scale = jnp.where(adversary, 2.0 * alpha[1], 1.0)
    metrics = {
        "admo/alpha_1": alpha[0],
        "admo/alpha_2": alpha[1],
        "admo/returns_gap": gap,
        "admo/team_welfare": welfare,
        "admo/ppo_epochs": epochs[a].astype(jnp.float32),
        "admo/reciprocal_weight_scale": scale[a],
    }
    return UpdateSchedule(epochs.astype(jnp.int32), scale, max(most, ordinary_epochs), metrics)


@struct.dataclass
class ProgramADMOCode(TracedSign, ADMOCode):
    """`ADMOCode.program_form`: the mode's sign (`CODE_MODES`) as a traced leaf; the static
    `mode` is a placeholder. Not registered: the runner builds it from an `ADMOCode`."""

    traced_sign: Any = 1.0
