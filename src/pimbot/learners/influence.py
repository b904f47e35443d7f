"""Value of influence, the influence balance and the reciprocal reward (Reciprocator).

Learned models (docs/reciprocators.md), all MLPs in → 64 → 64 → N:
  * a joint reward model r̂(s, a) and a joint future-value model q̂(s, a)
    (target: the discounted env return after t, G_{t+1});
  * per agent j, counterfactual reward and future-value models r̂^{−j}, q̂^{−j}
    that do not see agent j's action. Fitted on data from j's recent policy,
    they approximate the expectation over j's actions.

VoI(j → i, t) = [r̂_i(s,a) − r̂_i^{−j}(s,a_{−j})] + γ[q̂_i(s,a) − q̂_i^{−j}(s,a_{−j})]
(γ applied once). The 2(N + 1) models are one stacked parameter pytree:
model m = kind·(N + 1) + variant, kind 0 = reward, 1 = future value; variant
0 = joint, 1 + j = without agent j's action (its one-hot input is zeroed).
The state s is the concatenation of every agent's observation.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from pimbot import nets


@struct.dataclass
class InfluenceModels:
    params: dict  # stacked model parameters, leaves [2(N+1), ...]
    opt: optax.OptState  # Adam state of the model fit


def model_module(hidden: Sequence[int], num_agents: int) -> nets.MLP:
    """One VoI model: joint input → one prediction per agent."""
    return nets.MLP(tuple(hidden), num_agents)


def model_inputs(obs: jax.Array, actions: jax.Array, num_actions: int) -> jax.Array:
    """Joint model input: every agent's observation and one-hot action, concatenated.

    Args:
        obs: [..., N, obs_dim]; actions: int [..., N].
    Returns:
        [..., N·obs_dim + N·num_actions].
    """
    flat_obs = obs.reshape(obs.shape[:-2] + (-1,))
    one_hot = jax.nn.one_hot(actions, num_actions, dtype=jnp.float32)
    return jnp.concatenate([flat_obs, one_hot.reshape(one_hot.shape[:-2] + (-1,))], axis=-1)


def input_masks(num_agents: int, obs_dim: int, num_actions: int) -> np.ndarray:
    """[2(N+1), in_dim] input masks: ones, except agent j's action slots for variant 1 + j."""
    in_dim = num_agents * (obs_dim + num_actions)
    variants = np.ones((num_agents + 1, in_dim), np.float32)
    for j in range(num_agents):
        start = num_agents * obs_dim + j * num_actions
        variants[1 + j, start : start + num_actions] = 0.0
    return np.concatenate([variants, variants])


def init_models(
    key: jax.Array, hidden: Sequence[int], num_agents: int, in_dim: int, lr: float
) -> InfluenceModels:
    module = model_module(hidden, num_agents)
    params = nets.init_stacked(module, key, 2 * (num_agents + 1), in_dim)
    return InfluenceModels(params=params, opt=optax.adam(lr).init(params))


def predict(params, hidden: Sequence[int], masks: jax.Array, x: jax.Array) -> jax.Array:
    """Every model's prediction: x [..., in_dim] -> [2(N+1), ..., N]."""
    module = model_module(hidden, masks.shape[0] // 2 - 1)
    return jax.vmap(lambda p, m: module.apply(p, x * m))(params, masks)


def next_returns(rewards: jax.Array, gamma: float) -> jax.Array:
    """G_{t+1} = Σ_{k>t} γ^(k−t−1) r_k, the future-value target: rewards [T, N] -> [T, N]."""
    steps = rewards.shape[0]
    t = jnp.arange(steps)
    exponent = t[None, :] - t[:, None] - 1
    discount = jnp.where(exponent >= 0, gamma ** jnp.maximum(exponent, 0), 0.0)
    return jnp.tensordot(discount.astype(rewards.dtype), rewards, axes=1)


MINIBATCH_ROWS = ("each_draw", "distinct_weighted")
"""How a refit step evaluates its minibatch of `batch_size` rows drawn with replacement
from the S stored samples: "each_draw" (every drawn row through the models, as the
original code) or "distinct_weighted" (every stored sample once, weighted by how often it
was drawn). The two are the same loss and gradient in exact arithmetic, summed in another
order (results differ at rounding level); "distinct_weighted" costs S rows instead of
`batch_size`, so it is the faster one where the history holds fewer samples than a
minibatch (one episode per update: 3 batches × 5 steps = 15 samples against 512 draws)."""


def minibatch_loss(
    params,
    hidden: Sequence[int],
    masks: jax.Array,
    x: jax.Array,
    rewards: jax.Array,
    future: jax.Array,
    valid: jax.Array,
    idx: jax.Array,
    rows: str = "each_draw",
) -> jax.Array:
    """Every model's weighted MSE on the minibatch of stored samples `idx` [B] (drawn with
    replacement), evaluated as `rows` says (`MINIBATCH_ROWS`); arguments as `fit`'s."""
    if rows == "distinct_weighted":
        draws = jnp.zeros(x.shape[0], jnp.float32).at[idx].add(1.0)  # draws of each sample
        inputs, reward_targets, future_targets = x, rewards, future
        weights = valid.astype(jnp.float32) * draws
    else:
        inputs, reward_targets, future_targets = x[idx], rewards[idx], future[idx]
        weights = valid[idx].astype(jnp.float32)
    num_variants = masks.shape[0] // 2
    preds = predict(params, hidden, masks, inputs)  # [M, rows, N]
    targets = jnp.stack([reward_targets] * num_variants + [future_targets] * num_variants)
    weight = weights[None, :, None]
    count = jnp.maximum(weight.sum(), 1.0) * preds.shape[-1]
    return jnp.sum(weight * (preds - targets) ** 2) / count


def fit(
    models: InfluenceModels,
    key: jax.Array,
    hidden: Sequence[int],
    masks: jax.Array,
    x: jax.Array,
    rewards: jax.Array,
    future: jax.Array,
    valid: jax.Array,
    *,
    lr: float,
    steps: int,
    batch_size: int,
    rows: str = "each_draw",
) -> tuple[InfluenceModels, jax.Array]:
    """`steps` Adam steps on the MSE of every model, each on a random minibatch.

    Args:
        x: [S, in_dim] inputs; rewards, future: [S, N] targets; valid: [S] sample weights.
        rows: how a minibatch is evaluated, one of `MINIBATCH_ROWS`.
    Returns:
        (refitted models, mean MSE of the last step).
    """
    num_variants = masks.shape[0] // 2
    optimizer = optax.adam(lr)

    def loss_fn(params, idx):
        return minibatch_loss(params, hidden, masks, x, rewards, future, valid, idx, rows)

    def step(carry, step_key):
        params, opt = carry
        idx = jax.random.randint(step_key, (batch_size,), 0, x.shape[0])
        loss, grads = jax.value_and_grad(loss_fn)(params, idx)
        updates, opt = optimizer.update(grads, opt)
        return (optax.apply_updates(params, updates), opt), loss

    (params, opt), losses = jax.lax.scan(
        step, (models.params, models.opt), jax.random.split(key, steps)
    )
    return InfluenceModels(params=params, opt=opt), losses[-1] / num_variants / 2


def value_of_influence(
    params, hidden: Sequence[int], masks: jax.Array, x: jax.Array, gamma: float
) -> jax.Array:
    """VoI(j → i) for every ordered pair: x [..., in_dim] -> [..., N influencer j, N influenced i].

    The diagonal (an agent's influence on itself) is zero.
    """
    num_agents = masks.shape[0] // 2 - 1
    preds = predict(params, hidden, masks, x)  # [2(N+1), ..., N]
    reward_joint, reward_without = preds[0], preds[1 : num_agents + 1]
    value_joint, value_without = preds[num_agents + 1], preds[num_agents + 2 :]
    voi = (reward_joint[None] - reward_without) + gamma * (value_joint[None] - value_without)
    voi = jnp.moveaxis(voi, 0, -2)  # [..., N j, N i]
    return voi * (1.0 - jnp.eye(num_agents, dtype=voi.dtype))


GRUDGES = ("accumulated", "petty", "one_step")
"""Balance variants: the general agent's accumulated credit − debit, the credit-only "petty"
balance (the original's `petty_rr`, its Escape Room script's 'linear'), or the original IPD
agent's one-step grudge."""


def grudge_index(grudge: str | int | jax.Array) -> int | jax.Array:
    """The balance variant as its index in `GRUDGES` (a name is looked up; an index, traced
    or not, is returned as it is)."""
    return GRUDGES.index(grudge) if isinstance(grudge, str) else grudge


def next_balance(
    balance: jax.Array, voi_t: jax.Array, gamma: float, grudge: str | int | jax.Array
) -> jax.Array:
    """B_t [N self, N other] from B_{t−1} and VoI(j→i, t) [N j, N i] (`voi_t.T[i, j]` is the
    credit VoI(j→i), `voi_t[i, j]` the debit VoI(i→j)). `grudge` is a name of `GRUDGES` or
    its index, which may be traced: every variant is computed and the index selects one, so
    the petty and the accumulated balance share one compiled program."""
    credit = gamma * balance + voi_t.T
    variants = (credit - voi_t, credit, voi_t.T)  # in the order of GRUDGES
    index = grudge_index(grudge)
    if isinstance(index, int):
        return variants[index]
    return jax.lax.select_n(index, *variants)


def balance_and_reciprocal_reward(
    voi: jax.Array, gamma: float, grudge: str | int | jax.Array = "accumulated"
) -> tuple[jax.Array, jax.Array]:
    """The influence balance per pair and the reciprocal reward, along one episode.

    grudge "accumulated": B_t[i, j] = γ B_{t−1}[i, j] + VoI(j→i, t) − VoI(i→j, t), B_{−1} = 0;
    grudge "petty" (credit only; johnlyzhou/reciprocator `src/agents/reciprocator.py`,
    `petty_rr`, which greedy_agent's `reciprocators/run_er.py` selects as 'linear'):
    B_t[i, j] = γ B_{t−1}[i, j] + VoI(j→i, t), no debit;
    grudge "one_step" (the original code's IPD agent): B_t[i, j] = VoI(j→i, t), no
    accumulation and no debit for the influence i exerted;
    reciprocal_t[i] = mean_{j≠i} B_{t−1}[i, j] · VoI(i→j, t).

    Args:
        voi: [T, N influencer, N influenced], zero on invalid steps and on the diagonal.
    Returns:
        (balances [T, N self, N other] = B_t, reciprocal rewards [T, N]).
    """
    num_agents = voi.shape[-1]

    def body(balance, voi_t):
        reward = jnp.sum(balance * voi_t, axis=1) / (num_agents - 1)
        balance = next_balance(balance, voi_t, gamma, grudge)
        return balance, (balance, reward)

    start = jnp.zeros((num_agents, num_agents), voi.dtype)
    _, (balances, rewards) = jax.lax.scan(body, start, voi)
    return balances, rewards


VOI_REWARDS = ("env", "after_earlier_agents")
"""What an agent's VoI on the others is measured in: their env rewards, or (the original IPD
code) their rewards after the agents before it in id order added their reciprocal rewards."""


def reciprocal_rewards_in_id_order(balances: jax.Array, voi: jax.Array, added_fn) -> jax.Array:
    """Reciprocal rewards where agent i's VoI(i→j) on an agent j < i counts what j added to
    its own learning reward (the original IPD code: each agent adds w·reciprocal in place to
    the joint reward tensor, agents update in id order, and a later agent's VoI reads it).

    Args:
        balances: [..., T, N self, N other] B_t; voi: [..., T, N j, N i];
        added_fn: reciprocal rewards [..., T, N] -> what each agent adds to its own
            learning reward [..., T, N] (w·reciprocal for a Reciprocator; per element).
    Returns:
        [..., T, N] reciprocal_t[i] = mean_{j≠i} B_{t−1}[i, j]·(VoI(i→j, t) + added_j(t)·[j < i]).
    """
    num_agents = voi.shape[-1]
    start = jnp.zeros_like(balances[..., :1, :, :])
    previous = jnp.concatenate([start, balances[..., :-1, :, :]], axis=-3)  # B_{t−1}
    reciprocal = jnp.zeros(voi.shape[:-1], voi.dtype)
    added = jnp.zeros_like(reciprocal)
    for i in range(num_agents):
        earlier = jnp.arange(num_agents) < i
        influence = voi[..., i, :] + jnp.where(earlier, added, 0.0)
        reward = jnp.sum(previous[..., i, :] * influence, axis=-1) / (num_agents - 1)
        reciprocal = reciprocal.at[..., i].set(reward)
        added = added_fn(reciprocal)
    return reciprocal
