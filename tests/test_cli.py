"""The command line: bad input gives one clear line and exit 2 with nothing written."""

import pytest

from pimbot import cli

BAD = [
    (["train", "nope-v0", "--out", "{d}"], "env_id: unknown environment 'nope-v0'"),
    (["train", "escape_room-v0", "min_at_lever=2", "--out", "{d}"], "min_at_lever"),
    (["train", "escape_room-v0", "n_agents=4", "min_at_lever=4", "--out", "{d}"], "[1, 3]"),
    (["train", "escape_room-v0", "--seeds", "0", "--out", "{d}"], "seeds: must be an integer ≥ 1"),
    (["train", "escape_room-v0", "--seeds", "-3", "--out", "{d}"], "seeds"),
    (["train", "escape_room-v0", "--iterations", "ten", "--out", "{d}"], "iterations"),
    (["train", "escape_room-v0", "n_agents=two", "--out", "{d}"], "n_agents: must be an integer"),
    (["train", "escape_room-v0", "colour=red", "--out", "{d}"], "colour: not a parameter"),
    (["train", "escape_room-v0", "--learner", "dqn", "--out", "{d}"], "learner: unknown learner"),
    (["train", "escape_room-v0", "--hp", "lr_policy=fast", "--out", "{d}"], "lr_policy: must be"),
    (["train", "escape_room-v0", "--hp", "momentum=0.9", "--out", "{d}"], "momentum: not a"),
    (["train", "ipd-v0", "n_players=1", "--out", "{d}"], "n_players"),
    (["train", "escape_room-v0", "--iterations", "150", "--out", "{d}"], "multiple of eval_period"),
    (["train", "escape_room-v0"], "--out"),
    (["frobnicate"], "invalid choice"),
    (["train", "escape_room-v0", "--attack", "nope", "--out", "{d}"], "attack: unknown attack"),
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


def _command_paths(parser, prefix=()):
    """Every command and subcommand of the parser, e.g. ("robot", "eval")."""
    for name, sub in parser.subcommands.items():
        yield (*prefix, name)
        yield from _command_paths(sub, (*prefix, name))


COMMANDS = list(_command_paths(cli.build_parser()))


def test_every_command_is_found():
    names = {path[0] for path in COMMANDS}
    assert {"train", "sweep", "reproduce", "report", "envs", "plot", "robot"} <= names
    assert ("robot", "eval") in COMMANDS and ("audit", "verify") in COMMANDS


@pytest.mark.parametrize("path", [(), *COMMANDS], ids=lambda p: " ".join(p) or "pimbot")
def test_help_of_every_command_has_no_traceback(path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main([*path, "--help"])
    assert exit_info.value.code == 0
    captured = capsys.readouterr()
    assert captured.out.startswith("usage: pimbot") and not captured.err
    assert "--plugin MODULE" in captured.out  # every command takes --plugin


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
