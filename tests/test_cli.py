"""The command line: bad input gives one clear line and exit 2 with nothing written."""

import json

import pytest

from pimbot import cli
from pimbot.training import store

BAD = [
    (["train", "nope-v0", "--out", "{d}"], "env_id: unknown value 'nope-v0'; allowed: escape"),
    (["train", "escape_room-v0", "min_at_lever=2", "--out", "{d}"], "min_at_lever"),
    (["train", "escape_room-v0", "n_agents=4", "min_at_lever=4", "--out", "{d}"], "[1, 3]"),
    (["train", "escape_room-v0", "--seeds", "0", "--out", "{d}"], "seeds: must be an integer ≥ 1"),
    (["train", "escape_room-v0", "--seeds", "-3", "--out", "{d}"], "seeds"),
    (["train", "escape_room-v0", "--iterations", "ten", "--out", "{d}"], "iterations"),
    (["train", "escape_room-v0", "n_agents=two", "--out", "{d}"], "n_agents: must be an integer"),
    (["train", "escape_room-v0", "colour=red", "--out", "{d}"], "colour: not a parameter"),
    (["train", "escape_room-v0", "--learner", "dqn", "--out", "{d}"], "learner: unknown value"),
    (["train", "escape_room-v0", "--hp", "lr_policy=fast", "--out", "{d}"], "lr_policy: must be"),
    (["train", "escape_room-v0", "--hp", "momentum=0.9", "--out", "{d}"], "momentum: not a"),
    (["train", "ipd-v0", "n_players=1", "--out", "{d}"], "n_players"),
    (["train", "escape_room-v0", "--iterations", "150", "--out", "{d}"], "multiple of eval_period"),
    (["train", "escape_room-v0"], "--out"),
    (["frobnicate"], "command: unknown command 'frobnicate'; allowed: train"),
    (["train", "escape_room-v0", "--attack", "nope", "--out", "{d}"], "attack: unknown value"),
    (
        ["train", "escape_room-v0", "--attack", "admo", "--ap", "adversary=2", "--out", "{d}"],
        "adversary: must be an agent index in [0, 1]",
    ),
    (
        ["train", "escape_room-v0", "--attack", "admo", "--ap", "budget=-1", "--out", "{d}"],
        "budget: must be ≥ 0",
    ),
    (
        ["train", "escape_room-v0", "--attack", "admo", "--ap", "mode=sneaky", "--out", "{d}"],
        "mode: unknown ADMO mode 'sneaky'; allowed: stealthy, disrupt",
    ),
    (
        ["train", "escape_room-v0", "--attack", "bypass", "--ap", "colour=1", "--out", "{d}"],
        "colour: not a parameter of attack bypass",
    ),
    (
        [
            "train",
            "escape_room-v0",
            "--learner",
            "pg",
            "--attack",
            "fake_incentive",
            "--out",
            "{d}",
        ],
        "fake_incentive acts at the hook point(s) emit, which learner pg does not have",
    ),
    (["train", "escape_room-v0", "--ap", "mode=disrupt", "--out", "{d}"], "without --attack"),
]


@pytest.mark.parametrize(("argv", "expected"), BAD)
def test_bad_input_is_one_line_exit_2_nothing_written(tmp_path, capsys, argv, expected):
    out = tmp_path / "run"
    code = cli.main([a.format(d=out) for a in argv])
    err = capsys.readouterr().err
    assert code == 2
    assert expected in err
    assert len(err.strip().splitlines()) == 1, err
    assert err.startswith("pimbot: error: ")
    assert not out.exists()


def test_envs_lists_every_environment_with_parameters(capsys):
    assert cli.main(["envs"]) == 0
    text = capsys.readouterr().out
    for env_id in ("escape_room-v0", "ipd-v0", "stag_hunt-v0", "stag_hunt_matrix-v0"):
        assert env_id in text
    assert "min_at_lever = 1" in text and "n_players = 2" in text


def test_attacks_lists_attacks_with_parameters(capsys):
    assert cli.main(["attacks"]) == 0
    text = capsys.readouterr().out
    for name in ("self_centered", "fake_incentive", "bypass", "reverse", "admo"):
        assert name in text
    assert "toggle_period = 0" in text and "budget = 10.0" in text


def test_learners_lists_hyperparameters(capsys):
    assert cli.main(["learners"]) == 0
    text = capsys.readouterr().out
    assert "lio:" in text and "pg:" in text and "lr_incentive" in text


def test_train_then_rerun_says_finished(tmp_path, capsys):
    argv = [
        "train",
        "escape_room-v0",
        "--seeds",
        "2",
        "--iterations",
        "200",
        "--eval-period",
        "100",
        "--eval-episodes",
        "4",
        "--quiet",
        "--out",
        str(tmp_path / "r"),
    ]
    assert cli.main(argv) == 0
    assert "success" in capsys.readouterr().out
    assert cli.main(argv) == 0
    assert "already finished" in capsys.readouterr().out


COMMANDS = list(cli.command_paths())


def test_every_command_is_found():
    names = {path[0] for path in COMMANDS}
    assert {"train", "sweep", "reproduce", "report", "envs", "plot", "robot"} <= names
    assert ("robot", "eval") in COMMANDS and ("audit", "verify") in COMMANDS


GROUPS = [(), ("audit",), ("robot",)]


@pytest.mark.parametrize("path", GROUPS, ids=lambda p: " ".join(p) or "pimbot")
def test_help_of_a_command_group_lists_its_commands(path, capsys):
    assert cli.main([*path, "--help"]) == 0
    captured = capsys.readouterr()
    assert captured.out.startswith("usage: pimbot") and not captured.err
    assert "commands:" in captured.out


@pytest.mark.parametrize("path", [p for p in COMMANDS if p not in GROUPS], ids=" ".join)
def test_help_of_every_command_has_no_traceback(path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main([*path, "--help"])
    assert exit_info.value.code == 0
    captured = capsys.readouterr()
    assert captured.out.startswith("usage: pimbot") and not captured.err
    assert "--plugin MODULE" in captured.out  # every command takes --plugin
    assert "--config FILE" in captured.out


def test_bare_pimbot_prints_the_commands(capsys):
    assert cli.main([]) == 0
    text = capsys.readouterr().out
    assert text.startswith("usage: pimbot")
    assert all(name in text for name in ("train", "sweep", "reproduce", "envs"))


def test_version(capsys):
    import pimbot

    with pytest.raises(SystemExit) as exit_info:
        cli.main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"pimbot {pimbot.__version__}"


def test_help_shows_docstrings_defaults_and_allowed_values(capsys):
    with pytest.raises(SystemExit):
        cli.main(["train", "--help"])
    text = capsys.readouterr().out
    assert "Number of independent seeds S" in text and "(default: 10)" in text
    # The registries' names: --help points to the listings (the registries import JAX).
    words = " ".join(text.replace("│", " ").split())  # tyro wraps the text in a box
    for listing in ("pimbot envs", "pimbot learners", "pimbot attacks", "pimbot defenses"):
        assert f"`{listing}`" in words, listing
    assert "--from RUN_DIR" in text and "--ap NAME=VALUE" in text
    with pytest.raises(SystemExit):
        cli.main(["profile", "--help"])
    assert "{benign,admo,admo_code}" in capsys.readouterr().out  # a fixed set is listed


def test_listings_show_each_parameters_docstring(capsys):
    assert cli.main(["learners"]) == 0
    assert "SGD learning rate β of the policy step." in capsys.readouterr().out
    assert cli.main(["attacks"]) == 0
    assert "alternate bypass and normal play" in capsys.readouterr().out
    assert cli.main(["envs"]) == 0
    assert "Agents needed at the lever to open the door" in capsys.readouterr().out


TOML = """
env_id = "escape_room-v0"
learner = "pg"
seeds = 3
quiet = true
attack = "bypass"
defense = ["exploration_floor"]
[env_params]
n_agents = 3
[hp]
lr_policy = 0.002
[attack_param]
toggle_period = 5
[defense_param.exploration_floor]
min_epsilon = 0.2
"""

YAML = """
env_id: escape_room-v0
learner: pg
seeds: 3
quiet: true
attack: bypass
defense: [exploration_floor]
env_params: {n_agents: 3}
hp: {lr_policy: 0.002}
attack_param: {toggle_period: 5}
defense_param: {exploration_floor: {min_epsilon: 0.2}}
"""


@pytest.mark.parametrize(("suffix", "text"), [(".toml", TOML), (".yaml", YAML)])
def test_config_file_gives_the_options_and_the_command_line_overrides_it(tmp_path, suffix, text):
    config = tmp_path / f"train{suffix}"
    config.write_text(text)
    path, command = cli.parse(["train", "--config", str(config), "--seeds", "5", "--out", "d"])
    assert path == ("train",)
    assert (command.env_id, command.learner, command.seeds, command.quiet) == (
        "escape_room-v0",
        "pg",
        5,
        True,
    )
    assert command.env_params == ("n_agents=3",) and command.hp == ("lr_policy=0.002",)
    assert command.attack == "bypass" and command.attack_param == ("toggle_period=5",)
    assert command.defense == ("exploration_floor",)
    assert command.defense_param == ("exploration_floor.min_epsilon=0.2",)


CONFIG_BAD = [
    ("missing.toml", None, "config: {d}/missing.toml is not a file"),
    ("c.toml", "seeds = 'two'", "seeds: {d}/c.toml: must be an integer, got 'two'"),
    ("c.toml", "colour = 1", "'colour' is not an option; allowed: plugin"),
    ("c.toml", "learner = 'dqn'", "learner: {d}/c.toml: unknown value 'dqn'; allowed: lio"),
    ("c.toml", "seeds = ", "config: cannot read {d}/c.toml"),
    ("c.yaml", "- 1\n- 2", "must hold a table of options, got list"),
    ("c.json", "{}", "must end in .toml, .yaml or .yml"),
    ("c.toml", "seeds = 0", "seeds: must be an integer ≥ 1, got 0"),
]


@pytest.mark.parametrize(("name", "text", "expected"), CONFIG_BAD)
def test_bad_config_file_is_one_line(tmp_path, capsys, name, text, expected):
    if text is not None:
        (tmp_path / name).write_text(text)
    argv = ["train", "escape_room-v0", "--config", str(tmp_path / name), "--out", "x"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert expected.format(d=tmp_path) in err and len(err.strip().splitlines()) == 1, err


def _results(run_dir):
    """metrics.csv without its timing columns (perf/*)."""
    return [
        {k: v for k, v in row.items() if not k.startswith("perf/")}
        for row in store.read_metrics(run_dir)
    ]


def test_from_reruns_a_saved_run_elsewhere_or_continues_it(tmp_path, capsys):
    first = tmp_path / "first"
    argv = ["train", "ipd-v0", "--seeds", "2", "--iterations", "200", "--eval-period", "100"]
    assert cli.main([*argv, "--hp", "lr_policy=0.002", "--quiet", "--out", str(first)]) == 0
    again = tmp_path / "again"
    assert cli.main(["train", "--from", str(first), "--out", str(again), "--quiet"]) == 0
    read = lambda d, name: (d / name).read_text()  # noqa: E731
    assert _results(again) == _results(first)
    first_config, again_config = (json.loads(read(d, "config.json")) for d in (first, again))
    assert again_config["identity"] == first_config["identity"]
    capsys.readouterr()
    assert cli.main(["train", "--from", str(first), "--quiet"]) == 0  # continues it: finished
    assert "already finished" in capsys.readouterr().out
    path, command = cli.parse(["train", "--from", str(first), "--seeds", "4", "--out", "x"])
    assert (command.env_id, command.seeds, command.hp) == ("ipd-v0", 4, ("lr_policy=0.002",))
