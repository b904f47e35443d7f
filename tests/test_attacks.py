"""Attacks: each hook does exactly what docs/attacks.md says, under jit and vmap."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from pimbot import attacks, envs, learners
from pimbot.attacks import admo
from pimbot.contracts.attack import Decision
from pimbot.contracts.rollout import received, rollout
from pimbot.errors import InvalidParameter
from pimbot.learners import lio, pg

ENV = envs.make("escape_room-v0", n_agents=3, min_at_lever=1)
CFG = learners.default_config("lio", "escape_room-v0")
PM, IM = lio._modules(ENV, CFG)


# --- KKT (Pareto) weights -------------------------------------------------------------


def _brute_force_objective(g1, g2, c, points=20001):
    rest = 1.0 - c.sum()
    x = np.linspace(0.0, rest, points)
    alphas = np.stack([c[0] + x, c[1] + rest - x], axis=1)
    combined = alphas[:, :1] * g1[None] + alphas[:, 1:] * g2[None]
    return 0.5 * np.min(np.sum(combined**2, axis=1))


def _check_kkt(g1, g2, c):
    alpha = np.asarray(admo.kkt_weights(jnp.asarray(g1), jnp.asarray(g2), jnp.asarray(c)))
    assert alpha.sum() == pytest.approx(1.0, abs=1e-5)
    assert np.all(alpha >= c - 1e-5)
    value = 0.5 * np.sum((alpha[0] * g1 + alpha[1] * g2) ** 2)
    best = _brute_force_objective(g1, g2, c)
    assert value <= best + 1e-4 * max(1.0, best), (alpha, value, best)


bounds = st.tuples(st.floats(0.05, 0.45), st.floats(0.05, 0.45)).map(np.array)
vectors = st.lists(st.floats(-3, 3), min_size=4, max_size=4).map(lambda v: np.array(v, np.float32))


@settings(max_examples=60, deadline=None)
@given(g1=vectors, g2=vectors, c=bounds)
def test_kkt_weights_match_brute_force(g1, g2, c):
    _check_kkt(g1, g2, c.astype(np.float32))


@settings(max_examples=30, deadline=None)
@given(g=vectors, scale=st.floats(-3, 3), c=bounds)
def test_kkt_weights_parallel_and_opposite_gradients(g, scale, c):
    _check_kkt(g, (scale * g).astype(np.float32), c.astype(np.float32))


@settings(max_examples=60, deadline=None)
@given(g1=vectors, g2=vectors, c=bounds, parallel=st.sampled_from([None, 0.0, 1.0, -1.0, 2.5]))
def test_closed_form_kkt_weights_equal_the_pseudo_inverse_solution(g1, g2, c, parallel):
    if parallel is not None:
        g2 = (parallel * g1).astype(np.float32)
    args = (jnp.asarray(g1), jnp.asarray(g2), jnp.asarray(c.astype(np.float32)))
    fast, reference = admo.kkt_weights(*args), admo.kkt_weights_pinv(*args)
    value = lambda a: 0.5 * np.sum((a[0] * g1 + a[1] * g2) ** 2)  # noqa: E731
    # Equal weights, or (degenerate directions) equally good ones.
    assert np.allclose(fast, reference, atol=1e-3) or value(fast) <= value(reference) + 1e-4 * max(
        1.0, value(reference)
    )


def test_kkt_weights_zero_gradients_stay_feasible():
    c = np.array([0.2, 0.3], np.float32)
    zero = np.zeros(4, np.float32)
    for g1, g2 in ((zero, zero), (zero, np.ones(4, np.float32)), (np.ones(4, np.float32), zero)):
        _check_kkt(g1, g2, c)
        np.testing.assert_allclose(
            admo.kkt_weights(g1, g2, jnp.asarray(c)),
            admo.kkt_weights_pinv(g1, g2, jnp.asarray(c)),
            atol=1e-5,
        )
    # A zero gradient for one objective puts all free weight on it.
    alpha = np.asarray(admo.kkt_weights(jnp.zeros(4), jnp.ones(4), jnp.asarray(c)))
    np.testing.assert_allclose(alpha, [0.7, 0.3], atol=1e-5)


# --- strategy hooks -------------------------------------------------------------------


def _play(attack, seed=0, policy_seed=0):
    state = lio.init(jax.random.PRNGKey(policy_seed), ENV, CFG, attack)
    give = lio.give_fn(IM, state.incentive, ENV.num_actions, CFG.incentive_max)
    act = pg.act_fn(PM, state.policy, jnp.float32(0.5))
    return jax.jit(lambda k: rollout(ENV, k, act, give, attack))(jax.random.PRNGKey(seed))


def test_bypass_always_plays_the_idle_action():
    attack = attacks.make("bypass", 3, adversary=1)
    for seed in range(5):
        traj = _play(attack, seed)
        actions = np.asarray(traj.actions)[np.asarray(traj.valid)]
        assert np.all(actions[:, 1] == ENV.idle_action)
    clean = np.concatenate([np.asarray(_play(attacks.Attack(), s).actions[:, 1]) for s in range(5)])
    assert np.any(clean != ENV.idle_action)  # the hook, not the policy, does it


def test_bypass_toggle_alternates_every_k_environment_steps():
    attack = attacks.make("bypass", 3, toggle_period=3)
    actions = jnp.array([2, 2, 2])
    played = [
        int(attack.act({}, None, actions, Decision(ENV.idle_action, 3, jnp.int32(t)))[0])
        for t in range(9)
    ]
    assert played == [1, 1, 1, 2, 2, 2, 1, 1, 1]


def test_recipients_receive_exactly_c_under_fake_incentive():
    attack = attacks.make("fake_incentive", 3, adversary=2, amount=50.0)
    traj = _play(attack)
    valid = np.asarray(traj.valid)
    inc = np.asarray(traj.incentives)[valid]
    np.testing.assert_array_equal(inc[:, 2, :2], 50.0)
    np.testing.assert_array_equal(inc[:, 2, 2], 0.0)
    # The honest givers' incentives stay learned (inside [0, R_max]).
    assert inc[:, :2].max() <= CFG.incentive_max
    # In the modelled recipient updates the fake incentive is a constant: no gradient to η_2.
    grads = jax.grad(lambda eta: lio.emitted(ENV, CFG, eta, traj)[:, 2].sum())(
        lio.init(jax.random.PRNGKey(0), ENV, CFG).incentive
    )
    assert all(float(jnp.abs(g).max()) == 0.0 for g in jax.tree.leaves(grads))


def test_budget_zeroes_incentives_once_exceeded():
    attack = attacks.make("admo", 3, adversary=0, budget=1.0)
    given_so_far = jnp.zeros((3, 3))
    scale, _ = attack.emit({}, None, given_so_far)
    assert float(scale[0, 1]) == 1.0
    scale, _ = attack.emit({}, None, given_so_far.at[0, 1].set(1.5))
    assert np.all(np.asarray(scale[0]) == 0.0) and np.all(np.asarray(scale[1]) == 1.0)
    # In an episode: once a's cumulative incentives exceed B_a it emits nothing.
    for seed in range(3):
        traj = _play(attack, seed)
        given = np.asarray(traj.incentives[:, 0].sum(axis=1))
        cumulative = np.concatenate([[0.0], np.cumsum(given)[:-1]])
        assert np.all(given[cumulative > 1.0] == 0.0)


def _policies_equal(a, b, agent, atol=1e-7):
    """Agent `agent`'s parameters agree (up to float rounding of equal computations)."""
    return all(
        np.allclose(np.asarray(x[agent]), np.asarray(y[agent]), rtol=1e-5, atol=atol)
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
    )


def _actual_and_modelled(attack, seed=3):
    state = lio.init(jax.random.PRNGKey(seed), ENV, CFG)
    traj = _play(attack, seed, policy_seed=seed)
    eps = jnp.float32(0.3)
    actual = jax.jit(lio.actual_update, static_argnums=(0, 1, 2))(
        ENV, CFG, attack, {}, state.policy, traj, eps
    )
    modelled = jax.jit(lio.recipient_update, static_argnums=(0, 1))(
        ENV, CFG, state.policy, state.incentive, traj, eps
    )
    return state, traj, eps, actual, modelled


def test_self_centered_step_ignores_incentives_but_is_modelled_as_ordinary():
    attack = attacks.make("self_centered", 3, adversary=0)
    state, traj, eps, actual, modelled = _actual_and_modelled(attack)
    assert float(received(traj.incentives)[:, 0].sum()) > 0
    env_only = pg.policy_step(
        PM, state.policy, traj, traj.env_rewards, eps, CFG.lr_policy, CFG.gamma, CFG.entropy_coef
    )
    assert _policies_equal(actual, env_only, 0)  # the adversary learns from env reward only
    assert _policies_equal(actual, modelled, 1) and _policies_equal(actual, modelled, 2)
    assert not _policies_equal(actual, modelled, 0)  # the others model it with incentives


def test_reverse_flips_the_sign_of_the_adversarys_step():
    attack = attacks.make("reverse", 3, adversary=1)
    state, _, _, actual, modelled = _actual_and_modelled(attack)
    for x, y, p in zip(
        *(jax.tree.leaves(t) for t in (actual, modelled, state.policy)), strict=True
    ):
        step_actual, step_modelled = x[1] - p[1], y[1] - p[1]
        assert np.abs(step_modelled).max() > 1e-6
        np.testing.assert_allclose(step_actual, -step_modelled, rtol=1e-3, atol=1e-7)
        np.testing.assert_allclose(x[0], y[0], rtol=1e-5, atol=1e-7)


def test_admo_freezes_the_learners_own_step_for_the_adversary():
    attack = attacks.make("admo", 3, adversary=2)
    state, _, _, actual, _ = _actual_and_modelled(attack)
    assert _policies_equal(actual, state.policy, 2)


# --- every attack under jit and vmap ------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "params"),
    [
        ("self_centered", {}),
        ("fake_incentive", {}),
        ("bypass", {"toggle_period": 2}),
        ("reverse", {}),
        ("admo", {"mode": "stealthy"}),
        ("admo", {"mode": "disrupt", "budget": 0.5}),
    ],
)
def test_every_attack_runs_under_jit_and_vmap_over_seeds(name, params):
    env = envs.make("escape_room-v0")
    cfg = learners.default_config("lio", "escape_room-v0")
    attack = attacks.make(name, 2, **params)
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    states = jax.vmap(lambda k: lio.init(k, env, cfg, attack))(keys)

    @jax.jit
    def two_iterations(states):
        def body(s, _):
            return jax.vmap(lambda x: lio.update(x, env, cfg, attack))(s)

        return jax.lax.scan(body, states, None, length=2)

    states, metrics = two_iterations(states)
    assert int(states.iteration[0]) == 2
    for leaf in jax.tree.leaves(states.policy):
        assert bool(jnp.all(jnp.isfinite(leaf)))
    if name == "admo":
        alpha = np.asarray(metrics["admo/alpha_1"]) + np.asarray(metrics["admo/alpha_2"])
        np.testing.assert_allclose(alpha, 1.0, atol=1e-5)
        assert np.all(np.asarray(metrics["admo/c_1"]) >= 0.05)


def test_pg_supports_policy_attacks():
    env = envs.make("escape_room-v0")
    cfg = learners.default_config("pg", "escape_room-v0")
    for attack in (attacks.make("bypass", 2), attacks.make("reverse", 2)):
        state = pg.init(jax.random.PRNGKey(0), env, cfg, attack)
        state, _ = jax.jit(pg.update, static_argnums=(1, 2, 3))(state, env, cfg, attack)
        assert int(state.iteration) == 1


def test_admo_moves_only_the_adversarys_parameters_beyond_the_lio_step():
    env = envs.make("escape_room-v0")
    cfg = dataclasses.replace(learners.default_config("lio", "escape_room-v0"), lr_cost=0.0)
    attack = attacks.make("admo", 2, adversary=0)
    state = lio.init(jax.random.PRNGKey(1), env, cfg, attack)
    new_state, metrics = jax.jit(lio.update, static_argnums=(1, 2, 3))(state, env, cfg, attack)
    moved = [not _policies_equal(new_state.incentive, state.incentive, i) for i in range(2)]
    assert all(moved)
    assert float(metrics["admo/skipped"]) == 0.0


def test_admo_view_pullbacks_equal_jax_grad_through_the_modelled_updates():
    """ADMO's second-order path, batched with the other givers' cotangents, equals jax.grad
    of the recipients' log-probabilities on τ̂ w.r.t. η_a through their modelled updates;
    the other givers' part read back equals their own pass; `emitted` is as emitted (on the
    episode's valid steps)."""
    cfg = dataclasses.replace(CFG, incentive_updates="own")  # the batched path for N = 3
    attack = attacks.make("admo", 3, adversary=1)
    eps = jnp.float32(0.3)

    @jax.jit
    def check(key):
        k0, k1, k2, k3 = jax.random.split(key, 4)
        state = lio.init(k0, ENV, cfg, attack)
        give = lio.give_fn(IM, state.incentive, ENV.num_actions, cfg.incentive_max)
        traj = rollout(ENV, k1, pg.act_fn(PM, state.policy, eps), give, attack)
        new_policy = lio.recipient_update(ENV, cfg, state.policy, state.incentive, traj, eps)
        new_traj = rollout(ENV, k2, pg.act_fn(PM, new_policy, eps), give, attack)
        pullbacks = lio.recipient_pullbacks(
            ENV, cfg, state.policy, state.incentive, traj, eps, new_traj
        )
        theirs = lio.giver_cotangents(ENV, cfg, new_traj)[jnp.array([0, 2])]
        view, read_back = lio.adversary_view(
            ENV, cfg, attack, state, pullbacks, new_policy, traj, new_traj, 0.0, eps, theirs
        )
        cotangents = jax.random.normal(k3, (2,) + new_traj.valid.shape + (3,))
        got = view.meta_pullback(cotangents)
        eta_a = jax.tree.map(lambda x: x[1], state.incentive)

        def modelled(own, c):
            eta = jax.tree.map(lambda x, o: x.at[1].set(o), state.incentive, own)
            updated = lio.recipient_update(ENV, cfg, state.policy, eta, traj, eps)
            return jnp.sum(lio.taken_log_probs(ENV, cfg, updated, new_traj) * c)

        expected = jax.vmap(jax.grad(modelled), in_axes=(None, 0))(eta_a, cotangents)
        own_pass = jax.vmap(pullbacks[1])(theirs)
        valid = new_traj.valid[:, None, None]
        return (
            got,
            expected,
            read_back(),
            own_pass,
            view.emitted(eta_a) * valid,
            new_traj.incentives,
        )

    got, expected, back, own_pass, emitted, given = check(jax.random.PRNGKey(3))
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(expected), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(np.asarray(back), np.asarray(own_pass), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(np.asarray(emitted), np.asarray(given), rtol=1e-5, atol=1e-6)


# --- admo_code: the published code's scheduler of extra ordinary steps --------------------


def _code_weights_reference(g_inc, g_pol, c):
    """The code's own solve, in float64 numpy (the gram in float32, as there)."""
    g = np.array([[g_inc, g_pol]], np.float32)
    gram = g.T @ g
    e = np.ones(2, np.float32)
    m = np.block([[gram, e[:, None]], [e[None, :], np.zeros((1, 1))]])
    rhs = np.concatenate([-gram @ c, [1 - np.dot(e, c)]])
    raw = np.linalg.solve(m + 1e-6 * np.eye(3), rhs)[:2]
    clipped = np.maximum(raw + c, c)
    return clipped / clipped.sum()


scalars = st.floats(-1.0, 1.0, allow_nan=False, width=32)


@settings(max_examples=60, deadline=None)
@given(
    g_inc=scalars,
    g_pol=scalars,
    c=st.tuples(st.floats(0.0, 0.45), st.floats(0.0, 0.45)),
    tie=st.sampled_from([None, 1.0, -1.0, 0.0]),
)
def test_admo_code_weights_match_the_codes_regularised_solve(g_inc, g_pol, c, tie):
    from pimbot.attacks.admo_code import code_weights

    if tie is not None:  # equal, opposite and zero scalars: the unregularised M is singular
        g_pol = tie * g_inc
    # Within ~1e-4 of a tie (not at one) the 1e-6 ridge meets the float32 rounding of the
    # gram entries, which the code's own solve carries too: α is then only good to a few %
    assume(g_pol == g_inc or abs(g_inc - g_pol) > 1e-3)
    c = np.array(c, np.float32)
    got = np.asarray(code_weights(jnp.float32(g_inc), jnp.float32(g_pol), jnp.asarray(c)))
    np.testing.assert_allclose(got, _code_weights_reference(g_inc, g_pol, c), atol=1e-5)
    assert got.sum() == pytest.approx(1.0, abs=1e-6)


def test_admo_code_weights_known_values():
    from pimbot.attacks.admo_code import code_weights, scheduled_steps

    c = jnp.array([0.1, 0.1])
    for g in [(1.0, -1.0), (1.0, 1.0), (0.0, 0.0)]:  # symmetric cases: an even split
        np.testing.assert_allclose(code_weights(*map(jnp.float32, g), c), [0.5, 0.5], atol=1e-5)
    # g_pol = 0: the unconstrained optimum is α̂ = (−0.1, 0.9) (α1 = 0); the code lifts α̂1 + c1
    # to c1 and renormalises (0.1, 1.0), so α1 ends below its bound: 1/11
    alpha = code_weights(jnp.float32(1.0), jnp.float32(0.0), c)
    np.testing.assert_allclose(alpha, [1 / 11, 10 / 11], atol=1e-5)
    steps = scheduled_steps(jnp.array([0.1, 0.5, 0.9, 0.17]), 3)  # 0.3, 1.5, 2.7, 0.51
    np.testing.assert_array_equal(steps, [1, 2, 3, 1])  # max(1, ·); 1.5 rounds to even


def test_admo_code_doubles_the_adversarys_policy_step_only():
    """The code's extra policy steps all restart from the same parameters: one takes
    effect, so the adversary's actual step is twice the ordinary (modelled) one."""
    attack = attacks.make("admo_code", 3, adversary=1)
    state, _, _, actual, modelled = _actual_and_modelled(attack)
    for x, y, p in zip(
        *(jax.tree.leaves(t) for t in (actual, modelled, state.policy)), strict=True
    ):
        np.testing.assert_allclose(x[1] - p[1], 2 * (y[1] - p[1]), rtol=1e-3, atol=1e-7)
        np.testing.assert_allclose(x[0], y[0], rtol=1e-5, atol=1e-7)


def test_admo_code_takes_the_ordinary_incentive_step_then_the_scheduled_extra_ones():
    """η_a after the attack's step = 1 + max(1, round(3·α1)) Adam steps along the giver's
    own LIO meta-gradient (lr_cost 0), with that gradient equal to clean LIO's."""
    from pimbot.attacks import admo_code

    env = envs.make("escape_room-v0")
    cfg = dataclasses.replace(learners.default_config("lio", "escape_room-v0"), lr_cost=0.0)
    attack = attacks.make("admo_code", 2, adversary=0, lr_cost=0.0)
    pm, im = lio._modules(env, cfg)
    eps = jnp.float32(0.3)

    @jax.jit
    def check(key):
        k0, k1, k2 = jax.random.split(key, 3)
        state = lio.init(k0, env, cfg, attack)
        give = lio.give_fn(im, state.incentive, env.num_actions, cfg.incentive_max)
        traj = rollout(env, k1, pg.act_fn(pm, state.policy, eps), give, attack)
        new_policy = lio.recipient_update(env, cfg, state.policy, state.incentive, traj, eps)
        new_traj = rollout(env, k2, pg.act_fn(pm, new_policy, eps), give, attack)
        pullbacks = lio.recipient_pullbacks(
            env, cfg, state.policy, state.incentive, traj, eps, new_traj
        )
        view, _ = lio.adversary_view(
            env, cfg, attack, state, pullbacks, new_policy, traj, new_traj, 0.0, eps, None
        )
        own, _, metrics = admo_code.step(attack, state.attack_state, view)
        clean = lio.meta_gradients_from(env, cfg, pullbacks, traj, new_traj)
        return own, metrics, jax.tree.map(lambda g: g[0], clean), state.incentive

    own, metrics, clean_grad, incentive = check(jax.random.PRNGKey(5))
    steps = int(metrics["admo/incentive_steps"])
    assert steps == max(1, round(3 * float(metrics["admo/alpha_1"])))
    adam = optax.adam(cfg.lr_incentive)
    eta = jax.tree.map(lambda x: x[0], incentive)
    opt = adam.init(eta)
    ascent = jax.tree.map(jnp.negative, clean_grad)
    for _ in range(1 + steps):
        updates, opt = adam.update(ascent, opt)
        eta = optax.apply_updates(eta, updates)
    for got, want in zip(jax.tree.leaves(own.incentive), jax.tree.leaves(eta), strict=True):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-4, atol=1e-7)


def test_admo_code_needs_an_incentive_channel_or_an_epoch_schedule():
    """LIO (incentive steps) and the Reciprocator (PPO epochs) run it; PG has neither."""
    from pimbot.training.config import RunConfig, resolve

    with pytest.raises(
        envs.InvalidParameter, match="admo_code acts at the hook point.s. update_schedule"
    ):
        resolve(RunConfig("escape_room-v0", learner="pg", attack="admo_code"))
    for learner in ("lio", "reciprocator", "nl"):
        resolved = resolve(RunConfig("escape_room-v0", learner=learner, attack="admo_code"))
        assert resolved.attack.name == "admo_code"


@pytest.mark.parametrize("name", ["admo", "admo_code", "negated_env_reward"])
@pytest.mark.parametrize("missing", ["emitted", "meta_pullback"])
def test_an_incentive_channel_without_its_pullback_is_refused_at_trace(name, missing):
    """The AdversaryView contract, as the attacks that train η_a read it: `emitted` and
    `meta_pullback` are None exactly when `incentive` is. A learner's view that sets
    `incentive` without one of them is refused in one line (InvalidParameter, which the
    command line prints as such) when the attack's step is traced, before any iteration."""
    attack = attacks.make(name, 3, adversary=1)

    def step(key):
        k0, k1, k2 = jax.random.split(key, 3)
        state = lio.init(k0, ENV, CFG, attack)
        give = lio.give_fn(IM, state.incentive, ENV.num_actions, CFG.incentive_max)
        traj = rollout(ENV, k1, pg.act_fn(PM, state.policy, 0.1), give, attack)
        pullbacks = lio.recipient_pullbacks(
            ENV, CFG, state.policy, state.incentive, traj, 0.1, traj
        )
        theirs = lio.giver_cotangents(ENV, CFG, traj)[jnp.array([0, 2])]
        view, _ = lio.adversary_view(
            ENV, CFG, attack, state, pullbacks, state.policy, traj, traj, 0.0, 0.1, theirs
        )
        view = dataclasses.replace(view, **{missing: None})
        return attack.adversary_step(state.attack_state, k2, view)

    with pytest.raises(InvalidParameter, match=f"sets `incentive` without `{missing}`"):
        jax.eval_shape(step, jax.random.PRNGKey(0))
