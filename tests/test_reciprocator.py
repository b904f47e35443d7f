"""Reciprocator: value of influence (learned and exact), balance recursion, weight 0 = PPO,
the tabulated matrix-game path, N players, jit/vmap, VoI metrics, IPD cooperation."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pimbot import envs, learners, nets
from pimbot.attacks import ADMO, Bypass, Reverse
from pimbot.contracts.attack import NO_ATTACK, UpdateSchedule
from pimbot.contracts.rollout import rollout
from pimbot.envs.core import InvalidParameter
from pimbot.learners import (
    epoch_schedule,
    exact_voi,
    influence,
    reciprocator,
    reciprocator_nets,
    tabular,
)
from pimbot.training.config import RunConfig, resolve

IPD = envs.make("ipd-v0")
COOP_ENVS, COOP_ITERATIONS, COOP_RATE = 256, 100, 0.85  # see the cooperation test
# Small networks and batches: the tests check the mechanics, not learning speed. SMALL is
# the general agent (learned VoI, accumulated balance); MATRIX the matrix-game default.
SMALL = dataclasses.replace(
    learners.default_config("reciprocator", "ipd-v0"),
    voi="learned",
    grudge="accumulated",
    voi_refit_period=2,
    voi_history=3,
    num_envs=8,
    policy_hidden=(16,),
    voi_hidden=(16,),
    ppo_epochs=3,
    voi_steps=3,
    voi_batch=32,
)


# --- value of influence ---------------------------------------------------------------


def test_voi_of_a_constant_policy_is_zero():
    """Agent 1 always cooperates, agent 0 plays at random: after fitting, agent 1 has
    (almost) no influence while agent 0's influence on agent 1 is large (IPD: ±1 per step).
    The residue is the models' fitting noise on the noisy future-value targets."""

    def act(key, obs):
        del obs
        return jnp.stack([jax.random.bernoulli(key).astype(jnp.int32), jnp.int32(0)])

    gamma = 0.96

    @jax.jit  # one program, not op by op
    def episodes(keys):
        trajs = jax.vmap(lambda k: rollout(IPD, k, act))(keys)
        x = influence.model_inputs(trajs.obs, trajs.actions, IPD.num_actions).reshape(-1, 14)
        future = jax.vmap(lambda r: influence.next_returns(r, gamma))(trajs.env_rewards)
        return trajs, x, future

    trajs, x, future = episodes(jax.random.split(jax.random.PRNGKey(0), 256))
    masks = jnp.asarray(influence.input_masks(2, IPD.obs_dim, IPD.num_actions))
    hidden = (64, 64)
    models = influence.init_models(jax.random.PRNGKey(1), hidden, 2, 14, 1e-2)
    fit = jax.jit(
        lambda m, k: influence.fit(
            m,
            k,
            hidden,
            masks,
            x,
            trajs.env_rewards.reshape(-1, 2),
            future.reshape(-1, 2),
            trajs.valid.reshape(-1),
            lr=1e-2,
            steps=300,
            batch_size=512,
        )
    )
    models, loss = fit(models, jax.random.PRNGKey(2))
    voi = jax.jit(influence.value_of_influence, static_argnums=(1, 4))(
        models.params, hidden, masks, x, gamma
    )  # [S, j, i]
    from_constant = float(jnp.abs(voi[:, 1, 0]).mean())
    from_random = float(jnp.abs(voi[:, 0, 1]).mean())
    assert from_random > 0.8, from_random
    assert from_constant < 0.1 * from_random, (from_constant, from_random, float(loss))
    assert np.all(np.asarray(voi[:, [0, 1], [0, 1]]) == 0.0)


def test_distinct_weighted_minibatch_is_the_each_draw_loss_and_gradient():
    """A minibatch of 512 draws from 15 stored samples (3 batches of one 5-step episode, some
    padding rows invalid): evaluated row by row or as the 15 samples weighted by their draw
    counts, the loss and every gradient are the same up to float rounding, and so is a whole
    refit (both ways, one program each)."""
    samples, in_dim = 15, 14
    keys = jax.random.split(jax.random.PRNGKey(3), 5)
    x = jax.random.normal(keys[0], (samples, in_dim))
    rewards = jax.random.normal(keys[1], (samples, 2))
    future = jax.random.normal(keys[2], (samples, 2))
    valid = jnp.arange(samples) % 5 != 4  # the last step of each episode is padding
    masks = jnp.asarray(influence.input_masks(2, IPD.obs_dim, IPD.num_actions))
    hidden = (16, 16)
    models = influence.init_models(keys[3], hidden, 2, in_dim, 1e-2)
    idx = jax.random.randint(keys[4], (512,), 0, samples)
    assert len(np.unique(np.asarray(idx))) == samples  # every sample drawn, many repeatedly

    @jax.jit
    def both(params):
        def loss(rows):
            return jax.value_and_grad(influence.minibatch_loss)(
                params, hidden, masks, x, rewards, future, valid, idx, rows
            )

        return loss("each_draw"), loss("distinct_weighted")

    (loss_a, grads_a), (loss_b, grads_b) = both(models.params)
    assert float(loss_a) > 0
    np.testing.assert_allclose(float(loss_b), float(loss_a), rtol=1e-5)
    for a, b in zip(jax.tree.leaves(grads_a), jax.tree.leaves(grads_b), strict=True):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-4, atol=1e-6)

    @jax.jit
    def refits(m):
        def refit(rows):
            return influence.fit(
                m, keys[4], hidden, masks, x, rewards, future, valid,
                lr=1e-3, steps=10, batch_size=512, rows=rows,
            )  # fmt: skip

        return refit("each_draw"), refit("distinct_weighted")

    (fit_a, last_a), (fit_b, last_b) = refits(models)
    np.testing.assert_allclose(float(last_b), float(last_a), rtol=1e-4)
    for a, b in zip(jax.tree.leaves(fit_a.params), jax.tree.leaves(fit_b.params), strict=True):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), atol=1e-5)


def test_balance_recursion_on_a_hand_computed_sequence():
    # voi[t, j, i] = VoI(j → i, t); γ = 0.5.
    voi = jnp.array([[[0, 1], [0, 0]], [[0, 0], [2, 0]], [[0, 3], [1, 0]]], jnp.float32)
    balances, rewards = influence.balance_and_reciprocal_reward(voi, 0.5)
    # Agent 0 about agent 1: B0 = 0 − 1 = −1, B1 = −0.5 + 2 − 0 = 1.5, B2 = 0.75 + 1 − 3 = −1.25.
    np.testing.assert_allclose(balances[:, 0, 1], [-1.0, 1.5, -1.25])
    np.testing.assert_allclose(balances[:, 1, 0], [1.0, -1.5, 1.25])
    # Reciprocal reward uses B_{t−1}: agent 0: 0, −1·0, 1.5·3; agent 1: 0, 1·2, −1.5·1.
    np.testing.assert_allclose(rewards, [[0.0, 0.0], [0.0, 2.0], [4.5, -1.5]])
    # The original code's one-step grudge: B_{t−1}[i, j] = VoI(j → i, t − 1) only.
    grudges, rewards = influence.balance_and_reciprocal_reward(voi, 0.5, grudge="one_step")
    np.testing.assert_allclose(grudges[:, 0, 1], [0.0, 2.0, 1.0])
    # Agent 0: 0, 0·0, 2·3; agent 1: 0, 1·2, 0·1.
    np.testing.assert_allclose(rewards, [[0.0, 0.0], [0.0, 2.0], [6.0, 0.0]])
    # The petty balance (credit only): agent 0 about agent 1: B = 0, 2, 1 + 1 = 2; agent 1
    # about agent 0: B = 1, 0.5, 0.25 + 3 = 3.25.
    petty, rewards = influence.balance_and_reciprocal_reward(voi, 0.5, grudge="petty")
    np.testing.assert_allclose(petty[:, 0, 1], [0.0, 2.0, 2.0])
    np.testing.assert_allclose(petty[:, 1, 0], [1.0, 0.5, 3.25])
    # Agent 0: 0, 0·0, 2·3; agent 1: 0, 1·2, 0.5·1.
    np.testing.assert_allclose(rewards, [[0.0, 0.0], [0.0, 2.0], [6.0, 0.5]])


@pytest.mark.parametrize("grudge", influence.GRUDGES)
def test_balance_recursion_matches_a_loop_reference_for_three_agents(grudge):
    rng = np.random.default_rng(0)
    voi = rng.normal(size=(6, 3, 3)).astype(np.float32)
    voi[:, range(3), range(3)] = 0.0
    gamma = 0.9
    balance = np.zeros((3, 3))
    expected = np.zeros((6, 3))
    for t in range(6):
        for i in range(3):
            others = [j for j in range(3) if j != i]
            expected[t, i] = np.mean([balance[i, j] * voi[t, i, j] for j in others])
        for i in range(3):
            for j in range(3):
                if i == j:
                    continue
                credit, debit = voi[t, j, i], voi[t, i, j]
                balance[i, j] = {
                    "accumulated": gamma * balance[i, j] + credit - debit,
                    "petty": gamma * balance[i, j] + credit,
                    "one_step": credit,
                }[grudge]
    _, rewards = influence.balance_and_reciprocal_reward(jnp.asarray(voi), gamma, grudge)
    np.testing.assert_allclose(rewards, expected, rtol=1e-5, atol=1e-6)


def test_voi_after_earlier_agents_counts_their_added_reciprocal_reward():
    """The original IPD code's in-place update: agent 1's VoI on agent 0 reads agent 0's
    reward after agent 0 added w·reciprocal_0; agent 0 (updated first) sees env rewards."""
    a, b, c, d, w = 0.5, -1.5, 2.0, 0.25, 5.0
    voi = jnp.array([[[0.0, a], [b, 0.0]], [[0.0, c], [d, 0.0]]])  # [T, j, i] = VoI(j → i)
    balances, env_based = influence.balance_and_reciprocal_reward(voi, 0.96, "one_step")
    aliased = influence.reciprocal_rewards_in_id_order(balances, voi, lambda rec: w * rec)
    np.testing.assert_allclose(env_based, [[0.0, 0.0], [b * c, a * d]], rtol=1e-6)
    np.testing.assert_allclose(aliased, [[0.0, 0.0], [b * c, a * (d + w * b * c)]], rtol=1e-6)
    # three agents, the accumulated balance, per-agent weights: against a loop
    voi = jax.random.normal(jax.random.PRNGKey(1), (4, 3, 3)) * (1 - jnp.eye(3))
    balances, _ = influence.balance_and_reciprocal_reward(voi, 0.9, "accumulated")
    weights = jnp.array([5.0, 0.0, 2.0])  # agent 1 adds nothing (a self-centered adversary)
    got = influence.reciprocal_rewards_in_id_order(balances, voi, lambda rec: weights * rec)
    prev = np.concatenate([np.zeros((1, 3, 3)), np.asarray(balances)[:-1]])
    voi, want = np.asarray(voi), np.zeros((4, 3))
    for t in range(4):
        for i in range(3):
            for j in range(3):
                added = weights[j] * want[t, j] if j < i else 0.0
                want[t, i] += prev[t, i, j] * (voi[t, i, j] + added) / 2
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)


def test_next_returns_start_after_the_step():
    rewards = jnp.array([[1.0], [2.0], [4.0]])
    np.testing.assert_allclose(influence.next_returns(rewards, 0.5)[:, 0], [2.0 + 2.0, 4.0, 0.0])


# --- the learner ----------------------------------------------------------------------


def test_weight_zero_is_exactly_the_naive_ppo_update():
    state = reciprocator.init(jax.random.PRNGKey(3), IPD, SMALL)
    naive_cfg = dataclasses.replace(SMALL, reciprocal_weight=0.0)

    @jax.jit
    def both(state):
        naive, metrics = reciprocator.update(state, IPD, naive_cfg)
        _, play_key, _ = jax.random.split(state.key, 3)
        trajs = reciprocator.play_batch(IPD, SMALL, state.policy, play_key, NO_ATTACK, 0, {})
        returns = reciprocator.normalized_returns(trajs.env_rewards, trajs.valid, SMALL.gamma)
        policy, _, _ = reciprocator.ppo_update(
            IPD, SMALL, state.policy, state.value, state.opt, trajs, returns, jnp.ones((2,))
        )
        return naive.policy, metrics, policy

    naive, metrics, policy = both(state)
    for got, want in zip(jax.tree.leaves(naive), jax.tree.leaves(policy), strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-7)
    # The reciprocal reward was there; weight 0 removed it.
    assert float(jnp.abs(metrics["train/reciprocal_reward"]).sum()) > 0


def test_a_seed_in_a_batch_equals_the_seed_alone():
    def one_update(key):
        state, _ = reciprocator.update(reciprocator.init(key, IPD, SMALL), IPD, SMALL)
        return state.policy

    keys = jax.vmap(jax.random.PRNGKey)(jnp.arange(3))
    batched = jax.jit(jax.vmap(one_update))(keys)
    alone = jax.jit(one_update)(keys[1])
    for b, a in zip(jax.tree.leaves(batched), jax.tree.leaves(alone), strict=True):
        np.testing.assert_allclose(b[1], a, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize(
    ("env_id", "params", "attack"),
    [
        ("escape_room-v0", {"n_agents": 3, "min_at_lever": 2}, ADMO()),
        ("stag_hunt-v0", {"n_players": 4, "grid_size": 3, "max_steps": 4}, Reverse(adversary=2)),
        ("stag_hunt_matrix-v0", {"n_players": 3, "max_steps": 3}, Bypass(adversary=1)),
    ],
)
def test_n_player_shapes_under_jit_and_vmap(env_id, params, attack):
    env = envs.make(env_id, **params)
    n = env.num_agents
    cfg = dataclasses.replace(SMALL, reciprocal_weight=1.0, num_envs=4)
    keys = jax.random.split(jax.random.PRNGKey(0), 2)

    def run(key):
        state, metrics = reciprocator.update(
            reciprocator.init(key, env, cfg, attack), env, cfg, attack
        )
        return state, metrics, reciprocator.evaluate(key, state, env, cfg, 3, attack)

    state, metrics, evaluation = jax.jit(jax.vmap(run))(keys)
    assert state.iteration.tolist() == [1, 1]
    assert metrics["train/reciprocal_reward"].shape == (2, n)
    assert state.models.params["params"]["Dense_0"]["kernel"].shape[:2] == (2, 2 * (n + 1))
    assert evaluation["return_env"].shape == (2, 3, n)
    for value in jax.tree.leaves(metrics):
        assert np.all(np.isfinite(value))
    if isinstance(attack, ADMO):
        assert metrics["admo/alpha_1"].shape == (2,)
        np.testing.assert_allclose(metrics["admo/alpha_1"] + metrics["admo/alpha_2"], 1.0, 1e-5)


def test_attacks_without_an_incentive_channel():
    for learner in ("reciprocator", "nl"):
        with pytest.raises(InvalidParameter, match="fake_incentive acts at the hook point.s. emit"):
            resolve(RunConfig("ipd-v0", learner=learner, attack="fake_incentive"))
        for name in ("self_centered", "bypass", "reverse", "admo"):
            assert resolve(RunConfig("ipd-v0", learner=learner, attack=name)).attack.name == name


def test_self_centered_adversary_learns_from_env_reward_only():
    resolved = resolve(RunConfig("ipd-v0", learner="reciprocator", attack="self_centered"))
    env_rewards = jnp.ones((2, 5, 2))
    reciprocal = jnp.full((2, 5, 2), 3.0)
    rewards = resolved.attack.learning_rewards({}, env_rewards, reciprocal)
    np.testing.assert_allclose(rewards[..., 0], 1.0)
    np.testing.assert_allclose(rewards[..., 1], 4.0)


def test_default_configs():
    ipd = learners.default_config("reciprocator", "ipd-v0")
    assert (ipd.reciprocal_weight, ipd.voi, ipd.grudge) == (5.0, "exact", "one_step")
    assert (ipd.policy_hidden, ipd.num_envs, ipd.voi_refit_period, ipd.voi_history) == (
        (2, 2),
        2048,
        3,
        1,
    )
    matrix_hunt = learners.default_config("reciprocator", "stag_hunt_matrix-v0")
    assert (matrix_hunt.voi, matrix_hunt.reciprocal_weight) == ("exact", 1.0)
    hunt = learners.default_config("reciprocator", "stag_hunt-v0")
    assert (hunt.voi, hunt.grudge, hunt.reciprocal_weight) == ("learned", "accumulated", 1.0)
    # Escape Room: the authors' credit − debit balance at greedy_agent
    # reciprocators/run_er.py's learner settings and 128 episodes per update (the script's
    # own 'linear' balance, petty, is a named row); NL the same with weight 0.
    for env_id in ("escape_room-v0", "escape_room_transfer-v0"):
        for learner, weight in (("reciprocator", 5.0), ("nl", 0.0)):
            room = learners.default_config(learner, env_id)
            balance = (room.voi, room.grudge, room.reciprocal_weight)
            assert balance == ("learned", "accumulated", weight)
            assert (room.lr, room.gamma, room.ppo_epochs, room.clip) == (1e-4, 0.99, 10, 0.1)
            assert (room.entropy_coef, room.policy_hidden, room.voi_lr) == (0.01, (64, 64), 1e-3)
            assert room.num_envs == 128
    # every room: the env parameters do not change the declared defaults
    run = resolve(
        RunConfig("escape_room-v0", (("min_at_lever", 3), ("n_agents", 4)), "reciprocator")
    )
    assert (run.learner_config.grudge, run.learner_config.lr) == ("accumulated", 1e-4)
    nl = learners.default_config("nl", "ipd-v0")
    assert (nl.reciprocal_weight, nl.voi) == (0.0, "exact")


def test_ipd_runs_of_the_reciprocator_default_to_the_originals_32_step_episodes(capsys):
    """ipd-v0 declares max_steps = 32 for the Reciprocator (and NL, which shares its
    defaults); a max_steps the run gives wins; other learners keep the env's 5."""
    for learner in ("reciprocator", "nl"):
        run = resolve(RunConfig("ipd-v0", learner=learner, iterations=100))
        assert run.env.max_steps == 32
        assert run.identity()["env_params"]["max_steps"] == 32
        assert run.eval_period == 100  # shorter than the default period: one evaluation
        given = RunConfig("ipd-v0", (("max_steps", 5),), learner=learner, iterations=100)
        assert resolve(given).env.max_steps == 5
    assert resolve(RunConfig("ipd-v0", learner="lio", iterations=1000)).env.max_steps == 5
    assert resolve(RunConfig("escape_room-v0", learner="reciprocator")).env.max_steps == 5
    from pimbot.cli import listing

    listing.print_envs()
    assert "with --learner reciprocator (unless given): max_steps=32" in capsys.readouterr().out


def test_bad_options_are_refused():
    with pytest.raises(InvalidParameter, match="voi: must be one of learned, exact"):
        reciprocator.init(jax.random.PRNGKey(0), IPD, dataclasses.replace(SMALL, voi="tabular"))
    with pytest.raises(
        InvalidParameter, match="grudge: must be one of accumulated, petty, one_step"
    ):
        reciprocator.init(jax.random.PRNGKey(0), IPD, dataclasses.replace(SMALL, grudge="x"))
    room = envs.make("escape_room-v0")
    with pytest.raises(InvalidParameter, match="voi: 'exact' needs a matrix game"):
        reciprocator.init(jax.random.PRNGKey(0), room, dataclasses.replace(SMALL, voi="exact"))
    general = dataclasses.replace(
        SMALL, net_input="observation", policy_head="softmax", net_init="glorot"
    )
    with pytest.raises(InvalidParameter, match="needs a matrix game"):
        reciprocator.init(
            jax.random.PRNGKey(0), room, dataclasses.replace(general, net_input="previous_actions")
        )
    with pytest.raises(InvalidParameter, match="policy_head: 'sigmoid' needs two actions"):
        reciprocator.init(
            jax.random.PRNGKey(0), room, dataclasses.replace(general, policy_head="sigmoid")
        )
    for name in ("voi_rewards", "net_input", "policy_head", "net_init"):
        with pytest.raises(InvalidParameter, match=f"{name}: must be one of"):
            reciprocator.init(jax.random.PRNGKey(0), IPD, dataclasses.replace(SMALL, **{name: "x"}))


# --- the networks (reciprocator_nets) ----------------------------------------------------


def test_general_network_choices_are_the_plain_mlp_drawn_as_before():
    """observation / softmax / glorot: `nets.MLP` itself, with `nets.init_stacked`'s draw."""
    cfg = dataclasses.replace(SMALL, net_input="observation", policy_head="softmax")
    policy_module, value_module = reciprocator._modules(IPD, cfg)
    assert type(policy_module) is nets.MLP and type(value_module) is nets.MLP
    key = jax.random.PRNGKey(4)
    got = reciprocator_nets.init_params(policy_module, key, 2, IPD.obs_dim, "glorot")
    want = nets.init_stacked(policy_module, key, 2, IPD.obs_dim)
    for g, w in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True):
        np.testing.assert_array_equal(g, w)


def test_previous_actions_input_and_sigmoid_head_on_the_ipd():
    """The original IPD agent's state: (a0, a1) of the previous step, (−1, 0) at the first;
    the network on the env's observation equals the MLP on that state; the sigmoid head's
    logits are [0, z], so p(defect) = σ(z)."""
    tables = exact_voi.game_tables(IPD)
    rows = reciprocator_nets.previous_actions_rows(tables)
    # dense states in code order: CC CD DC DD first (one-hot index 2·a0 + a1, 4 first)
    np.testing.assert_array_equal(rows, [[0, 0], [0, 1], [1, 0], [1, 1], [-1, 0]])
    obs, state = IPD.reset(jax.random.PRNGKey(0))
    after_dc, *_ = IPD.step(jax.random.PRNGKey(0), state, jnp.array([1, 0]))
    module, _ = reciprocator_nets.modules(IPD, (4,), "previous_actions", "sigmoid")
    params = module.init(jax.random.PRNGKey(1), obs[0])
    inner = {"params": params["params"]["MLP_0"]}
    for observation, row in ((obs[0], [-1.0, 0.0]), (after_dc[0], [1.0, 0.0])):
        logits = module.apply(params, observation)
        z = nets.MLP((4,), 1).apply(inner, jnp.array(row))
        np.testing.assert_allclose(logits, jnp.concatenate([jnp.zeros(1), z]), rtol=1e-6)
        np.testing.assert_allclose(jax.nn.softmax(logits)[1], jax.nn.sigmoid(z[0]), rtol=1e-6)


def test_fan_in_uniform_draws_kernels_and_biases_within_one_over_root_fan_in():
    shapes = {"Dense_0": (16, 64), "Dense_1": (64, 2)}  # stacked for 3 agents
    zeros = {
        name: {"kernel": jnp.zeros((3, i, o)), "bias": jnp.zeros((3, o))}
        for name, (i, o) in shapes.items()
    }
    params = reciprocator_nets.fan_in_uniform(jax.random.PRNGKey(5), {"params": zeros})["params"]
    for name, (fan_in, _) in shapes.items():
        bound = 1 / np.sqrt(fan_in)
        for leaf in ("kernel", "bias"):
            x = np.asarray(params[name][leaf])
            assert np.all(np.abs(x) <= bound) and np.abs(x).max() > 0.5 * bound, (name, leaf)
    kernel = np.asarray(params["Dense_0"]["kernel"])  # enough draws: a uniform's spread
    np.testing.assert_allclose(kernel.std(), 1 / np.sqrt(3 * 16), rtol=0.1)
    assert not np.allclose(kernel[0], kernel[1])  # every agent its own draw


# --- the matrix-game path (exact VoI, tabulated play and PPO) --------------------------


def test_exact_voi_by_hand_on_the_ipd():
    """p̂(defect) = 1/4 for both agents in every state: VoI(j → i) = r_i(a) − E_{a'_j} r_i."""
    tables = exact_voi.game_tables(IPD)
    np.testing.assert_array_equal(tables.states, [1, 2, 4, 8, 16])  # one-hot 5: CC CD DC DD first
    assert tables.first_state == 4
    np.testing.assert_array_equal(tables.next_states, [0, 2, 1, 3])  # joint j = a0 + 2 a1
    probs = jnp.broadcast_to(jnp.array([0.75, 0.25]), (5, 2, 2))
    actions = jnp.array([[0, 0], [0, 1], [1, 1]])  # CC, CD, DD
    states = jax.nn.one_hot(jnp.array([4, 0, 3]), 5)
    voi = exact_voi.value_of_influence(probs, tables, states, actions)
    # CC: agent 1's influence on 0: −1 − (0.75·−1 + 0.25·−3) = 0.5; symmetric.
    # CD: VoI(1→0) = −3 − (−1.5) = −1.5; VoI(0→1) = 0 − (0.75·0 + 0.25·−2) = 0.5.
    # DD: VoI(1→0) = −2 − (0.75·0 + 0.25·−2) = −1.5.
    np.testing.assert_allclose(voi[:, 1, 0], [0.5, -1.5, -1.5])
    np.testing.assert_allclose(voi[:, 0, 1], [0.5, 0.5, -1.5])
    np.testing.assert_allclose(voi[:, [0, 1], [0, 1]], 0.0)


def test_action_frequencies_are_refit_when_due_and_keep_unvisited_states():
    freqs = exact_voi.init_frequencies(IPD, history=1)
    states = jax.nn.one_hot(jnp.array([4, 4, 4, 4, 0]), 5)
    actions = jnp.array([[0, 1], [0, 1], [1, 1], [0, 0], [1, 0]])
    valid = jnp.array([True, True, True, True, False])
    stale = exact_voi.store_and_refit(freqs, states, actions, valid, 0, jnp.array(False))
    np.testing.assert_allclose(stale.probs, 0.5)
    fresh = exact_voi.store_and_refit(freqs, states, actions, valid, 0, jnp.array(True))
    np.testing.assert_allclose(fresh.probs[4], [[0.75, 0.25], [0.25, 0.75]])
    np.testing.assert_allclose(fresh.probs[0], 0.5)  # only an invalid step visited it


def test_tabulated_ppo_equals_the_per_sample_ppo():
    n = 3
    env = envs.make("ipd-v0", n_players=n, max_steps=4)
    cfg = dataclasses.replace(learners.default_config("reciprocator", "ipd-v0"), num_envs=32)
    tables = exact_voi.game_tables(env)

    @jax.jit
    def both():  # one program, not op by op
        state = reciprocator.init(jax.random.PRNGKey(4), env, cfg)
        trajs = reciprocator.play_batch(
            env, cfg, state.policy, jax.random.PRNGKey(5), NO_ATTACK, 0, {}
        )
        returns = jax.random.normal(jax.random.PRNGKey(6), trajs.env_rewards.shape)
        sign = jnp.ones((n,)).at[0].set(-1.0)
        per_sample = reciprocator.ppo_update(
            env, cfg, state.policy, state.value, state.opt, trajs, returns, sign
        )
        tabulated = tabular.ppo_update(
            reciprocator._modules(env, cfg),
            cfg,
            tables,
            state.policy,
            state.value,
            state.opt,
            exact_voi.state_one_hot(trajs.obs, tables).reshape(-1, len(tables.states)),
            jnp.moveaxis(trajs.actions, 2, 0).reshape(n, -1),
            jnp.moveaxis(returns, 2, 0).reshape(n, -1),
            trajs.valid.reshape(-1),
            sign,
        )
        return per_sample, tabulated

    per_sample, tabulated = both()
    for a, b in zip(jax.tree.leaves(per_sample), jax.tree.leaves(tabulated), strict=True):
        np.testing.assert_allclose(a, b, rtol=2e-4, atol=2e-6)


def test_game_tables_are_each_joint_actions_step_made_once_per_env_and_read_only():
    """The tables (one compiled call, asked for by a program's init, update and
    evaluation alike) hold what stepping the game on each joint action gives; an equal env
    gets the same tables, and nothing can write into the shared arrays."""
    env = envs.make("ipd-v0", n_players=3, max_steps=4)
    tables = exact_voi.game_tables(env)
    assert exact_voi.game_tables(envs.make("ipd-v0", n_players=3, max_steps=4)) is tables
    with pytest.raises(ValueError, match="read-only"):
        tables.rewards[0, 0] = 1.0
    key = jax.random.PRNGKey(0)
    obs, state = env.reset(key)
    np.testing.assert_array_equal(tables.state_obs[tables.first_state], obs[0])
    for j, actions in enumerate(exact_voi.joint_actions(3, env.num_actions)):
        next_obs, _, rewards, _, info = env.step(key, state, jnp.asarray(actions))
        np.testing.assert_array_equal(tables.rewards[j], rewards)
        np.testing.assert_array_equal(tables.state_obs[tables.next_states[j]], next_obs[0])
        assert tables.success[j] == bool(info["success"])


def test_a_scheduled_epoch_count_is_the_ordinary_update_with_that_many_epochs():
    """An `update_schedule` of epochs (1, 3) within a 6-epoch masked scan: agent 0 ends where
    the ordinary PPO with ppo_epochs 1 leaves it, agent 1 where ppo_epochs 3 does (the
    tabulated path here; the per-sample path runs the same `epoch_schedule.run`, and the
    admo_code test below runs both through `update`)."""
    cfg = dataclasses.replace(
        learners.default_config("reciprocator", "ipd-v0"), num_envs=16, ppo_epochs=3
    )
    schedule = UpdateSchedule(jnp.array([1, 3], jnp.int32), jnp.ones((2,)), 6, {})
    tables = exact_voi.game_tables(IPD)

    def update(cfg, opt, policy, value, trajs, returns, schedule):
        return tabular.ppo_update(
            reciprocator._modules(IPD, cfg),
            cfg,
            tables,
            policy,
            value,
            opt,
            exact_voi.state_one_hot(trajs.obs, tables).reshape(-1, len(tables.states)),
            jnp.moveaxis(trajs.actions, 2, 0).reshape(2, -1),
            jnp.moveaxis(returns, 2, 0).reshape(2, -1),
            trajs.valid.reshape(-1),
            jnp.ones((2,)),
            schedule,
        )

    state = reciprocator.init(jax.random.PRNGKey(7), IPD, cfg)
    key = jax.random.PRNGKey(8)
    trajs = reciprocator.play_batch(IPD, cfg, state.policy, key, NO_ATTACK, 0, {})
    returns = jax.random.normal(jax.random.PRNGKey(9), trajs.env_rewards.shape)
    per_agent = epoch_schedule.init(cfg.lr, (state.policy, state.value))
    scheduled = jax.jit(lambda *a: update(cfg, *a, schedule))(
        per_agent, state.policy, state.value, trajs, returns
    )
    assert scheduled[2][0].count.tolist() == [1, 3]
    for agent, epochs in ((0, 1), (1, 3)):
        ordinary_cfg = dataclasses.replace(cfg, ppo_epochs=epochs)
        ordinary = jax.jit(lambda *a, c=ordinary_cfg: update(c, *a, None))(
            state.opt, state.policy, state.value, trajs, returns
        )
        for got, want in zip(
            jax.tree.leaves(scheduled[:2]), jax.tree.leaves(ordinary[:2]), strict=True
        ):
            np.testing.assert_allclose(got[agent], want[agent], rtol=1e-5, atol=1e-7)
        assert not np.allclose(
            scheduled[0]["params"]["Dense_0"]["kernel"][agent],
            state.policy["params"]["Dense_0"]["kernel"][agent],
        )


@pytest.mark.parametrize("env_id", ["ipd-v0", "escape_room-v0"])
def test_admo_code_schedules_the_adversarys_ppo_epochs_and_reciprocal_weight(env_id):
    """The published code's ADMO on the Reciprocator: α of the batch's env-reward scalars
    sets the adversary's epochs max(1, round(2·α1·K)) and weight scale 2·α2 (logged); the
    other agent's update is the clean one (same batch, its own return normalisation), and
    the clean run keeps the ordinary program (one Adam state, a scalar step count)."""
    from pimbot import attacks

    env = envs.make(env_id)
    resolved = resolve(RunConfig(env_id, learner="reciprocator", attack="admo_code"))
    base = learners.default_config("reciprocator", env_id)
    cfg = dataclasses.replace(
        base, num_envs=8, voi_steps=3, voi_batch=32, voi_hidden=(8,), policy_hidden=(8,)
    )
    attack = attacks.make("admo_code", 2, adversary=1)
    assert resolved.attack.name == "admo_code"

    def both(key):
        clean, _ = reciprocator.update(reciprocator.init(key, env, cfg), env, cfg)
        attacked, metrics = reciprocator.update(
            reciprocator.init(key, env, cfg, attack), env, cfg, attack
        )
        return clean.policy, attacked.policy, clean.opt[0].count, attacked.opt[0].count, metrics

    clean, attacked, clean_count, count, metrics = jax.jit(both)(jax.random.PRNGKey(12))
    assert clean_count.shape == ()
    alpha_1, alpha_2 = float(metrics["admo/alpha_1"]), float(metrics["admo/alpha_2"])
    assert abs(alpha_1 + alpha_2 - 1.0) < 1e-5 and min(alpha_1, alpha_2) > 0.0
    epochs = max(1, round(2 * alpha_1 * cfg.ppo_epochs))
    assert float(metrics["admo/ppo_epochs"]) == epochs and count.tolist() == [
        cfg.ppo_epochs,
        epochs,
    ]
    np.testing.assert_allclose(metrics["admo/reciprocal_weight_scale"], 2 * alpha_2, rtol=1e-6)
    for got, want in zip(jax.tree.leaves(attacked), jax.tree.leaves(clean), strict=True):
        np.testing.assert_allclose(got[0], want[0], rtol=1e-5, atol=1e-7)


def test_tabulated_play_follows_the_game():
    env = envs.make("ipd-v0", n_players=3, max_steps=4)
    cfg = dataclasses.replace(learners.default_config("reciprocator", "ipd-v0"), num_envs=16)
    state = reciprocator.init(jax.random.PRNGKey(0), env, cfg)
    trajs = reciprocator.play_batch(env, cfg, state.policy, jax.random.PRNGKey(1), NO_ATTACK, 0, {})
    obs, env_state = env.reset(jax.random.PRNGKey(0))
    for e in range(3):
        o, s = obs, env_state
        for t in range(env.max_steps):
            np.testing.assert_array_equal(trajs.obs[e, t], o)
            o, s, r, _, info = env.step(jax.random.PRNGKey(0), s, trajs.actions[e, t])
            np.testing.assert_allclose(trajs.env_rewards[e, t], r)
            assert bool(trajs.success[e, t]) == bool(info["success"])
    # the sampled actions follow the policy: agent 0's first-step action frequency
    tables = exact_voi.game_tables(env)
    logits = tabular.logits_table(reciprocator._modules(env, cfg)[0], state.policy, tables, 3)
    p = jax.nn.softmax(logits[:, tables.first_state])
    wide = dataclasses.replace(cfg, num_envs=4000)
    first = reciprocator.play_batch(
        env, wide, state.policy, jax.random.PRNGKey(2), NO_ATTACK, 0, {}
    )
    np.testing.assert_allclose((first.actions[:, 0] == 0).mean(0), p[:, 0], atol=0.03)  # 4σ


def test_voi_metrics_per_pair_and_role():
    voi = jnp.zeros((1, 2, 3, 3)).at[0, 0, 1, 0].set(2.0).at[0, 1, 2, 1].set(4.0)
    actions = jnp.array([[[2, 0, 1], [1, 1, 2]]])
    metrics = reciprocator.voi_metrics(voi, actions, jnp.array([[True, True]]), 3)
    assert metrics["train/voi/agent_1_to_agent_0"] == 1.0  # 2 on one of two steps
    assert metrics["train/voi/agent_2_to_agent_1"] == 2.0
    assert metrics["train/voi/agent_0_to_agent_1"] == 0.0
    # (j plays 0, i plays 2): only step 0's 1 → 0, VoI 2. (j plays 2, i plays 1): step 0's
    # 0 → 2 (VoI 0) and step 1's 2 → 0 (0) and 2 → 1 (4).
    assert metrics["train/voi_role/action_0_to_action_2"] == 2.0
    np.testing.assert_allclose(metrics["train/voi_role/action_2_to_action_1"], 4.0 / 3)
    np.testing.assert_allclose(
        sum(v for k, v in metrics.items() if k.startswith("train/voi_role_share/")), 1.0
    )


def test_the_default_matrix_agent_cooperates_on_the_ipd():
    """The default matrix agent (the original's IPD algorithm: exact VoI, one-step grudge,
    width 2, w 5; pimbot's network details) learns to cooperate: every one of 3 seeds
    cooperates on ≥ 85 % of its steps over updates 91–100 (a batch of 256 games instead of
    the original's 2048, to keep the test cheap; random play cooperates on 50 %). Fixed
    seeds, a regression check: not every seed cooperates, at 2048 games too
    (docs/reciprocators.md says why)."""
    env = envs.make("ipd-v0", max_steps=32)
    cfg = dataclasses.replace(learners.default_config("reciprocator", "ipd-v0"), num_envs=COOP_ENVS)

    def run(key):
        state = reciprocator.init(key, env, cfg)
        state, metrics = jax.lax.scan(
            lambda s, _: reciprocator.update(s, env, cfg), state, None, length=COOP_ITERATIONS
        )
        return metrics["train/success"][-10:].mean(), metrics["train/action_0_rate"][-10:].mean()

    mutual, cooperate = jax.jit(jax.vmap(run))(jax.vmap(jax.random.PRNGKey)(jnp.arange(3)))
    assert np.all(np.asarray(cooperate) >= COOP_RATE), (mutual, cooperate)
