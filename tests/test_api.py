"""The Python API (`pimbot.train`, `sweep`, `report`, `load_run`): the command line's
steps and checks as keyword calls, and a run directory as an object (docs/usage.md,
"Python API")."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

import pimbot
from pimbot.errors import InvalidParameter

TINY = dict(seeds=2, iterations=100, eval_period=50)
"""LIO on ER(2,1): one compiled program shared by every run of this file."""


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("api") / "lio"
    run = pimbot.train("escape_room-v0", out=out, **TINY)
    assert isinstance(run, pimbot.Run) and run.dir == out
    return out


def _rows(path: Path) -> list[dict]:
    with open(path / "metrics.csv") as f:
        return [
            {k: v for k, v in r.items() if not k.startswith("perf/")} for r in csv.DictReader(f)
        ]


def test_train_is_the_command_line_run(run_dir, tmp_path):
    cli = tmp_path / "cli"
    args = ["--seeds", "2", "--iterations", "100", "--eval-period", "50"]
    args += ["--quiet", "--out", str(cli)]
    done = subprocess.run(
        [sys.executable, "-m", "pimbot.cli", "train", "escape_room-v0", *args],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    assert _rows(cli) == _rows(run_dir)


def test_load_run_gives_config_summary_and_metrics(run_dir):
    run = pimbot.load_run(run_dir)
    assert run.config["run_config"]["learner"] == "lio"
    assert run.config["pimbot_version"] == pimbot.__version__
    assert run.summary["finished"] is True
    assert isinstance(run.metrics, pd.DataFrame)
    assert len(run.metrics) == 2 * 2  # seeds × evaluation points
    assert list(run.metrics["iteration"].unique()) == [50, 100]
    assert run.metrics["eval/success"].between(0, 1).all()
    assert run.seeds == (0, 1) and run.iteration == 100
    assert "lio on escape_room-v0" in repr(run)


def test_policy_gives_probabilities_and_actions(run_dir):
    run = pimbot.load_run(run_dir)
    obs, _ = run.env.reset(jax.random.key(0))
    policy = run.policy(0)
    probabilities, actions = policy(obs[0])
    assert probabilities.shape == (run.env.num_actions,) and actions.shape == ()
    np.testing.assert_allclose(float(probabilities.sum()), 1.0, rtol=1e-6)
    assert int(actions) == int(jnp.argmax(probabilities))  # no key: the most probable
    batch = np.stack([np.asarray(obs[0])] * 64)
    p_batch, sampled = policy(batch, key=jax.random.key(1))
    assert p_batch.shape == (64, run.env.num_actions) and sampled.dtype == jnp.int32
    np.testing.assert_allclose(p_batch[0], probabilities, rtol=1e-6)
    again = policy(batch, key=jax.random.key(1)).actions
    assert (sampled == again).all()  # the key decides
    assert len(set(np.asarray(sampled).tolist())) > 1  # sampled, not the argmax
    other_seed = run.policy(0, seed=1)(obs[0]).probabilities
    assert not np.allclose(other_seed, probabilities)


def test_incentive_gives_what_an_agent_pays_each_agent(run_dir):
    run = pimbot.load_run(run_dir)
    obs, _ = run.env.reset(jax.random.key(0))
    incentive = run.incentive(0)
    given = incentive(obs[0], jnp.array([0, 2]))
    assert given.shape == (2,) and float(given[0]) == 0.0  # nothing to itself
    bound = run.config["identity"]["learner_config"]["incentive_max"]
    assert 0.0 <= float(given[1]) <= bound
    batch = incentive(jnp.stack([obs[0], obs[0]]), jnp.array([[0, 2], [0, 0]]))
    assert batch.shape == (2, 2)
    np.testing.assert_allclose(batch[0], given, rtol=1e-6)


def test_a_learner_without_incentives_says_so(run_dir, monkeypatch):
    from pimbot.robot import exportable

    real = exportable.exported_agents

    def without_give(loaded, index):
        return [exportable.Agent(a.index, a.logits, None) for a in real(loaded, index)]

    monkeypatch.setattr(exportable, "exported_agents", without_give)
    with pytest.raises(InvalidParameter, match="^incentive: learner lio has no incentive"):
        pimbot.load_run(run_dir).incentive(0)


@pytest.mark.parametrize(
    ("options", "line"),
    [
        (dict(seeds=0), "seeds: must be an integer ≥ 1, got 0 (pimbot.train)"),
        (dict(learner="lioo"), "learner: unknown value 'lioo'; allowed: "),
        (dict(seeds="2"), "seeds: pimbot.train: must be an integer, got '2'"),
        (dict(hp={"lr_policy": "fast"}), "lr_policy: must be a number, got 'fast'"),
        (dict(attack="admo", attack_param={"mode": "x"}), "mode: unknown ADMO mode 'x'; allowed: "),
        (dict(sedes=2), "sedes: not an option of pimbot.train; allowed: "),
        (dict(env_params={"n_agents": 1}), "n_agents: "),
    ],
)
def test_bad_keywords_are_one_line_before_anything_is_written(tmp_path, options, line):
    out = tmp_path / "never"
    with pytest.raises(InvalidParameter) as error:
        pimbot.train("escape_room-v0", out=out, **options)
    assert str(error.value).startswith(line) and "\n" not in str(error.value)
    assert not out.exists()


def test_load_run_loads_the_plugins_a_run_was_made_with(run_dir):
    """In a process of its own: a plugin loaded here would move this worker's later
    programs to another compilation cache folder."""
    plugin = Path(__file__).resolve().parents[1] / "examples" / "plugins" / "tiny_env.py"
    code = (
        "import pimbot\n"
        "from pimbot import envs\n"
        f"pimbot.load_run({str(run_dir)!r}, plugins=[{str(plugin)!r}])\n"
        "print('public_goods_game-v0' in envs.registered())\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.stdout.strip() == "True", done.stderr


def test_bad_run_and_suite_directories_are_one_line(tmp_path):
    with pytest.raises(InvalidParameter, match="is not a pimbot run"):
        pimbot.load_run(tmp_path)
    with pytest.raises(InvalidParameter, match="^suite_dir: .* is not a directory"):
        pimbot.report(tmp_path / "none")
    with pytest.raises(InvalidParameter, match="^grid: cannot read"):
        pimbot.sweep(tmp_path / "none.toml", out=tmp_path / "suite")


def test_sweep_and_report_as_keyword_calls(run_dir, tmp_path):
    grid = tmp_path / "tiny.toml"
    grid.write_text(
        'name = "tiny"\nseeds = 2\niterations = 100\neval_period = 50\n'
        '[[envs]]\nid = "escape_room-v0"\nlabel = "er21"\n'
        '[[learners]]\nname = "lio"\n'
    )
    suite = pimbot.sweep(grid, out=tmp_path / "suite", workers=1)
    assert suite.jobs == {"tiny/er21_lio_clean": "finished"} and suite.failed == []
    run = suite.run("tiny/er21_lio_clean")
    assert _rows(run.dir) == _rows(run_dir)  # the same run as pimbot.train's
    html = pimbot.report(suite.dir, out=tmp_path / "report")
    assert html == tmp_path / "report" / "report.html" and html.is_file()
    assert (tmp_path / "report" / "report.md").is_file()
    with pytest.raises(InvalidParameter, match="^name: unknown job 'tiny/er21_lio'"):
        suite.run("tiny/er21_lio")


def test_import_pimbot_imports_no_jax():
    code = "import sys, pimbot; pimbot.__version__; print('jax' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.stdout.strip() == "False", done.stderr
