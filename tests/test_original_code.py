"""The original PIMbot code's logs, packaged as pimbot run directories (analysis.original_code)."""

from __future__ import annotations

import collections

import numpy as np
import pytest

from pimbot import envs
from pimbot.analysis import original_code, runs
from pimbot.analysis.runs import load_table
from pimbot.training import store
from pimbot.training.summary import summarize

CLEAN_ER21_10_RUNS = original_code.ROOT / "er_40k" / "er2_1_pure"


def test_packaged_runs_load_as_original_code():
    dirs = original_code.run_dirs()
    assert len(dirs) >= 40
    table = load_table(original_code.ROOT)
    assert not table.records  # nothing there is a pimbot run
    assert sorted(r.path for r in table.original) == sorted(dirs)
    for record in table.original:
        if original_code.made_here(record.path):  # tests/test_original_code_made_here.py
            continue
        info = record.config["original"]
        assert record.config["source"] == "original code"
        assert (info["repository"], info["commit"]) == (
            original_code.REPOSITORY,
            original_code.COMMIT,
        )
        assert record.learner == "lio" and record.seeds == len(info["seeds"])
        assert record.seeds + info["reruns_merged"] == info["distinct_files"]
        assert record.iterations == record.identity["iterations"]
        assert all(p.endswith("/log.csv") for s in info["seeds"] for p in s["paths"])


def test_byte_identical_logs_count_once():
    logs = original_code.distinct_logs(
        [("r/er10/a/log.csv", b"x"), ("r/er2/a/log.csv", b"x"), ("r/er1/a/log.csv", b"y")]
    )
    assert [(log.data, log.paths, log.copies_merged) for log in logs] == [
        (b"y", ("r/er1/a/log.csv",), 0),
        (b"x", ("r/er2/a/log.csv", "r/er10/a/log.csv"), 1),
    ]
    files = original_code.manifest()["files"]
    hashes = collections.Counter(f["sha256"] for f in files)
    assert len(files) == original_code.manifest()["log_files"] == 498
    assert len(hashes) == original_code.manifest()["distinct_log_files"] == 285
    for run_dir in original_code.shipped_runs():
        info = original_code.original_info(run_dir)
        seeds = info["seeds"]
        assert len({s["sha256"] for s in seeds}) == len(seeds)
        assert len(seeds) + info["reruns_merged"] == info["distinct_files"]
        assert info["copies_merged"] == info["files"] - info["distinct_files"]
        assert all(hashes[s["sha256"]] >= len(s["paths"]) for s in seeds)
    # ER(4,2) at 20k: 19 "seeds" in the repository, one file
    one = original_code.original_info(original_code.ROOT / "er_20k" / "er_n2_1_pure_LIO")
    assert (one["files"], one["distinct_files"], one["copies_merged"]) == (19, 1, 18)


def test_reruns_of_one_random_seed_count_once():
    """Logs that open with the same evaluation rows are reruns of one random seed: one
    seed, in a directory and across the directories pooled at one setting."""
    head = b"episode,success\n"
    logs = original_code.distinct_logs(
        [
            ("r/1/log.csv", head + b"100,0.1\n200,0.2\n300,0.3\n400,0.4\n"),
            ("r/2/log.csv", head + b"100,0.1\n200,0.2\n300,0.3\n400,0.9\n"),  # drifts later
            ("r/3/log.csv", head + b"100,0.5\n200,0.2\n300,0.3\n400,0.4\n"),  # another seed
        ]
    )
    kept = original_code.one_per_seed(logs)
    assert [(first.paths[0], [r.paths[0] for r in reruns]) for first, reruns in kept] == [
        ("r/1/log.csv", ["r/2/log.csv"]),
        ("r/3/log.csv", []),
    ]
    # in the repository: ER(2,1) at 20k has 13 distinct logs of one random seed
    info = original_code.original_info(original_code.ROOT / "er_20k" / "er_n2_1T_pure_LIO")
    assert (len(info["seeds"]), info["distinct_files"], info["reruns_merged"]) == (1, 13, 12)
    reruns = [f for f in original_code.manifest()["files"] if f.get("status") == "rerun"]
    assert sum(f["run"] == "er_20k/er_n2_1T_pure_LIO" for f in reruns) >= 12
    # the 20k IPD series' first seed is a rerun of the 30k series' seed: pooled, it counts once
    table = load_table(original_code.ROOT)
    found = sorted(
        (r for r in table.original if r.setting in ("ipd_greedy", "ipd_greedy_lio")),
        key=lambda r: r.name,
    )
    both = runs.pooled(found)
    assert [r.seeds for r in found] == [5, 1] and both.seeds == 5
    assert both.summary["reruns_dropped"] == 1


def test_clean_er21_series_ends_where_the_original_does():
    """The original PIMbot code's 10-run clean ER(2,1) series, by pimbot's own metrics."""
    summary = summarize(CLEAN_ER21_10_RUNS)
    assert summary["seeds"] == list(range(10))
    assert summary["iterations"] == 40_000
    assert summary["final"]["eval/success"]["mean"] == pytest.approx(0.880, abs=5e-4)
    assert summary["final"]["eval/return_ratio"]["mean"] == pytest.approx(0.846, abs=2e-3)
    convergence = summary["convergence"]
    assert convergence["curve"] == "eval/return_ratio"
    crossings = [c for c in convergence["first_crossing_per_seed"] if c is not None]
    assert len(crossings) == 10 and 10_000 < np.median(crossings) < 20_000
    # cut at the paper's 25k budget: the final window is the evaluations 24 100 … 25 000
    rows = [r for r in store.read_metrics(CLEAN_ER21_10_RUNS) if int(r["iteration"]) > 24_000]
    rows = [r for r in rows if int(r["iteration"]) <= 25_000]
    at_25k = original_code.summary_at(CLEAN_ER21_10_RUNS, 25_000)
    assert at_25k["iterations"] == 25_000
    assert at_25k["final"]["eval/success"]["mean"] == pytest.approx(
        np.mean([float(r["eval/success"]) for r in rows])
    )
    with pytest.raises(ValueError, match="fewer than"):
        original_code.summary_at(CLEAN_ER21_10_RUNS, 50_000)


def test_escape_room_log_rows_in_pimbot_columns():
    log = (
        "episode,step_train,step,A1_reward_total,A1_n_lever,A1_n_door,A1_received,A1_given,"
        "A1_r-lever,A1_r-start,A1_r-door,A1_win_rate,A2_reward_total,A2_n_lever,A2_n_door,"
        "A2_received,A2_given,A2_r-lever,A2_r-start,A2_r-door,A2_win_rate,steps_per_eps\n"
        "100,100,626,2.0,1,1,3.0,1.5,0,0,0,80.0,4.0,1,1,1.5,3.0,0,0,0,0.0,3.00\n"
    )
    [row], sources = original_code.metrics_rows(log, envs.make("escape_room-v0"), seed=3)
    values = {k: float(v) for k, v in row.items()}
    assert values["seed"] == 3 and values["iteration"] == 100
    assert values["eval/return_env/agent_0"] == pytest.approx(2.0 - 3.0 + 1.5)
    assert values["eval/return_env/agent_1"] == pytest.approx(4.0 - 1.5 + 3.0)
    assert values["eval/team_return"] == pytest.approx(6.0)
    assert values["eval/return_ratio"] == pytest.approx(6.0 / 9.0, rel=1e-5)
    assert values["eval/adversary_margin_env"] == pytest.approx(0.5 - 5.5)
    assert values["eval/adversary_margin_total"] == pytest.approx(2.0 - 4.0)
    assert (values["eval/success"], values["eval/steps"]) == (0.8, 3.0)
    assert set(sources) >= {"eval/success", "eval/return_ratio"}


def test_ipd_success_bounds_from_mean_rewards():
    outcomes = original_code.joint_outcomes(envs.make("ipd-v0"))
    assert original_code.success_bounds(np.array([-1.0, -1.0]), outcomes) == pytest.approx((1, 1))
    assert original_code.success_bounds(np.array([-2.0, -2.0]), outcomes) == pytest.approx((0, 0))
    # 60 % mutual cooperation, 40 % agent 0 defecting alone: the only distribution
    lo, hi = original_code.success_bounds(np.array([-0.6, -1.8]), outcomes)
    assert lo == pytest.approx(0.6, abs=1e-6) and hi == pytest.approx(0.6, abs=1e-6)
    # welfare −3 per step is 1/2 CC + 1/2 DD or all one-sided: success anywhere in [0, 1/2]
    lo, hi = original_code.success_bounds(np.array([-1.5, -1.5]), outcomes)
    assert (lo, hi) == pytest.approx((0.0, 0.5), abs=1e-6)


def test_claims_and_derived_columns_are_consistent():
    for claim in ("C1", "C2", "C3", "C4"):
        assert original_code.runs_for_claim(claim)
    assert not original_code.runs_for_claim("C5")
    assert "C1" in original_code.claims_of(CLEAN_ER21_10_RUNS)
    first = original_code.runs_for_claim("C1")[0]  # a plotted series of independent seeds
    assert original_code.plotted_by(first) and original_code.independent_seeds(first)
    assert not original_code.independent_seeds(original_code.ROOT / "ipd_30k" / "ipd_pure_lio")
    for run_dir in (CLEAN_ER21_10_RUNS, original_code.ROOT / "er_25k" / "er4_2_greedy_det"):
        config = store.read_json(run_dir / store.CONFIG)
        n, optimum = config["env"]["num_agents"], config["env"]["optimal_team_return"]
        for row in store.read_metrics(run_dir):
            env = [float(row[f"eval/return_env/agent_{i}"]) for i in range(n)]
            assert float(row["eval/team_return"]) == pytest.approx(sum(env), abs=1e-4)
            assert float(row["eval/return_ratio"]) == pytest.approx(sum(env) / optimum, abs=1e-4)
