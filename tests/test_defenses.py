"""Training-time defenses: guard, exploration floor and health monitor, under jit and vmap."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pimbot import attacks, cli, defenses, envs, learners, nets
from pimbot.contracts import defense as defense_hooks
from pimbot.contracts.attack import NO_ATTACK
from pimbot.contracts.defense import EpsilonContext
from pimbot.defenses import guard as guard_lib
from pimbot.defenses import monitor as monitor_lib
from pimbot.envs.core import InvalidParameter
from pimbot.learners import lio

ENV = envs.make("escape_room-v0")  # ER(2,1), T = 5, 3 actions
CFG = learners.default_config("lio", "escape_room-v0")
R_MAX = CFG.incentive_max
ALL_HONEST = jnp.ones((2,), bool)


def _sent(values, steps=5):
    """[T, 2, 2] incentives: values[t] from agent 0 to agent 1, nothing else."""
    column = jnp.zeros((steps,), jnp.float32).at[: len(values)].set(jnp.stack(values))
    return jnp.zeros((steps, 2, 2), jnp.float32).at[:, 0, 1].set(column)


# --- incentive guard ----------------------------------------------------------------------


def test_guard_clips_to_the_honest_range_and_counts():
    guard = defenses.make("incentive_guard", 2)
    state = guard_lib.init_state(guard, 2)
    sent = _sent([50.0, -3.0, 1.5, 2.0, 0.0])
    valid = jnp.ones((5,), bool)
    accepted, _, metrics = guard_lib.apply(guard, state, sent, valid, R_MAX, ALL_HONEST)
    np.testing.assert_allclose(accepted[:, 0, 1], [2.0, 0.0, 1.5, 2.0, 0.0])
    assert float(metrics["defense/guard_clipped"]) == 2
    assert float(metrics["defense/guard_budget_cut"]) == 0


def test_guard_budget_caps_each_pair_per_episode():
    guard = defenses.make("incentive_guard", 2, budget_fraction=0.5)  # 0.5 · 2 · 5 = 5
    state = guard_lib.init_state(guard, 2)
    accepted, _, metrics = guard_lib.apply(
        guard, state, _sent([2.0] * 5), jnp.ones((5,), bool), R_MAX, ALL_HONEST
    )
    np.testing.assert_allclose(accepted[:, 0, 1], [2.0, 2.0, 1.0, 0.0, 0.0])
    assert float(accepted.sum()) == pytest.approx(5.0)
    assert float(metrics["defense/guard_budget_cut"]) == 3


def test_guard_drops_outliers_against_the_givers_history_only_after_enough_history():
    guard = defenses.make("incentive_guard", 2, outlier_z=4.0, min_history=8)
    apply = jax.jit(guard_lib.apply, static_argnums=(0, 4))
    state = guard_lib.init_state(guard, 2)
    valid = jnp.ones((5,), bool)
    rng = np.random.default_rng(0)
    for k in range(12):
        if k == 3:  # a jump before min_history episodes is not judged
            accepted, state, metrics = apply(
                guard, state, _sent([2.0] * 5), valid, R_MAX, ALL_HONEST
            )
            assert float(metrics["defense/guard_dropped"]) == 0
            continue
        level = 0.3 + 0.02 * rng.standard_normal()
        accepted, state, metrics = apply(guard, state, _sent([level] * 5), valid, R_MAX, ALL_HONEST)
        assert float(metrics["defense/guard_dropped"]) == 0
    accepted, _, metrics = apply(guard, state, _sent([2.0] * 5), valid, R_MAX, ALL_HONEST)
    assert float(metrics["defense/guard_dropped"]) == 1
    assert float(accepted.sum()) == 0.0
    accepted, _, _ = apply(guard, state, _sent([0.31] * 5), valid, R_MAX, ALL_HONEST)
    assert float(accepted.sum()) == pytest.approx(5 * 0.31)
    # A recipient that does not guard (the adversary) takes what it is sent.
    adversary_recipient = jnp.array([True, False])
    accepted, _, _ = apply(guard, state, _sent([50.0] * 5), valid, R_MAX, adversary_recipient)
    assert float(accepted.sum()) == pytest.approx(250.0)


def test_guard_ignores_invalid_steps_and_vmaps_over_seeds():
    guard = defenses.make("incentive_guard", 2, budget_fraction=0.3)  # budget 3
    states = jax.vmap(lambda _: guard_lib.init_state(guard, 2))(jnp.arange(3))
    sent = jnp.stack([_sent([1.0] * 5), _sent([50.0] * 5), _sent([0.5] * 5)])
    valid = jnp.array([True, True, False, False, False])
    accepted, _, metrics = jax.vmap(
        lambda st, s: guard_lib.apply(guard, st, s, valid, R_MAX, ALL_HONEST)
    )(states, sent)
    np.testing.assert_allclose(accepted[:, :, 0, 1].sum(axis=1), [2.0, 3.0, 1.0])
    np.testing.assert_allclose(metrics["defense/guard_clipped"], [0, 2, 0])


def test_guard_is_transparent_to_honest_lio_incentives():
    """With outliers off, the guard leaves an honest team's update bit for bit alone."""
    guard = defenses.compose([("incentive_guard", {"outlier_z": 0.0})], 2)
    state = lio.init(jax.random.PRNGKey(7), ENV, CFG, NO_ATTACK, guard)
    plain = lio.init(jax.random.PRNGKey(7), ENV, CFG)
    a, metrics = jax.jit(lio.update, static_argnums=(1, 2, 3, 4))(state, ENV, CFG, NO_ATTACK, guard)
    b, _ = jax.jit(lio.update, static_argnums=(1, 2))(plain, ENV, CFG)
    for x, y in zip(jax.tree.leaves(a.policy), jax.tree.leaves(b.policy), strict=True):
        np.testing.assert_array_equal(x, y)
    assert float(metrics["defense/guard_clipped"]) == 0


# --- exploration floor --------------------------------------------------------------------


def test_floor_lifts_only_honest_agents():
    floor = defenses.make("exploration_floor", 3, min_epsilon=0.3)
    d = (floor,)
    honest = defense_hooks.honest_agents(attacks.make("bypass", 3, adversary=1), 3)
    np.testing.assert_allclose(_epsilon(d, 0.1, honest), [0.3, 0.1, 0.3])
    np.testing.assert_allclose(_epsilon(d, 0.5, honest), [0.5] * 3)
    assert _epsilon(defenses.NO_DEFENSE, 0.1, honest).ndim == 0


def _epsilon(defense_set, epsilon, honest):
    states = defense_hooks.init_states(defense_set, honest.shape[0], None)
    ctx = EpsilonContext(jnp.float32(epsilon), honest)
    return defense_hooks.acting_epsilon(defense_set, states, ctx)


def _trained_under_fake_incentive(defense_set, iterations=150):
    # A larger policy step than ER's 1e-4, so that 150 iterations saturate the softmax.
    cfg = dataclasses.replace(CFG, epsilon_decay_iters=50, lr_policy=1e-2)
    fake = attacks.make("fake_incentive", 2, amount=50.0)
    state = lio.init(jax.random.PRNGKey(0), ENV, cfg, fake, defense_set)
    run = jax.jit(
        lambda s: jax.lax.scan(
            lambda s, _: lio.update(s, ENV, cfg, fake, defense_set), s, None, length=iterations
        )
    )
    state, _ = run(state)
    honest = defense_hooks.honest_agents(fake, 2)
    epsilon = _epsilon(defense_set, cfg.epsilon_end, honest)
    # The honest agent's acting distribution on the observations of fresh episodes.
    traj = jax.vmap(
        lambda k: lio.rollout(
            ENV,
            k,
            lio.act_fn(lio._modules(ENV, cfg)[0], state.policy, epsilon),
            None,
            fake,
        )
    )(jax.random.split(jax.random.PRNGKey(1), 32))
    module = lio._modules(ENV, cfg)[0]
    own = jax.tree.map(lambda x: x[1], state.policy)
    logits = module.apply(own, traj.obs[:, :, 1])
    eps_1 = epsilon if jnp.ndim(epsilon) == 0 else epsilon[1]
    acting = jnp.exp(nets.mixed_log_probs(logits, eps_1))
    unfloored = jnp.exp(nets.mixed_log_probs(logits, cfg.epsilon_end))
    softmax = jax.nn.softmax(logits)
    actions = traj.actions[:, :, 1][traj.valid]
    freq = np.bincount(actions, minlength=3) / actions.size
    return float(acting.min()), float(unfloored.min()), float(softmax.min()), freq


def test_the_floor_holds_under_a_fake_incentive_of_50():
    floor = defenses.compose([("exploration_floor", {"min_epsilon": 0.3})], 2)
    floored_min, unfloored_min, softmax_min, freq = _trained_under_fake_incentive(floor)
    # The incentives of 50 have pushed the honest agent's softmax to (near) a point mass …
    assert softmax_min < 1e-3
    # … but its acting policy keeps every action at ≥ min_epsilon/|A| = 0.1, as it plays,
    assert floored_min >= 0.1 - 1e-6
    assert freq.min() > 0.05
    # where the schedule's own ε = 0.1 would leave the rarest action at ≈ 0.033.
    assert unfloored_min < 0.05


# --- health monitor -----------------------------------------------------------------------


def _monitor_run(monitor, sent_fn, iterations, policy):
    state = monitor_lib.init_state(2, policy)
    valid = jnp.ones((5,), bool)
    grads = lambda r: jnp.ones((r.shape[0], 2, 4))  # noqa: E731  (no conflict: cos = 1)

    def body(carry, k):
        state, policy = carry
        policy = jax.tree.map(lambda x: x + 1.0, policy)  # learning moves the policy
        policy, state, metrics = monitor_lib.step(
            monitor,
            state,
            k,
            sent_fn(k),
            valid,
            jnp.float32(5.0),
            grads,
            jnp.ones((5, 2)),
            policy,
            R_MAX,
            ALL_HONEST,
        )
        return (state, policy), metrics

    (state, policy), metrics = jax.lax.scan(body, (state, policy), jnp.arange(iterations))
    return state, policy, metrics


def test_monitor_alarms_on_out_of_range_incentives_falls_back_and_cools_down():
    monitor = defenses.make("health_monitor", 2, patience=10, warmup=20, cooldown=30)
    policy = {"w": jnp.zeros((2, 3))}
    fake_after = 40
    sent = lambda k: jnp.where(k >= fake_after, _sent([50.0] * 5), _sent([1.0] * 5))  # noqa: E731
    state, policy, metrics = jax.jit(lambda p: _monitor_run(monitor, sent, 100, p))(policy)
    alarms = np.asarray(metrics["defense/monitor_alarms_by_giver"])  # [iterations, giver]
    first = int(np.argmax(alarms.sum(axis=1) > 0))
    assert alarms[:, 1].sum() == 0  # the honest giver is never flagged
    assert fake_after < first <= fake_after + 10 + 20  # EMA crosses 1/2, then patience
    assert int(state["first_alarm"]) == first
    # The jump from 1 to 50 trips the variance flag (std > R_max/2), or the range flag.
    reasons = metrics["defense/monitor_alarms_range"] + metrics["defense/monitor_alarms_variance"]
    assert float(reasons[first]) >= 1
    assert float(metrics["defense/monitor_alarms_conflict"].sum()) == 0
    assert float(metrics["defense/monitor_fallbacks"][first]) == 1
    # Cool-down: a second alarm on the same pair only after `cooldown` iterations, and
    # the pair is refused while it lasts.
    later = np.flatnonzero(alarms[:, 0])
    assert len(later) >= 2 and np.all(np.diff(later) >= 30)
    assert bool(monitor_lib.refused(state)[0, 1]) == (99 - later[-1] < 30)


def test_monitor_fallback_restores_the_last_good_checkpoint():
    monitor = defenses.make(
        "health_monitor", 2, patience=5, warmup=0, cooldown=1000, checkpoint_period=10
    )
    policy = {"w": jnp.zeros((2, 3))}
    sent = lambda k: jnp.where(k >= 25, _sent([50.0] * 5), _sent([1.0] * 5))  # noqa: E731
    _, final, metrics = _monitor_run(monitor, sent, 60, policy)
    first = int(np.argmax(np.asarray(metrics["defense/monitor_alarms"]) > 0))
    # Recipient 1's policy was reset to its checkpoint (a multiple of 10 updates, before
    # the flag went up) and then moved by the updates since; recipient 0 never fell back.
    w1, w0 = float(final["w"][1, 0]), float(final["w"][0, 0])
    assert w0 == 60.0
    restored_from = w1 - (60 - 1 - first)
    assert restored_from % 10 == 0 and restored_from <= 30


def test_monitor_is_quiet_on_steady_honest_incentives_and_vmaps():
    monitor = defenses.make("health_monitor", 2, patience=5, warmup=0)
    policy = {"w": jnp.zeros((2, 3))}
    sent = lambda k: _sent([1.0 + 0.5 * jnp.sin(k)] * 5)  # noqa: E731
    run = jax.vmap(lambda p: _monitor_run(monitor, sent, 200, p))
    states, _, metrics = run(jax.tree.map(lambda x: jnp.stack([x, x]), policy))
    assert float(metrics["defense/monitor_alarms"].sum()) == 0
    np.testing.assert_array_equal(states["first_alarm"], [-1, -1])


def test_conflict_cosines():
    env = jnp.array([[1.0, 0.0], [0.0, 1.0]])  # [N, P]
    inc = jnp.stack([jnp.array([[0.0, 0.0], [0.0, -2.0]]), jnp.array([[3.0, 0.0], [0.0, 0.0]])])
    cos = monitor_lib.conflict_cosines(jnp.concatenate([env[None], inc]))
    np.testing.assert_allclose(cos, [[0.0, -1.0], [1.0, 0.0]])


# --- inside training ----------------------------------------------------------------------


ALL = [("incentive_guard", {}), ("exploration_floor", {}), ("health_monitor", {"warmup": 0})]


@pytest.fixture(scope="module")
def fake_run():
    """ER(2,1) under a fake incentive of 50, two seeds, every defense, vmapped in one jit."""
    d = defenses.compose(ALL, 2)
    fake = attacks.make("fake_incentive", 2)
    keys = jax.random.split(jax.random.PRNGKey(3), 2)
    states = jax.vmap(lambda k: lio.init(k, ENV, CFG, fake, d))(keys)
    run = jax.jit(
        jax.vmap(
            lambda s: jax.lax.scan(
                lambda s, _: lio.update(s, ENV, CFG, fake, d), s, None, length=120
            )
        )
    )
    return run(states)


def test_all_defenses_train_under_jit_and_vmap_and_detect_the_fake_incentive(fake_run):
    states, metrics = fake_run
    alarms = np.asarray(metrics["defense/monitor_alarms_by_giver"])  # [seed, it, giver]
    assert alarms[:, :, 0].sum(axis=1).min() >= 1  # every seed flags the adversary (agent 0)
    assert alarms[:, :, 1].sum() == 0
    assert np.all(np.asarray(states.defense_state[2]["first_alarm"]) <= 80)
    assert np.asarray(metrics["defense/guard_clipped"])[:, 0].min() >= 1
    for leaf in jax.tree.leaves(states.policy):
        assert np.all(np.isfinite(np.asarray(leaf)))


def test_defense_config_errors_name_the_field():
    with pytest.raises(InvalidParameter, match="^min_epsilon: must be > 0 and ≤ 1"):
        defenses.make("exploration_floor", 2, min_epsilon=0.0)
    with pytest.raises(InvalidParameter, match="^budget_fraction"):
        defenses.make("incentive_guard", 2, budget_fraction=-1.0)
    with pytest.raises(InvalidParameter, match="^patience"):
        defenses.make("health_monitor", 2, patience=0)
    with pytest.raises(InvalidParameter, match="^foo: not a parameter of defense"):
        defenses.make("incentive_guard", 2, foo=1)
    with pytest.raises(InvalidParameter, match="^defenses: unknown defense 'x'; allowed:"):
        defenses.make("x", 2)
    with pytest.raises(InvalidParameter, match="given twice"):
        defenses.compose([("incentive_guard", {}), ("incentive_guard", {})], 2)


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--defense", "nope"], "defense: unknown value 'nope'; allowed: incentive_guard"),
        (["--dp", "min_epsilon=0.3"], "defense_param: given without --defense"),
        (["--defense", "exploration_floor", "--dp", "min_epsilon=2"], "min_epsilon: must be"),
        (["--defense", "incentive_guard", "--dp", "zz=1"], "defense_param: 'zz' is not"),
        (
            ["--defense", "incentive_guard", "--learner", "pg"],
            "defenses: incentive_guard acts at the hook point(s) learning_incentives",
        ),
    ],
)
def test_train_defense_errors_are_one_line_exit_2_nothing_written(tmp_path, capsys, argv, expected):
    out = tmp_path / "run"
    code = cli.main(["train", "ipd-v0", "--out", str(out), *argv])
    err = capsys.readouterr().err
    assert code == 2 and expected in err and err.count("\n") == 1
    assert not out.exists()


def test_train_with_defenses_and_audit_log_then_verify(tmp_path, capsys, monkeypatch):
    log, key = tmp_path / "audit.jsonl", tmp_path / "keys" / "audit.key"
    argv = [
        "train", "ipd-v0", "--seeds", "2", "--iterations", "40", "--eval-period", "20",
        "--chunk-iterations", "20", "--quiet", "--out", str(tmp_path / "run"),
        "--defense", "incentive_guard", "--defense", "health_monitor",
        "--dp", "health_monitor.patience=5", "--audit-log", str(log), "--audit-key", str(key),
    ]  # fmt: skip
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    assert "audit log" in out and "head" in out
    assert key.stat().st_mode & 0o777 == 0o600  # created on first use
    assert cli.main(["audit", "verify", str(log), "--audit-key", str(key)]) == 0
    monkeypatch.setenv("PIMBOT_AUDIT_KEY_FILE", str(tmp_path / "other.key"))
    assert cli.main(["audit", "verify", str(log)]) == 2  # no such key: one line, exit 2
    lines = log.read_text().splitlines()
    assert len(lines) == 3  # the run record and one per chunk
    assert "policy_sha256" in lines[1] and "defense/monitor_alarms" in lines[1]
    assert cli.main(["defenses"]) == 0
    listed = capsys.readouterr().out
    for name in (*defenses.registered(), "authenticated_channel", "audit_log"):
        assert name in listed
