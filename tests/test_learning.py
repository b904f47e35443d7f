"""Small learning checks: the learners are run on several seeds and judged on measured success.

Budgets are cut from the published ones to keep the suite short; the full-budget
numbers come from the paper suite (see docs/lio.md and docs/report/report.md).
"""

import numpy as np

from pimbot.training import runner, summary
from pimbot.training.config import RunConfig


def _final(run_dir, column):
    return np.array(summary.summarize(run_dir)["final"][column]["per_seed"])


def test_lio_solves_escape_room_2_1(tmp_path):
    run = RunConfig(env_id="escape_room-v0", learner="lio", seeds=4, iterations=25_000)
    result = runner.train(run, tmp_path / "lio", progress=False, chunk_iterations=25_000)
    ratio = _final(result.run_dir, "eval/return_ratio")
    success = _final(result.run_dir, "eval/success")
    # A uniformly random team: success 0.72, return ratio 0.38.
    assert ratio.mean() >= 0.8, ratio
    assert success.mean() >= 0.9, success
    assert (ratio >= 0.8).sum() >= 3, ratio


def test_pg_fails_escape_room_2_1(tmp_path):
    run = RunConfig(env_id="escape_room-v0", learner="pg", seeds=4, iterations=5_000)
    result = runner.train(run, tmp_path / "pg", progress=False, chunk_iterations=5_000)
    assert _final(result.run_dir, "eval/success").mean() <= 0.1


def test_lio_cooperates_in_the_prisoners_dilemma(tmp_path):
    run = RunConfig(env_id="ipd-v0", learner="lio", seeds=4, iterations=10_000, eval_period=500)
    result = runner.train(run, tmp_path / "ipd", progress=False, chunk_iterations=10_000)
    cooperation = _final(result.run_dir, "eval/success")
    assert (cooperation >= 0.8).sum() >= 3, cooperation


def test_lio_with_the_default_shared_incentive_updates_solves_escape_room_4_2(tmp_path):
    run = RunConfig(
        env_id="escape_room-v0",
        env_params=(("min_at_lever", 2), ("n_agents", 4)),
        learner="lio",
        seeds=4,
        iterations=10_000,
    )
    result = runner.train(run, tmp_path / "er42", progress=False, chunk_iterations=10_000)
    success = _final(result.run_dir, "eval/success")
    # A uniformly random team: success 0.80, return ratio 0.17.
    assert success.mean() >= 0.9, success
    assert _final(result.run_dir, "eval/return_ratio").mean() >= 0.7
