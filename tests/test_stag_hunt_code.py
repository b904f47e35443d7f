"""C6 on what the published code measured: its Stag Hunt ADMO (`negated_env_reward`), the
random team's stag captures computed from the env, and the section judging C6 on the code's
success (the adversary's own episode env reward / 5)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from pimbot import attacks, envs, learners
from pimbot.analysis import runs, verdicts
from pimbot.analysis.document import Context
from pimbot.analysis.sections import stag_hunt
from pimbot.analysis.tables import Estimate
from pimbot.attacks import negated_env_reward
from pimbot.contracts.rollout import received, rollout
from pimbot.learners import lio, pg

SH = "stag_hunt-v0"

# --- the attack ---------------------------------------------------------------------------


def test_learning_rewards_negate_only_the_adversarys_env_reward():
    attack = attacks.make("negated_env_reward", 3, adversary=1)
    env_rewards = jnp.array([[1.0, 1.0, 0.0], [5.0, 5.0, 5.0], [0.0, 1.0, 1.0]])
    got = jnp.array([[0.5, 0.25, 0.0], [0.0, 2.0, 1.0], [1.0, 0.0, 0.5]])
    out = np.asarray(attack.learning_rewards({}, env_rewards, got))
    want = np.array(env_rewards + got)
    want[:, 1] = -np.asarray(env_rewards)[:, 1] + np.asarray(got)[:, 1]
    np.testing.assert_array_equal(out, want)


PIECES_ENV = envs.make(SH, n_players=2)
PIECES_CFG = learners.default_config("lio", SH)


@jax.jit
def _pieces(attack, key):
    env, cfg = PIECES_ENV, PIECES_CFG
    pm, im = lio._modules(env, cfg)
    eps = jnp.float32(0.3)
    k0, k1, k2 = jax.random.split(key, 3)
    state = lio.init(k0, env, cfg, attack)
    give = lio.give_fn(im, state.incentive, env.num_actions, cfg.incentive_max)
    traj = rollout(env, k1, pg.act_fn(pm, state.policy, eps), give, attack)
    actual = lio.actual_update(env, cfg, attack, state.attack_state, state.policy, traj, eps)
    modelled = lio.recipient_update(env, cfg, state.policy, state.incentive, traj, eps)
    new_traj = rollout(env, k2, pg.act_fn(pm, modelled, eps), give, attack)
    pullbacks = lio.recipient_pullbacks(
        env, cfg, state.policy, state.incentive, traj, eps, new_traj
    )
    view, _ = lio.adversary_view(
        env, cfg, attack, state, pullbacks, actual, traj, new_traj, 0.0, eps, None
    )
    own, _, _ = attack.adversary_step(state.attack_state, key, view)
    clean = lio.meta_gradients_from(env, cfg, pullbacks, traj, new_traj)
    negated = negated_env_reward.negated_for(attack, traj.env_rewards)
    on_negated = pg.policy_step(
        pm, state.policy, traj, negated + received(traj.incentives) * traj.valid[:, None],
        eps, cfg.lr_policy, cfg.gamma, cfg.entropy_coef,
    )  # fmt: skip
    return state, traj, actual, modelled, on_negated, own, clean


def _lio_pieces(attack, seed=3):
    """One iteration's τ, θ (actual step under `attack`, and the modelled ordinary one), the
    adversary's step, and clean LIO's meta-gradients (one program for every attack value)."""
    return PIECES_CFG, _pieces(attack, jax.random.PRNGKey(seed))


def _rows_equal(a, b, i) -> bool:
    return all(
        np.allclose(x[i], y[i], rtol=1e-5, atol=1e-7)
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
    )


def test_the_adversarys_policy_step_is_ordinary_on_its_negated_env_reward():
    attack = attacks.make("negated_env_reward", 2, adversary=0)
    _, (state, traj, actual, modelled, on_negated, own, _) = _lio_pieces(attack)
    assert float(jnp.abs(traj.env_rewards[:, 0]).sum()) > 0  # a reward to negate
    assert _rows_equal(actual, on_negated, 0)  # the adversary: −r_env + received
    assert not _rows_equal(actual, modelled, 0)
    assert _rows_equal(actual, modelled, 1)  # the other hunter: its ordinary step
    for got, want in zip(jax.tree.leaves(own.policy), jax.tree.leaves(actual), strict=True):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want)[0])


def test_the_adversarys_incentive_step_ascends_its_negated_env_return():
    """With no cost step, η_a moves by one Adam step along minus clean LIO's meta-gradient
    of giver a (the surrogate is linear in the giver's return, so negating the return
    negates the gradient)."""
    attack = attacks.make("negated_env_reward", 2, adversary=0, lr_cost=0.0)
    cfg, (state, traj, *_, own, clean) = _lio_pieces(attack, seed=5)
    clean_a = jax.tree.map(lambda g: g[0], clean)
    assert max(float(jnp.abs(g).max()) for g in jax.tree.leaves(clean_a)) > 0
    adam = optax.adam(cfg.lr_incentive)
    eta = jax.tree.map(lambda x: x[0], state.incentive)
    updates, _ = adam.update(clean_a, adam.init(eta))  # descent on J_a = ascent on −J_a
    want = optax.apply_updates(eta, updates)
    for got, w in zip(jax.tree.leaves(own.incentive), jax.tree.leaves(want), strict=True):
        np.testing.assert_allclose(np.asarray(got), np.asarray(w), rtol=1e-4, atol=1e-7)


def test_lio_trains_under_the_attack_on_the_stag_hunt():
    env = envs.make(SH, n_players=2)
    cfg = learners.default_config("lio", SH)
    attack = attacks.make("negated_env_reward", 2)
    state = lio.init(jax.random.PRNGKey(0), env, cfg, attack)
    new, _ = jax.jit(lio.update, static_argnums=(1, 2, 3))(state, env, cfg, attack)
    assert int(new.iteration) == 1
    for i in range(2):  # both givers' incentive functions moved
        assert not _rows_equal(new.incentive, state.incentive, i)
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree.leaves(new.incentive))


def test_bad_rates_are_refused_by_name():
    with pytest.raises(envs.InvalidParameter, match="lr_cost"):
        attacks.make("negated_env_reward", 2, lr_cost=-1.0)


# --- the random team, from the env ------------------------------------------------------


def test_random_team_captures_are_computed_from_the_env_deterministically():
    two = stag_hunt.random_team_captures(SH, {"n_players": 2}, 3000, 0)
    assert two == stag_hunt.random_team_captures(SH, {"n_players": 2}, 3000, 0)
    assert 0.045 < two.mean < 0.095 and two.lo < two.mean < two.hi  # ≈ 0.07
    other = stag_hunt.random_team_captures(SH, {"n_players": 2}, 3000, 1)
    assert other.mean != two.mean and other.lo < two.hi and two.lo < other.hi
    four = stag_hunt.random_team_captures(SH, {"n_players": 4}, 3000, 0)
    assert four.mean < 0.005 and four.lo >= 0.0
    # The env decides: a stag that never moves on a 2×2 grid is caught far more often.
    easy = stag_hunt.random_team_captures(
        SH, {"n_players": 2, "grid_size": 2, "stag_random_action_prob": 0.0}, 500, 0
    )
    assert easy.mean > 10 * two.mean


# --- the section on small fake runs -----------------------------------------------------


def write_run(root: Path, name: str, values, *, attack=None, params=None, n=2, horizon=1000):
    """A finished Stag Hunt run whose metrics at iteration t are values(seed, t)."""
    params = {"adversary": 0, **(params or {})} if attack else {}
    env_params = {"n_players": n}
    path = root / name
    path.mkdir(parents=True)
    identity = {
        "attack": attack,
        "attack_params": params,
        "env_id": SH,
        "env_params": env_params,
        "eval_period": 100,
        "first_seed": 0,
        "iterations": horizon,
        "learner": "lio",
        "learner_config": {},
        "seeds": 5,
    }
    config = {
        "identity": identity,
        "run_config": {"attack_params": [], "hparams": [], "defenses": [], "env_params": []},
        "env": {"id": SH, "num_agents": n, "params": env_params},
    }
    (path / "config.json").write_text(json.dumps(config))
    (path / "summary.json").write_text(json.dumps({"finished": True}))
    rows = [(s, t, values(s, t)) for s in range(5) for t in range(100, horizon + 1, 100)]
    header = sorted(rows[0][2])
    with open(path / "metrics.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["iteration", "seed", *header, "perf/iters_per_s"])
        for s, t, v in rows:
            writer.writerow([t, s, *(v[k] for k in header), 1000.0])
    return runs.load_record(root, name)


def curve(code_start, code_end, success, captures):
    """Metrics moving linearly from the first evaluation to the last, a little per seed."""

    def values(s, t):
        f = (t - 100) / 900
        return {
            stag_hunt.code_metric(0): code_start + f * (code_end - code_start) + 0.01 * s,
            stag_hunt.code_metric(1): 0.3,
            stag_hunt.SUCCESS: success + 0.01 * s,
            stag_hunt.CAPTURES: captures + 0.001 * s,
        }

    return values


RANDOM = Estimate(0.07, 0.066, 0.074, digits=4)


def test_c6_judged_on_the_codes_metric_with_both_admos(tmp_path):
    clean = write_run(tmp_path, "stag_hunt/sh2_clean", curve(0.3, 0.5, 0.45, 0.06))
    paper = write_run(
        tmp_path,
        "stag_hunt/sh2_admo_disrupt",
        curve(0.3, 0.7, 0.8, 0.05),
        attack="admo",
        params={"mode": "disrupt"},
    )
    code = write_run(
        tmp_path,
        "stag_hunt/sh2_negated_env_reward",
        curve(0.3, 0.05, 0.3, 0.01),
        attack="negated_env_reward",
    )
    attacked = {paper.condition: paper, code.condition: code}
    assert set(attacked) == set(stag_hunt.ATTACKED)
    parts, line = stag_hunt.judge_env("SH(2)", clean, attacked, RANDOM)
    assert parts["SH(2) code's success rises"].kind == verdicts.REPRODUCED
    captures = parts["SH(2) stag captures above a random team's"]
    assert captures.causes == (verdicts.PAPER_METRIC,) and "0.07" in captures.reason
    assert parts["SH(2) negated_env_reward → 0"].kind == verdicts.REPRODUCED
    assert parts["SH(2) admo_disrupt → 0"].causes == (verdicts.PAPER_CODE,)
    assert "train_lio_staghunt_admo.py" in parts["SH(2) admo_disrupt → 0"].reason
    # final: the mean of the last evaluations
    assert "negated_env_reward final 0.1" in line and ", Δ -0.2" in line
    # Neither ADMO lowers it: no evidence of a cause, so nobody's defect.
    flat = write_run(
        tmp_path, "stag_hunt/flat", curve(0.3, 0.6, 0.4, 0.05), attack="negated_env_reward"
    )
    neither = {paper.condition: paper, flat.condition: flat}
    parts, _ = stag_hunt.judge_env("SH(2)", clean, neither, RANDOM)
    for condition in stag_hunt.ATTACKED:
        verdict = parts[f"SH(2) {condition} → 0"]
        assert verdict.kind == verdicts.INCONCLUSIVE and not verdict.causes
    parts, _ = stag_hunt.judge_env("SH(2)", clean, {paper.condition: paper}, RANDOM)
    assert parts["SH(2) negated_env_reward → 0"].kind == verdicts.NOT_RUN
    # Captures above a random team's reproduce that part.
    hunting = write_run(tmp_path, "stag_hunt/hunting", curve(0.3, 0.9, 0.9, 0.5))
    parts, _ = stag_hunt.judge_env("SH(2)", hunting, attacked, RANDOM)
    assert parts["SH(2) stag captures above a random team's"].kind == verdicts.REPRODUCED


def test_the_section_renders_on_small_runs(tmp_path, monkeypatch):
    monkeypatch.setattr(stag_hunt, "RANDOM_EPISODES", 200)
    suite = tmp_path / "suite"
    records = [
        write_run(suite, "stag_hunt/sh2_clean", curve(0.3, 0.5, 0.45, 0.06)),
        write_run(
            suite,
            "stag_hunt/sh2_admo_disrupt",
            curve(0.3, 0.7, 0.8, 0.05),
            attack="admo",
            params={"mode": "disrupt"},
        ),
        write_run(
            suite,
            "stag_hunt/sh2_negated_env_reward",
            curve(0.3, 0.05, 0.3, 0.01),
            attack="negated_env_reward",
        ),
    ]
    section = stag_hunt.section(runs.RunTable(tuple(records)), Context(suite, tmp_path / "rep", {}))
    (table,) = section.tables
    assert [row[1] for row in table.rows] == ["clean", "admo_disrupt", "negated_env_reward"]
    assert table.rows[0][4] is None and table.rows[2][4].mean < -0.2
    assert all(row[-1].mean > 0 for row in table.rows)  # the random team's, computed
    (claim,) = section.claims
    assert claim.id == "C6" and claim.judged.kind == verdicts.REFUTED
    assert set(claim.judged.causes) == {verdicts.PAPER_METRIC, verdicts.PAPER_CODE}
    assert verdicts.IMPLEMENTATION not in claim.judged.causes
    names = {f.path.name for f in section.figures}
    assert names == {"fig6_stag_hunt.png", "fig6b_stag_captures.png", "fig6c_team_success.png"}
