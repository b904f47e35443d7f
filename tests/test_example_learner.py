"""The example learner plugin, examples/plugins/actor_critic.py (docs/extending.md, (e)).

Loaded as a user loads it (`--plugin`), listed, and trained from the command line on
Escape Room ER(2, 1) clean, under attacks of each lever it can take (`self_centered`,
`bypass`, `reverse`, `admo`), with a defense (`exploration_floor`), and refused an attack
at a hook point it lacks (`fake_incentive`, at `emit`); each run is judged by what its
metrics.csv and config.json hold. Budgets are tiny (2 seeds, 100 iterations).
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from pimbot import attacks, cli, envs, learners, plugins
from pimbot.contracts.attack import HOOKS, NO_ATTACK, AgentParams, Attack, agent_row
from pimbot.contracts.defense import HOOKS as DEFENSE_HOOKS
from pimbot.contracts.defense import Defense
from pimbot.training import store

ROOT = Path(__file__).resolve().parents[1]
PLUGIN = ROOT / "examples" / "plugins" / "actor_critic.py"
LEARNER = "actor_critic"
ENV = "escape_room-v0"  # ER(2, 1): agent 1 must pull the lever for agent 0 to exit
BUDGET = ["--seeds", "2", "--iterations", "100", "--eval-period", "50", "--quiet"]


@pytest.fixture(scope="module", autouse=True)
def loaded():
    """The plugin loaded once, as `--plugin` loads it (a second load is a no-op)."""
    return plugins.load(str(PLUGIN))


def train(out: Path, *options: str, env_id: str = ENV, budget=BUDGET) -> Path:
    argv = ["train", env_id, "--plugin", str(PLUGIN), "--learner", LEARNER, *options]
    assert cli.main([*argv, *budget, "--out", str(out)]) == 0
    return out


def metrics(run_dir: Path) -> list[dict[str, float]]:
    return [{k: float(v) for k, v in row.items()} for row in store.read_metrics(run_dir)]


def learning_metrics(run_dir: Path) -> list[dict[str, float]]:
    """The metric rows without the timing columns (which differ between any two runs)."""
    return [{k: v for k, v in r.items() if not k.startswith("perf/")} for r in metrics(run_dir)]


def column(run_dir: Path, name: str) -> np.ndarray:
    return np.array([row[name] for row in metrics(run_dir)])


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> Path:
    """The clean run every attacked run is compared with (same seeds)."""
    return train(tmp_path_factory.mktemp("clean") / "run")


# --- the file, its docs and the plugin as registered ------------------------------------


def test_one_file_whose_doc_section_quotes_it():
    text = PLUGIN.read_text()
    doc = (ROOT / "docs" / "extending.md").read_text()
    start = doc.index("## (e) A learner")
    section = doc[start : doc.index("\n## ", start + 1)]
    lines = len(text.splitlines())
    assert f"actor_critic.py), {lines} lines" in section.replace("\n", " ")
    assert f"| {lines} |" in doc  # the overview table
    excerpts = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert excerpts and all(e in text for e in excerpts), "excerpt out of date"
    assert "from pimbot.learners" not in text  # written against the contracts, no copy


def test_listed_with_its_hook_points_and_env_defaults(capsys):
    assert cli.main(["learners", "--plugin", str(PLUGIN)]) == 0
    out = capsys.readouterr().out
    assert f"{LEARNER}: independent advantage actor-critic" in out
    assert "attack hooks: act, learning_rewards, policy_sign, adversary_step, observe" in out
    assert "defense hooks: acting_epsilon" in out
    assert f"on {ENV} (declared for this env): lr_actor=0.003, epsilon_decay_iters=500" in out


@struct.dataclass
class Spy(Attack):
    """Records every hook point consulted while a program is traced (not registered)."""

    calls: ClassVar[list] = []
    hooks: ClassVar[tuple[str, ...]] = HOOKS  # so that the learner consults every one it has

    def act(self, state, key, actions, at):
        self.calls.append("act")
        return actions

    def emit(self, state, key, given_so_far):
        self.calls.append("emit")
        return super().emit(state, key, given_so_far)

    def learning_rewards(self, state, env_rewards, received):
        self.calls.append("learning_rewards")
        return env_rewards + received

    def policy_sign(self, state, num_agents):
        self.calls.append("policy_sign")
        return jnp.ones((num_agents,))

    def adversary_step(self, state, key, view):
        self.calls.append("adversary_step")
        return AgentParams(agent_row(view.policy, self.adversary), {}), state, {}

    def observe(self, state, key, outcome):
        self.calls.append("observe")
        return state

    def update_schedule(self, state, key, view, ordinary_epochs):
        self.calls.append("update_schedule")
        return super().update_schedule(state, key, view, ordinary_epochs)


@struct.dataclass
class SpyDefense(Defense):
    calls: ClassVar[list] = []
    hooks: ClassVar[tuple[str, ...]] = DEFENSE_HOOKS

    def acting_epsilon(self, state, ctx):
        self.calls.append("acting_epsilon")
        return ctx.epsilon


def test_every_hook_point_it_lists_is_consulted():
    """What `pimbot learners` says is what `update` and `evaluate` do (traced, not run)."""
    definition = learners.get(LEARNER)
    env = envs.make(ENV)
    cfg = learners.default_config(LEARNER, ENV)
    Spy.calls.clear()
    SpyDefense.calls.clear()
    spy = Spy()

    def iteration(key):
        state = definition.init(key, env, cfg, spy, (SpyDefense(),))
        state, _ = definition.update(state, env, cfg, spy, (SpyDefense(),))
        return definition.evaluate(key, state, env, cfg, 2, spy)

    jax.eval_shape(iteration, jax.random.key(0))
    # rollout asks emit at every step, whose output a learner without a channel (give=None)
    # never uses; every other hook point is consulted if and only if it is listed
    assert set(Spy.calls) - {"emit"} == set(definition.attack_hooks)
    assert set(definition.defense_hooks) == set(SpyDefense.calls)
    assert definition.has_incentives is False


# --- training: clean, and the learner's defaults on a built-in env -----------------------


def test_clean_run_uses_the_defaults_declared_for_the_env(clean):
    config = json.loads((clean / "config.json").read_text())
    learner_config = config["identity"]["learner_config"]
    assert config["identity"]["learner"] == LEARNER
    base = learners.get(LEARNER).config_cls()
    assert (base.lr_actor, base.epsilon_decay_iters) == (1e-3, 1000)  # overridden on ER:
    assert learner_config["lr_actor"] == 3e-3 and learner_config["epsilon_decay_iters"] == 500
    rows = metrics(clean)
    assert sorted((r["iteration"], r["seed"]) for r in rows) == [
        (50, 0),
        (50, 1),
        (100, 0),
        (100, 1),
    ]
    for name in ("eval/success", "train/success", "learner/actor_critic/critic_loss"):
        assert all(math.isfinite(r[name]) for r in rows), name
    # the mean ε of iterations 0-49 under the declared default: 0.5 → 0.05 over 500
    first = [r["train/epsilon"] for r in rows if r["iteration"] == 50]
    np.testing.assert_allclose(first, 0.5 - 0.45 * 24.5 / 500, rtol=1e-5)


def test_defaults_set_by_another_plugin_for_a_built_in_env(tmp_path):
    tuning = tmp_path / "tune_actor_critic.py"
    tuning.write_text(
        "from pimbot import learners\n"
        "learners.set_env_defaults('actor_critic', 'ipd-v0', lr_critic=0.05, gae_lambda=0.5)\n"
    )
    budget = ["--seeds", "1", "--iterations", "10", "--eval-period", "10", "--quiet"]
    run = train(tmp_path / "run", "--plugin", str(tuning), env_id="ipd-v0", budget=budget)
    learner_config = json.loads((run / "config.json").read_text())["identity"]["learner_config"]
    assert learner_config["lr_critic"] == 0.05 and learner_config["gae_lambda"] == 0.5
    assert learner_config["lr_actor"] == 1e-3  # ER's default is ER's only


# --- attacks -------------------------------------------------------------------------------


def test_an_incentive_attack_is_refused_in_one_line(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["train", ENV, "--plugin", str(PLUGIN), "--learner", LEARNER]
    assert cli.main([*argv, "--attack", "fake_incentive", *BUDGET, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(
        "pimbot: error: attack: fake_incentive acts at the hook point(s) emit, which learner "
        f"{LEARNER} does not have; usable with {LEARNER}: "
    ), err
    assert len(err.strip().splitlines()) == 1 and "self_centered" in err
    assert not out.exists()


def test_self_centered_is_accepted_and_without_incentives_changes_nothing(clean, tmp_path):
    """Its lever is what the adversary learns from (`learning_rewards`): it ignores the
    incentives it receives, and an agent of this learner receives none."""
    run = train(tmp_path / "run", "--attack", "self_centered")
    assert learning_metrics(run) == learning_metrics(clean)


def test_bypass_adversary_stays_idle(tmp_path):
    """Agent 0 always plays ER's idle action (stay at the start): it never moves (a move
    costs −1, the door pays +10), never exits, and agent 1 alone never succeeds."""
    run = train(tmp_path / "run", "--attack", "bypass")
    assert (column(run, "eval/return_env/agent_0") == 0).all()
    assert (column(run, "eval/exit_success/agent_0") == 0).all()
    assert (column(run, "eval/success") == 0).all() and (column(run, "train/success") == 0).all()


def test_reverse_changes_the_run_with_the_same_seeds(clean, tmp_path):
    run = train(tmp_path / "run", "--attack", "reverse")
    assert learning_metrics(run) != learning_metrics(clean)
    assert [r["iteration"] for r in metrics(run)] == [r["iteration"] for r in metrics(clean)]


def test_reverse_takes_the_adversary_s_actor_step_back():
    """One update from the same state: the adversary's actor moves by minus its clean step
    (`policy_sign` −1 scales the Adam step), the other agent's exactly as in the clean run."""
    definition, env = learners.get(LEARNER), envs.make(ENV)
    cfg = learners.default_config(LEARNER, ENV)
    state = definition.init(jax.random.key(1), env, cfg, NO_ATTACK, ())
    step = jax.jit(lambda s, attack: definition.update(s, env, cfg, attack, ())[0].actor)
    moved = {}
    for name, attack in (("clean", NO_ATTACK), ("reverse", attacks.make("reverse", 2))):
        after = step(state, attack)
        moved[name] = jax.tree.map(lambda new, old: np.asarray(new - old), after, state.actor)
    for clean_leaf, reverse_leaf in zip(*map(jax.tree.leaves, moved.values()), strict=True):
        assert np.abs(clean_leaf[0]).max() > 0
        np.testing.assert_allclose(reverse_leaf[0], -clean_leaf[0], atol=1e-7)
        np.testing.assert_array_equal(reverse_leaf[1], clean_leaf[1])


def test_admo_trains_the_adversary_through_the_view(clean, tmp_path):
    run = train(tmp_path / "run", "--attack", "admo")
    rows = metrics(run)
    admo = {name for name in rows[0] if name.startswith("admo/")}
    assert {"admo/alpha_1", "admo/L_inc", "admo/g_pol_norm"} <= admo
    assert all(math.isfinite(r[name]) for r in rows for name in admo)
    assert any(r["admo/g_pol_norm"] > 0 for r in rows)  # the adversary's actor had a gradient
    assert learning_metrics(run) != learning_metrics(clean)


# --- a defense ----------------------------------------------------------------------------


def test_exploration_floor_holds_the_honest_agent_only(tmp_path):
    """Against `reverse` on agent 0, only agent 1 is honest and runs the defense."""
    options = ["--attack", "reverse", "--defense", "exploration_floor", "--dp", "min_epsilon=0.9"]
    run = train(tmp_path / "run", *options)
    np.testing.assert_allclose(column(run, "train/acting_epsilon/agent_1"), 0.9, rtol=1e-5)
    schedule = column(run, "train/epsilon")
    assert (schedule < 0.9).all()
    np.testing.assert_allclose(column(run, "train/acting_epsilon/agent_0"), schedule, rtol=1e-6)
