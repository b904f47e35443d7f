"""LIO — learning to incentivize other learners (Yang et al., NeurIPS 2020).

One iteration, per seed and for all agents at once (docs/lio.md):
  1. play τ with the current policies θ and incentive functions η;
  2. every recipient j takes a policy-gradient step on env + received
     incentives: θ̂_j(η) = θ_j + β∇_θj[Σ_t log π(a_t|o_t) G_t + c_ent·H];
  3. play τ̂ with θ̂;
  4. every giver i ascends its *env* return on τ̂ through the recipients'
     updates: ∇_ηi Σ_{j≠i} Σ_t log π_θ̂j(η)(â_t^j|ô_t^j) Ĝ_t^{i,env} — `jax.grad`
     of that surrogate at θ̂(η), nothing hand-derived — plus a separate cost
     step on the discounted sigmoid outputs it gave on τ;
  5. θ ← θ̂.
Attacks and defenses are consulted at the hook points named in `update`.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import optax
from flax import struct

from pimbot import nets
from pimbot.contracts import defense as defense_hooks
from pimbot.contracts.attack import (
    NO_ATTACK,
    AdversaryView,
    AgentParams,
    Attack,
    Outcome,
    agent_row,
    attack_key,
    with_agent_row,
)
from pimbot.contracts.defense import (
    NO_DEFENSE,
    Defenses,
    EpsilonContext,
    IncentiveContext,
    PolicyStepContext,
)
from pimbot.contracts.learner import Actor
from pimbot.contracts.rollout import (
    Trajectory,
    discounted_returns,
    episode_metrics,
    received,
    rollout,
)
from pimbot.envs.core import Env, TracedFields
from pimbot.errors import check_choice
from pimbot.learners.pg import act_fn, epsilon_at, evaluate_actor, policy_step, reinforce_loss

INCENTIVE_UPDATES = ("shared", "own")
"""The values of `LIOConfig.incentive_updates`, the default first."""


@dataclasses.dataclass(frozen=True)
class LIOConfig(TracedFields):
    """LIO hyperparameters (defaults: the original Escape Room column; other games declare
    the IPD column at their registration). The numbers in `traced_fields` are traced
    arguments of the compiled program (runs that differ only in them share it); the ε
    schedule and the cost's rate stay structure (computed on the host, or branched on),
    and so does `lr_policy`: traced, it moved ADMO's 2-agent runs (ER(2,1), IPD) in the
    last bits from the first evaluation on (XLA folds it with other constants when it
    is one), and chaotic training makes that a different run."""

    traced_fields: ClassVar[tuple[str, ...]] = (
        "lr_incentive",
        "incentive_max",
        "entropy_coef",
        "gamma",
    )

    policy_hidden: tuple[int, ...] = (64, 32)
    """Hidden layer widths of the policy MLP."""
    incentive_hidden: tuple[int, ...] = (64, 16)
    """Hidden layer widths of the incentive MLP."""
    lr_policy: float = 1e-4
    """SGD learning rate β of the policy step."""
    lr_incentive: float = 1e-3
    """Adam learning rate of the incentive (meta-gradient) step."""
    lr_cost: float = 1e-4
    """Adam learning rate of the separate cost step; 0 disables the cost."""
    incentive_max: float = 2.0
    """R_max: incentives are sigmoid outputs × R_max."""
    entropy_coef: float = 0.01
    """Weight of the entropy bonus in the policy step."""
    gamma: float = 0.99
    """Discount factor."""
    epsilon_start: float = 0.5
    """Initial exploration weight ε."""
    epsilon_end: float = 0.1
    """Final ε."""
    epsilon_decay_iters: int = 1000
    """Iterations over which ε decays linearly."""
    incentive_updates: str = "shared"
    """Which parameters a giver's incentive (meta-gradient) step moves. "shared" (the
    original code's: each giver's optimizer has no variable list, so its Adam step along its
    own surrogate moves everything the surrogate depends on — every other giver's η, and the
    recipients' current policies until θ ← θ̂ replaces them — one giver after another, each
    seeing what the previous givers moved). "own": each giver moves only its own η_i, all at
    once. The two are identical for N = 2 (giver i's surrogate then depends on no parameter
    another giver's step moves); they differ for N ≥ 3."""

    RANGES: ClassVar[dict] = {
        "gamma": (0.0, 1.0),
        "epsilon_start": (0.0, 1.0),
        "epsilon_end": (0.0, 1.0),
    }
    """Checked ranges (low, high) of the fields; the others are ≥ 0 (`check_fields`)."""

    def __post_init__(self):
        check_choice("incentive_updates", self.incentive_updates, INCENTIVE_UPDATES)


@struct.dataclass
class LIOState:
    policy: dict  # stacked policy parameters θ, leaves [N, ...]
    incentive: dict  # stacked incentive parameters η, leaves [N, ...]
    incentive_opt: optax.OptState  # Adam state of the meta-gradient step
    cost_opt: optax.OptState  # Adam state of the cost step
    attack_state: Any  # the attack's own state (ADMO's), else an empty dict
    defense_state: tuple  # each defense's own state (guard history, monitor), in order
    key: jax.Array
    iteration: jax.Array  # int32 []
    env_steps: jax.Array  # int32 [], environment steps taken in training


def _modules(env: Env, cfg: LIOConfig) -> tuple[nets.MLP, nets.MLP]:
    return (
        nets.policy_module(cfg.policy_hidden, env.num_actions),
        nets.incentive_module(cfg.incentive_hidden, env.num_agents),
    )


def incentive_input(obs: jax.Array, actions: jax.Array, num_actions: int) -> jax.Array:
    """Each giver's incentive-net input: own observation + one-hot actions of the others.

    Args:
        obs: [..., N, obs_dim]; actions: int [..., N].
    Returns:
        [..., N, obs_dim + (N−1)·num_actions].
    """
    n = actions.shape[-1]
    others = jnp.array([[j for j in range(n) if j != i] for i in range(n)])  # [N, N-1]
    one_hot = jax.nn.one_hot(actions, num_actions)  # [..., N, A]
    others_one_hot = one_hot[..., others, :]  # [..., N, N-1, A]
    flat = others_one_hot.reshape(others_one_hot.shape[:-2] + (-1,))
    return jnp.concatenate([obs, flat], axis=-1)


def sigmoid_outputs(module: nets.MLP, incentive, obs, actions, num_actions) -> jax.Array:
    """Raw sigmoid outputs with the giver's own entry masked: [T, N, N] -> (giver, recipient)."""
    x = incentive_input(obs, actions, num_actions)  # [T, N, D]
    out = jax.nn.sigmoid(jax.vmap(module.apply, in_axes=(0, 1), out_axes=1)(incentive, x))
    return out * (1.0 - jnp.eye(actions.shape[-1]))


def give_fn(module: nets.MLP, incentive, num_actions: int, incentive_max: float):
    """A rollout `give` function emitting every giver's incentives."""

    def give(obs, actions):
        out = sigmoid_outputs(module, incentive, obs[None], actions[None], num_actions)[0]
        return incentive_max * out

    return give


def one_by_one(cfg: LIOConfig, num_agents: int) -> bool:
    """Whether the givers' incentive steps are taken one giver after another ("shared"
    updates with N ≥ 3); otherwise all at once, each on its own η (for N = 2 the same)."""
    return cfg.incentive_updates == "shared" and num_agents >= 3


def _init_optimizers(cfg: LIOConfig, policy, incentive, num_agents: int):
    """(meta-gradient, cost) optimizer states. One by one, as the original: one Adam per
    giver over every η and θ (its surrogate's parameters) and one cost Adam per giver over
    its own η_i (leaves [N giver, ...]); otherwise one Adam each over the stacked η."""
    meta, cost = optax.adam(cfg.lr_incentive), optax.adam(cfg.lr_cost)
    if one_by_one(cfg, num_agents):
        per_giver = jax.vmap(lambda _: meta.init((incentive, policy)))(jnp.arange(num_agents))
        return per_giver, jax.vmap(cost.init)(incentive)
    return meta.init(incentive), cost.init(incentive)


def init(
    key: jax.Array,
    env: Env,
    cfg: LIOConfig,
    attack: Attack = NO_ATTACK,
    defenses: Defenses = NO_DEFENSE,
) -> LIOState:
    policy_module, incentive_module = _modules(env, cfg)
    policy_key, incentive_key, key = jax.random.split(key, 3)
    n = env.num_agents
    policy = nets.init_stacked(policy_module, policy_key, n, env.obs_dim)
    in_dim = env.obs_dim + (n - 1) * env.num_actions
    incentive = nets.init_stacked(incentive_module, incentive_key, n, in_dim)
    a = attack.adversary
    incentive_opt, cost_opt = _init_optimizers(cfg, policy, incentive, n)
    return LIOState(
        policy=policy,
        incentive=incentive,
        incentive_opt=incentive_opt,
        cost_opt=cost_opt,
        attack_state=attack.init_state(
            attack_key(key), n, AgentParams(agent_row(policy, a), agent_row(incentive, a))
        ),
        defense_state=defense_hooks.init_states(defenses, n, policy),
        key=key,
        iteration=jnp.zeros((), jnp.int32),
        env_steps=jnp.zeros((), jnp.int32),
    )


def emitted(env, cfg, incentive, traj: Trajectory) -> jax.Array:
    """The incentives emitted on `traj` [T, N, N], recomputed from η (differentiable).

    Learned incentives R_max·sigmoid(η_i(o_i, a_−i)), scaled and offset as the
    attack emitted them during the episode (a fake incentive is a constant;
    a suppressed giver emits nothing).
    """
    _, incentive_module = _modules(env, cfg)
    learned = cfg.incentive_max * sigmoid_outputs(
        incentive_module, incentive, traj.obs, traj.actions, env.num_actions
    )
    return learned * traj.incentive_scale + traj.incentive_offset


def ordinary_step(env, cfg, policy, traj: Trajectory, received_incentives, epsilon):
    """Every agent's ordinary policy step on env reward + `received_incentives` [T, N]."""
    policy_module, _ = _modules(env, cfg)
    rewards = traj.env_rewards + received_incentives * traj.valid[:, None]
    return policy_step(
        policy_module, policy, traj, rewards, epsilon, cfg.lr_policy, cfg.gamma, cfg.entropy_coef
    )


def taken_log_probs(env, cfg, policy, traj: Trajectory) -> jax.Array:
    """log π(a_t^j | o_t^j) [T, N] of the actions taken in `traj`, plain softmax (as the
    original's updated policy inside the incentive gradient)."""
    policy_module, _ = _modules(env, cfg)
    logits = jax.vmap(policy_module.apply, in_axes=(0, 1), out_axes=1)(policy, traj.obs)
    log_probs = jax.nn.log_softmax(logits)  # [T, N, A]
    return jnp.take_along_axis(log_probs, traj.actions[..., None], axis=-1)[..., 0]


def recipient_update(env, cfg, policy, incentive, traj: Trajectory, epsilon):
    """θ̂(η): every agent's ordinary policy step on env reward + incentives received on `traj`.

    This is how every giver models every recipient, the adversary included.
    The incentives are recomputed from η on the recorded observations and
    actions, so θ̂ is a differentiable function of η.
    """
    return ordinary_step(
        env, cfg, policy, traj, received(emitted(env, cfg, incentive, traj)), epsilon
    )


def actual_update(
    env, cfg, attack: Attack, attack_state, policy, traj: Trajectory, epsilon, accepted=None
):
    """Every agent's actual policy step: the ordinary one, except where the attack
    changes the adversary's learning reward (self-centered) or sign (reverse, ADMO).

    `accepted` [T, N, N]: the incentives recipients learn from (defenses); default all sent.
    """
    policy_module, _ = _modules(env, cfg)
    sent = traj.incentives if accepted is None else accepted
    got = received(sent) * traj.valid[:, None]
    rewards = attack.learning_rewards(attack_state, traj.env_rewards, got)
    return policy_step(
        policy_module,
        policy,
        traj,
        rewards,
        epsilon,
        cfg.lr_policy,
        cfg.gamma,
        cfg.entropy_coef,
        sign=attack.policy_sign(attack_state, env.num_agents),
    )


def giver_objective(
    incentive, giver: jax.Array, env, cfg, policy, traj, epsilon, new_traj
) -> jax.Array:
    """Giver i's surrogate: Σ_{j≠i} Σ_t log π_θ̂j(η)(â_t^j|ô_t^j)·Ĝ_t^{i,env} (plain softmax).

    Args:
        incentive: all givers' stacked η; θ̂(η) is recomputed from it on τ.
        giver: i.
        traj, new_traj: τ (played with θ) and τ̂ (played with θ̂).
    """
    new_policy = recipient_update(env, cfg, policy, incentive, traj, epsilon)
    taken = taken_log_probs(env, cfg, new_policy, new_traj)
    env_returns = discounted_returns(new_traj.env_rewards[:, giver], cfg.gamma)  # [T]
    recipients = (jnp.arange(env.num_agents) != giver).astype(jnp.float32)
    mask = new_traj.valid.astype(jnp.float32)
    return jnp.sum(taken * recipients[None, :] * (mask * env_returns)[:, None])


def own_giver_objective(own_incentive, giver, env, cfg, policy, incentive, traj, epsilon, new_traj):
    """`giver_objective` as a function of giver i's own η_i, the other givers' η held fixed."""
    eta = jax.tree.map(lambda stacked, own: stacked.at[giver].set(own), incentive, own_incentive)
    return giver_objective(eta, giver, env, cfg, policy, traj, epsilon, new_traj)


def recipient_log_probs(env, cfg, policy, traj, received_incentives, epsilon, new_traj):
    """log π_θ̂j(â_t^j | ô_t^j) [T, N] on τ̂, with θ̂ the policy step on τ taken on
    env reward + `received_incentives` [T, N] (plain softmax, as the original)."""
    new_policy = ordinary_step(env, cfg, policy, traj, received_incentives, epsilon)
    return taken_log_probs(env, cfg, new_policy, new_traj)


def recipient_pullbacks(env, cfg, policy, incentive, traj, epsilon, new_traj):
    """The two reverse passes of the second-order path, as pullback functions.

    Returns:
        (pull_incentives, pull_recipients): `pull_incentives(c [T, N, N])` pulls a
        cotangent on the incentives emitted on τ back to η; `pull_recipients(c [T, N])`
        pulls a cotangent on the recipients' log π_θ̂j(â_t^j|ô_t^j) on τ̂ back to the
        incentives each received on τ.
    """
    given, pull_incentives = jax.vjp(lambda eta: emitted(env, cfg, eta, traj), incentive)
    _, pull_recipients = jax.vjp(
        lambda r: recipient_log_probs(env, cfg, policy, traj, r, epsilon, new_traj),
        received(given),
    )
    return (lambda c: pull_incentives(c)[0]), (lambda c: pull_recipients(c)[0])


def meta_gradients(env, cfg, policy, incentive, traj, epsilon, new_traj):
    """Every giver's gradient of its surrogate (`giver_objective`), by the chain rule in JAX.

    The surrogates depend on η only through the incentives u(η) [T, giver, recipient]
    on τ, and the recipients' updates only through what each receives. So one
    reverse pass through the recipients' updates (θ̂ and log π_θ̂ on τ̂), pulled back
    with one cotangent per giver, and one pass through the incentive nets give every
    giver's gradient — equal to `jax.grad(own_giver_objective)` per giver (tested),
    at a fraction of the cost of differentiating N copies of the whole update.

    Returns leaves [N, ...] (giver i's gradient w.r.t. η_i): the "own" updates, and the
    "shared" ones for N = 2 (`one_by_one` takes the shared ones for N ≥ 3).
    """
    pullbacks = recipient_pullbacks(env, cfg, policy, incentive, traj, epsilon, new_traj)
    return meta_gradients_from(env, cfg, pullbacks, traj, new_traj)


def giver_cotangents(env, cfg, new_traj) -> jax.Array:
    """[giver, T, recipient]: giver i's surrogate J_i = Σ_t Σ_{j≠i} log π_θ̂j(â_t^j)·Ĝ_t^{i,env}
    as a cotangent on the recipients' log-probabilities on τ̂."""
    env_returns = discounted_returns(new_traj.env_rewards, cfg.gamma) * new_traj.valid[:, None]
    others = 1.0 - jnp.eye(env.num_agents)
    return env_returns.T[:, :, None] * others[:, None, :]


def meta_gradients_from(env, cfg, pullbacks, traj, new_traj):
    """`meta_gradients` from already computed `recipient_pullbacks`."""
    pull_incentives, pull_recipients = pullbacks
    cotangents = giver_cotangents(env, cfg, new_traj)  # [giver, T, recipient]
    d_received = jax.vmap(pull_recipients)(cotangents)  # dJ_i / d received_j(t)
    # Giver k's own objective only, on its own row u[t, k, :].
    return pull_incentives(jnp.swapaxes(d_received, 0, 1))


def meta_gradients_reference(env, cfg, policy, incentive, traj, epsilon, new_traj):
    """The slow reference: `jax.grad` of each giver's surrogate w.r.t. its own η (vmapped)."""
    givers = jnp.arange(env.num_agents)

    def own(own_incentive, giver):
        return own_giver_objective(
            own_incentive, giver, env, cfg, policy, incentive, traj, epsilon, new_traj
        )

    return jax.vmap(jax.grad(own))(incentive, givers)


def meta_step(cfg, incentive, opt_state, grads):
    """The meta-gradient step: Adam ascent (rate `lr_incentive`) along `grads` — every
    giver on its own surrogate at once (`incentive` the stacked η), or one giver's turn
    (`incentive` the pair (η, θ) its surrogate depends on, `giver_turns`)."""
    ascent = jax.tree.map(jnp.negative, grads)  # Adam minimises
    updates, opt_state = optax.adam(cfg.lr_incentive).update(ascent, opt_state)
    return optax.apply_updates(incentive, updates), opt_state


def cost_step(cfg, incentive, opt_state, cost_grad, giver: int | None = None):
    """The separate cost step: Adam descent (rate `lr_cost`) along `cost_grad()`, the
    gradient of the incentive cost, taken only when there is a step (`lr_cost` > 0).

    Args:
        incentive: every giver's stacked η.
        giver: None: the step moves every η_i (`cost_grad()` over the stacked η); giver i:
            only η_i (`cost_grad()` over η_i, `opt_state` giver i's own).
    """
    if not cfg.lr_cost > 0:
        return incentive, opt_state
    updates, opt_state = optax.adam(cfg.lr_cost).update(cost_grad(), opt_state)
    if giver is None:
        return optax.apply_updates(incentive, updates), opt_state
    own = optax.apply_updates(agent_row(incentive, giver), updates)
    return with_agent_row(incentive, giver, own), opt_state


def giver_cost(own_incentive, giver, env, cfg, traj: Trajectory) -> jax.Array:
    """Giver i's term of `incentive_cost`, a function of its own η_i."""
    _, incentive_module = _modules(env, cfg)
    x = incentive_input(traj.obs, traj.actions, env.num_actions)[:, giver]  # [T, D]
    out = jax.nn.sigmoid(incentive_module.apply(own_incentive, x))
    out = out * (1.0 - jax.nn.one_hot(giver, env.num_agents))
    discount = cfg.gamma ** jnp.arange(traj.valid.shape[0]) * traj.valid
    return jnp.sum(discount[:, None] * out)


def other_givers_gradients(env, cfg, givers, incentive, traj, d_received):
    """(meta, cost) gradients [N, ...] of the givers `givers` (all but a learning attack's
    adversary, whose rows are zero), in one backward pass through the incentive nets.

    Args:
        d_received: [G, T, N] each giver's surrogate pulled back to the incentives every
            recipient received on τ (the recipients' part of the second-order path).
    """
    _, incentive_module = _modules(env, cfg)
    n = env.num_agents
    _, pull = jax.vjp(
        lambda eta: sigmoid_outputs(incentive_module, eta, traj.obs, traj.actions, env.num_actions),
        incentive,
    )
    taking = jnp.zeros((n,)).at[jnp.array(givers)].set(1.0)  # [giver]
    rows = jnp.zeros((n,) + d_received.shape[1:]).at[jnp.array(givers)].set(d_received)
    emitted_scale = cfg.incentive_max * traj.incentive_scale  # d emitted / d sigmoid output
    discount = cfg.gamma ** jnp.arange(traj.valid.shape[0]) * traj.valid
    cotangents = jnp.stack(
        [
            jnp.swapaxes(rows, 0, 1) * emitted_scale,  # [T, giver, recipient]
            discount[:, None, None] * taking[None, :, None] * jnp.ones((1, 1, n)),
        ]
    )
    (grads,) = jax.vmap(pull)(cotangents)
    return jax.tree.map(lambda g: g[0], grads), jax.tree.map(lambda g: g[1], grads)


def giver_turns(env, cfg, givers, frozen, policy, incentive, opts, traj, epsilon, new_traj):
    """The "shared" incentive updates for N ≥ 3, one giver after another (the original's).

    Giver i's Adam step ascends its surrogate (`giver_objective`) in every parameter it
    depends on — every giver's η and the recipients' current θ — and its cost step
    descends its own cost term, both gradients taken where the previous givers left the
    parameters. The moved θ only affect the later givers' gradients: θ ← θ̂ follows.

    Args:
        givers: the givers taking a turn, in order (static).
        frozen: a giver whose η no step may move (a learning attack's adversary), or None.
        opts: (per-giver meta states, per-giver cost states), leaves [N giver, ...].
    Returns:
        (η, opts).
    """

    def turn(incentive, policy, giver: int, own_meta, own_cost):
        grads = jax.grad(giver_objective, argnums=(0, 4))(
            incentive, giver, env, cfg, policy, traj, epsilon, new_traj
        )
        (moved, policy_moved), own_meta = meta_step(cfg, (incentive, policy), own_meta, grads)
        moved, own_cost = cost_step(
            cfg,
            moved,
            own_cost,
            lambda: jax.grad(giver_cost)(agent_row(incentive, giver), giver, env, cfg, traj),
            giver,
        )
        if frozen is not None:
            moved = with_agent_row(moved, frozen, agent_row(incentive, frozen))
        return moved, policy_moved, own_meta, own_cost

    # Unrolled over the (static) givers: each turn reads its own row of the per-giver
    # optimizer states by a static slice, and the rows are stacked back once. A scan over
    # the givers made the seed vmap transpose the states to [giver, seed, ...] and back
    # (as the scan's inputs and outputs) or copy them whole twice per turn (as its carry).
    n = jax.tree.leaves(incentive)[0].shape[0]
    rows = [jax.tree.map(lambda x, i=i: x[i], opts) for i in range(n)]
    for giver in givers:
        incentive, policy, own_meta, own_cost = turn(incentive, policy, giver, *rows[giver])
        rows[giver] = (own_meta, own_cost)
    return incentive, jax.tree.map(lambda *r: jnp.concatenate([x[None] for x in r]), *rows)


def incentive_cost(incentive, env, cfg, traj: Trajectory) -> jax.Array:
    """Σ_i Σ_t γ^t Σ_{j≠i} sigmoid_i^j on τ (raw outputs, not × R_max), invalid steps masked."""
    _, incentive_module = _modules(env, cfg)
    out = sigmoid_outputs(incentive_module, incentive, traj.obs, traj.actions, env.num_actions)
    discount = cfg.gamma ** jnp.arange(traj.valid.shape[0]) * traj.valid
    return jnp.sum(discount[:, None, None] * out)


def policy_gradient_components(env, cfg, policy, traj: Trajectory, rewards, epsilon):
    """Flat score-function gradients [K, N, P] of every agent's policy loss (no entropy)
    on `traj`, one per reward source `rewards` [K, T, N] (the health monitor's input)."""
    policy_module, _ = _modules(env, cfg)

    def one(source):
        returns = discounted_returns(source, cfg.gamma)
        per_agent_epsilon = 0 if jnp.ndim(epsilon) else None
        grads = jax.vmap(
            jax.grad(reinforce_loss), in_axes=(0, None, 1, 1, 1, None, per_agent_epsilon, None)
        )(policy, policy_module, traj.obs, traj.actions, returns, traj.valid, epsilon, 0.0)
        leaves = jax.tree.leaves(grads)
        return jnp.concatenate([g.reshape(g.shape[0], -1) for g in leaves], axis=1)

    return jax.vmap(one)(rewards)


def update(
    state: LIOState,
    env: Env,
    cfg: LIOConfig,
    attack: Attack = NO_ATTACK,
    defenses: Defenses = NO_DEFENSE,
) -> tuple[LIOState, dict[str, jax.Array]]:
    """One LIO iteration (two rollouts), with the attack and the defenses consulted at
    their hook points."""
    key, key_first, key_second = jax.random.split(state.key, 3)
    schedule_epsilon = epsilon_at(
        state.iteration, cfg.epsilon_start, cfg.epsilon_end, cfg.epsilon_decay_iters
    )
    honest = defense_hooks.honest_agents(attack, env.num_agents)

    # 1. EXPLORE: the acting ε (defense hook: acting_epsilon)
    epsilon = defense_hooks.acting_epsilon(
        defenses, state.defense_state, EpsilonContext(schedule_epsilon, honest)
    )
    # 2. COLLECT τ with θ and η (attack hooks: act, emit)
    traj = play(env, cfg, attack, state, state.policy, epsilon, key_first, state.env_steps)
    env_steps = state.env_steps + traj.valid.sum()
    # 3. RECIPIENTS θ → θ̂ on env reward + the incentives they accept (defense hooks:
    #    learning_incentives, after_policy_step; attack hooks: learning_rewards, policy_sign)
    new_policy, defense_state, defense_metrics = recipients_step(
        env, cfg, attack, defenses, state, traj, epsilon, honest
    )
    # 4. COLLECT τ̂ with θ̂
    new_traj = play(env, cfg, attack, state, new_policy, epsilon, key_second, env_steps)
    env_steps = env_steps + new_traj.valid.sum()
    # 5. GIVERS η → η' through the recipients' updates, and the cost step; a learning
    #    attack's step replaces the adversary's (attack hook: adversary_step)
    success = episode_metrics(env, traj)["success"]
    incentive, opts, new_policy, attack_state, attack_metrics = givers_step(
        env, cfg, attack, state, traj, new_traj, new_policy, epsilon, schedule_epsilon, success
    )
    # 6. OBSERVE: the attack's own state (attack hook: observe)
    attack_state = attack.observe(
        attack_state, attack_key(key_first), Outcome(success, state.iteration, env_steps)
    )

    # 7. θ ← θ̂
    new_state = LIOState(
        policy=new_policy,
        incentive=incentive,
        incentive_opt=opts[0],
        cost_opt=opts[1],
        attack_state=attack_state,
        defense_state=defense_state,
        key=key,
        iteration=state.iteration + 1,
        env_steps=env_steps,
    )
    metrics = {"train/epsilon": schedule_epsilon, "train/success": success}
    return new_state, {**metrics, **defense_metrics, **attack_metrics}


def play(env, cfg, attack, state: LIOState, policy, epsilon, key, env_steps) -> Trajectory:
    """One episode with the policies `policy` (ε-mixed) and the incentive functions η of
    `state` (attack hooks: act, emit)."""
    policy_module, incentive_module = _modules(env, cfg)
    give = give_fn(incentive_module, state.incentive, env.num_actions, cfg.incentive_max)
    act = act_fn(policy_module, policy, epsilon)
    return rollout(env, key, act, give, attack, env_steps, state.attack_state)


def recipients_step(env, cfg, attack, defenses, state: LIOState, traj: Trajectory, epsilon, honest):
    """θ → θ̂: every recipient's actual policy step on τ, on env reward + the incentives it
    accepts (defense hooks: learning_incentives, after_policy_step; attack hooks:
    learning_rewards, policy_sign).

    Returns:
        (θ̂, the defenses' states, their metrics).
    """
    accepted, defense_state, incentive_metrics = defense_hooks.learning_incentives(
        defenses,
        state.defense_state,
        IncentiveContext(
            traj.incentives * traj.valid[:, None, None],
            traj.incentives,
            traj.valid,
            cfg.incentive_max,
            honest,
        ),
    )
    new_policy = actual_update(
        env, cfg, attack, state.attack_state, state.policy, traj, epsilon, accepted
    )
    new_policy, defense_state, monitor_metrics = defense_hooks.after_policy_step(
        defenses,
        defense_state,
        PolicyStepContext(
            new_policy,
            state.iteration,
            traj.incentives,
            traj.valid,
            traj.env_rewards,
            lambda r: policy_gradient_components(env, cfg, state.policy, traj, r, epsilon),
            cfg.incentive_max,
            honest,
        ),
    )
    return new_policy, defense_state, {**incentive_metrics, **monitor_metrics}


def givers_step(
    env, cfg, attack, state, traj, new_traj, new_policy, epsilon, schedule_epsilon, success
):
    """η → η': every giver's meta-gradient step through the recipients' updates and its cost
    step; a learning attack's own step replaces the adversary's (attack hook: adversary_step).

    "Shared" updates for N ≥ 3 take the givers' steps one after another (`giver_turns`),
    otherwise all at once (`all_at_once`), the attack's second-order pass then batched with
    the other givers' (taken at the same point).

    Returns:
        (η', (meta-gradient opt state, cost opt state), θ̂ with the adversary's row
        replaced, attack state, attack metrics).
    """
    learning = "adversary_step" in attack.hooks
    a, sequential = attack.adversary, one_by_one(cfg, env.num_agents)
    givers = [i for i in range(env.num_agents) if not (learning and i == a)]
    policy, incentive, opts = state.policy, state.incentive, (state.incentive_opt, state.cost_opt)
    if learning or not sequential:
        pullbacks = recipient_pullbacks(env, cfg, policy, incentive, traj, epsilon, new_traj)
    if sequential:
        frozen = a if learning else None
        incentive, opts = giver_turns(
            env, cfg, givers, frozen, policy, incentive, opts, traj, epsilon, new_traj
        )
    attack_state, attack_metrics, read_back = state.attack_state, {}, None
    if learning:
        batched = None if sequential else giver_cotangents(env, cfg, new_traj)[jnp.array(givers)]
        # the adversary runs no defense: its ε is the schedule's
        view, read_back = adversary_view(
            env,
            cfg,
            attack,
            state,
            pullbacks,
            new_policy,
            traj,
            new_traj,
            success,
            schedule_epsilon,
            batched,
        )
        own, attack_state, attack_metrics = attack.adversary_step(
            attack_state, attack_key(state.key), view
        )
    if not sequential:
        incentive, opts = all_at_once(env, cfg, givers, state, pullbacks, traj, new_traj, read_back)
    if learning:
        new_policy = with_agent_row(new_policy, a, own.policy)
        incentive = with_agent_row(incentive, a, own.incentive)
    return incentive, opts, new_policy, attack_state, attack_metrics


def all_at_once(env, cfg, givers, state: LIOState, pullbacks, traj, new_traj, read_back):
    """The givers' meta-gradient and cost steps all at once, each on its own η_i.

    Without a learning attack (`read_back` None) every giver's gradients come from the
    second-order pass `pullbacks` (`meta_gradients_from`); with one, those of `givers` (all
    but the adversary) from their cotangents that `read_back()` gives back from the
    attack's batched pass (`other_givers_gradients`).

    Returns:
        (η', (meta-gradient opt state, cost opt state)).
    """
    if read_back is None:
        meta_grad = meta_gradients_from(env, cfg, pullbacks, traj, new_traj)

        def cost_grad():
            return jax.grad(incentive_cost)(state.incentive, env, cfg, traj)

    else:
        d_received = read_back()  # [giver ≠ a, T, N], from the attack's pass (or its own)
        meta_grad, their_cost_grad = other_givers_gradients(
            env, cfg, givers, state.incentive, traj, d_received
        )

        def cost_grad():
            return their_cost_grad

    incentive, incentive_opt = meta_step(cfg, state.incentive, state.incentive_opt, meta_grad)
    incentive, cost_opt = cost_step(cfg, incentive, state.cost_opt, cost_grad)
    return incentive, (incentive_opt, cost_opt)


def adversary_view(
    env, cfg, attack, state, pullbacks, new_policy, traj, new_traj, success, epsilon, batched
):
    """What a learning attack sees of this iteration: τ̂ judged, τ learnt from.

    Its `meta_pullback` goes through the recipients' modelled updates (at θ, η of the
    iteration's start) and then through the adversary's own incentive net only; its
    `emitted` recomputes only the adversary's row from η_a. `batched`: other givers'
    cotangents [K', T, N] to pull back through the recipients in the same pass as the
    attack's, or None.

    Returns:
        (view, read_back): read_back() gives the pulled-back `batched` cotangents
        [K', T, N] — from the attack's pass when it made one, else from a pass of their own.
    """
    policy_module, incentive_module = _modules(env, cfg)
    a = attack.adversary

    def log_probs(theta_a):
        logits = policy_module.apply(theta_a, new_traj.obs[:, a])
        log_probs = nets.mixed_log_probs(logits, epsilon)
        taken = jnp.take_along_axis(log_probs, new_traj.actions[:, a, None], axis=1)[:, 0]
        return taken * new_traj.valid

    def own_row(eta_a, t: Trajectory):
        """The adversary's emitted incentives [T, N] on `t` as a function of η_a."""
        x = incentive_input(t.obs, t.actions, env.num_actions)[:, a]
        out = jax.nn.sigmoid(incentive_module.apply(eta_a, x)) * (1.0 - jnp.eye(env.num_agents)[a])
        return cfg.incentive_max * out * t.incentive_scale[:, a] + t.incentive_offset[:, a]

    def emitted_hat(eta_a):  # the other givers' rows as they gave them on τ̂
        return new_traj.incentives.at[:, a].set(own_row(eta_a, new_traj))

    eta_a = agent_row(state.incentive, a)
    _, pull_own = jax.vjp(lambda eta: own_row(eta, traj), eta_a)
    meta_pullback, read_back = adversary_pullback(pullbacks[1], pull_own, batched)
    view = AdversaryView(
        policy=new_policy,  # the adversary's row is unchanged: its policy sign is 0
        incentive=state.incentive,
        log_probs=log_probs,
        env_rewards=new_traj.env_rewards,
        valid=new_traj.valid,
        emitted=emitted_hat,
        meta_pullback=meta_pullback,
        received=received(traj.incentives)[:, a],
        received_valid=traj.valid,
        emission_scales=tuple((t.incentive_scale, t.valid) for t in (traj, new_traj)),
        success=success,
        gamma=cfg.gamma,
        iteration=state.iteration,
    )
    return view, read_back


def adversary_pullback(pull_recipients, pull_own, batched):
    """The adversary's `meta_pullback`: its cotangents [K, T, N] on the recipients'
    log-probabilities on τ̂ pulled back through their modelled updates (`pull_recipients`)
    and then through its own incentive net (`pull_own`), the other givers' cotangents
    `batched` [K', T, N] (or None) pulled back through the recipients in the same pass as
    its first call.

    Returns:
        (meta_pullback, read_back): read_back() gives the pulled-back `batched` cotangents
        [K', T, N] — from the attack's pass when it made one, else from a pass of their own.
    """
    pulled: list[jax.Array] = []

    def meta_pullback(cotangents):
        k = cotangents.shape[0]
        if batched is not None and not pulled:
            both = jax.vmap(pull_recipients)(jnp.concatenate([cotangents, batched]))
            pulled.append(both[k:])
            d_received = both[:k]
        else:
            d_received = jax.vmap(pull_recipients)(cotangents)
        return jax.vmap(lambda c: pull_own(c)[0])(d_received)

    def read_back():
        return pulled[0] if pulled else jax.vmap(pull_recipients)(batched)

    return meta_pullback, read_back


def acting(env: Env, cfg: LIOConfig, state: LIOState) -> Actor:
    """The trained policies at ε = 0 (actions sampled) and the learned incentives."""
    policy_module, incentive_module = _modules(env, cfg)
    return Actor(
        act_fn(policy_module, state.policy, jnp.float32(0.0)),
        give_fn(incentive_module, state.incentive, env.num_actions, cfg.incentive_max),
    )


def evaluate(
    key: jax.Array,
    state: LIOState,
    env: Env,
    cfg: LIOConfig,
    episodes: int,
    attack: Attack = NO_ATTACK,
):
    """Per-episode metrics [episodes, ...] of evaluation episodes (ε = 0, actions sampled).

    The attack acts and emits during evaluation as during training.
    """
    return evaluate_actor(key, env, acting(env, cfg, state), episodes, attack, state)
