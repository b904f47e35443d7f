"""A probe of every command against every bad-value class: one line naming the field,
exit status 2, no traceback, nothing written.

The cases are generated from the command dataclasses (`pimbot.cli.commands`), so a new
command or option is probed without editing this file.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from pathlib import Path

import pytest
import tyro

from pimbot import cli
from pimbot.cli import commands

VALID = {  # a value that parses for each required argument, so the probe hits one option
    "env_id": "ipd-v0",
    "env": "ipd-v0",
    "run_dirs": "no_such_run",
    "run_dir": "no_such_run",
    "suite_dir": "no_such_suite",
    "grid": "no_such_grid.toml",
    "log": "no_such_log",
    "file": "no_such_plugin.py",
    "out": "{out}",
}


def _kind(hint):
    """(base type, Literal choices or None, is_positional, is_tuple) of a field hint."""
    metadata = ()
    while typing.get_origin(hint) is typing.Annotated:
        metadata += hint.__metadata__
        hint = hint.__origin__
    positional = tyro.conf.Positional in metadata
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        hint = next(a for a in typing.get_args(hint) if a is not type(None))
    is_tuple = typing.get_origin(hint) is tuple
    if is_tuple:
        hint = typing.get_args(hint)[0]
    choices = typing.get_args(hint) if typing.get_origin(hint) is typing.Literal else None
    return hint, choices, positional, is_tuple


def _option(field: dataclasses.Field) -> str:
    name = {"from_run": "from"}.get(field.name, field.name)
    return "--" + name.replace("_", "-")


def _cases():
    tree = commands.build(cli.choices())
    for path in cli.command_paths(tree):
        node = tree
        for name in path:
            node = node[name]
        if isinstance(node, dict):
            continue
        hints = typing.get_type_hints(node, include_extras=True)
        fields = {f.name: f for f in dataclasses.fields(node)}
        required: list[str] = []
        for name, field in fields.items():
            if field.default is dataclasses.MISSING and name in VALID:
                kind, _, positional, _ = _kind(hints[name])
                value = VALID[name]
                required += [value] if positional else [_option(field), value]
        base = [*path, *required]
        yield ("unknown option", [*base, "--no-such-option", "1"], "unrecognized arguments")
        yield ("config missing", [*base, "--config", "no_such.toml"], "config:")
        yield ("plugin missing", [*base, "--plugin", "no_such_plugin_module"], "plugin:")
        for name, field in fields.items():
            kind, choices, positional, is_tuple = _kind(hints[name])
            if positional:
                continue
            flag = _option(field)
            label = f"{' '.join(path)} {flag}"
            if choices:
                yield (f"{label} unknown choice", [*base, flag, "bogus"], f"{name}: unknown")
            elif kind is int:
                yield (f"{label} not an integer", [*base, flag, "abc"], name)
                yield (f"{label} fraction", [*base, flag, "1.5"], name)
                bounds = node.int_bounds(node.__new__(node)) if not is_tuple else {}
                if name in bounds:
                    low = bounds[name]
                    yield (f"{label} below {low}", [*base, flag, str(low - 1)], name)
            elif kind is float:
                for bad in ("abc", "nan", "inf", "-inf", "0", "-1"):
                    yield (f"{label} {bad}", [*base, flag, bad], name)
    for path in (("frobnicate",), ("robot", "fly"), ("audit", "check")):
        yield (f"unknown command {' '.join(path)}", list(path), "unknown")


CASES = list(_cases())


def test_every_command_is_probed():
    probed = {tuple(c[1][:2]) if c[1][0] in ("robot", "audit") else (c[1][0],) for c in CASES}
    wanted = {p for p in cli.command_paths() if p not in (("robot",), ("audit",))}
    assert wanted <= probed


@pytest.mark.parametrize(("label", "argv", "expected"), CASES, ids=[c[0] for c in CASES])
def test_bad_value_is_one_line_exit_2_nothing_written(tmp_path, capsys, label, argv, expected):
    out = tmp_path / "out"
    argv = [a.replace("{out}", str(out)) for a in argv]
    code = cli.main(argv)
    err = capsys.readouterr().err
    assert code == 2, (label, err)
    assert err.startswith("pimbot: error: ") and len(err.strip().splitlines()) == 1, err
    assert expected in err, (label, err)
    assert not out.exists()


OUT_IS_A_FILE = [
    ["train", "ipd-v0", "--out", "{file}"],
    ["reproduce", "--quick", "--out", "{file}"],
    ["sweep", "docs/examples/grid.toml", "--out", "{file}"],
    ["profile", "--env", "ipd-v0", "--out", "{file}"],
    ["train", "ipd-v0", "--out", "{file}/run"],
    ["train", "ipd-v0", "--out", "{dir}/run", "--audit-log", "{dir}"],
]


@pytest.mark.parametrize("argv", OUT_IS_A_FILE, ids=" ".join)
def test_an_output_that_cannot_be_made_is_one_line(tmp_path, capsys, argv):
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    file = tmp_path / "a_file"
    file.write_text("keep me")
    argv = [a.format(file=file, dir=tmp_path) for a in argv]
    argv = [str(root / a) if a.startswith("docs/") else a for a in argv]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and ("not a directory" in err or "a directory" in err)
    assert file.read_text() == "keep me" and not (tmp_path / "run").exists()


def test_a_listing_into_a_closed_pipe_ends_quietly():
    """`pimbot learners | head -1`: the reader leaves before the listing is written."""
    import os
    import subprocess
    import sys

    read_end, write_end = os.pipe()
    os.close(read_end)  # nobody will read: the first write fails with EPIPE
    listing = subprocess.run(
        [sys.executable, "-m", "pimbot.cli", "learners"],
        stdout=write_end,
        stderr=subprocess.PIPE,
        text=True,
    )
    os.close(write_end)
    assert listing.returncode == 1 and listing.stderr == "", listing.stderr


NAME_VALUE = [  # the NAME=VALUE options: hyperparameters, attack and env parameters
    ("--hp", "lr_policy=nan", "lr_policy: must be a finite number"),
    ("--hp", "lr_policy=inf", "lr_policy: must be a finite number"),
    ("--hp", "lr_policy=-1", "lr_policy: must be ≥ 0"),
    ("--hp", "lr_policy=1e30", "lr_policy: must be ≥ 0 and ≤ 1e+06"),
    ("--hp", "gamma=nan", "gamma: must be a finite number"),
    ("--hp", "gamma=1.5", "gamma: must be ≥ 0 and ≤ 1"),
    ("--hp", "incentive_max=-1", "incentive_max: must be ≥ 0"),
    ("--hp", "epsilon_start=inf", "epsilon_start: must be a finite number"),
    ("--hp", "policy_hidden=0", "policy_hidden[0]: must be an integer ≥ 1"),
    ("--hp", "policy_hidden=64,x", "policy_hidden: must be a comma-separated list"),
    ("--hp", "epsilon_decay_iters=-5", "epsilon_decay_iters: must be an integer ≥ 0"),
    ("--hp", "incentive_updates=both", "incentive_updates: must be one of shared, own"),
    ("--ap", "amount=1e30", "amount: must be ≥ -1e+06 and ≤ 1e+06"),
    ("--ap", "amount=nan", "amount: must be a finite number"),
    ("env", "n_agents=10000", "needs at least"),
    ("env", "n_agents=-2", "n_agents"),
]


@pytest.mark.parametrize(("flag", "value", "expected"), NAME_VALUE, ids=lambda v: str(v))
def test_bad_name_value_is_one_line_exit_2_nothing_written(tmp_path, capsys, flag, value, expected):
    out = tmp_path / "out"
    argv = ["train", "escape_room-v0", "--out", str(out)]
    if flag == "env":
        argv.insert(2, value)
    else:
        argv += [flag, value] + (["--attack", "fake_incentive"] if flag == "--ap" else [])
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("pimbot: error: ") and len(err.strip().splitlines()) == 1, err
    assert expected in err, err
    assert not out.exists()


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc")
@pytest.mark.parametrize(
    "argv",
    [
        ["reproduce", "--quick", "--out", "/proc/pimbot_probe/suite"],
        ["train", "ipd-v0", "--iterations", "10", "--out", "/proc/pimbot_probe"],
    ],
    ids=" ".join,
)
def test_a_place_the_checks_cannot_foresee_is_one_line(capsys, argv):
    # /proc passes os.access for root, so the refusal comes from the OSError itself.
    code = cli.main(argv)
    err = capsys.readouterr().err
    assert code in (1, 2), err
    assert err.startswith("pimbot: error: ") and len(err.strip().splitlines()) == 1, err
    assert "pimbot_probe" in err, err  # the run directory or its lock file
