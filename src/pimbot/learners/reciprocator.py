"""Reciprocator (Zhou, Hong, Kao, NeurIPS 2024) and the naive learner `nl` (its weight 0).

One iteration, per seed and for all agents at once (docs/reciprocators.md):
  1. play `num_envs` parallel episodes with the current softmax policies;
  2. store them, and every `voi_refit_period` iterations refit the value-of-
     influence estimate on the last `voi_history` batches: learned models
     (`voi="learned"`, `influence.py`) or, on matrix games, the others' action
     frequencies per state for the exact VoI (`voi="exact"`, `exact_voi.py`);
  3. VoI of every ordered pair on every step, the influence balance per pair
     (`grudge="accumulated"`: γ-discounted credit − debit; `"petty"`: γ-discounted
     credit only, the original's `petty_rr`; `"one_step"`: the other's influence on
     the previous step only, the original's IPD agent), and each agent's reciprocal
     reward mean_j B_{t−1}·VoI(self→j, t);
  4. PPO (clip, entropy bonus, `ppo_epochs` full-batch Adam epochs) on the
     Monte-Carlo return of env + w·reciprocal reward, normalized per batch per
     agent; advantage = normalized return − V̂(o).
No reward moves between agents: a Reciprocator shapes others only by acting.
Matrix games declare the original's IPD agent as their default (exact VoI,
one-step grudge, width-2 networks, 2048 games, refit every 3 on the last batch);
gridworlds use the learned VoI: Escape Room with the credit − debit balance the
Reciprocator's authors publish (johnlyzhou/reciprocator `configs/coins.yaml`, "petty_payoff")
at the PIMbot code's Escape Room script's learner settings (greedy_agent
`reciprocators/run_er.py`: lr 1e-4, γ 0.99, entropy 0.01, w 5, VoI lr 1e-3) and 128
episodes per update (the script's credit-only 'linear' balance is `grudge="petty"`), the
Stag Hunt gridworld with the accumulated balance as well.

Attacks act through the adversary's actions (bypass), its learning reward
(self-centered: it learns from env reward only, i.e. it is a naive learner),
the sign of its policy loss (reverse), or replace its policy update through
the `AdversaryView` of the batch (ADMO on θ_a; the signal the adversary
"receives" is the influence others exert on it), or schedule every agent's PPO
epochs and the scale of its reciprocal weight before step 4 from the same view
of the batch, before the update (`update_schedule`; the published code's ADMO).
There is no incentive channel.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import optax
from flax import struct

from pimbot import nets
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
from pimbot.contracts.defense import NO_DEFENSE, Defenses
from pimbot.contracts.learner import Actor
from pimbot.contracts.rollout import Trajectory, discounted_returns, episode_metrics, rollout
from pimbot.envs.core import Env, InvalidParameter, TracedFields
from pimbot.errors import check_choice
from pimbot.learners import epoch_schedule, exact_voi, influence, reciprocator_nets, tabular
from pimbot.learners.pg import act_fn, evaluate_actor


@dataclasses.dataclass(frozen=True)
class ReciprocatorConfig(TracedFields):
    """Reciprocator hyperparameters. The base is the general (learned-VoI) agent with the
    original IPD's PPO settings; matrix games declare the original's IPD agent at their
    registration, Escape Room the original Escape Room script's settings, the Stag Hunt
    gridworld w = 1.

    The numbers in `traced_fields` and the balance (`grudge`, as its index in `GRUDGES`:
    `program_form`) are traced arguments of the compiled program, so runs that differ only
    in them (the petty and the credit − debit balance, `nl`'s weight 0) share one program;
    sizes, counts and the other choices are its structure."""

    traced_fields: ClassVar[tuple[str, ...]] = (
        "reciprocal_weight",
        "lr",
        "clip",
        "entropy_coef",
        "value_coef",
        "gamma",
        "voi_lr",
        "grudge",
    )

    reciprocal_weight: float = 5.0
    """w: weight of the reciprocal reward added to the env reward (0 = naive learner)."""
    num_envs: int = 128
    """Parallel episodes per update per seed (original IPD: 2048; 128 fits a laptop)."""
    policy_hidden: tuple[int, ...] = (64, 64)
    """Hidden layer widths of the policy MLP (the value MLP has the same)."""
    lr: float = 5e-3
    """Adam learning rate of the policy and value networks."""
    ppo_epochs: int = 10
    """Full-batch PPO epochs per update."""
    clip: float = 0.1
    """PPO ratio clip."""
    entropy_coef: float = 0.02
    """Weight of the entropy bonus."""
    value_coef: float = 0.5
    """Weight of the value loss (MSE to the normalized return)."""
    gamma: float = 0.96
    """Discount of the returns, the future-value models and the balance."""
    voi_hidden: tuple[int, ...] = (64, 64)
    """Hidden layer widths of every VoI model."""
    voi_lr: float = 1e-2
    """Adam learning rate of the VoI models."""
    voi_refit_period: int = 2
    """Iterations between refits of the VoI models."""
    voi_history: int = 3
    """Refit on the last this many batches."""
    voi_steps: int = 10
    """Adam steps per refit."""
    voi_batch: int = 512
    """Samples per Adam step of the refit (drawn from the stored batches)."""
    voi_minibatch_rows: str = "each_draw"
    """How a refit step evaluates its `voi_batch` draws: "each_draw" (every drawn sample,
    as the original) or "distinct_weighted" (each stored sample once, weighted by its
    draws: the same loss in exact arithmetic, rounding apart, and far fewer rows where
    the history holds fewer samples than `voi_batch`, e.g. num_envs = 1; `influence`)."""
    voi: str = "learned"
    """How the value of influence is computed: "learned" (reward and future-value models
    against counterfactual models, any env) or "exact" (matrix games: the known payoffs
    against the others' empirical action frequencies per state; reward term only)."""
    grudge: str = "accumulated"
    """The balance B_{t−1} that scales the reciprocal reward: "accumulated" (γ B + VoI(j→self)
    − VoI(self→j), the general agent), "petty" (γ B + VoI(j→self): credit only, the
    original's `petty_rr`, its Escape Room script's 'linear') or "one_step" (VoI(j→self, t−1)
    only: no accumulation, no debit, the original's IPD agent)."""
    voi_rewards: str = "env"
    """What an agent's VoI on the others, in its reciprocal reward, is measured in: "env"
    (their env rewards) or "after_earlier_agents" (an agent j < i counts with the weighted
    reciprocal reward it added to its own: the original IPD code's in-place update of the
    shared reward tensor, agents updated in id order; `influence`)."""
    net_input: str = "observation"
    """What the policy and value networks see: "observation" (the env's) or
    "previous_actions" (matrix games: every agent's previous action as a number, (−1, 0, …)
    at the first step; the original's IPD state). `reciprocator_nets`."""
    policy_head: str = "softmax"
    """"softmax" (a logit per action) or "sigmoid" (two actions, one logit: the original's
    Bernoulli actor)."""
    net_init: str = "glorot"
    """Network init: "glorot" (Glorot-uniform kernels, zero biases) or "fan_in_uniform"
    (kernels and biases uniform in ±1/√fan_in, PyTorch's default, the original's)."""

    RANGES: ClassVar[dict] = {
        "num_envs": (1, None),
        "ppo_epochs": (1, None),
        "clip": (0.0, 1.0),
        "gamma": (0.0, 1.0),
        "voi_refit_period": (1, None),
        "voi_history": (1, None),
        "voi_batch": (1, None),
    }
    """Checked ranges (low, high) of the fields; the others are ≥ 0 (`check_fields`)."""

    def program_form(self) -> ReciprocatorConfig:
        """The config as the compiled program takes it: the balance as its index in
        `GRUDGES` (`influence.next_balance` selects the formula by it)."""
        check_choice("grudge", self.grudge, GRUDGES)
        return dataclasses.replace(self, grudge=influence.grudge_index(self.grudge))


VOI_KINDS = ("learned", "exact")
GRUDGES = influence.GRUDGES
CHOICES = {
    "voi": VOI_KINDS,
    "grudge": GRUDGES,
    "voi_rewards": influence.VOI_REWARDS,
    "voi_minibatch_rows": influence.MINIBATCH_ROWS,
    "net_input": reciprocator_nets.NET_INPUTS,
    "policy_head": reciprocator_nets.POLICY_HEADS,
    "net_init": reciprocator_nets.NET_INITS,
}


def check_config(env: Env, cfg: ReciprocatorConfig) -> None:
    """Refuses unknown choices, exact VoI or previous-action inputs outside matrix games,
    and the sigmoid head unless there are two actions."""
    for name, allowed in CHOICES.items():
        value = getattr(cfg, name)
        if name in cfg.traced_fields and not isinstance(value, str):
            continue  # the program form's traced index (`program_form` checked the name)
        check_choice(name, value, allowed)
    if cfg.voi == "exact" or cfg.net_input == "previous_actions":
        exact_voi.check_env(env)
    if cfg.policy_head == "sigmoid" and env.num_actions != 2:
        raise InvalidParameter(
            f"policy_head: 'sigmoid' needs two actions, the env has {env.num_actions}"
        )


@struct.dataclass
class ReplayBatches:
    """The last `voi_history` batches, flattened to samples (episode × step)."""

    x: jax.Array  # [H, S, in_dim] model inputs
    rewards: jax.Array  # [H, S, N] env rewards
    future: jax.Array  # [H, S, N] G_{t+1}
    valid: jax.Array  # [H, S] bool


@struct.dataclass
class ReciprocatorState:
    policy: dict  # stacked policy parameters, leaves [N, ...]
    value: dict  # stacked value parameters, leaves [N, ...]
    opt: optax.OptState  # Adam state over (policy, value)
    models: influence.InfluenceModels | exact_voi.ActionFrequencies  # by `voi`
    replay: ReplayBatches | None  # learned VoI: the stored batches; exact: None
    attack_state: Any  # the attack's own state (ADMO's), else an empty dict
    defense_state: tuple  # no defense hook point: always empty
    key: jax.Array
    iteration: jax.Array  # int32 []
    env_steps: jax.Array  # int32 [], environment steps taken in training


def _modules(env: Env, cfg: ReciprocatorConfig):
    return reciprocator_nets.modules(env, cfg.policy_hidden, cfg.net_input, cfg.policy_head)


def _masks(env: Env) -> jax.Array:
    return jnp.asarray(influence.input_masks(env.num_agents, env.obs_dim, env.num_actions))


def init(
    key: jax.Array,
    env: Env,
    cfg: ReciprocatorConfig,
    attack: Attack = NO_ATTACK,
    defenses: Defenses = NO_DEFENSE,
) -> ReciprocatorState:
    check_config(env, cfg)
    policy_module, value_module = _modules(env, cfg)
    policy_key, value_key, model_key, key = jax.random.split(key, 4)
    n = env.num_agents
    policy = reciprocator_nets.init_params(policy_module, policy_key, n, env.obs_dim, cfg.net_init)
    value = reciprocator_nets.init_params(value_module, value_key, n, env.obs_dim, cfg.net_init)
    if cfg.voi == "exact":
        models, replay = exact_voi.init_frequencies(env, cfg.voi_history), None
    else:
        in_dim = n * (env.obs_dim + env.num_actions)
        shape = (cfg.voi_history, cfg.num_envs * env.max_steps)
        models = influence.init_models(model_key, cfg.voi_hidden, n, in_dim, cfg.voi_lr)
        replay = ReplayBatches(
            x=jnp.zeros(shape + (in_dim,), jnp.float32),
            rewards=jnp.zeros(shape + (n,), jnp.float32),
            future=jnp.zeros(shape + (n,), jnp.float32),
            valid=jnp.zeros(shape, bool),
        )
    own = agent_row(policy, attack.adversary)
    attack_state = attack.init_state(attack_key(key), n, AgentParams(own, {}))
    del defenses  # the Reciprocator has no defense hook point
    zero = jnp.zeros((), jnp.int32)
    return ReciprocatorState(
        policy=policy,
        value=value,
        opt=(
            epoch_schedule.init(cfg.lr, (policy, value))  # per-agent epoch counts
            if "update_schedule" in attack.hooks
            else optax.adam(cfg.lr).init((policy, value))
        ),
        models=models,
        replay=replay,
        attack_state=attack_state,
        defense_state=(),
        key=key,
        iteration=zero,
        env_steps=zero,
    )


def normalized_returns(rewards: jax.Array, valid: jax.Array, gamma: float) -> jax.Array:
    """Monte-Carlo returns normalized per agent over the valid steps of the batch.

    Args:
        rewards: [E, T, N] (zero on invalid steps); valid: bool [E, T].
    Returns:
        [E, T, N], zero on invalid steps.
    """
    returns = jax.vmap(lambda r: discounted_returns(r, gamma))(rewards)
    mask = valid.astype(jnp.float32)[..., None]
    count = jnp.maximum(mask.sum(axis=(0, 1)), 1.0)
    mean = jnp.sum(returns * mask, axis=(0, 1)) / count
    var = jnp.sum(mask * (returns - mean) ** 2, axis=(0, 1)) / count
    return mask * (returns - mean) / (jnp.sqrt(var) + 1e-8)


def ppo_loss(params, modules, obs, actions, old_log_probs, returns, valid, sign, cfg):
    """Every agent's PPO loss, summed over agents (agent i's policy term × sign[i]).

    Args:
        params: (policy, value) stacked parameters.
        obs: [N, S, obs_dim]; actions, old_log_probs, returns: [N, S]; valid: [S]; sign: [N].
    """
    policy_module, value_module = modules
    policy, value = params
    log_probs = jax.nn.log_softmax(nets.apply_stacked(policy_module, policy, obs))  # [N, S, A]
    taken = jnp.take_along_axis(log_probs, actions[..., None], axis=-1)[..., 0]
    entropy = -jnp.sum(jnp.exp(log_probs) * log_probs, axis=-1)
    values = nets.apply_stacked(value_module, value, obs)[..., 0]
    advantage = jax.lax.stop_gradient(returns - values)
    ratio = jnp.exp(taken - old_log_probs)
    clipped = jnp.clip(ratio, 1.0 - cfg.clip, 1.0 + cfg.clip)
    surrogate = jnp.minimum(ratio * advantage, clipped * advantage)
    mask = valid.astype(jnp.float32)
    count = jnp.maximum(mask.sum(), 1.0)

    def mean(v):
        return jnp.sum(v * mask, axis=-1) / count

    policy_loss = -mean(surrogate) - cfg.entropy_coef * mean(entropy)  # [N]
    value_loss = mean((values - returns) ** 2)
    return jnp.sum(sign * policy_loss + cfg.value_coef * value_loss)


def ppo_update(env, cfg, policy, value, opt, trajs: Trajectory, returns, sign, schedule=None):
    """`ppo_epochs` full-batch Adam steps of `ppo_loss` on a batch of episodes.

    Args:
        trajs: leaves [E, T, ...]; returns: [E, T, N] normalized returns; sign: [N];
        schedule: an attack's `UpdateSchedule` (per-agent epochs; `opt` then holds Adam
            states per agent, `epoch_schedule.init`), or None: `ppo_epochs` for all.
    Returns:
        (policy, value, opt).
    """
    modules = _modules(env, cfg)
    n = env.num_agents
    obs = jnp.moveaxis(trajs.obs, 2, 0).reshape(n, -1, env.obs_dim)  # [N, S, obs_dim]
    actions = jnp.moveaxis(trajs.actions, 2, 0).reshape(n, -1)
    targets = jnp.moveaxis(returns, 2, 0).reshape(n, -1)
    valid = trajs.valid.reshape(-1)
    logits = nets.apply_stacked(modules[0], policy, obs)
    old = jnp.take_along_axis(jax.nn.log_softmax(logits), actions[..., None], axis=-1)[..., 0]
    optimizer = optax.adam(cfg.lr)
    grad_fn = jax.grad(ppo_loss)
    if schedule is not None:
        (policy, value), opt = epoch_schedule.run(
            lambda params: grad_fn(params, modules, obs, actions, old, targets, valid, sign, cfg),
            cfg.lr,
            (policy, value),
            opt,
            schedule.epochs,
            schedule.most_epochs,
        )
        return policy, value, opt

    def epoch(carry, _):
        params, opt = carry
        grads = grad_fn(params, modules, obs, actions, old, targets, valid, sign, cfg)
        updates, opt = optimizer.update(grads, opt, params)
        return (optax.apply_updates(params, updates), opt), None

    ((policy, value), opt), _ = jax.lax.scan(
        epoch, ((policy, value), opt), None, length=cfg.ppo_epochs
    )
    return policy, value, opt


def play_batch(env, cfg, policy, key, attack, env_steps, attack_state) -> Trajectory:
    """`num_envs` episodes with the current policies (no ε): leaves [E, T, ...].

    With `voi="exact"` (a matrix game) the policies are tabulated per state first, and
    without an attack that acts the batch is played by `tabular.play`."""
    if cfg.voi == "exact":
        tables = exact_voi.game_tables(env)
        logits = tabular.logits_table(_modules(env, cfg)[0], policy, tables, env.num_agents)
        trajs = None if "act" in attack.hooks else tabular.play(env, logits, key, cfg.num_envs)
        if trajs is not None:
            return trajs
        act = tabular.act_from_table(logits, tables)
    else:
        act = act_fn(_modules(env, cfg)[0], policy, jnp.float32(0.0))
    keys = jax.random.split(key, cfg.num_envs)
    return jax.vmap(lambda k: rollout(env, k, act, None, attack, env_steps, attack_state))(keys)


@jax.custom_batching.custom_vmap
def _same_in_every_seed(x: jax.Array) -> jax.Array:
    """`x`, unbatched under vmap (its first element): for a per-seed value that all seeds
    of a batch share, such as the iteration count (seeds start together and step
    together). It lets a `lax.cond` on it skip the untaken branch for every seed at
    once instead of computing both and selecting."""
    return x


@_same_in_every_seed.def_vmap
def _same_in_every_seed_vmap(axis_size, in_batched, x):
    del axis_size
    return (x[0] if in_batched[0] else x), False


def refit_due(cfg: ReciprocatorConfig, iteration: jax.Array) -> jax.Array:
    """Whether this iteration refits the VoI estimate (every `voi_refit_period`, from 0)."""
    return _same_in_every_seed(iteration % cfg.voi_refit_period == 0)


def refit_models(env, cfg, state: ReciprocatorState, key, x, trajs: Trajectory):
    """Stores this batch and refits the VoI models every `voi_refit_period` iterations."""
    future = jax.vmap(lambda r: influence.next_returns(r, cfg.gamma))(trajs.env_rewards)
    slot = state.iteration % cfg.voi_history
    samples = (-1,)
    replay = ReplayBatches(
        x=state.replay.x.at[slot].set(x.reshape(samples + x.shape[-1:])),
        rewards=state.replay.rewards.at[slot].set(trajs.env_rewards.reshape(-1, env.num_agents)),
        future=state.replay.future.at[slot].set(future.reshape(-1, env.num_agents)),
        valid=state.replay.valid.at[slot].set(trajs.valid.reshape(-1)),
    )

    def refit(models):
        return influence.fit(
            models,
            key,
            cfg.voi_hidden,
            _masks(env),
            replay.x.reshape(-1, x.shape[-1]),
            replay.rewards.reshape(-1, env.num_agents),
            replay.future.reshape(-1, env.num_agents),
            replay.valid.reshape(-1),
            lr=cfg.voi_lr,
            steps=cfg.voi_steps,
            batch_size=cfg.voi_batch,
            rows=cfg.voi_minibatch_rows,
        )

    due = refit_due(cfg, state.iteration)
    models, loss = jax.lax.cond(due, refit, lambda m: (m, jnp.zeros((), jnp.float32)), state.models)
    # × period: the mean over an evaluation period (a multiple of it) is the mean refit loss.
    return models, replay, loss * cfg.voi_refit_period


def influence_step(env, cfg, state: ReciprocatorState, key, trajs: Trajectory):
    """Refits the VoI estimate when due and returns it with every step's VoI.

    Returns:
        (models, replay, voi [E, T, N influencer, N influenced] zero on invalid steps,
        extra metrics).
    """
    if cfg.voi == "exact":
        tables = exact_voi.game_tables(env)
        states = exact_voi.state_one_hot(trajs.obs, tables)  # [E, T, K]
        models = exact_voi.store_and_refit(
            state.models,
            states.reshape(-1, states.shape[-1]),
            trajs.actions.reshape(-1, env.num_agents),
            trajs.valid.reshape(-1),
            state.iteration % cfg.voi_history,
            refit_due(cfg, state.iteration),
        )
        voi = exact_voi.value_of_influence(models.probs, tables, states, trajs.actions)
        return models, None, voi * trajs.valid[..., None, None], {}
    x = influence.model_inputs(trajs.obs, trajs.actions, env.num_actions)  # [E, T, in_dim]
    models, replay, model_loss = refit_models(env, cfg, state, key, x, trajs)
    voi = influence.value_of_influence(models.params, cfg.voi_hidden, _masks(env), x, cfg.gamma)
    return models, replay, voi * trajs.valid[..., None, None], {"train/model_loss": model_loss}


def voi_metrics(voi: jax.Array, actions: jax.Array, valid: jax.Array, num_actions: int) -> dict:
    """Mean VoI per ordered pair and by role, over the valid steps of the batch.

    `train/voi/agent_j_to_agent_i`: mean VoI(j → i) per step. The role of an agent on a
    step is the action it took (Escape Room: 0 lever, 1 start, 2 door; IPD: 0 cooperate,
    1 defect): `train/voi_role/action_x_to_action_y` is the mean VoI(j → i) over the
    ordered pairs and steps where j played x and i played y (0 where there were none),
    `train/voi_role_share/...` the share of pair-steps with those roles.

    Args:
        voi: [E, T, N, N] zero on invalid steps; actions: int [E, T, N]; valid: bool [E, T].
    """
    n = voi.shape[-1]
    mask = valid.astype(jnp.float32)
    steps = jnp.maximum(mask.sum(), 1.0)
    pair = voi.sum(axis=(0, 1)) / steps  # [N j, N i]
    off = 1.0 - jnp.eye(n, dtype=voi.dtype)
    one_hot = jax.nn.one_hot(actions, num_actions, dtype=jnp.float32) * mask[..., None, None]
    # weight[x, y, j, i]: pair-steps with j playing x and i playing y
    weight = jnp.einsum("etjx,etiy->xyji", one_hot, one_hot) * off
    total = jnp.einsum("etjx,etiy,etji->xy", one_hot, one_hot, voi)
    count = weight.sum(axis=(-2, -1))
    role = total / jnp.maximum(count, 1.0)
    share = count / jnp.maximum(count.sum(), 1.0)
    out = {}
    for j in range(n):
        for i in range(n):
            if i != j:
                out[f"train/voi/agent_{j}_to_agent_{i}"] = pair[j, i]
    for x in range(num_actions):
        for y in range(num_actions):
            out[f"train/voi_role/action_{x}_to_action_{y}"] = role[x, y]
            out[f"train/voi_role_share/action_{x}_to_action_{y}"] = share[x, y]
    return out


def update(
    state: ReciprocatorState,
    env: Env,
    cfg: ReciprocatorConfig,
    attack: Attack = NO_ATTACK,
    defenses: Defenses = NO_DEFENSE,
) -> tuple[ReciprocatorState, dict[str, jax.Array]]:
    """One training iteration: a batch of parallel episodes, a VoI refit when due, one PPO
    update."""
    del defenses
    key, play_key, fit_key = jax.random.split(state.key, 3)
    # 1. COLLECT the batch (attack hook: act)
    trajs = play_batch(
        env, cfg, state.policy, play_key, attack, state.env_steps, state.attack_state
    )
    # 2. STORE the batch and REFIT the VoI estimate when due; VoI of every ordered pair, step
    models, replay, voi, fit_metrics = influence_step(env, cfg, state, fit_key, trajs)
    # 3. BALANCE per pair and each agent's RECIPROCAL REWARD
    balances, reciprocal = jax.vmap(
        lambda v: influence.balance_and_reciprocal_reward(v, cfg.gamma, cfg.grudge)
    )(voi)
    # 4. PPO on env + w·reciprocal (attack hooks: update_schedule, learning_rewards, policy_sign)
    schedule, weight = attack_schedule(env, cfg, attack, state, trajs, voi, fit_key)
    rewards, reciprocal = shaped_rewards(
        cfg, attack, state, trajs, balances, voi, reciprocal, weight
    )
    returns = normalized_returns(rewards, trajs.valid, cfg.gamma)
    sign = attack.policy_sign(state.attack_state, env.num_agents)
    policy, value, opt = ppo_step(env, cfg, state, trajs, returns, sign, schedule)
    success = batch_success(env, trajs)
    metrics = {
        "train/success": success,
        **batch_metrics(trajs, reciprocal, voi),
        **fit_metrics,
        **voi_metrics(voi, trajs.actions, trajs.valid, env.num_actions),
        **(schedule.metrics if schedule is not None else {}),
    }
    # 5. a learning attack's step replaces the adversary's update (attack hook: adversary_step)
    policy, attack_state, attack_metrics = adversary_turn(
        env, cfg, attack, state, policy, trajs, voi, success
    )
    env_steps = state.env_steps + trajs.valid.sum()
    # 6. OBSERVE: the attack's own state (attack hook: observe)
    attack_state = attack.observe(
        attack_state, attack_key(play_key), Outcome(success, state.iteration, env_steps)
    )

    new_state = ReciprocatorState(
        policy=policy,
        value=value,
        opt=opt,
        models=models,
        replay=replay,
        attack_state=attack_state,
        defense_state=state.defense_state,
        key=key,
        iteration=state.iteration + 1,
        env_steps=env_steps,
    )
    return new_state, {**metrics, **attack_metrics}


def batch_success(env: Env, trajs: Trajectory) -> jax.Array:
    """The share of the batch's episodes that succeeded."""
    return jax.vmap(lambda t: episode_metrics(env, t))(trajs)["success"].mean()


def attack_schedule(env, cfg, attack, state: ReciprocatorState, trajs, voi, key):
    """(schedule, w): an attack's `update_schedule` of every agent's PPO epochs, from its view
    of the batch before the update, and the reciprocal weight it scales (per agent [N]);
    without that hook (None, `reciprocal_weight`)."""
    if "update_schedule" not in attack.hooks:
        return None, cfg.reciprocal_weight
    success = batch_success(env, trajs)
    view = adversary_view(env, cfg, attack, state.policy, trajs, voi, success, state.iteration)
    schedule = attack.update_schedule(state.attack_state, attack_key(key), view, cfg.ppo_epochs)
    return schedule, cfg.reciprocal_weight * schedule.reward_weight_scale


def shaped_rewards(cfg, attack, state: ReciprocatorState, trajs, balances, voi, reciprocal, weight):
    """Every agent's learning reward [E, T, N], env + `weight` · reciprocal reward as the
    attack lets it learn (attack hook: learning_rewards), and the reciprocal reward in it:
    `reciprocal` as given, or with `voi_rewards="after_earlier_agents"` recomputed in agent
    id order on the earlier agents' shaped rewards.

    Returns:
        (rewards, reciprocal) [E, T, N].
    """

    def learning_rewards(rec):
        return attack.learning_rewards(state.attack_state, trajs.env_rewards, weight * rec)

    if cfg.voi_rewards == "after_earlier_agents":
        reciprocal = influence.reciprocal_rewards_in_id_order(
            balances, voi, lambda rec: learning_rewards(rec) - trajs.env_rewards
        )
    return learning_rewards(reciprocal), reciprocal


def ppo_step(env, cfg, state: ReciprocatorState, trajs, returns, sign, schedule):
    """PPO on the batch (`ppo_update`); on a matrix game (`voi="exact"`) the same loss summed
    per state (`tabular.ppo_update`).

    Returns:
        (policy, value, opt).
    """
    if cfg.voi != "exact":
        return ppo_update(
            env, cfg, state.policy, state.value, state.opt, trajs, returns, sign, schedule
        )
    n, tables = env.num_agents, exact_voi.game_tables(env)
    states = exact_voi.state_one_hot(trajs.obs, tables)
    return tabular.ppo_update(
        _modules(env, cfg),
        cfg,
        tables,
        state.policy,
        state.value,
        state.opt,
        states.reshape(-1, states.shape[-1]),
        jnp.moveaxis(trajs.actions, 2, 0).reshape(n, -1),
        jnp.moveaxis(returns, 2, 0).reshape(n, -1),
        trajs.valid.reshape(-1),
        sign,
        schedule,
    )


def batch_metrics(trajs: Trajectory, reciprocal, voi) -> dict:
    """Per agent, means over the batch's valid steps: its reciprocal reward, the VoI it
    exerts on and receives from the others, and the share of steps on which it played
    action 0 (IPD: cooperate)."""
    valid = trajs.valid.astype(jnp.float32)
    count = jnp.maximum(valid.sum(), 1.0)

    def mean(x):  # [E, T, N] -> [N]
        return jnp.sum(x * valid[..., None], axis=(0, 1)) / count

    return {
        "train/reciprocal_reward": mean(reciprocal),
        "train/voi_given": mean(voi.sum(-1)),
        "train/voi_received": mean(voi.sum(-2)),
        "train/action_0_rate": mean(trajs.actions == 0),
    }


def adversary_turn(env, cfg, attack, state: ReciprocatorState, policy, trajs, voi, success):
    """A learning attack's step in place of the adversary's PPO update, from its view of the
    batch at the updated `policy` (attack hook: adversary_step).

    Returns:
        (policy with the adversary's row replaced, attack state, attack metrics); unchanged
        without that hook.
    """
    if "adversary_step" not in attack.hooks:
        return policy, state.attack_state, {}
    view = adversary_view(env, cfg, attack, policy, trajs, voi, success, state.iteration)
    own, attack_state, attack_metrics = attack.adversary_step(
        state.attack_state, attack_key(state.key), view
    )
    return with_agent_row(policy, attack.adversary, own.policy), attack_state, attack_metrics


def adversary_view(env, cfg, attack, policy, trajs, voi, success, iteration) -> AdversaryView:
    """What a learning attack sees: the batch it was played on (ω = θ_a, r = env reward),
    at the stacked `policy` (before PPO for `update_schedule`, after it for
    `adversary_step`)."""
    policy_module = _modules(env, cfg)[0]
    a = attack.adversary

    def log_probs(theta_a):  # invalid steps carry zero weight in the attack's losses
        logits = policy_module.apply(theta_a, trajs.obs[:, :, a])
        taken = jnp.take_along_axis(
            jax.nn.log_softmax(logits), trajs.actions[:, :, a, None], axis=-1
        )
        return taken[..., 0]

    return AdversaryView(
        policy=policy,  # after PPO for `adversary_step` (the adversary's sign is then 0)
        incentive=None,
        log_probs=log_probs,
        env_rewards=trajs.env_rewards,
        valid=trajs.valid,
        emitted=None,
        meta_pullback=None,
        received=voi[..., a].sum(-1),  # the influence the others exert on a [E, T]
        received_valid=trajs.valid,
        emission_scales=(),
        success=success,
        gamma=cfg.gamma,
        iteration=iteration,
    )


def acting(env: Env, cfg: ReciprocatorConfig, state: ReciprocatorState) -> Actor:
    """The trained policies (softmax, actions sampled)."""
    return Actor(act_fn(_modules(env, cfg)[0], state.policy, jnp.float32(0.0)))


def evaluate(
    key: jax.Array,
    state: ReciprocatorState,
    env: Env,
    cfg: ReciprocatorConfig,
    episodes: int,
    attack: Attack = NO_ATTACK,
):
    """Per-episode metrics [episodes, ...] of evaluation episodes (actions sampled)."""
    return evaluate_actor(key, env, acting(env, cfg, state), episodes, attack, state)
