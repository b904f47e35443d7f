"""The worked extension examples of docs/extending.md, each one file in examples/plugins/.

Every plugin is listed by its `pimbot` listing and trained from the command line
through `--plugin`, with a check that it really acts; all four are swept in one grid
(the one in the docs) and reported. Budgets are tiny (2 seeds, 100 iterations); the
cells of the sweep reuse the programs the training tests compiled (one persistent
compilation cache per test session), so the tests run in order: the sweep last.
"""

from __future__ import annotations

import json
import re
import shlex
import tomllib
from pathlib import Path

import flax.serialization
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pimbot import attacks, cli, defenses, envs, learners, plugins
from pimbot.contracts import learner as learner_contract
from pimbot.contracts.attack import Outcome
from pimbot.contracts.defense import IncentiveContext
from pimbot.contracts.rollout import rollout
from pimbot.training import store

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "extending.md"
PLUGIN_DIR = ROOT / "examples" / "plugins"
NAMES = ("adaptive_fake_incentive", "epsilon_random", "per_giver_cap", "tiny_env")
FILES = {name: PLUGIN_DIR / f"{name}.py" for name in NAMES}
PGG = "public_goods_game-v0"
BUDGET = ["--seeds", "2", "--iterations", "100", "--eval-period", "50", "--quiet"]


@pytest.fixture(scope="module", autouse=True)
def loaded():
    """Every example loaded once, as `--plugin` loads it (a second load is a no-op)."""
    return {name: plugins.load(str(path)) for name, path in FILES.items()}


def train(out: Path, env_id: str, plugin: str, *options: str) -> Path:
    argv = ["train", env_id, "--plugin", str(FILES[plugin]), *options, *BUDGET]
    assert cli.main([*argv, "--out", str(out)]) == 0
    return out


def metrics(run_dir: Path) -> list[dict[str, float]]:
    return [{k: float(v) for k, v in row.items()} for row in store.read_metrics(run_dir)]


def learning_metrics(run_dir: Path) -> list[dict[str, float]]:
    """The metric rows without the timing columns (which differ between any two runs)."""
    return [{k: v for k, v in r.items() if not k.startswith("perf/")} for r in metrics(run_dir)]


@pytest.fixture(scope="module")
def clean_pgg(tmp_path_factory) -> Path:
    """A clean LIO run on the plugin env (the baseline of the ε-random and sweep tests)."""
    return train(tmp_path_factory.mktemp("clean") / "run", PGG, "tiny_env")


# --- the files and the docs ------------------------------------------------------------


def doc_section(title: str) -> str:
    text = DOC.read_text()
    start = text.index(f"## {title}")
    end = text.find("\n## ", start + 1)
    return text[start : end if end >= 0 else None]


def code_blocks(text: str, language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", text, flags=re.S)


SECTIONS = {
    "adaptive_fake_incentive": "(a)",
    "epsilon_random": "(b)",
    "per_giver_cap": "(c)",
    "tiny_env": "(d)",
}


@pytest.mark.parametrize("name", NAMES)
def test_each_example_is_one_short_file_and_its_doc_quotes_it(name):
    path = FILES[name]
    lines = len(path.read_text().splitlines())
    assert lines < 100, f"{path.name}: {lines} lines"
    assert "src" not in path.relative_to(ROOT).parts
    section = doc_section(SECTIONS[name])
    assert f"{path.name}), {lines} lines" in section.replace("\n", " ")
    assert "files touched: only this one" in section.replace("\n", " ")
    excerpts = code_blocks(section, "python")
    assert excerpts and all(e in path.read_text() for e in excerpts), "excerpt out of date"
    assert f"| {lines} |" in DOC.read_text()  # the overview table


def documented_commands() -> list[list[str]]:
    commands = []
    for block in code_blocks(DOC.read_text(), "bash"):
        for line in block.replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            if words[:1] == ["pimbot"]:
                commands.append(words[1:])
    return commands


class Resolved(Exception):
    """Raised in place of training: the command got as far as a resolved run."""


def test_documented_commands_run_up_to_training(tmp_path, monkeypatch, capsys):
    """Every `pimbot` line of the docs parses; listings run; train commands resolve."""
    from pimbot.training import runner

    def stop(run, *args, **kwargs):
        raise Resolved(run)

    monkeypatch.setattr(runner, "train", stop)
    commands = documented_commands()
    assert {c[0] for c in commands} >= {"attacks", "defenses", "envs", "train", "sweep", "report"}
    for argv in commands:
        assert all((ROOT / p).exists() for p in cli.parsing.option_values(argv, "--plugin")), argv
        # The plugins as loaded above (absolute paths), and a fresh run directory.
        argv = [str(ROOT / a) if a.startswith("examples/") else a for a in argv]
        if "--out" in argv:
            argv[argv.index("--out") + 1] = str(tmp_path / "run")
        if argv[0] in ("attacks", "defenses", "envs", "learners"):
            assert cli.main(argv) == 0
        elif argv[0] == "train":
            with pytest.raises(Resolved):
                cli.main(argv)
    assert "error" not in capsys.readouterr().err


@pytest.mark.parametrize(
    ("command", "plugin", "listed"),
    [
        ("attacks", "adaptive_fake_incentive", "adaptive_fake_incentive [incentive lever; hooks"),
        ("attacks", "epsilon_random", "epsilon_random [policy lever; hooks: act]"),
        ("defenses", "per_giver_cap", "per_giver_cap ["),
        ("envs", "tiny_env", f"{PGG}: Repeated public goods game"),
        ("learners", "tiny_env", f"on {PGG} (declared for this env): policy_hidden=(16,)"),
    ],
)
def test_listing_shows_the_plugin(command, plugin, listed, capsys):
    assert cli.main([command, "--plugin", str(FILES[plugin])]) == 0
    assert listed in capsys.readouterr().out


# --- (a) adaptive_fake_incentive ---------------------------------------------------------


def test_adaptive_amount_grows_each_time_the_running_success_exceeds_the_threshold():
    attack = attacks.make(
        "adaptive_fake_incentive", 3, amount=10.0, factor=2.0, threshold=0.5, smoothing=0.5
    )
    attack = attack.replace(max_amount=30.0)
    state = attack.init_state(jax.random.key(0), 3, None)
    amounts = []
    for success in (1.0, 1.0, 0.0, 1.0, 1.0, 1.0, 1.0):
        outcome = Outcome(jnp.float32(success), jnp.int32(0), jnp.int32(0))
        state = attack.observe(state, jax.random.key(0), outcome)
        amounts.append(float(state["amount"]))
    # running success 0.5, 0.75 > 0.5 (grow, restart), 0, 0.5, 0.75 (grow, capped), 0, 0.5
    assert amounts == [10.0, 20.0, 20.0, 20.0, 30.0, 30.0, 30.0]
    scale, offset = attack.emit(state, jax.random.key(0), jnp.zeros((3, 3)))
    np.testing.assert_array_equal(offset, [[0, 30, 30], [0, 0, 0], [0, 0, 0]])
    np.testing.assert_array_equal(scale, [[0, 0, 0], [1, 1, 1], [1, 1, 1]])


def test_adaptive_fake_incentive_trains_and_its_amount_grows(tmp_path):
    # Random play on the public goods game succeeds ~1/9 of the steps: above 0.05.
    run = train(
        tmp_path / "run", PGG, "adaptive_fake_incentive",
        "--plugin", str(FILES["tiny_env"]),
        "--attack", "adaptive_fake_incentive", "--ap", "threshold=0.05",
    )  # fmt: skip
    state_bytes, _ = store.load_checkpoint(run)
    amount = flax.serialization.msgpack_restore(state_bytes)["attack_state"]["amount"]
    assert amount.shape == (2,) and (amount > 10.0).all()  # per seed, grown from 10
    last = [r for r in metrics(run) if r["iteration"] == 100]
    per_step = [r["eval/received/agent_1"] / r["eval/steps"] for r in last]
    assert min(per_step) > 10.0  # the recipient gets the grown amount
    np.testing.assert_allclose(per_step, amount, rtol=1e-5)


# --- (b) epsilon_random ------------------------------------------------------------------


def adversary_actions(epsilon: float, episodes: int = 2000) -> np.ndarray:
    """Actions [episodes, T, N] on the plugin env when every policy always plays 0."""
    env = envs.make(PGG)
    attack = attacks.make("epsilon_random", env.num_agents, adversary=1, epsilon=epsilon)

    def play(key):
        act = lambda k, obs: jnp.zeros(env.num_agents, jnp.int32)  # noqa: E731
        return rollout(env, key, act, None, attack, 0, {}).actions

    keys = jax.random.split(jax.random.key(0), episodes)
    return np.asarray(jax.jit(jax.vmap(play))(keys))


def test_epsilon_one_plays_uniformly_and_epsilon_zero_not_at_all():
    actions = adversary_actions(1.0)
    frequencies = np.bincount(actions[..., 1].ravel(), minlength=3) / actions[..., 1].size
    np.testing.assert_allclose(frequencies, [1 / 3] * 3, atol=0.02)  # 10,000 draws
    assert (actions[..., 0] == 0).all()  # the honest agent plays its own policy
    assert (adversary_actions(0.0) == 0).all()


def test_epsilon_random_zero_trains_as_the_clean_run_and_positive_does_not(clean_pgg, tmp_path):
    options = ["--plugin", str(FILES["tiny_env"]), "--attack", "epsilon_random"]
    zero = train(tmp_path / "zero", PGG, "epsilon_random", *options, "--ap", "epsilon=0")
    assert learning_metrics(zero) == learning_metrics(clean_pgg)
    half = train(tmp_path / "half", PGG, "epsilon_random", *options, "--ap", "epsilon=0.5")
    assert learning_metrics(half) != learning_metrics(clean_pgg)


# --- (c) per_giver_cap -------------------------------------------------------------------


def test_per_giver_cap_on_a_hand_made_context():
    sent = jax.random.uniform(jax.random.key(3), (4, 3, 3), maxval=5.0) * (1 - jnp.eye(3))
    valid = jnp.array([True, True, True, False])
    honest = jnp.array([False, True, True])  # agent 0 is the adversary
    accepted = sent * valid[:, None, None]
    ctx = IncentiveContext(accepted, sent, valid, 2.0, honest)
    cap = defenses.make("per_giver_cap", 3, cap=1.5)
    out, state, metrics_ = cap.learning_incentives({}, ctx)
    out, accepted = np.asarray(out), np.asarray(accepted)
    assert (out[:, :, 1:] <= 1.5).all()  # per giver, per step, for every honest recipient
    np.testing.assert_array_equal(out[:, :, 1:], np.minimum(accepted[:, :, 1:], 1.5))
    np.testing.assert_array_equal(out[:, :, 0], accepted[:, :, 0])  # the adversary's own
    assert float(metrics_["defense/cap_cut"]) == (accepted[:, :, 1:] > 1.5).sum()
    assert metrics_["defense/cap_cut"].dtype == jnp.float32 and state == {}


def test_per_giver_cap_trains_against_a_fake_incentive(tmp_path):
    options = [
        "--plugin",
        str(FILES["tiny_env"]),
        "--attack",
        "fake_incentive",
        "--ap",
        "amount=50",
    ]
    open_run = train(tmp_path / "open", PGG, "per_giver_cap", *options)
    capped = train(
        tmp_path / "capped",
        PGG,
        "per_giver_cap",
        *options,
        "--defense",
        "per_giver_cap",
        "--dp",
        "cap=1",
    )
    rows, open_rows = metrics(capped), metrics(open_run)
    assert "defense/cap_cut" not in open_rows[0]
    assert all(r["defense/cap_cut"] > 0 for r in rows)  # 50 a step is cut every iteration
    returns = [[r[f"eval/return_env/agent_{a}"] for a in (0, 1)] for r in rows]
    open_returns = [[r[f"eval/return_env/agent_{a}"] for a in (0, 1)] for r in open_rows]
    assert returns != open_returns  # the honest recipient learnt from other rewards


# --- (d) tiny_env ----------------------------------------------------------------------


def test_tiny_env_conforms_and_validates():
    envs.check_env(envs.make(PGG))
    envs.check_env(envs.make(PGG, n_agents=3, multiplier=2.0, max_steps=3))
    with pytest.raises(envs.InvalidParameter, match="^multiplier: must be > 0"):
        envs.make(PGG, multiplier=-1.0)


def test_tiny_env_learner_defaults_are_the_runs_config(clean_pgg):
    declared = envs.spec(PGG).learner_defaults
    config = json.loads((clean_pgg / "config.json").read_text())
    used = config["identity"]["learner_config"]
    for name, value in declared["lio"].items():
        assert used[name] == (list(value) if isinstance(value, tuple) else value), name
    pg = learners.default_config("pg", PGG)
    assert all(getattr(pg, name) == value for name, value in declared["pg"].items())


def test_a_learners_entry_declares_over_what_the_plugin_env_declared():
    declared = envs.spec(PGG).learner_defaults["pg"]
    saved = learners.get("pg")
    try:
        learners.set_env_defaults("pg", PGG, lr_policy=0.5)  # no env registered again
        pg = learners.default_config("pg", PGG)
    finally:
        learner_contract.register(saved, replace=True)
    assert pg.lr_policy == 0.5
    assert all(getattr(pg, k) == v for k, v in declared.items() if k != "lr_policy")
    assert learners.default_config("pg", PGG).lr_policy == declared["lr_policy"]


# --- all four in one grid, and the report -----------------------------------------------


def test_sweep_of_the_documented_grid_and_its_report(clean_pgg, tmp_path, capsys):
    (grid_text,) = code_blocks(doc_section("All four in one grid"), "toml")
    grid = tomllib.loads(grid_text)
    assert {e["id"] for e in grid["envs"]} == {PGG, "escape_room-v0"}
    assert {a["name"] for a in grid["attacks"]} >= {"adaptive_fake_incentive", "epsilon_random"}
    assert grid["defenses"][1]["names"] == ["per_giver_cap"]
    budget = "seeds = 2\niterations = 100\neval_period = 50\n"
    text = re.sub(r"^(seeds|iterations|eval_period) = \d+\n", "", grid_text, flags=re.M)
    path = tmp_path / "plugins_grid.toml"
    path.write_text(budget + text)

    out = tmp_path / "sweep"
    argv = ["sweep", str(path), "--out", str(out)]
    for plugin in FILES.values():
        argv += ["--plugin", str(plugin)]
    # The cells whose programs the tests above compiled (the persistent cache has them).
    for cell in ("clean", "adaptive", "eps_random", "fake_incentive", "fake_incentive_cap"):
        argv += ["--only", f"plugins/pgg_lio_{cell}"]
    argv += ["--workers", "1", "--devices-per-job", "2", "--quiet"]
    assert cli.main(argv) == 0, capsys.readouterr().err
    assert "5/5 jobs finished" in capsys.readouterr().out
    # The sweep's clean cell is the same run as the clean training run.
    assert learning_metrics(out / "plugins" / "pgg_lio_clean") == learning_metrics(clean_pgg)

    assert cli.main(["report", str(out)]) == 0, capsys.readouterr().err
    report = (out / "report.md").read_text()
    for label in (
        "adaptive_fake_incentive(threshold=0.5)",
        "epsilon_random(epsilon=0.5)",
        "fake_incentive(amount=50)",
        "per_giver_cap(cap=1)",
        "PGG(2)",
    ):
        assert label in report, label
