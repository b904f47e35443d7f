"""The claim rules on small synthetic run tables: every verdict kind is reachable, each
refutation carries the cause its evidence points to, and intervals are scipy's BCa at ≥ 5
seeds and the seeds' range below.

The runs are written by hand (config.json and metrics.csv with chosen per-seed curves;
nothing is trained): they test the rules, not any measured figure.
"""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from pimbot import statistics
from pimbot.analysis import claims, judging, runs, verdicts
from pimbot.analysis.claims import Claim
from pimbot.analysis.sections import attack_claims, reciprocators
from pimbot.analysis.tables import difference, estimate

ER = "escape_room-v0"


def er(n: int, m: int) -> dict:
    return {"max_steps": 5, "min_at_lever": m, "n_agents": n, "randomize_start": False}


def write_run(
    root: Path,
    name: str,
    curve,
    *,
    env_id=ER,
    env_params=None,
    attack=None,
    attack_params=None,
    learner="lio",
    seeds=5,
    horizon=10_000,
    period=500,
    learner_config=None,
    source=None,
) -> runs.RunRecord:
    """A finished run whose metric `column` of seed s at iteration t is curve(s, t)[column]."""
    env_params = env_params or er(2, 1)
    n = env_params.get("n_agents", env_params.get("n_players", 2))
    path = root / name
    path.mkdir(parents=True)
    config = {
        "identity": {
            "attack": attack,
            "attack_params": {"adversary": 0, **(attack_params or {})} if attack else {},
            "env_id": env_id,
            "env_params": env_params,
            "eval_period": period,
            "first_seed": 0,
            "iterations": horizon,
            "learner": learner,
            "learner_config": learner_config or {},
            "seeds": seeds,
        },
        "run_config": {"attack_params": [], "hparams": [], "defenses": [], "env_params": []},
        "env": {"id": env_id, "num_agents": n, "params": env_params},
    }
    if source:
        config["source"] = source
    (path / "config.json").write_text(json.dumps(config))
    (path / "summary.json").write_text(json.dumps({"finished": True}))
    rows = [(s, t, curve(s, t)) for s in range(seeds) for t in range(period, horizon + 1, period)]
    header = sorted(rows[0][2])
    with open(path / "metrics.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["iteration", "seed", *header, "perf/iters_per_s"])
        for s, t, values in rows:
            writer.writerow([t, s, *(values[k] for k in header), 1000.0])
    return runs.load_record(root, name)


def const(**values):
    """A curve with the same value at every point; a value may be a function of the seed."""
    return lambda s, t: {k: (v(s) if callable(v) else v) for k, v in values.items()}


def data_of(records) -> attack_claims.Runs:
    table = runs.RunTable(tuple(records))
    return attack_claims.Runs(table, {(r.env, r.condition): r for r in records})


# --- statistics -------------------------------------------------------------------------


def test_intervals_are_scipy_bca_at_five_seeds_and_the_range_below():
    few = np.array([0.2, 0.5, 0.9])
    interval = statistics.mean_interval(few)
    assert (interval.kind, interval.lo, interval.hi) == ("range", 0.2, 0.9)
    assert "(range 0.200 … 0.900)" in str(estimate(few)) and "[" not in str(estimate(few))
    many = np.array([0.1, 0.4, 0.35, 0.8, 0.55, 0.2, 0.9])
    interval = statistics.mean_interval(many)
    expected = stats.bootstrap(
        (many,),
        np.mean,
        method="BCa",
        n_resamples=statistics.RESAMPLES,
        rng=np.random.default_rng(0),
    ).confidence_interval
    assert interval.kind == "ci"
    assert (interval.lo, interval.hi) == pytest.approx((expected.low, expected.high))
    assert str(estimate(many)).count("[") == 1
    # Equal values: a zero-width interval, not BCa's NaN.
    assert statistics.mean_interval(np.ones(6)) == statistics.Interval(1.0, 1.0, "ci", 6)
    # A difference below 5 seeds spans every pairwise difference.
    d = difference(np.array([1.0, 2.0]), np.array([0.0, 0.5, 1.5]))
    assert (d.lo, d.hi, d.kind) == (-0.5, 2.0, "range")
    mean, lo, hi, kind = statistics.band(np.array([[0.0, 1.0], [1.0, 1.0], [0.5, 1.0]]))
    assert kind == "range" and list(lo) == [0.0, 1.0] and list(hi) == [1.0, 1.0]


# --- verdicts ---------------------------------------------------------------------------


def test_verdict_vocabulary():
    with pytest.raises(ValueError, match="needs a cause"):
        verdicts.Verdict(verdicts.REFUTED, "x")
    with pytest.raises(ValueError, match="needs a reason"):
        verdicts.inconclusive("")
    wrong = verdicts.refuted(verdicts.SPEC, "0.2 < 0.8")
    assert wrong.label == "refuted — cause: our spec" and str(wrong).endswith("0.2 < 0.8")
    parts = {"a": verdicts.reproduced("1"), "b": verdicts.inconclusive("2"), "c": wrong}
    assert verdicts.combine(parts).kind == verdicts.REFUTED
    assert verdicts.combine({"a": verdicts.reproduced(), "b": verdicts.at_budget("x")}).kind == (
        verdicts.AT_BUDGET
    )
    # The quick budget: learning evidence becomes inconclusive, whatever the cause it names
    # (short runs show no more that the paper contradicts itself); the env's rules do not.
    for cause in (verdicts.IMPLEMENTATION, verdicts.PAPER_METRIC, verdicts.PAPER_ENVIRONMENT):
        quick = verdicts.at_quick_budget(verdicts.refuted(cause, "0.1"))
        assert quick.kind == verdicts.INCONCLUSIVE and "0.1" in quick.reason
    structural = verdicts.refuted(verdicts.IMPLEMENTATION, "idle", structural=True)
    rules = verdicts.at_quick_budget(verdicts.combine({"a": structural, "b": wrong}))
    assert rules.kind == verdicts.INCONCLUSIVE  # a learning part among the refuted ones
    rules = verdicts.at_quick_budget(verdicts.combine({"a": structural, "b": parts["a"]}))
    assert rules.kind == verdicts.REFUTED and rules.qualifier == "quick budget"


def test_a_cause_is_named_only_where_pimbot_and_the_original_code_differ():
    # ER(4,3) reverse at 25k, measured: 2 of our 10 seeds solve it, none of the 5 logs.
    ours = np.array([0, 0.01, 1, 0, 0.26, 0, 1, 0, 0, 0])
    logs = np.array([0, 0, 0, 0, 0.01])
    p = statistics.difference_p_value(ours, logs)
    exact = stats.permutation_test(
        (ours, logs), lambda a, b: a.mean() - b.mean(), permutation_type="independent"
    ).pvalue  # all 3003 splits: exact
    assert p == pytest.approx(exact) and 0.3 < p < 0.6
    assert statistics.difference_p_value(np.zeros(3), np.zeros(4)) == 1.0
    undecided = judging.disagreement("0.227 not ≤ 0.05", True, ours, logs)
    assert undecided.kind == verdicts.INCONCLUSIVE and "p = 0.4" in undecided.reason
    apart = judging.disagreement("0.9 not ≤ 0.05", True, np.full(10, 0.9), logs)
    assert apart.kind == verdicts.REFUTED and apart.causes == (verdicts.IMPLEMENTATION,)
    theirs = judging.disagreement("0.9 not ≤ 0.05", False, np.full(10, 0.9), logs)
    assert theirs.causes == (verdicts.PAPER_CODE,)


def test_no_original_log_names_no_cause():
    alone = judging.disagreement("margin -0.1 not above 0", None)
    assert alone.kind == verdicts.INCONCLUSIVE and not alone.causes
    assert "margin -0.1 not above 0" in alone.reason
    assert "no original-code log at these settings" in alone.reason
    assert "no cause can be named" in alone.reason


def test_our_implementation_needs_a_significant_difference_named_in_full():
    ours = np.array([0.9, 0.8, 0.95, 0.85, 0.9, 0.88, 0.92, 0.87, 0.9, 0.91])
    logs = np.array([0.0, 0.01, 0.0, 0.02, 0.0])
    v = judging.disagreement("0.89 not ≤ 0.05", True, ours, logs)
    assert v.kind == verdicts.REFUTED and v.causes == (verdicts.IMPLEMENTATION,)
    p = statistics.difference_p_value(ours, logs)
    assert p < judging.DIFFERS_P and f"p = {p:.3f}" in v.reason
    # Both distributions: n, mean and median of each.
    assert "ours n = 10, mean 0.888, median 0.900" in v.reason
    assert "the logs' n = 5, mean 0.006, median 0.000" in v.reason


def test_logs_that_reproduce_the_paper_without_per_seed_values_name_no_cause():
    for ours, logs in ((None, None), (np.full(10, 0.9), None), (np.full(10, 0.9), np.array([]))):
        v = judging.disagreement("0.9 not ≤ 0.05", True, ours, logs)
        assert v.kind == verdicts.INCONCLUSIVE and not v.causes
        assert "reproduce the paper" in v.reason and "no per-seed values" in v.reason


# --- C1, C3, C4 ---------------------------------------------------------------------------


def test_success_reachable_with_an_idle_agent_follows_the_env_rules():
    assert not judging.success_reachable_with_idle(ER, er(2, 1), 0)
    assert not judging.success_reachable_with_idle(ER, er(4, 3), 0)
    assert judging.success_reachable_with_idle(ER, er(4, 2), 0)
    assert judging.success_reachable_with_idle(ER, er(3, 1), 2)


def test_c3_structural_parts_and_evidence(tmp_path):
    def bypass(name, params, success):
        return write_run(
            tmp_path,
            f"attacks/{name}",
            const(**{"eval/success": success}),
            env_params=params,
            attack="bypass",
        )

    good = [bypass("er21", er(2, 1), 0.0), bypass("er43", er(4, 3), 0.0)]
    claim = attack_claims.c3(data_of([*good, bypass("er42", er(4, 2), 0.95)]))
    assert claim.judged.kind == verdicts.REPRODUCED
    assert "ER(2,1) structural" in claim.measured and "ER(4,2) evidence" in claim.measured
    # Success where the rules forbid it: our implementation; ER(4,2) unsolved: evidence.
    bad = bypass("er21_bug", er(2, 1), lambda s: 0.2 * (s == 0))
    claim = attack_claims.c3(data_of([bad, good[1], bypass("er42_low", er(4, 2), 0.3)]))
    assert claim.judged.kind == verdicts.REFUTED
    assert claim.judged.causes == (verdicts.IMPLEMENTATION,)
    assert "the env's rules forbid success" in claim.judged.reason and "0.300" in claim.measured


EXPLORING = {"epsilon_decay_iters": 1000}
"""LIO's exploration schedule as config.json records it: the early window of C2 and C4."""


def falling(early: float, then, after=None):
    """A success curve: `early` during the exploration period, `then` (a function of the
    seed, or a value) up to 25k, `after` (default `then`) later."""

    def curve(s, t):
        late = then if after is None or t <= 25_000 else after
        value = early if t <= 1000 else late
        return {"eval/success": value(s) if callable(value) else value}

    return curve


def test_c4_at_the_paper_budget_with_the_later_run_as_a_note(tmp_path):
    def reverse(name, params, curve, horizon=25_000, source=None, attack_params=None):
        return write_run(
            tmp_path,
            f"{'original' if source else 'attacks'}/{name}",
            curve,
            env_params=params,
            attack="reverse",
            attack_params=attack_params,
            horizon=horizon,
            period=500,
            learner_config=EXPLORING,
            source=source,
        )

    late = reverse("er21", er(2, 1), falling(0.5, 0.0, 0.5), 50_000)
    rest = [
        reverse("er42", er(4, 2), const(**{"eval/success": 1.0})),
        reverse("er43", er(4, 3), falling(0.3, 0.0)),
    ]
    claim = attack_claims.c4(data_of([late, *rest]))
    assert claim.id == "C4" and claim.judged.kind == verdicts.REPRODUCED, claim.judged
    assert "note (not judged" in claim.measured and "+0.500" in claim.measured
    assert "sign-flip permutation" in claim.rule and "≤ 0.05" not in claim.rule
    short = reverse("er21_short", er(2, 1), const(**{"eval/success": 0.3}), 10_000)
    main = attack_claims.c4(data_of([short, *rest]))
    assert main.judged.kind == verdicts.INCONCLUSIVE and "10,000 it" in main.judged.reason
    # A run short of the paper's 25k is marked so (the quick budget cannot decide it).
    parts = dict(main.judged.parts)
    assert parts["ER(2,1)"].short_horizon == (10_000, 25_000)
    assert parts["ER(4,2)"].short_horizon is None
    assert verdicts.by_design(main.judged) and not verdicts.by_design(claim.judged)
    # ER(4,3) solved by our seeds, not by the logs at the same settings: a named difference.
    solved = reverse("er43_solved", er(4, 3), falling(0.3, 1.0))
    logs = reverse("er43_logs", er(4, 3), falling(0.3, 0.0), source=runs.ORIGINAL_CODE)
    other = reverse(
        "er43_other", er(4, 3), falling(0.3, 0.0), source=runs.ORIGINAL_CODE,
        attack_params={"adversary": 1},
    )  # fmt: skip
    records = [late, rest[0], solved]
    table = runs.RunTable(tuple(records), (logs,))
    data = attack_claims.Runs(table, {(r.env, r.condition): r for r in records})
    judged = attack_claims.c4(data).judged
    assert judged.causes == (verdicts.IMPLEMENTATION,) and "p = 0.00" in judged.reason
    # Logs of the same attack under other parameters are named, never compared.
    table = runs.RunTable(tuple(records), (other,))
    data = attack_claims.Runs(table, {(r.env, r.condition): r for r in records})
    judged = attack_claims.c4(data).judged
    assert judged.kind == verdicts.INCONCLUSIVE and "adversary 1 in the original" in judged.reason


def test_c2_at_the_codes_c_and_the_papers_c(tmp_path):
    def fake(name, params, curve, amount, source=None):
        return write_run(
            tmp_path,
            f"{'original' if source else 'attacks'}/{name}",
            curve,
            env_params=params,
            attack="fake_incentive",
            attack_params={"amount": amount},
            horizon=25_000,
            period=500,
            learner_config=EXPLORING,
            source=source,
        )

    rooms = (("21", er(2, 1)), ("42", er(4, 2)), ("43", er(4, 3)))
    code = [fake(f"er{n}", p, falling(0.4, 0.0), 10.0) for n, p in rooms]
    paper = [fake(f"er{n}_c50", p, falling(0.0, 0.0), 50.0) for n, p in rooms]
    logs = [fake(f"log{n}", p, falling(0.3, 0.0), 10.0, runs.ORIGINAL_CODE) for n, p in rooms]
    records = [*code, *paper]
    table = runs.RunTable(tuple(records), tuple(logs))
    main, second = attack_claims.c2(attack_claims.Runs(table, {(r.name, ""): r for r in records}))
    assert (main.id, second.id, main.jobs_of, second.jobs_of) == ("C2", "C2 (C = 50)", "C2", "C2")
    assert main.judged.kind == verdicts.REPRODUCED, main.judged
    assert "exploration period" in main.rule and "0.1" not in main.rule
    # No early success at C = 50; the logs are at C = 10: named, not compared.
    assert second.judged.kind == verdicts.INCONCLUSIVE
    assert "amount 10 in the original code's logs, 50 here" in second.judged.reason
    assert all("not compared" in n.original for n in second.numbers)
    # At C = 10, ours without early success against logs with it: a named difference.
    flat = [fake(f"flat{n}", p, falling(0.0, 0.0), 10.0) for n, p in rooms]
    table = runs.RunTable(tuple(flat), tuple(logs))
    (main,) = attack_claims.c2(attack_claims.Runs(table, {(r.name, ""): r for r in flat}))
    assert main.judged.causes == (verdicts.IMPLEMENTATION,), main.judged
    # Without any log: no cause.
    (alone,) = attack_claims.c2(attack_claims.Runs(runs.RunTable(tuple(flat)), {
        (r.name, ""): r for r in flat}))  # fmt: skip
    assert alone.judged.kind == verdicts.INCONCLUSIVE and "no original-code log" in (
        alone.judged.reason
    )


def test_c1b_speed_by_a_rank_test_at_equal_horizon(tmp_path):
    def run(name, condition, params, at, seeds=5, source=None):
        attack = None if condition == "clean" else "self_centered"

        def curve(s, t):
            step = at(s) if callable(at) else at
            return {"eval/return_ratio": 1.0 if t >= step else 0.0}

        return write_run(
            tmp_path,
            f"{'original' if source else 'attacks'}/{name}",
            curve,
            env_params=params,
            attack=attack,
            seeds=seeds,
            horizon=30_000,
            period=500,
            source=source,
        )

    fast = [
        run("a", "clean", er(2, 1), 20_000),
        run("b", "self", er(2, 1), 12_500),
        run("c", "clean", er(4, 2), 14_000),
        run("d", "self", er(4, 2), 10_500),
    ]
    claim = attack_claims.c1b(data_of(fast))
    assert claim.judged.kind == verdicts.REPRODUCED, claim.judged
    assert "Mann–Whitney" in claim.rule and "Mann–Whitney p = 0.004 earlier" in claim.measured
    # Smoothed over 10 evaluations, a step at 20k (12.5k) first reaches 0.9 nine points later.
    first = next(n for n in claim.numbers if n.quantity.startswith("ER(2,1)"))
    assert (first.paper, first.pimbot, first.horizon) == (
        "20k → 12.5k",
        "24.0k → 16.5k",
        "30,000 it",
    )
    slow = [run("e", "clean", er(2, 1), 10_000), run("f", "self", er(2, 1), 15_000), *fast[2:]]
    slower = attack_claims.c1b(data_of(slow)).judged  # no original-code log: no cause
    assert slower.kind == verdicts.INCONCLUSIVE and "no original-code log" in slower.reason
    few = [run("g", "clean", er(2, 1), 10_000, 3), run("h", "self", er(2, 1), 15_000, 3)]
    assert attack_claims.c1b(data_of(few + fast[2:])).judged.kind == verdicts.INCONCLUSIVE
    # Runs that stop before the paper's clean run converged (ER(4,2): 14k) are marked so.
    early = [
        write_run(tmp_path, f"attacks/{name}", lambda s, t: {"eval/return_ratio": 0.0},
                  env_params=er(4, 2), attack=attack, horizon=5_000, period=500)
        for name, attack in (("o", None), ("p", "self_centered"))
    ]  # fmt: skip
    short = dict(attack_claims.c1b(data_of([*fast[:2], *early])).judged.parts)
    assert short["ER(4,2)"].short_horizon == (5_000, 14_000)
    assert short["ER(2,1)"].short_horizon is None  # 30,000 it reach the paper's 20,000
    # Overlapping seeds cannot be told apart: inconclusive, the logs named beside them.
    mixed = [
        run("i", "clean", er(4, 2), lambda s: 5_000 + 1_000 * s),
        run("j", "self", er(4, 2), lambda s: 5_500 + 1_000 * s),
    ]
    logs = (
        run("k", "clean", er(4, 2), 7_000, 4, runs.ORIGINAL_CODE),
        run("l", "self", er(4, 2), 5_000, 4, runs.ORIGINAL_CODE),
    )
    records = [*fast[:2], *mixed]
    table = runs.RunTable(tuple(records), logs)
    data = attack_claims.Runs(table, {(r.env, r.condition): r for r in records})
    claim = attack_claims.c1b(data)
    assert claim.judged.kind == verdicts.INCONCLUSIVE and "cannot tell" in claim.judged.reason
    assert "the original code's logs: 4+4 logs at 30,000 it" in claim.judged.reason
    row = next(n for n in claim.numbers if n.quantity.startswith("ER(4,2)"))
    assert row.original == "11.0k → 9.0k (4+4 logs)"
    assert "per seed clean 9.0k/10.0k/11.0k/12.0k/13.0k / " in claim.measured
    # Above ten seeds a part gives the quartiles over seeds, not forty numbers.
    many = [
        run("m", "clean", er(4, 2), lambda s: 1_000 * (s + 1) if s < 11 else 10**9, 12),
        run("n", "self", er(4, 2), 10_500, 12),
    ]
    measured = attack_claims.c1b(data_of([*fast[:2], *many])).measured
    assert "(12+12 seeds; quartiles over seeds clean 8.0k–13.0k, never 1 / " in measured


# --- C5, C6, C7 ---------------------------------------------------------------------------


def test_c5_margin_against_the_symmetric_baseline_and_own_exit_success(tmp_path):
    def run(name, attack, params, margin, own, success, mode="stealthy"):
        n = params["n_agents"]
        values = {"eval/adversary_margin_env": margin, "eval/success": success, "eval/steps": 2.0}
        values |= {f"eval/exit_success/agent_{i}": (own if i == 0 else 0.5) for i in range(n)}
        given = {"mode": mode} if attack else None
        return write_run(
            tmp_path,
            f"attacks/{name}",
            const(**values),
            env_params=params,
            attack=attack,
            attack_params=given,
        )

    records = []
    for n, m in ((2, 1), (4, 2), (4, 3)):
        records += [
            run(f"c{n}{m}", None, er(n, m), lambda s: (-10.0, 10.0)[s % 2], 0.5, 0.9),
            run(f"s{n}{m}", "admo", er(n, m), 3.0, 0.9, 0.9),
            run(f"d{n}{m}", "admo", er(n, m), 0.0, 0.5, 0.1, "disrupt"),
        ]
    data = data_of(records)
    claim = attack_claims.c5(data)
    assert claim.judged.kind == verdicts.REPRODUCED, claim.judged
    # Disrupt is judged only where the task is non-redundant (not in ER(4,2)).
    assert "ER(4,2) admo_disrupt disrupts" not in claim.measured
    assert "ER(4,3) admo_disrupt disrupts" in claim.measured
    assert "admo_code (the published code's scheduler): no runs" in claim.measured
    parts = attack_claims.admo_parts(data, "admo")[0]
    assert not any("steps" in name for name in parts) and "measured, not judged" in claim.measured
    assert "sign-flip permutation" in claim.judged.reason and "25" not in claim.rule


def test_c7_er_shortfall_classified_by_the_transfer_counterfactual(tmp_path):
    def run(name, success, env_id=ER, attack=None, config=None):
        params = er(4, 2) | ({"transfer": 0.5} if "transfer" in env_id else {})
        config = config or {"grudge": "one_step"}  # the suite's C7 runs
        return write_run(
            tmp_path,
            f"reciprocators/{name}",
            const(**{"eval/success": success}),
            env_id=env_id,
            env_params=params,
            learner="reciprocator",
            attack=attack,
            attack_params={"mode": "disrupt"} if attack else None,
            horizon=100,
            period=5,
            learner_config=config,
        )

    base = [run("clean", 0.2), run("admo", 0.05, attack="admo")]
    short = reciprocators.c7(base).judged  # no original-code log: no cause
    assert short.kind == verdicts.INCONCLUSIVE and "log no success" in short.reason
    transfer = run("transfer", 0.95, env_id="escape_room_transfer-v0")
    assert reciprocators.c7([*base, transfer]).judged.causes == (verdicts.PAPER_ENVIRONMENT,)
    # another balance solving the paper's room: the environment is not the cause
    petty = run("petty", 0.95, config={"grudge": "petty"})
    judged = reciprocators.c7([*base, transfer, petty]).judged
    assert judged.kind == verdicts.INCONCLUSIVE
    assert "with the PIMbot code's ER script's balance, 'linear' → petty_rr" in judged.reason
    # Each setting is its own part, never the best of several: the defaults solving the
    # room do not outvote the code's batch of one, which without a log is inconclusive.
    code = {"lr": 1e-4, "gamma": 0.99, "reciprocal_weight": 5.0, "grudge": "petty"}
    solved = [run("solved", 0.95), run("solved_admo", 0.05, attack="admo")]
    assert reciprocators.c7(solved).judged.kind == verdicts.REPRODUCED
    batch = run("code_e1", 0.04, config=code | {"num_envs": 1})
    judged = reciprocators.c7([*solved, batch])
    assert judged.judged.kind == verdicts.INCONCLUSIVE and not judged.judged.causes
    assert "ER(4,2) baseline, the original code's batch of one" in judged.judged.reason
    assert "0.95" not in judged.judged.reason  # the reproduced part does not decide it
    # By the interval, not the mean: a baseline whose seeds straddle 0.8 is undecided,
    # and an ADMO success whose interval reaches above the bound is not "below" it.
    wide = [
        run("wide", lambda s: (1.0, 0.65)[s % 2]),  # 1 .65 1 .65 1: mean 0.86
        run("wide_admo", lambda s: (0.0, 0.6)[s % 2], attack="admo"),  # mean 0.24
    ]
    judged = reciprocators.c7(wide).judged
    assert judged.kind == verdicts.INCONCLUSIVE, judged
    assert "ER(4,2) baseline: clean 0.860 [" in judged.reason
    assert "ER(4,2) ADMO: ADMO success 0.240 [" in judged.reason
    assert judged.reason.count("the interval includes") == 2


def test_claims_table_at_the_quick_budget():
    from pimbot.suites import presets

    jobs = [
        {"name": j.name, "claims": list(j.claims), "status": "finished"}
        for j in presets.suite(quick=True)
    ]
    learning = Claim("C3", "c", "r", "m", verdicts.refuted(verdicts.IMPLEMENTATION, "0.3"))
    rules = Claim(
        "C4", "d", "r", "m", verdicts.refuted(verdicts.IMPLEMENTATION, "idle", structural=True)
    )
    rows = {
        c.id: c for c in claims.suite_claims([learning, rules], {"suite": "quick", "jobs": jobs})
    }
    assert rows["C3"].judged.kind == verdicts.INCONCLUSIVE
    assert rows["C3"].judged.label == "inconclusive (quick budget)"
    assert rows["C4"].judged.kind == verdicts.REFUTED
    assert rows["C1"].judged.kind == verdicts.NOT_RUN  # no section judged it
    jobs[0]["status"] = "failed"
    rows = {
        c.id: c for c in claims.suite_claims([learning, rules], {"suite": "quick", "jobs": jobs})
    }
    assert any(c.judged.kind == verdicts.NOT_RUN for c in rows.values())


def test_original_code_rows_at_the_common_horizon(tmp_path):
    """The original code's log and pimbot's run are read by the same metric code, both cut
    at the horizon they share; a log of the same attack at other parameters is named in
    the row and never compared."""

    def curve(s, t):
        return {"eval/success": 1.0 if t <= 5000 else 0.0}

    def ours_at(name, amount):
        return write_run(
            tmp_path,
            f"attacks/{name}",
            curve,
            env_params=er(4, 2),
            attack="fake_incentive",
            attack_params={"amount": amount},
        )

    ours, c50 = ours_at("er42_fake", 10.0), ours_at("er42_fake50", 50.0)
    log = write_run(
        tmp_path,
        "original/er42_bignum",
        const(**{"eval/success": 0.5}),
        env_params=er(4, 2),
        attack="fake_incentive",
        attack_params={"amount": 10.0},
        horizon=5000,
        seeds=2,
        source=runs.ORIGINAL_CODE,
    )
    table = runs.RunTable((ours, c50), (log,))
    assert runs.load_table(tmp_path).original[0].source == runs.ORIGINAL_CODE
    assert table.original_for(ours) is log and table.original_for(c50) is None
    assert table.originals_elsewhere(c50) == [log]
    data = attack_claims.Runs(table, {(ours.env, ours.condition): ours})
    row = data.compare("q", "~0", ours, "eval/success")
    assert row.horizon == "5,000 it" and row.pimbot.startswith("1.000")
    assert row.original.startswith("0.500") and "2 original seeds" in row.original
    row = data.compare("q", "~0", c50, "eval/success")
    assert row.horizon == "10,000 it"
    assert row.original.startswith("not compared") and "amount 10" in row.original
    # Without a log: pimbot at its own horizon, "no log" in the table.
    row = attack_claims.Runs(runs.RunTable((ours,)), {}).compare("q", "~0", ours, "eval/success")
    assert (row.horizon, row.original) == ("10,000 it", None)


def write_reverse_run(root, name, finals, source, horizon, period, learner_config=None):
    """A reverse-attack ER(2,1) run: success 0.7 up to iteration 2 500, then `finals[s]`."""
    return write_run(
        root,
        name,
        lambda s, t: {"eval/success": finals[s] if t > 2500 else 0.7},
        attack="reverse",
        seeds=len(finals),
        horizon=horizon,
        period=period,
        learner_config=learner_config,
        source=source,
    )


def test_every_log_directory_at_the_runs_settings_is_read(tmp_path):
    """Two original log directories at a run's exact settings that reach the horizon are
    pooled, never one picked by a tie-break: the cause rests on all of them (here the
    first alone would make ours differ, p < 0.05; with the second, which ours match, the
    seeds cannot tell)."""

    def reverse_run(name, finals, source=None):
        return write_reverse_run(tmp_path, name, finals, source, horizon=5000, period=100)

    ours = reverse_run("attacks/er21_reverse", [0.03, 0.02, 0.01, 0.01, 0.03, 0.04, 0.02, 0.06])
    zeros = reverse_run("original/policy_det", [0.0] * 5, runs.ORIGINAL_CODE)
    a2d = reverse_run("original/policy_test_a2d", [0.0, 0.0, 0.01, 0.03, 0.01], runs.ORIGINAL_CODE)
    table = runs.RunTable((ours,), (zeros, a2d))
    log = table.original_for(ours, 5000)
    assert log.seeds == 10 and log.name == "original/policy_det + original/policy_test_a2d"
    np.testing.assert_allclose(
        sorted(log.curves.final("eval/success")), sorted([0.0] * 7 + [0.01, 0.01, 0.03])
    )
    np.testing.assert_allclose(log.per_seed("eval/success"), log.curves.final("eval/success"))
    assert table.original_for(ours, 6000).seeds == 10  # none reaches: all at the longest
    data = attack_claims.Runs(table, {(ours.env, ours.condition): ours})
    row = data.compare("q", "0", ours, "eval/success")
    assert "10 original seeds" in row.original and "inferred" not in row.original
    alone = statistics.difference_p_value(ours.curves.final("eval/success"), np.zeros(5))
    pooled = statistics.difference_p_value(
        ours.curves.final("eval/success"), log.curves.final("eval/success")
    )
    assert alone < judging.DIFFERS_P and pooled > alone


def test_a_log_whose_attack_is_inferred_is_shown_but_grounds_no_cause(tmp_path):
    """A log whose name does not record its attack (er*_policy_det: "policy" names the
    lever; the attack is read off a plot notebook) is shown in the original-code column,
    marked, and pooled there; a cause rests only on logs that record their attack. Here
    ours differ from the inferred log (5 × 0.0, p < 0.05) but not from the recorded one, so
    C4's ER(2,1) part is inconclusive; with the inferred log alone, inconclusive too,
    naming it."""

    def reverse_run(name, finals, source=None, inferred=False):
        run = write_reverse_run(
            tmp_path, name, finals, source, 25_000, 500, {"epsilon_decay_iters": 2500}
        )
        config = {**run.config, "identity": {**run.identity, "eval_episodes": 10}}
        if inferred:
            config["original"] = {"attack_inferred": True, "attack_evidence": "e"}
        (run.path / "config.json").write_text(json.dumps(config))
        return dataclasses.replace(run, config=config)

    ours = reverse_run("attacks/er21_reverse", [0.03, 0.02, 0.01, 0.01, 0.03, 0.04, 0.02, 0.06])
    det = reverse_run("original/er2_1_policy_det", [0.0] * 5, runs.ORIGINAL_CODE, inferred=True)
    a2d = reverse_run("original/policy_test_a2d", [0.0, 0.0, 0.01, 0.03, 0.01], runs.ORIGINAL_CODE)
    assert det.attack_inferred and not a2d.attack_inferred
    assert runs.load_table(tmp_path).original[0].attack_inferred  # read from config.json
    ours_finals = ours.curves.final("eval/success")
    assert statistics.difference_p_value(ours_finals, np.zeros(5)) < judging.DIFFERS_P
    for originals, shown in (((det, a2d), 10), ((det,), 5)):
        table = runs.RunTable((ours,), originals)
        assert table.original_for(ours).seeds == shown
        assert table.original_for(ours, recorded=True) is (a2d if len(originals) == 2 else None)
        data = attack_claims.Runs(table, {(ours.env, ours.condition): ours})
        row = data.compare("q", "0", ours, "eval/success")
        assert f"{shown} original seeds, attack inferred" in row.original
        verdict = attack_claims.reverse(data, "ER(2,1)", ours).at_budget
        assert verdict.kind == verdicts.INCONCLUSIVE, verdict
        assert "er2_1_policy_det" in verdict.reason and "attack" in verdict.reason
    assert "er2_1_policy_det" in verdict.reason and "do not record their attack" in verdict.reason


def test_direction_tests_over_seeds():
    """The tests that replace thresholds: a sign-flip permutation test against 0, a rank
    test of iterations with "never" as +∞, and the fall to ≈ 0 from the early success."""
    assert statistics.sign_p_value(np.full(5, 3.0)) == pytest.approx(1 / 32)
    assert statistics.sign_p_value(np.zeros(5)) == 1.0
    assert statistics.rank_p_value([1, 1, 1], [2, 2, 2], "less") == pytest.approx(0.05)
    assert statistics.rank_p_value([np.inf] * 3, [1, 2, 3], "greater") == pytest.approx(0.05)
    assert judging.earlier([None] * 4, [1, 2, 3, 4])[1] < judging.DIFFERS_P
    res = 0.01
    assert judging.falls_to_zero(np.full(5, 0.4), np.zeros(5), res).kind == verdicts.REPRODUCED
    assert judging.falls_to_zero(np.full(5, 0.4), np.full(5, 0.3), res) is None  # not ≈ 0
    assert judging.falls_to_zero(np.zeros(3), np.zeros(3), res).kind == verdicts.INCONCLUSIVE
    assert judging.above_zero(np.full(5, -1.0), "margin") is None
    assert judging.above_zero(np.array([-1.0, 1.0, 0.5]), "m").kind == verdicts.INCONCLUSIVE


def test_c7_stag_hunt_rows_show_the_logged_stag_captures(tmp_path):
    """The C7 table's captures column is the runs' own eval/stag_captures (the Stag Hunt's
    step metric), final per seed; an Escape Room row has none."""
    stag = write_run(
        tmp_path,
        "reciprocators/sh2_clean",
        const(**{"eval/success": 0.5, "eval/stag_captures": lambda s: 0.01 * s}),
        env_id="stag_hunt-v0",
        env_params={"n_players": 2},
        learner="reciprocator",
        horizon=100,
        period=5,
    )
    room = write_run(
        tmp_path,
        "reciprocators/er21_clean",
        const(**{"eval/success": 0.9}),
        learner="reciprocator",
        horizon=100,
        period=5,
    )
    rows = {row["env"]: row for row in reciprocators.results_rows([stag, room])}
    assert rows["SH(2)"]["stag_captures"].mean == pytest.approx(0.02)  # seeds 0..4
    assert rows["ER(2,1)"]["stag_captures"] is None


def test_coverage_counts_a_renamed_job_under_its_former_name():
    """A suite directory made before the Escape Room Reciprocator rows were renamed
    (rec_er*_spec → rec_er*, rec_er* → rec_er*_petty) still has every C7 job finished; one
    without a finished run under either name does not."""
    from pimbot.analysis.claims import claim_coverage
    from pimbot.suites import presets

    old_names = {presets.FORMER_JOB_NAMES.get(j.name, j.name) for j in presets.suite(quick=True)}
    index = {"suite": "quick", "jobs": [{"name": n, "status": "finished"} for n in old_names]}
    done, planned = claim_coverage(index)["C7"]
    assert done == planned > 0
    missing = "reciprocators/rec_er42_admo_disrupt"  # the former petty row
    index["jobs"] = [j for j in index["jobs"] if j["name"] != missing]
    assert claim_coverage(index)["C7"] == (planned - 1, planned)


def test_c7_code_batch_shortfall_is_classified_by_the_original_code_at_its_settings(tmp_path):
    """The baseline at the PIMbot code's ER script as it runs: without an original-code run
    inconclusive; with one at the same settings that also stays below 0.8, the paper
    contradicts its own code; with one that reproduces the paper and differs from ours by
    a permutation test, our implementation. An original run at other settings is named,
    never compared."""
    code = {"lr": 1e-4, "gamma": 0.99, "reciprocal_weight": 5.0, "grudge": "petty", "num_envs": 1}

    def run(name, success, config=code, seeds=10):
        return write_run(
            tmp_path,
            f"reciprocators/{name}",
            const(**{"eval/success": success}),
            env_params=er(2, 1),
            learner="reciprocator",
            seeds=seeds,
            horizon=1000,
            period=100,
            learner_config=config,
        )

    ours = run("code_e1", lambda s: 0.1 * (s % 2))  # 0 .1 0 .1 …: mean 0.05
    part = "ER(2,1) baseline, the original code's batch of one episode per update"
    alone = reciprocators.c7([ours]).verdict.parts
    assert dict(alone)[part].kind == verdicts.INCONCLUSIVE
    short = run("original_short", lambda s: 0.1 * (s % 3 == 0), seeds=5)
    judged = dict(reciprocators.c7([ours], (short,)).verdict.parts)[part]
    assert judged.causes == (verdicts.PAPER_CODE,), judged
    assert "the original code (reciprocators/original_short, 5 seeds, the same" in judged.reason
    assert "does not reach 0.8 either; ours do not differ from it" in judged.reason
    few = run("original_few", 0.75, seeds=3)  # too few seeds to name a cause
    judged = dict(reciprocators.c7([ours], (few,)).verdict.parts)[part]
    assert judged.kind == verdicts.INCONCLUSIVE and "3 original seeds are too few" in judged.reason
    random_level = run("original_random", lambda s: 0.7 + 0.01 * (s % 3), seeds=5)
    judged = dict(reciprocators.c7([ours], (random_level,)).verdict.parts)[part]
    assert judged.causes == (verdicts.PAPER_CODE,) and "ours differ from it" in judged.reason
    # what was seen of the original's learning when it was run here is named with it
    random_level.config["original"] = {"finding": "its agents stop learning at episode 1–2"}
    judged = dict(reciprocators.c7([ours], (random_level,)).verdict.parts)[part]
    assert "0.708 [0.702, 0.714] — its agents stop learning at episode 1–2:" in judged.reason
    solved = run("original_solved", 0.95, seeds=5)
    judged = dict(reciprocators.c7([ours], (solved,)).verdict.parts)[part]
    assert judged.causes == (verdicts.IMPLEMENTATION,), judged
    elsewhere = run("original_other", 0.95, config=code | {"lr": 1e-3}, seeds=5)
    judged = dict(reciprocators.c7([ours], (elsewhere,)).verdict.parts)[part]
    assert judged.kind == verdicts.INCONCLUSIVE and "lr 0.001 in the original" in judged.reason
