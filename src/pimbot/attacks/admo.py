"""ADMO — adaptive multi-objective manipulation (docs/attacks.md).

The adversary a's parameters ω = [θ_a, η_a] are trained by ADMO instead of its
normal update (its `adversary_step`, written once against the learner's
`AdversaryView`: LIO shows it τ̂, the episode played with the updated policies;
a Reciprocator its batch, where ω = θ_a and r = env reward). Per iteration:

* L_inc = −Σ_t γ^t (r_t^a − mean_{j≠a} r_t^j) + β_b·Σ_t γ^t Σ_j u_t^{a→j}   (raise its margin)
* L_pol = −s·Σ_t γ^t Σ_j r_t^j + λ_d·½‖θ_a − θ_ref‖²    (s = +1 stealthy, −1 disrupt)

with r^j = env reward + incentives received, measured on τ̂. Gradients w.r.t.
θ_a by the score function (stop-gradient returns); w.r.t. η_a through the
recipients' one-step updates exactly as LIO's meta-gradient, plus the direct
dependence of the rewards on the incentives (where the learner has an incentive
channel; losses are means over the view's episodes). The two gradients are combined
with the closed-form KKT (Pareto) weights under adaptive lower bounds c,
clipped, and applied with AdamW. Every `ref_period` iterations the reference
policy is refreshed. Once the incentives a gave in an episode exceed the budget
B_a, a emits nothing until the episode ends.

Adaptive bounds (the paper leaves the rule open; this is our decision, all
rates configurable): c1 = c_init + c1_variance_gain · EMA(variance of the
signal a receives: incentives on τ, or the influence others exert on it); c2
grows by c2_step after each `stall_window` iterations in which the EMA of team
success moved less than `stall_threshold`, and shrinks by c2_step otherwise;
both clipped to
[c_min, c_max] (c_max < 0.5 keeps c1 + c2 < 1).
"""

from __future__ import annotations

from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import optax
from flax import struct
from jax.flatten_util import ravel_pytree

from pimbot.attacks.signed_modes import TracedSign, with_traced_sign
from pimbot.contracts.attack import AdversaryView, AgentParams, Attack, incentive_channel
from pimbot.contracts.params import check_int, check_number
from pimbot.contracts.rollout import discounted_returns, received
from pimbot.envs.core import InvalidParameter

MODES = {"stealthy": 1.0, "disrupt": -1.0}


@struct.dataclass
class ADMO(Attack):
    """Adaptive multi-objective manipulation of agent `adversary`."""

    mode: str = struct.field(pytree_node=False, default="disrupt")
    """"stealthy" (s = +1: keep team welfare up while raising its margin) or "disrupt" (s = −1)."""
    lr: float = 1e-3
    """AdamW learning rate on ω = [θ_a, η_a]."""
    weight_decay: float = 1e-4
    """AdamW weight decay."""
    clip_norm: float = 1.0
    """Clip ‖g*‖ to at most this."""
    beta_budget: float = 0.01
    """β_b: weight of the L1 cost of the incentives the adversary gives, in L_inc."""
    lambda_d: float = 0.0
    """λ_d: weight of the reference term ½‖θ_a − θ_ref‖² in L_pol."""
    lambda_d_drift: float = 0.05
    """λ_d for the next ref_period iterations after a drift above drift_threshold."""
    drift_threshold: float = 0.5
    """Drift ½‖θ_a − θ_ref_old‖² above which λ_d_drift applies."""
    ref_period: int = 100
    """K_ref: iterations between reference-policy refreshes."""
    budget: float = 10.0
    """B_a: incentives the adversary may give per episode before it emits nothing."""
    c_init: float = 0.1
    """Initial lower bounds c1 = c2."""
    c_min: float = 0.05
    """Lower clip of each bound."""
    c_max: float = 0.45
    """Upper clip of each bound (< 0.5 so that c1 + c2 < 1)."""
    ema_rate: float = 0.05
    """Rate of the EMAs of received-incentive variance and team success."""
    c1_variance_gain: float = 0.1
    """c1 = c_init + gain · EMA(variance of incentives received)."""
    c2_step: float = 0.01
    """Change of c2 after each stall window."""
    stall_window: int = 100
    """Iterations per stall check of the success EMA."""
    stall_threshold: float = 0.01
    """Success-EMA change below which success counts as stalled."""

    name: ClassVar[str] = "admo"
    lever: ClassVar[str] = "incentive + policy"
    hooks: ClassVar[tuple[str, ...]] = ("policy_sign", "adversary_step")
    optional_hooks: ClassVar[tuple[str, ...]] = ("emit",)
    """Its incentive budget (`emit`) applies where the learner has an incentive channel."""

    def validate(self, num_agents: int) -> None:
        super().validate(num_agents)
        if self.mode not in MODES:
            raise InvalidParameter(
                f"mode: unknown ADMO mode {self.mode!r}; allowed: {', '.join(MODES)}"
            )
        for name in (
            "lr",
            "weight_decay",
            "clip_norm",
            "beta_budget",
            "lambda_d",
            "lambda_d_drift",
            "drift_threshold",
            "budget",
            "ema_rate",
            "c1_variance_gain",
            "c2_step",
            "stall_threshold",
        ):
            check_number(name, getattr(self, name), low=0.0)
        for name in ("ref_period", "stall_window"):
            check_int(name, getattr(self, name), 1)
        if not 0 <= self.c_min <= self.c_init <= self.c_max < 0.5:
            raise InvalidParameter(
                "c_init: need 0 ≤ c_min ≤ c_init ≤ c_max < 0.5, got "
                f"c_min={self.c_min}, c_init={self.c_init}, c_max={self.c_max}"
            )
        if not 0 < self.ema_rate <= 1:
            raise InvalidParameter(f"ema_rate: must be in (0, 1], got {self.ema_rate}")

    @property
    def sign(self) -> float:
        return MODES[self.mode]

    def program_form(self) -> ProgramADMO:
        """ADMO with its mode's sign traced: stealthy and disrupt runs share a program."""
        return with_traced_sign(self, ProgramADMO, "disrupt")

    def emit(self, state, key, given_so_far):
        del state, key
        n = given_so_far.shape[0]
        over = given_so_far[self.adversary].sum() > self.budget
        scale = jnp.where(self.is_adversary(n) & over, 0.0, 1.0)
        return jnp.broadcast_to(scale[:, None], (n, n)), jnp.zeros((n, n))

    def policy_sign(self, state, num_agents):
        del state  # the adversary's policy is moved by ADMO's own step, not the learner's
        return jnp.where(self.is_adversary(num_agents), 0.0, 1.0)

    def optimizer(self) -> optax.GradientTransformation:
        return optax.adamw(self.lr, weight_decay=self.weight_decay)

    def init_state(self, key, num_agents, adversary: AgentParams) -> ADMOState:
        del key, num_agents
        zero = jnp.zeros((), jnp.float32)
        omega, _ = ravel_pytree((adversary.policy, adversary.incentive))
        theta, _ = ravel_pytree(adversary.policy)
        return ADMOState(
            opt=self.optimizer().init(omega),
            theta_ref=theta,
            lambda_d=jnp.asarray(self.lambda_d, jnp.float32),
            bounds=jnp.full((2,), self.c_init, jnp.float32),
            variance_ema=zero,
            success_ema=zero,
            success_ema_at_window=zero,
        )

    def adversary_step(self, state, key, view):
        del key
        return step(self, state, view)


@struct.dataclass
class ADMOState:
    opt: optax.OptState  # AdamW state over the flat ω = (θ_a, η_a)
    theta_ref: jax.Array  # flat reference policy parameters
    lambda_d: jax.Array  # λ_d in force
    bounds: jax.Array  # [2] c1, c2
    variance_ema: jax.Array
    success_ema: jax.Array
    success_ema_at_window: jax.Array


def kkt_weights(g_inc: jax.Array, g_pol: jax.Array, bounds: jax.Array) -> jax.Array:
    """Pareto weights α = argmin ½‖Gα‖² s.t. α1 + α2 = 1, α ≥ c, in closed form.

    The KKT system of the shifted problem (α = c + α̂, α̂1 + α̂2 = r = 1 − c1 − c2)
    has one free variable x = α̂1; its stationarity condition
    (g1 − g2)ᵀG(c + [x, r − x]) = 0 gives
    x* = −[(Q11 − Q12)c1 + (Q12 − Q22)(c2 + r)] / ‖g1 − g2‖², with Q = GᵀG.
    Where ‖g1 − g2‖ = 0 (identical or zero gradients: Q singular) every x is
    optimal and we take the minimum-norm solution x = r/2 — exactly the
    pseudo-inverse solution of `kkt_weights_pinv`, which is the reference this
    is tested against, at a fraction of the cost (no SVD). A negative component
    of α̂ is set to 0 and the other takes the rest (x clipped to [0, r]).

    Args:
        g_inc, g_pol: flat gradients [D].
        bounds: c [2] with c1 + c2 ≤ 1.
    Returns:
        α [2].
    """
    q11, q12, q22 = jnp.vdot(g_inc, g_inc), jnp.vdot(g_inc, g_pol), jnp.vdot(g_pol, g_pol)
    c1, c2 = bounds[0], bounds[1]
    rest = 1.0 - c1 - c2
    curvature = q11 - 2.0 * q12 + q22  # ‖g1 − g2‖²
    flat = curvature <= 1e-12 * (q11 + q22) + 1e-30
    x = -((q11 - q12) * c1 + (q12 - q22) * (c2 + rest)) / jnp.where(flat, 1.0, curvature)
    x = jnp.clip(jnp.where(flat, rest / 2, x), 0.0, rest)
    return jnp.stack([c1 + x, c2 + rest - x])


def kkt_weights_pinv(g_inc: jax.Array, g_pol: jax.Array, bounds: jax.Array) -> jax.Array:
    """The reference: the KKT system solved with the pseudo-inverse, as the paper writes it.

    With Q = GᵀG, e = [1, 1] and M = [[Q, e], [eᵀ, 0]], solve
    M·[α̂; λ] = [−Q c; 1 − eᵀc] with M⁺ (singular Q: parallel or zero gradients),
    then set a negative component of α̂ to 0 and give the other the rest.
    """
    grads = jnp.stack([g_inc, g_pol], axis=1)  # [D, 2]
    gram = grads.T @ grads
    e = jnp.ones((2,), grads.dtype)
    system = jnp.block([[gram, e[:, None]], [e[None, :], jnp.zeros((1, 1), grads.dtype)]])
    rest = 1.0 - bounds.sum()
    rhs = jnp.concatenate([-gram @ bounds, rest[None]])
    shift = (jnp.linalg.pinv(system) @ rhs)[:2]
    shift = jnp.where(
        shift[0] < 0,
        jnp.stack([0.0, rest]),
        jnp.where(shift[1] < 0, jnp.stack([rest, 0.0]), shift),
    )
    return bounds + shift


def update_bounds(attack: ADMO, state: ADMOState, received_var, success, iteration):
    """EMAs of the received-incentive variance and of team success, and the new c."""
    rate = attack.ema_rate
    variance_ema = (1 - rate) * state.variance_ema + rate * received_var
    success_ema = (1 - rate) * state.success_ema + rate * success
    c1 = attack.c_init + attack.c1_variance_gain * variance_ema
    at_check = (iteration + 1) % attack.stall_window == 0
    stalled = jnp.abs(success_ema - state.success_ema_at_window) < attack.stall_threshold
    c2 = state.bounds[1] + jnp.where(
        at_check, jnp.where(stalled, attack.c2_step, -attack.c2_step), 0.0
    )
    bounds = jnp.clip(jnp.stack([c1, c2]), attack.c_min, attack.c_max)
    window = jnp.where(at_check, success_ema, state.success_ema_at_window)
    return state.replace(
        bounds=bounds.astype(jnp.float32),
        variance_ema=variance_ema,
        success_ema=success_ema,
        success_ema_at_window=window,
    )


def weighted_step(attack: ADMO, state: ADMOState, flat_inc, flat_pol, omega):
    """KKT weights α, then one clipped AdamW step on the flat ω along α·(g_inc, g_pol).

    A zero combined gradient leaves parameters and optimizer state unchanged.
    Returns (α, whether the step was skipped, new ω, new optimizer state).
    """
    alpha = kkt_weights(flat_inc, flat_pol, state.bounds)
    combined = alpha[0] * flat_inc + alpha[1] * flat_pol
    norm = jnp.linalg.norm(combined)
    skip = norm == 0
    combined = combined * jnp.minimum(1.0, attack.clip_norm / jnp.where(skip, 1.0, norm))
    updates, opt = attack.optimizer().update(combined, state.opt, omega)
    stepped = jnp.where(skip, omega, optax.apply_updates(omega, updates))
    opt = jax.tree.map(lambda new, old: jnp.where(skip, old, new), opt, state.opt)
    return alpha, skip, stepped, opt


def refresh_reference(attack: ADMO, state: ADMOState, theta_new: jax.Array, iteration):
    """Every K_ref iterations θ_ref ← θ (flat), and λ_d follows the drift rule; (θ_ref, λ_d)."""
    refresh = (iteration + 1) % attack.ref_period == 0
    drift = 0.5 * jnp.sum((theta_new - state.theta_ref) ** 2)
    theta_ref = jnp.where(refresh, theta_new, state.theta_ref)
    lambda_d = jnp.where(
        refresh,
        jnp.where(drift > attack.drift_threshold, attack.lambda_d_drift, attack.lambda_d),
        state.lambda_d,
    ).astype(jnp.float32)
    return theta_ref, lambda_d


def masked_variance(values: jax.Array, mask: jax.Array) -> jax.Array:
    """Variance of `values` over the entries where `mask` is 1 (0 when none are)."""
    count = jnp.maximum(mask.sum(), 1.0)
    mean = jnp.sum(values * mask) / count
    return jnp.sum(mask * (values - mean) ** 2) / count


def step_metrics(
    state: ADMOState, alpha, skip, flat_inc, flat_pol, losses, d_proxy, budget_hits=None
) -> dict:
    """The `admo/*` metrics of one step (weights, bounds, gradient geometry, losses);
    `budget_hits` where the adversary has an incentive budget. Key order is the
    metrics.csv column order."""
    norm_inc, norm_pol = jnp.linalg.norm(flat_inc), jnp.linalg.norm(flat_pol)
    return {
        "admo/alpha_1": alpha[0],
        "admo/alpha_2": alpha[1],
        "admo/c_1": state.bounds[0],
        "admo/c_2": state.bounds[1],
        "admo/g_inc_norm": norm_inc,
        "admo/g_pol_norm": norm_pol,
        "admo/cos_g_inc_g_pol": jnp.vdot(flat_inc, flat_pol)
        / jnp.maximum(norm_inc * norm_pol, 1e-12),
        "admo/L_inc": losses[0],
        "admo/L_pol": losses[1] + state.lambda_d * d_proxy,
        "admo/D_proxy": d_proxy,
        "admo/lambda_d": state.lambda_d,
        **({} if budget_hits is None else {"admo/budget_hits": budget_hits.astype(jnp.float32)}),
        "admo/skipped": skip.astype(jnp.float32),
    }


def along_time(fn, values: jax.Array) -> jax.Array:
    """`fn` over the last (time) axis of `values` [B..., T], vmapped over batch axes."""
    for _ in range(values.ndim - 1):
        fn = jax.vmap(fn)
    return fn(values)


def step(attack: ADMO, state: ADMOState, view: AdversaryView):
    """One ADMO update of ω = [θ_a, η_a] on the learner's view.

    Returns:
        (new ω, new state, `admo/*` metrics).
    """
    a = attack.adversary
    n = view.env_rewards.shape[-1]
    channel = incentive_channel(view, attack.name)
    theta_a = jax.tree.map(lambda x: x[a], view.policy)
    eta_a = jax.tree.map(lambda x: x[a], view.incentive) if channel else {}
    valid = view.valid.astype(jnp.float32)
    episodes = valid.size // valid.shape[-1]
    discount = view.gamma ** jnp.arange(valid.shape[-1]) * valid
    others = (jnp.arange(n) != a).astype(jnp.float32)

    def objectives(rewards):
        """Per-step margin of a and team reward: each [B..., T]."""
        margin = rewards[..., a] - (rewards * others).sum(axis=-1) / (n - 1)
        return margin, rewards.sum(axis=-1)

    def direct_losses(eta_adversary):
        given = view.emitted(eta_adversary) * view.valid[..., None, None]
        margin, team = objectives(view.env_rewards + received(given))
        spent = given[..., a, :].sum(axis=-1)
        loss_inc = -jnp.sum(discount * margin) + attack.beta_budget * jnp.sum(discount * spent)
        loss_pol = -attack.sign * jnp.sum(discount * team)
        return jnp.stack([loss_inc, loss_pol]) / episodes, (margin, team)

    if channel:
        losses, pull_direct, (margin, team) = jax.vjp(direct_losses, eta_a, has_aux=True)
    else:
        margin, team = objectives(view.env_rewards)
        losses = jnp.stack([-jnp.sum(discount * margin), -attack.sign * jnp.sum(discount * team)])
        losses = losses / episodes
    # Score-function weights: reward-to-go of each objective's per-step reward.
    to_go = jnp.stack(
        [
            along_time(lambda m: discounted_returns(m, view.gamma), margin),
            attack.sign * along_time(lambda w: discounted_returns(w, view.gamma), team),
        ]
    )
    to_go = jax.lax.stop_gradient(to_go * valid)  # [2, B..., T]

    # θ_a: REINFORCE surrogate on the judged batch.
    def theta_surrogate(theta_adv, weights):
        return -jnp.sum(view.log_probs(theta_adv) * weights) / episodes

    theta_flat, _ = ravel_pytree(theta_a)
    theta_grads = jax.vmap(jax.grad(theta_surrogate), in_axes=(None, 0))(theta_a, to_go)
    grads = [jax.vmap(lambda g: ravel_pytree(g)[0])(theta_grads)]  # [2, |θ_a|]
    drift = theta_flat - state.theta_ref
    grads[0] = grads[0].at[1].add(state.lambda_d * drift)

    if channel:
        # η_a: through the recipients' updates (as LIO), plus the direct dependence.
        cotangents = -to_go[..., None] * others  # [2, T, N]
        eta_score = view.meta_pullback(cotangents)  # one batched pass, [2, ...]
        (eta_direct,) = jax.vmap(pull_direct)(jnp.eye(2))
        eta_grads = jax.tree.map(lambda s, d: s + d, eta_score, eta_direct)
        grads.append(jax.vmap(lambda g: ravel_pytree(g)[0])(eta_grads))  # [2, |η_a|]

    flat = jnp.concatenate(grads, axis=1)  # [2, |ω|]: rows g_inc, g_pol
    flat_inc, flat_pol = flat[0], flat[1]
    omega, unravel = ravel_pytree((theta_a, eta_a))
    alpha, skip, omega_new, opt = weighted_step(attack, state, flat_inc, flat_pol, omega)
    theta_new, eta_new = unravel(omega_new)
    d_proxy = 0.5 * jnp.sum(drift**2)
    theta_ref, lambda_d = refresh_reference(
        attack, state, omega_new[: theta_flat.size], view.iteration
    )

    received_var = masked_variance(view.received, view.received_valid.astype(jnp.float32))
    new_state = update_bounds(
        attack,
        state.replace(opt=opt, theta_ref=theta_ref, lambda_d=lambda_d),
        received_var,
        view.success,
        view.iteration,
    )
    budget_hits = None
    if channel:
        budget_hits = sum(
            jnp.sum(jnp.all(scale[:, a] == 0, axis=-1) & ok) for scale, ok in view.emission_scales
        )
    metrics = step_metrics(
        state, alpha, skip, flat_inc, flat_pol, losses, d_proxy, budget_hits=budget_hits
    )
    return AgentParams(theta_new, eta_new), new_state, metrics


@struct.dataclass
class ProgramADMO(TracedSign, ADMO):
    """`ADMO.program_form`: the mode's sign (`MODES`) as a traced leaf; the static
    `mode` is a placeholder. Not registered: the runner builds it from an `ADMO`."""

    traced_sign: Any = -1.0
