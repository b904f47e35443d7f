"""The robustness scorecard (analysis.scorecard, analysis.sections.scorecard): rliable's
estimators checked against values worked out by hand, the pairing by seed at the common
horizon, skipped seeds and runs counted, each defense's recovery, and the report's table,
figures, CSV and marl-eval JSON, on synthetic run directories written here (no training)
whose attack, env, defense and learner are names no registry knows."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from pimbot import statistics
from pimbot.analysis import report, runs
from pimbot.analysis import scorecard as sc
from pimbot.analysis.sections import scorecard as section
from pimbot.suites import sweep
from pimbot.training import store

ATTACK = "sleeper_attack"
ENV = "crystal_maze-v1"
DEFENSE = "tripwire"
LEARNER = "a2c_plugin"


def success_of(seed: int, attacked: bool, defended: bool) -> float:
    """A run's success at every evaluation: clean 0.8 + 0.01·seed, an attack takes 0.3, a
    defense gives 0.2 of it back."""
    value = 0.8 + 0.01 * seed
    if attacked:
        value -= 0.3 - (0.2 if defended else 0.0)
    return value


def write_run(
    root: Path,
    name: str,
    attack: str | None = None,
    defended: bool = False,
    seeds: range = range(6),
    iterations: int = 400,
    late: float = 0.0,
) -> None:
    """A finished run directory: config.json, summary.json, metrics.csv (one row per seed
    and evaluation every 100 iterations). `late` is added to success after iteration 400."""
    path = root / name
    path.mkdir(parents=True)
    identity = {
        "attack": attack,
        "attack_params": {"adversary": 0} if attack else {},
        "env_id": ENV,
        "env_params": {"n_agents": 2, "min_at_lever": 1},
        "learner": LEARNER,
        "learner_config": {"lr": 0.001},
        "iterations": iterations,
        "eval_period": 100,
        "eval_episodes": 10,
        "seeds": len(seeds),
        "first_seed": seeds[0],
    }
    run_config = {"attack_params": [], "hparams": [], "defenses": []}
    if defended:
        run_config["defenses"] = [[DEFENSE, []]]
        identity["defenses"] = {DEFENSE: {}}
    config = {
        "identity": identity,
        "run_config": run_config,
        "env": {"id": ENV, "num_agents": 2, "params": identity["env_params"]},
    }
    (path / store.CONFIG).write_text(json.dumps(config))
    (path / store.SUMMARY).write_text(json.dumps({"finished": True}))
    with open(path / store.METRICS, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["seed", "iteration", "eval/success", "eval/adversary_margin_env"])
        for seed in seeds:
            for it in range(100, iterations + 1, 100):
                value = success_of(seed, attack is not None, defended) + (late if it > 400 else 0)
                writer.writerow([seed, it, value, 1.0 if attack else 0.0])


def write_suite(root: Path) -> Path:
    write_run(root, "grid/clean")
    # seeds 1..6 against the clean run's 0..5: 5 pairs, seeds 0 and 6 skipped; twice as
    # long, and different after iteration 400: compared at iteration 400
    write_run(root, "grid/attacked", ATTACK, seeds=range(1, 7), iterations=800, late=0.5)
    write_run(root, "grid/attacked_tripwire", ATTACK, defended=True)
    write_run(root, "grid/clean_tripwire", defended=True)
    jobs = [
        {"name": n, "group": "grid", "kind": "train", "claims": [], "status": "finished"}
        for n in ("grid/clean", "grid/attacked", "grid/attacked_tripwire", "grid/clean_tripwire")
    ]
    sweep.write_index(root, {"suite": "grid", "jobs": jobs})
    return root


@pytest.fixture(scope="module")
def suite(tmp_path_factory) -> Path:
    return write_suite(tmp_path_factory.mktemp("scorecard") / "suite")


@pytest.fixture(scope="module")
def written(suite, tmp_path_factory) -> Path:
    """The report of `suite`, written once for the tests that read it."""
    return report.write_report(suite, tmp_path_factory.mktemp("scorecard_report"))


# --- estimators, by hand -------------------------------------------------------------------


def test_estimators_match_hand_computed_values():
    assert sc.iqm(np.arange(1.0, 9.0)) == pytest.approx(4.5)  # mean of 3, 4, 5, 6
    # (1 > 0) + (1 > 2) + (2 > 0) + ½ (2 = 2) over 4 pairs
    assert sc.improvement(np.array([1.0, 2.0]), np.array([0.0, 2.0])) == pytest.approx(0.625)
    profile = sc.profile([np.array([0.2, 0.6]), np.array([1.0])], np.array([0.0, 0.5, 1.0]))
    np.testing.assert_allclose(profile, [1.0, 2 / 3, 0.0])


def test_bootstrap_resamples_within_each_stratum():
    """Two strata of constant values: the pooled mean never moves when each stratum keeps
    its size, while a bootstrap of the pooled runs would spread."""
    strata = [np.zeros(6), np.ones(6)]
    lo, hi = sc.stratified_bootstrap(strata, lambda s: np.concatenate(s, axis=-1).mean(-1))
    assert lo == hi == pytest.approx(0.5)
    spread = sc.stratified_bootstrap([np.r_[np.zeros(6), np.ones(6)]], lambda s: s[0].mean(-1))
    assert spread[0] < 0.4 and spread[1] > 0.6


def test_intervals_below_five_pairs_are_ranges():
    pairs = sc.Paired((0, 1), np.array([0.5, 0.7]), np.array([0.1, 0.6]), 100, 0)
    effect = sc.effect_estimate([pairs])
    assert effect.kind == statistics.RANGE
    assert (effect.mean, effect.lo, effect.hi) == pytest.approx((-0.25, -0.4, -0.1))
    assert sc.improvement_estimate([pairs]) == pytest.approx(0.75)  # no interval: a number


# --- pairing ----------------------------------------------------------------------------------


def test_pairs_by_seed_at_the_common_horizon(suite):
    card = sc.scorecard(runs.load_table(suite).records)
    (attack,) = [c for c in card.of(sc.ATTACK) if c.treated.name == "grid/attacked"]
    pairs = attack.pairs[sc.SUCCESS]
    assert pairs.seeds == (1, 2, 3, 4, 5) and pairs.unpaired == 2 and pairs.horizon == 400
    np.testing.assert_allclose(pairs.effect, -0.3, atol=1e-6)  # the late +0.5 is not read
    effect = sc.effect_estimate([pairs])
    assert effect.kind == statistics.CI and effect.mean == pytest.approx(-0.3, abs=1e-6)
    assert effect.lo == pytest.approx(-0.3, abs=1e-6) and effect.hi == pytest.approx(-0.3, abs=1e-6)
    assert sc.improvement_estimate([pairs]).mean == pytest.approx(1.0)
    assert card.unpaired_seeds == 4  # 2 vs clean, 2 in the recovery vs this run


def test_recovery_and_benign_control(suite):
    card = sc.scorecard(runs.load_table(suite).records)
    by = {(c.kind, c.treated.name): c for c in card.comparisons}
    recovered = by[(sc.RECOVERY, "grid/attacked_tripwire")].pairs[sc.SUCCESS]
    np.testing.assert_allclose(recovered.effect, 0.2, atol=1e-6)  # vs the attack without
    lost = by[(sc.CLEAN_RUN, "grid/attacked_tripwire")].pairs[sc.SUCCESS]
    np.testing.assert_allclose(lost.effect, -0.1, atol=1e-6)  # vs clean without defense
    benign = by[(sc.BENIGN, "grid/clean_tripwire")]
    assert benign.base.name == "grid/clean"
    np.testing.assert_allclose(benign.pairs[sc.SUCCESS].effect, 0.0, atol=1e-6)
    assert by[(sc.ATTACK, "grid/attacked_tripwire")].base.name == "grid/clean_tripwire"
    assert card.unmatched == []


def test_a_run_without_its_reference_is_listed(tmp_path):
    write_run(tmp_path, "grid/attacked_tripwire", ATTACK, defended=True)
    card = sc.scorecard(runs.load_table(tmp_path).records)
    assert card.comparisons == []
    reasons = dict.fromkeys(why for _, why in card.unmatched)
    assert f"no clean run with defenses {DEFENSE}" in reasons
    assert "no clean run with defenses none" in reasons
    assert len(card.unmatched) == 3  # vs clean + defense, vs the attack alone, vs clean


# --- the report ------------------------------------------------------------------------------


def test_report_shows_and_exports_the_scorecard(written):
    out = written
    markdown = (out / report.MARKDOWN).read_text()
    body = markdown.split(f"## {section.TITLE}", 1)[1]
    assert "4 seed(s) that only one of two compared runs has" in body
    row = next(
        line for line in body.splitlines() if f"| {ATTACK} | success | 5 | 2 | 400 |" in line
    )
    assert "-0.300 [-0.300, -0.300]" in row and row.endswith("| grid/clean |")
    assert "### Defense recovery" in body
    html = (out / report.HTML).read_text()
    assert section.TITLE in html and "scorecard_effects" in html
    for name in ("scorecard_effects.png", "scorecard_profiles.png", "scorecard_effects.svg"):
        assert (out / report.FIGURES / name).exists()
    with open(out / report.TABLES / "scorecard.csv") as f:
        rows = list(csv.DictReader(f))
    success = [r for r in rows if r["metric"] == "success" and r["defenses"] == "none"]
    assert len(success) == 1 and success[0]["skipped seeds"] == "2"
    assert float(success[0]["Δ attacked − clean"]) == pytest.approx(-0.3, abs=1e-6)
    assert success[0]["Δ attacked − clean interval"] == statistics.CI
    assert (out / report.TABLES / "scorecard_recovery.csv").exists()


def test_marl_eval_json_structure(written):
    out = written
    data = json.loads((out / report.TABLES / section.MARL_EVAL).read_text())
    assert list(data) == [ENV]  # environment: the env id
    (task,) = data[ENV].values()  # task: the env label, lower case
    assert set(task) == {
        f"{LEARNER}|none|clean",
        f"{LEARNER}|none|{ATTACK}",
        f"{LEARNER}|{DEFENSE}|clean",
        f"{LEARNER}|{DEFENSE}|{ATTACK}",
    }
    attacked = task[f"{LEARNER}|none|{ATTACK}"]
    assert list(attacked) == [f"seed_{s}" for s in range(1, 7)]
    run = attacked["seed_1"]
    assert list(run)[-1] == "absolute_metrics"  # the last key, where marl-eval reads it
    assert list(run)[:-1] == [f"step_{k}" for k in range(8)]
    assert run["step_0"] == {
        "step_count": 100,
        "success": [pytest.approx(success_of(1, True, False))],
        "adversary_margin": [1.0],
    }
    final = run["absolute_metrics"]["success"]
    # the mean of the last 10 evaluations: 4 before iteration 400, 4 after (+0.5)
    assert len(final) == 1 and final[0] == pytest.approx(success_of(1, True, False) + 0.25)


def test_no_pairs_names_the_unpaired_runs_and_leaves_no_stale_export(tmp_path):
    suite = write_suite(tmp_path / "suite")
    out = report.write_report(suite, tmp_path / "report")
    assert (out / report.TABLES / section.MARL_EVAL).exists()
    for name in ("grid/clean", "grid/clean_tripwire", "grid/attacked_tripwire"):
        for f in (suite / name).iterdir():
            f.unlink()
        (suite / name).rmdir()
    report.write_report(suite, out)
    assert not (out / report.TABLES / section.MARL_EVAL).exists()
    text = (out / report.MARKDOWN).read_text()  # the attacked run is named, not dropped
    scorecard = text.split(f"## {section.TITLE}", 1)[1]
    assert "run(s) without the run they are compared with: grid/attacked (" in scorecard
