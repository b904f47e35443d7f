"""The example learner that pays incentives, examples/plugins/incentive_pg.py (docs/extending.md,
"A learner that pays incentives").

Loaded as a user loads it (`--plugin`), checked with `pimbot check`, and trained from the
command line on Escape Room ER(2, 1) clean, under the incentive attacks `fake_incentive`
and `self_centered`, under `admo` (which trains the adversary's incentives through the view
the learner builds with `learner_kit.incentive_channel`), and with the `incentive_guard`
defense; each run is judged by what its metrics.csv holds. Budgets are tiny (2 seeds,
20 iterations): what is tested is what each attack or defense changes, not learning.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pimbot import cli, envs, learners, plugins
from pimbot.contracts.attack import NO_ATTACK
from pimbot.training import store

ROOT = Path(__file__).resolve().parents[1]
PLUGIN = ROOT / "examples" / "plugins" / "incentive_pg.py"
LEARNER = "incentive_pg"
ENV = "escape_room-v0"  # ER(2, 1); the adversary is agent 0
BUDGET = ["--seeds", "2", "--iterations", "20", "--eval-period", "10", "--quiet"]


@pytest.fixture(scope="module", autouse=True)
def loaded():
    return plugins.load(str(PLUGIN))


def train(out: Path, *options: str) -> Path:
    argv = ["train", ENV, "--plugin", str(PLUGIN), "--learner", LEARNER, *options]
    assert cli.main([*argv, *BUDGET, "--out", str(out)]) == 0
    return out


def metrics(run_dir: Path) -> list[dict[str, float]]:
    return [{k: float(v) for k, v in row.items()} for row in store.read_metrics(run_dir)]


def column(run_dir: Path, name: str) -> np.ndarray:
    return np.array([row[name] for row in metrics(run_dir)])


def learning_metrics(run_dir: Path) -> list[dict[str, float]]:
    return [{k: v for k, v in r.items() if not k.startswith("perf/")} for r in metrics(run_dir)]


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> Path:
    return train(tmp_path_factory.mktemp("clean") / "run")


def test_one_file_whose_doc_section_quotes_it():
    text = PLUGIN.read_text()
    doc = (ROOT / "docs" / "extending.md").read_text()
    start = doc.index("## (f) A learner that pays incentives")
    section = doc[start : doc.index("\n## ", start + 1)]
    lines = len(text.splitlines())
    assert f"incentive_pg.py), {lines} lines" in section.replace("\n", " ")
    assert f"| {lines} |" in doc  # the overview table
    excerpts = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert excerpts and all(e in text for e in excerpts), "excerpt out of date"
    assert "from pimbot.learners" not in text  # written against the contracts


def test_registered_with_its_channel_and_hook_points(capsys):
    definition = learners.get(LEARNER)
    assert definition.has_incentives and "emit" in definition.attack_hooks
    assert cli.main(["learners", "--plugin", str(PLUGIN)]) == 0
    out = capsys.readouterr().out
    assert "defense hooks: acting_epsilon, learning_incentives, after_policy_step" in out


def test_pimbot_check_passes(capsys):
    assert cli.main(["check", str(PLUGIN), "--iterations", "5"]) == 0
    out = capsys.readouterr().out
    assert "parameters moved" in out and "problem:" not in out


def test_export_gives_what_the_actor_gives():
    """`pimbot export`'s per-agent functions (registered by the plugin) equal `acting`."""
    from pimbot.robot.exportable import EXPORTS

    definition, env = learners.get(LEARNER), envs.make(ENV)
    cfg = learners.default_config(LEARNER, ENV)
    state = definition.init(jax.random.key(3), env, cfg, NO_ATTACK, ())
    export = EXPORTS[definition.acting]
    obs = jax.random.uniform(jax.random.key(4), (env.num_agents, env.obs_dim))
    actions = jnp.array([1, 2], jnp.int32)
    given = definition.acting(env, cfg, state).give(obs, actions)
    assert float(given.sum()) > 0
    for i in range(env.num_agents):
        row = export.incentive(env, cfg, state, i)(obs[i][None], actions[None])[0]
        np.testing.assert_allclose(row, given[i], rtol=1e-6)
        logits = export.policy(env, cfg, state, i)(obs[i][None])
        assert logits.shape == (1, env.num_actions)


def test_clean_run_pays_incentives(clean):
    rows = metrics(clean)
    assert all(math.isfinite(r[name]) for r in rows for name in ("eval/success", "train/success"))
    given, got = column(clean, "eval/given/agent_0"), column(clean, "eval/received/agent_1")
    assert (given > 0).all()
    np.testing.assert_allclose(got, given, rtol=1e-5)  # two agents: all 0 gives, 1 gets


def test_self_centered_changes_what_the_adversary_learns_from(clean, tmp_path):
    """The adversary's policy step ignores the incentives it receives (it still receives
    them): the run parts from the clean one with the same seeds."""
    run = train(tmp_path / "run", "--attack", "self_centered")
    assert (column(run, "eval/received/agent_0") > 0).all()
    assert learning_metrics(run) != learning_metrics(clean)


def test_admo_trains_the_adversary_s_policy_and_incentives(clean, tmp_path):
    run = train(tmp_path / "run", "--attack", "admo")
    rows = metrics(run)
    admo = {name for name in rows[0] if name.startswith("admo/")}
    # budget_hits is written only where the learner showed an incentive channel
    assert {"admo/alpha_1", "admo/g_inc_norm", "admo/budget_hits"} <= admo
    assert all(math.isfinite(r[name]) for r in rows for name in admo)
    assert all(r["admo/g_inc_norm"] > 0 for r in rows)
    assert learning_metrics(run) != learning_metrics(clean)


def test_fake_incentive_under_the_incentive_guard(clean, tmp_path):
    """Agent 0 sends C = 50 every step instead of its learned incentives: agent 1 receives
    exactly 50 × the episode's steps (`fake_incentive`), and, an honest recipient, clips
    every step's value to R_max = 2 before learning from it (`incentive_guard`)."""
    options = ["--attack", "fake_incentive", "--ap", "amount=50", "--defense", "incentive_guard"]
    run = train(tmp_path / "run", *options)
    got, steps = column(run, "eval/received/agent_1"), column(run, "eval/steps")
    np.testing.assert_allclose(got, 50 * steps, rtol=1e-5)
    assert (column(clean, "eval/received/agent_1") < 2 * column(clean, "eval/steps")).all()
    assert (column(run, "defense/guard_clipped") > 0).all()
