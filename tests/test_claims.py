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
from pimbot.analysis.sections import attack_claims, reciprocators, stag_hunt
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
    # The quick budget: learning evidence becomes inconclusive, the env's rules do not.
    quick = verdicts.at_quick_budget(verdicts.refuted(verdicts.IMPLEMENTATION, "0.1"))
    assert quick.kind == verdicts.INCONCLUSIVE and "0.1" in quick.reason
    rules = verdicts.at_quick_budget(verdicts.refuted(verdicts.PAPER_ENVIRONMENT, "idle"))
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


def test_c4_at_the_paper_budget_and_the_late_rise(tmp_path):
    def reverse(name, params, curve, horizon):
        return write_run(
            tmp_path,
            f"attacks/{name}",
            curve,
            env_params=params,
            attack="reverse",
            horizon=horizon,
            period=1000,
        )

    late = reverse(
        "er21", er(2, 1), lambda s, t: {"eval/success": 0.0 if t <= 25_000 else 0.5}, 50_000
    )
    rest = [
        reverse("er42", er(4, 2), const(**{"eval/success": 1.0}), 25_000),
        reverse("er43", er(4, 3), const(**{"eval/success": 0.0}), 25_000),
    ]
    main, longer = attack_claims.c4(data_of([late, *rest]))
    assert main.judged.kind == verdicts.AT_BUDGET
    assert longer.id == "C4b" and longer.judged.causes == (verdicts.BUDGET,)
    assert "+0.500" in longer.judged.reason
    short = reverse("er21_short", er(2, 1), const(**{"eval/success": 0.3}), 10_000)
    main = attack_claims.c4(data_of([short, *rest]))[0]
    assert main.judged.kind == verdicts.INCONCLUSIVE and "10,000 it" in main.judged.reason


def test_c1b_speed_by_both_criteria_at_equal_horizon(tmp_path):
    def run(name, condition, params, at, seeds=5):
        attack = None if condition == "clean" else "self_centered"
        curve = lambda s, t: {"eval/return_ratio": 1.0 if t >= at else 0.0}  # noqa: E731
        return write_run(
            tmp_path,
            f"attacks/{name}",
            curve,
            env_params=params,
            attack=attack,
            seeds=seeds,
            horizon=30_000,
            period=500,
        )

    fast = [
        run("a", "clean", er(2, 1), 20_000),
        run("b", "self", er(2, 1), 12_500),
        run("c", "clean", er(4, 2), 14_000),
        run("d", "self", er(4, 2), 10_500),
    ]
    claim = attack_claims.c1b(data_of(fast))
    assert claim.judged.kind == verdicts.REPRODUCED
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
    claim = attack_claims.c5(data_of(records))
    assert claim.judged.kind == verdicts.REPRODUCED, claim.judged
    # Disrupt is judged only where the task is non-redundant (not in ER(4,2)).
    assert "ER(4,2) admo_disrupt disrupts" not in claim.measured
    assert "ER(4,3) admo_disrupt disrupts" in claim.measured
    assert "admo_code (the published code's scheduler): no runs" in claim.measured


def test_c6_the_code_metric_as_the_cause(tmp_path):
    code = "eval/return_over_stag_payoff/agent_0"

    def run(name, attack, success, captures, metric):
        def curve(s, t):
            return {
                "eval/success": success * t / 5000,
                "eval/stag_captures": captures * t / 5000,
                code: metric,
            }

        return write_run(
            tmp_path,
            f"stag_hunt/{name}",
            curve,
            env_id="stag_hunt-v0",
            env_params={"n_players": 2},
            attack=attack,
            horizon=5000,
            period=100,
            attack_params={"mode": "disrupt"} if attack else None,
        )

    parts, _ = stag_hunt.judge_env(
        "SH(2)", run("c", None, 0.6, 0.3, 0.6), run("a", "admo", 0.4, 0.1, 0.02)
    )
    assert parts["SH(2) success rises"].kind == verdicts.REPRODUCED
    assert parts["SH(2) stag captures rise"].kind == verdicts.REPRODUCED
    assert parts["SH(2) ADMO → 0"].causes == (verdicts.PAPER_METRIC,)


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
    short = reciprocators.c7(base).judged  # no run at the code's settings: no cause
    assert short.kind == verdicts.INCONCLUSIVE and "no run at the original code's" in short.reason
    transfer = run("transfer", 0.95, env_id="escape_room_transfer-v0")
    assert reciprocators.c7([*base, transfer]).judged.causes == (verdicts.PAPER_ENVIRONMENT,)
    code = run("code", 0.1, config={"lr": 1e-4, "gamma": 0.99, "grudge": "accumulated"})
    assert reciprocators.c7([*base, code]).judged.causes == (verdicts.PAPER_CODE,)


def test_claims_table_at_the_quick_budget():
    from pimbot.suites import presets

    jobs = [
        {"name": j.name, "claims": list(j.claims), "status": "finished"}
        for j in presets.suite(quick=True)
    ]
    learning = Claim("C3", "c", "r", "m", verdicts.refuted(verdicts.IMPLEMENTATION, "0.3"))
    rules = Claim("C4", "d", "r", "m", verdicts.refuted(verdicts.PAPER_ENVIRONMENT, "idle"))
    rows = {
        c.id: c for c in claims.suite_claims([learning, rules], {"suite": "quick", "jobs": jobs})
    }
    assert rows["C3"].judged.kind == verdicts.INCONCLUSIVE
    assert rows["C3"].judged.label == "inconclusive (too few seeds or iterations) (quick budget)"
    assert rows["C4"].judged.kind == verdicts.REFUTED
    assert rows["C1"].judged.kind == verdicts.NOT_RUN  # no section judged it
    jobs[0]["status"] = "failed"
    rows = {
        c.id: c for c in claims.suite_claims([learning, rules], {"suite": "quick", "jobs": jobs})
    }
    assert any(c.judged.kind == verdicts.NOT_RUN for c in rows.values())


def test_original_code_rows_at_the_common_horizon(tmp_path):
    """The original code's log and pimbot's run are read by the same metric code, both cut
    at the horizon they share; the original's own attack parameters are named."""

    def curve(s, t):
        return {"eval/success": 1.0 if t <= 5000 else 0.0}

    ours = write_run(
        tmp_path, "attacks/er42_fake", curve, env_params=er(4, 2), attack="fake_incentive"
    )
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
    log = dataclasses.replace(log, condition="fake_incentive(amount=10)")  # as its config says
    table = runs.RunTable((ours,), (log,))
    assert runs.load_table(tmp_path).original[0].source == runs.ORIGINAL_CODE
    data = attack_claims.Runs(table, {(ours.env, ours.condition): ours})
    row, value = data.compare("q", "~0", ours, "eval/success")
    assert row.horizon == "5,000 it" and row.pimbot.startswith("1.000")
    assert row.original.startswith("0.500") and "(fake_incentive(amount=10))" in row.original
    assert value.mean == 0.5
    # Without a log: pimbot at its own horizon, "no log" in the table.
    row, value = attack_claims.Runs(runs.RunTable((ours,)), {}).compare(
        "q", "~0", ours, "eval/success"
    )
    assert (row.horizon, row.original, value) == ("10,000 it", None, None)
