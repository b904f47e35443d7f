"""LIO and PG: losses by hand, the second-order meta-gradient, the PG equivalence."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from pimbot import envs, learners, nets
from pimbot.contracts.rollout import discounted_returns, rollout
from pimbot.envs.core import InvalidParameter
from pimbot.learners import lio, pg

ENV = envs.make("escape_room-v0", n_agents=3, min_at_lever=1)
CFG = learners.default_config("lio", "escape_room-v0")


def test_discounted_returns_by_hand():
    rewards = jnp.array([1.0, 0.0, 2.0, -1.0])
    g = 0.5
    expected = [1 + 0 + 0.25 * 2 - 0.125, 0 + 0.5 * 2 - 0.25, 2 - 0.5, -1.0]
    np.testing.assert_allclose(discounted_returns(rewards, g), expected, rtol=1e-6)


def test_epsilon_schedule():
    assert float(pg.epsilon_at(jnp.int32(0), 0.5, 0.1, 1000)) == pytest.approx(0.5)
    assert float(pg.epsilon_at(jnp.int32(500), 0.5, 0.1, 1000)) == pytest.approx(0.3)
    assert float(pg.epsilon_at(jnp.int32(5000), 0.5, 0.1, 1000)) == pytest.approx(0.1)


def test_mixed_log_probs_match_definition():
    logits = jnp.array([[0.3, -1.0, 2.0], [0.0, 0.0, 0.0]])
    for eps in (0.0, 0.25, 1.0):
        expected = np.log((1 - eps) * np.asarray(jax.nn.softmax(logits)) + eps / 3)
        np.testing.assert_allclose(nets.mixed_log_probs(logits, eps), expected, rtol=1e-5)


def test_reinforce_loss_by_hand():
    """A linear-free check: with a constant-logit policy the loss is closed form."""
    module = nets.MLP((), 3)
    params = module.init(jax.random.PRNGKey(0), jnp.zeros(2))
    params = jax.tree.map(jnp.zeros_like, params)  # logits 0 → uniform
    obs = jnp.zeros((3, 2))
    actions = jnp.array([0, 2, 1])
    returns = jnp.array([2.0, 1.0, 5.0])
    valid = jnp.array([True, True, False])
    loss = pg.reinforce_loss(params, module, obs, actions, returns, valid, 0.1, 0.01)
    log_u = np.log(1 / 3)
    expected = -(log_u * 2.0 + log_u * 1.0) - 0.01 * 2 * (-log_u)
    assert float(loss) == pytest.approx(expected, rel=1e-5)


@jax.jit
def _fixed_trajectories_jit(seed):
    state = lio.init(jax.random.PRNGKey(seed), ENV, CFG)
    pm, im = lio._modules(ENV, CFG)
    eps = jnp.float32(0.3)
    give = lio.give_fn(im, state.incentive, ENV.num_actions, CFG.incentive_max)
    k1, k2 = jax.random.split(jax.random.PRNGKey(seed + 100))
    traj = rollout(ENV, k1, pg.act_fn(pm, state.policy, eps), give)
    new_policy = lio.recipient_update(ENV, CFG, state.policy, state.incentive, traj, eps)
    new_traj = rollout(ENV, k2, pg.act_fn(pm, new_policy, eps), give)
    return state, traj, new_traj, eps


def _fixed_trajectories(seed=0):
    """A learner state and a fixed pair (τ, τ̂) of ER(3,1) episodes."""
    return _fixed_trajectories_jit(jnp.int32(seed))


FD_STEP = 1e-6


def _to_f64(tree):
    return jax.tree.map(
        lambda x: jnp.asarray(x, jnp.float64) if jnp.issubdtype(x.dtype, jnp.floating) else x,
        tree,
    )


def test_meta_gradient_matches_finite_differences():
    """jax.grad of each giver's surrogate equals central differences (float64, N = 3)."""
    # A large policy step makes the second-order effect large; float64 keeps FD exact.
    cfg = dataclasses.replace(CFG, lr_policy=0.05)
    state, traj, new_traj, eps = _fixed_trajectories()
    with jax.enable_x64(True):
        state, traj, new_traj, eps = _to_f64((state, traj, new_traj, eps))

        def objective(own_incentive, giver):
            return lio.own_giver_objective(
                own_incentive,
                giver,
                ENV,
                cfg,
                state.policy,
                state.incentive,
                traj,
                eps,
                new_traj,
            )

        value_fn, grad_fn = jax.jit(objective), jax.jit(jax.grad(objective))
        for giver in range(ENV.num_agents):
            own = jax.tree.map(lambda x, g=giver: x[g], state.incentive)
            grad = grad_fn(own, jnp.int32(giver))
            direction = _to_f64(
                jax.tree.map(
                    lambda x, g=giver: jax.random.normal(jax.random.PRNGKey(7 + g), x.shape), own
                )
            )
            analytic = sum(
                float(jnp.vdot(g, d))
                for g, d in zip(jax.tree.leaves(grad), jax.tree.leaves(direction), strict=True)
            )
            plus = value_fn(
                jax.tree.map(lambda x, d: x + FD_STEP * d, own, direction), jnp.int32(giver)
            )
            minus = value_fn(
                jax.tree.map(lambda x, d: x - FD_STEP * d, own, direction), jnp.int32(giver)
            )
            numeric = float(plus - minus) / (2 * FD_STEP)
            assert abs(analytic) > 1e-3, "the meta-gradient should not vanish"
            assert analytic == pytest.approx(numeric, rel=1e-4)


def test_meta_gradient_flows_only_through_recipient_updates():
    """With the policy step switched off (lr 0), the giver's surrogate does not depend on η."""
    cfg = dataclasses.replace(CFG, lr_policy=0.0)
    state, traj, new_traj, eps = _fixed_trajectories(seed=1)
    own = jax.tree.map(lambda x: x[0], state.incentive)
    grad = jax.jit(
        jax.grad(
            lambda o: lio.own_giver_objective(
                o, jnp.int32(0), ENV, cfg, state.policy, state.incentive, traj, eps, new_traj
            )
        )
    )(own)
    assert all(float(jnp.abs(g).max()) == 0.0 for g in jax.tree.leaves(grad))


def test_zero_incentives_make_exactly_the_pg_step():
    cfg = dataclasses.replace(CFG, incentive_max=0.0)
    state, traj, _, eps = _fixed_trajectories(seed=2)
    pm, _ = lio._modules(ENV, cfg)

    @jax.jit  # one program, not op by op
    def both(policy, incentive, traj):
        lio_step = lio.recipient_update(ENV, cfg, policy, incentive, traj, eps)
        pg_step = pg.policy_step(
            pm, policy, traj, traj.env_rewards, eps, cfg.lr_policy, cfg.gamma, cfg.entropy_coef
        )
        return lio_step, pg_step

    lio_step, pg_step = both(state.policy, state.incentive, traj)
    for a, b in zip(jax.tree.leaves(lio_step), jax.tree.leaves(pg_step), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_full_lio_iteration_with_zero_incentives_is_the_pg_update_on_its_episode():
    cfg = dataclasses.replace(CFG, incentive_max=0.0)
    state = lio.init(jax.random.PRNGKey(3), ENV, cfg)
    new_state, _ = jax.jit(lio.update, static_argnums=(1, 2))(state, ENV, cfg)
    # Replay LIO's first rollout with the same key and take the PG step by hand.
    pm, im = lio._modules(ENV, cfg)
    _, key_first, _ = jax.random.split(state.key, 3)
    eps = pg.epsilon_at(
        state.iteration, cfg.epsilon_start, cfg.epsilon_end, cfg.epsilon_decay_iters
    )
    give = lio.give_fn(im, state.incentive, ENV.num_actions, 0.0)

    @jax.jit
    def replay(policy):
        traj = rollout(ENV, key_first, pg.act_fn(pm, policy, eps), give)
        return pg.policy_step(
            pm, policy, traj, traj.env_rewards, eps, cfg.lr_policy, cfg.gamma, cfg.entropy_coef
        )

    expected = replay(state.policy)
    for a, b in zip(jax.tree.leaves(new_state.policy), jax.tree.leaves(expected), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6, atol=1e-7)


def test_incentives_respect_range_and_mask():
    state = lio.init(jax.random.PRNGKey(4), ENV, CFG)
    _, im = lio._modules(ENV, CFG)
    give = lio.give_fn(im, state.incentive, ENV.num_actions, CFG.incentive_max)
    obs, _ = ENV.reset(jax.random.PRNGKey(0))
    inc = give(obs, jnp.array([0, 1, 2]))
    assert inc.shape == (3, 3)
    np.testing.assert_array_equal(np.diag(np.asarray(inc)), 0.0)
    assert float(inc.min()) >= 0.0 and float(inc.max()) <= CFG.incentive_max


def test_each_giver_updates_only_its_own_incentive_net():
    """With "own" updates giver i's step moves only η_i.

    With the meta step alone (cost off), the change in η_j (j ≠ i) when giver i
    is zeroed out must equal the change without it — i.e. rows are independent.
    """
    cfg = dataclasses.replace(CFG, lr_cost=0.0, incentive_updates="own")
    state = lio.init(jax.random.PRNGKey(5), ENV, cfg)
    new_state, _ = jax.jit(lio.update, static_argnums=(1, 2))(state, ENV, cfg)
    moved = [
        any(
            float(jnp.abs(a[i] - b[i]).max()) > 0
            for a, b in zip(
                jax.tree.leaves(new_state.incentive), jax.tree.leaves(state.incentive), strict=True
            )
        )
        for i in range(ENV.num_agents)
    ]
    assert all(moved)


def _one_by_one_reference(env, cfg, givers, state, traj, new_traj, eps):
    """The original's shared updates written plainly: a Python loop over givers, one Adam
    and one cost Adam per giver, jax.grad of each surrogate w.r.t. every η and θ."""
    meta, cost = optax.adam(cfg.lr_incentive), optax.adam(cfg.lr_cost)
    eta, theta = state.incentive, state.policy
    for giver in givers:
        grads = jax.grad(lio.giver_objective, argnums=(0, 4))(
            eta, jnp.int32(giver), env, cfg, theta, traj, eps, new_traj
        )
        opt = jax.tree.map(lambda x: x[giver], state.incentive_opt)  # noqa: B023
        updates, _ = meta.update(jax.tree.map(jnp.negative, grads), opt)
        cost_grad = jax.grad(lio.incentive_cost)(eta, env, cfg, traj)
        own = jax.tree.map(lambda g: g[giver], cost_grad)  # noqa: B023
        cost_updates, _ = cost.update(own, jax.tree.map(lambda x: x[giver], state.cost_opt))  # noqa: B023
        new_eta, theta = optax.apply_updates((eta, theta), updates)
        eta = jax.tree.map(
            lambda e, u: e.at[giver].set(e[giver] + u),  # noqa: B023
            new_eta,
            cost_updates,
        )
    return eta


@pytest.mark.parametrize("n", [2, 3])
def test_shared_updates_one_by_one_equal_the_plain_reference(n):
    """`giver_turns` equals the plain loop; for N = 2 both equal the all-at-once own
    updates (giver i's surrogate depends on nothing the other giver's step moves)."""
    env = envs.make("escape_room-v0", n_agents=n, min_at_lever=1)
    cfg = dataclasses.replace(CFG, incentive_updates="shared")
    eps = jnp.float32(0.3)
    givers = list(range(n))

    @jax.jit
    def episodes():  # one program, not op by op (each eager op would compile its own)
        state = lio.init(jax.random.PRNGKey(11), env, cfg)
        if n == 2:  # the default path for N = 2 is all at once: build per-giver states
            state = state.replace(
                incentive_opt=jax.vmap(
                    lambda _: optax.adam(cfg.lr_incentive).init((state.incentive, state.policy))
                )(jnp.arange(n)),
                cost_opt=jax.vmap(optax.adam(cfg.lr_cost).init)(state.incentive),
            )
        pm, im = lio._modules(env, cfg)
        give = lio.give_fn(im, state.incentive, env.num_actions, cfg.incentive_max)
        k1, k2 = jax.random.split(jax.random.PRNGKey(12))
        traj = rollout(env, k1, pg.act_fn(pm, state.policy, eps), give)
        new_policy = lio.recipient_update(env, cfg, state.policy, state.incentive, traj, eps)
        new_traj = rollout(env, k2, pg.act_fn(pm, new_policy, eps), give)
        return state, traj, new_traj

    @jax.jit
    def turns(state, traj, new_traj):
        opts = (state.incentive_opt, state.cost_opt)
        return lio.giver_turns(
            env, cfg, givers, None, state.policy, state.incentive, opts, traj, eps, new_traj
        )[0]

    state, traj, new_traj = episodes()
    fast = turns(state, traj, new_traj)
    slow = jax.jit(lambda s, t, u: _one_by_one_reference(env, cfg, givers, s, t, u, eps))(
        state, traj, new_traj
    )
    for a, b in zip(jax.tree.leaves(fast), jax.tree.leaves(slow), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-7)
    if n == 2:
        own = dataclasses.replace(cfg, incentive_updates="own")

        @jax.jit
        def own_update(traj, new_traj):
            fresh = lio.init(jax.random.PRNGKey(11), env, own)
            grads = lio.meta_gradients(env, own, fresh.policy, fresh.incentive, traj, eps, new_traj)
            expected, _ = lio.meta_step(own, fresh.incentive, fresh.incentive_opt, grads)
            cost_grad = jax.grad(lio.incentive_cost)(fresh.incentive, env, own, traj)
            cost_updates, _ = optax.adam(own.lr_cost).update(cost_grad, fresh.cost_opt)
            return optax.apply_updates(expected, cost_updates)

        expected = own_update(traj, new_traj)
        for a, b in zip(jax.tree.leaves(fast), jax.tree.leaves(expected), strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-7)


def test_shared_updates_move_the_other_givers_incentives_for_three_agents():
    """One turn of giver 0 (cost off) moves η_1 and η_2 as well; "own" would not."""
    cfg = dataclasses.replace(CFG, lr_cost=0.0)
    state, traj, new_traj, eps = _fixed_trajectories(seed=7)
    opts = (state.incentive_opt, state.cost_opt)

    def turn(frozen):  # jitted: one program, not op by op
        return jax.jit(lambda *args: lio.giver_turns(ENV, cfg, [0], frozen, *args)[0])(
            state.policy, state.incentive, opts, traj, eps, new_traj
        )

    moved = turn(None)
    for agent in range(ENV.num_agents):
        change = max(
            float(jnp.abs(a[agent] - b[agent]).max())
            for a, b in zip(jax.tree.leaves(moved), jax.tree.leaves(state.incentive), strict=True)
        )
        assert change > 0, agent
    frozen = turn(1)
    for a, b in zip(jax.tree.leaves(frozen), jax.tree.leaves(state.incentive), strict=True):
        np.testing.assert_array_equal(np.asarray(a[1]), np.asarray(b[1]))


def test_incentive_updates_option_is_checked():
    with pytest.raises(InvalidParameter, match="incentive_updates"):
        dataclasses.replace(CFG, incentive_updates="simultaneous")


def test_fast_meta_gradients_equal_the_per_giver_reference():
    """The chain-rule implementation equals vmapped jax.grad of each giver's surrogate."""
    state, traj, new_traj, eps = _fixed_trajectories(seed=6)
    args = (ENV, CFG, state.policy, state.incentive, traj, eps, new_traj)
    fast = jax.jit(lio.meta_gradients, static_argnums=(0, 1))(*args)
    slow = jax.jit(lio.meta_gradients_reference, static_argnums=(0, 1))(*args)
    for a, b in zip(jax.tree.leaves(fast), jax.tree.leaves(slow), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-6)
