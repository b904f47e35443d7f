"""The command classes and their dispatch: one table, --help without JAX, "did you mean",
plugins loaded once, --from mapped from the fields."""

import dataclasses
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from pimbot import cli, plugins
from pimbot.cli import commands, handlers, parsing

ROOT = Path(__file__).resolve().parents[1]


def test_help_of_every_command_path_imports_no_jax():
    script = textwrap.dedent(
        """
        import contextlib, io, sys
        from pimbot import cli
        assert "jax" not in sys.modules, "import pimbot.cli"
        paths = [(), *cli.command_paths()]
        for path in paths:
            out = io.StringIO()
            with contextlib.redirect_stdout(out):
                try:
                    code = cli.main([*path, "--help"])
                except SystemExit as exit:
                    code = exit.code
            assert code == 0 and out.getvalue().startswith("usage: pimbot"), (path, code)
            assert "jax" not in sys.modules, path
        print(len(paths))
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert int(done.stdout) == 1 + len(list(cli.command_paths()))


def test_the_dispatch_table_covers_every_command_path():
    tree = commands.build()
    leaves = set()
    for path in cli.command_paths(tree):
        node = tree
        for name in path:
            node = node[name]
        if isinstance(node, dict):
            assert path in commands.GROUPS, path
        else:
            leaves.add(path)
            assert commands.COMMANDS[path] is node
            assert "run" in vars(node), f"{node.__name__} runs nothing of its own"
    assert leaves == set(commands.COMMANDS)
    assert len(set(commands.COMMANDS.values())) == len(commands.COMMANDS)


@pytest.mark.parametrize("cls", [commands.Command, commands.Suite, commands.RobotRun])
def test_a_base_class_is_not_a_command(cls):
    assert cls not in commands.COMMANDS.values()
    with pytest.raises(NotImplementedError):
        cls.run(None, ())


def test_the_fixed_sets_are_the_ones_their_modules_use():
    from pimbot.profiling import CONTROLLERS
    from pimbot.suites import sweep
    from pimbot.training import tracking

    assert tuple(CONTROLLERS) == commands.CONTROLLERS
    assert tuple(sweep.BACKENDS) == commands.BACKENDS
    assert tuple(tracking.BACKENDS) == commands.TRACKERS


DID_YOU_MEAN = [
    (["trian"], "command: unknown command 'trian'; allowed: train", "did you mean 'train'?"),
    (["robot", "rnder"], "unknown robot command 'rnder'; allowed: eval", "'render'?"),
    (["train", "ipd-v1", "--out", "{d}"], "env_id: unknown value 'ipd-v1'", "'ipd-v0'"),
    (["train", "ipd-v0", "--learner", "lioo", "--out", "{d}"], "learner: unknown", "'lio'"),
    (["train", "ipd-v0", "--attack", "admoo", "--out", "{d}"], "attack: unknown", "'admo'"),
    (
        ["train", "ipd-v0", "--defense", "incentive_gaurd", "--out", "{d}"],
        "defense: unknown value 'incentive_gaurd'; allowed: ",
        "did you mean 'incentive_guard'?",
    ),
    (
        ["profile", "--env", "ipd-v0", "--controller", "benin", "--out", "{d}"],
        "controller: unknown value 'benin'; allowed: benign, admo, admo_code",
        "did you mean 'benign'?",
    ),
    (["reproduce", "--backend", "rya", "--out", "{d}"], "backend: unknown", "'ray'"),
    (["profile", "--env", "ipd_v0", "--out", "{d}"], "env: unknown value 'ipd_v0'", "'ipd-v0'"),
]


@pytest.mark.parametrize(("argv", "error", "suggestion"), DID_YOU_MEAN, ids=lambda v: str(v))
def test_an_unknown_name_gets_the_closest_ones(tmp_path, capsys, argv, error, suggestion):
    out = tmp_path / "out"
    assert cli.main([a.format(d=out) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pimbot: error: ") and len(err.strip().splitlines()) == 1, err
    assert error in err and suggestion in err, err
    assert not out.exists()


def test_no_close_name_no_suggestion(capsys):
    assert cli.main(["train", "qqqqqq", "--out", "x"]) == 2
    err = capsys.readouterr().err
    assert "env_id: unknown value 'qqqqqq'; allowed: " in err and "did you mean" not in err


def test_a_bad_name_in_a_config_file_names_the_file(tmp_path, capsys):
    config = tmp_path / "c.toml"
    config.write_text("learner = 'lioo'\n")
    assert cli.main(["train", "ipd-v0", "--config", str(config), "--out", "x"]) == 2
    err = capsys.readouterr().err
    assert f"learner: {config}: unknown value 'lioo'; allowed: lio" in err
    assert "did you mean 'lio'?" in err


def test_plugins_are_loaded_once_per_invocation(tmp_path, monkeypatch, capsys):
    """--plugin, the config's plugin key and PIMBOT_PLUGINS: one load_plugins call."""
    for name in ("from_file", "from_option"):
        (tmp_path / f"{name}_plugin.py").write_text("LOADED = True\n")
    config = tmp_path / "c.toml"
    config.write_text(f"plugin = [{str(tmp_path / 'from_file_plugin.py')!r}]\n")
    calls = []
    load = plugins.load_plugins
    monkeypatch.setattr(plugins, "load_plugins", lambda *a, **k: calls.append(a) or load(*a, **k))
    argv = [
        "defenses",
        "--config",
        str(config),
        "--plugin",
        str(tmp_path / "from_option_plugin.py"),
    ]
    assert cli.main(argv) == 0
    assert len(calls) == 1
    loaded = calls[0][0]
    assert [Path(p).name for p in loaded] == ["from_file_plugin.py", "from_option_plugin.py"]
    capsys.readouterr()


def test_from_maps_every_saved_field_through_the_train_options():
    """A RunConfig through --from's mapping (the Train fields) and back is the same run."""
    from pimbot.training.config import RunConfig, resolve

    run = RunConfig(
        env_id="escape_room-v0",
        env_params=(("n_agents", 3),),
        learner="lio",
        hparams=(("lr_policy", 0.002), ("policy_hidden", (16, 8))),
        seeds=3,
        first_seed=7,
        iterations=300,
        eval_period=100,
        eval_episodes=4,
        attack="bypass",
        attack_params=(("toggle_period", 5),),
        defenses=(("exploration_floor", (("min_epsilon", 0.2),)), ("incentive_guard", ())),
    )
    values = parsing.saved_values(commands.Train, run)
    train = parsing.defaults(commands.Train, values, "--from")
    assert train.env_id == "escape_room-v0" and train.defense_param == (
        "exploration_floor.min_epsilon=0.2",
    )
    again = handlers._run_config(train)  # hyperparameters as the command line's strings
    assert dataclasses.replace(again, hparams=run.hparams) == run
    assert resolve(again).identity() == resolve(run).identity()


def test_a_refused_command_line_never_shows_tyros_report(capsys):
    """Whatever tyro refuses is one line: `explain`'s, else tyro's reason in one line."""
    assert parsing._tyro_reason(
        " Value error \n ---- \n  Error parsing --x: bad  \n  more  \n ---- \n"
        "  Argument helptext:\n   --x INT\n"
    ) == ("Error parsing --x: bad more")
    for argv in (["train", "ipd-v0", "--seeds"], ["plot", "--bogus"], ["audit", "verify"]):
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "╭" not in err, err
