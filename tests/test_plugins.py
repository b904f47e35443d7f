"""Plugins: an env registered by a plugin file, module or entry point is listed and
trainable; a plugin that cannot be imported is one line and exit 2."""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

import pytest

from pimbot import cli, envs, plugins

PLUGIN_FILE = Path(__file__).parent / "data" / "coordination_plugin.py"
"""Registers my_env-v0 (loaded once per process, as in real use)."""


def write_plugin(directory: Path, module: str, env_id: str) -> None:
    """A one-line plugin module registering a built-in game under another id."""
    (directory / f"{module}.py").write_text(
        "from pimbot import envs\n"
        f"envs.register({env_id!r}, envs.StagHuntMatrix, 'registered by {module}')\n"
    )


@pytest.fixture
def plugin_file() -> Path:
    return PLUGIN_FILE


def test_envs_lists_an_env_from_a_plugin_file(plugin_file, capsys):
    assert cli.main(["envs", "--plugin", str(plugin_file)]) == 0
    text = capsys.readouterr().out
    assert "my_env-v0: Coordination game (test plugin)" in text
    assert "escape_room-v0" in text  # the built-ins are still there


def test_train_an_env_from_a_plugin_file(plugin_file, tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["train", "my_env-v0", "--plugin", str(plugin_file), "--seeds", "1"]
    argv += ["--iterations", "20", "--eval-period", "10", "--quiet", "--out", str(out)]
    assert cli.main(argv) == 0, capsys.readouterr().err
    assert "success" in capsys.readouterr().out
    assert (out / "summary.json").exists()


def test_plugin_option_before_the_command_and_loaded_once(plugin_file, capsys):
    argv = ["--plugin", str(plugin_file), "envs", "--plugin", str(plugin_file)]
    assert cli.main(argv) == 0  # a second registration of my_env-v0 would fail
    assert capsys.readouterr().out.count("my_env-v0:") == 1
    assert plugins.load(str(plugin_file)) is plugins.load(str(plugin_file))


def test_plugins_from_the_environment_variable(tmp_path, monkeypatch, capsys):
    write_plugin(tmp_path, "env_var_plugin", "env_var_game-v0")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv(plugins.ENV_VAR, "env_var_plugin")
    assert cli.main(["envs"]) == 0
    assert "env_var_game-v0:" in capsys.readouterr().out
    assert "env_var_game-v0" in envs.registered()


def test_entry_point_plugins_are_loaded(tmp_path, monkeypatch, capsys):
    write_plugin(tmp_path, "entry_point_plugin", "entry_point_game-v0")
    monkeypatch.syspath_prepend(str(tmp_path))
    entry = importlib.metadata.EntryPoint("demo", "entry_point_plugin", plugins.GROUP)
    monkeypatch.setattr(plugins, "_entry_points", lambda: [entry])
    assert cli.main(["envs"]) == 0
    assert "entry_point_game-v0:" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("plugin", "reason"),
    [
        ("no_such_plugin_module", "ModuleNotFoundError: No module named 'no_such_plugin_module'"),
        ("{tmp}/missing.py", "FileNotFoundError: no such file"),
        ("{tmp}/broken.py", "RuntimeError: this plugin is broken"),
        ("{tmp}/syntax.py", "SyntaxError"),
    ],
)
def test_bad_plugin_is_one_line_exit_2(tmp_path, capsys, plugin, reason):
    (tmp_path / "broken.py").write_text("raise RuntimeError('this plugin is broken')\n")
    (tmp_path / "syntax.py").write_text("def (:\n")
    plugin = plugin.format(tmp=tmp_path)
    out = tmp_path / "run"
    code = cli.main(["train", "ipd-v0", "--plugin", plugin, "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith(f"pimbot: error: plugin: cannot import {plugin}: "), err
    assert reason in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_plugin_file_module_name_is_stable(tmp_path):
    path = str(tmp_path / "a-b.py")
    assert plugins.file_module_name(path) == plugins.file_module_name(path)
    assert plugins.file_module_name(path).startswith("pimbot_plugin_a_b_")
    assert plugins.canonical(path) == str((tmp_path / "a-b.py").resolve())
    assert plugins.canonical("some.module") == "some.module"


def test_workers_receive_canonical_paths(plugin_file, monkeypatch):
    monkeypatch.chdir(plugin_file.parent)
    monkeypatch.setenv(plugins.ENV_VAR, "")
    assert plugins.load_plugins([plugin_file.name]) == (str(plugin_file.resolve()),)


def test_loading_a_plugin_moves_the_compilation_cache_to_its_key(tmp_path, monkeypatch):
    from pimbot import jax_setup

    monkeypatch.setenv(jax_setup.CACHE_ENV, str(tmp_path / "cache"))
    try:
        before = jax_setup.enable_compilation_cache()
        first, second = tmp_path / "v1", tmp_path / "v2"
        for version, folder in enumerate((first, second)):
            folder.mkdir()
            (folder / "cache_key_plugin.py").write_text(f"VERSION = {version}\n")
        plugins.load(str(first / "cache_key_plugin.py"))
        moved = jax_setup.active_cache_dir()
        assert moved != before and moved.parent == tmp_path / "cache"
        assert moved == jax_setup.cache_dir(tmp_path / "cache")  # the files loaded now
        digests = jax_setup.loaded_plugin_digests()
        ours = plugins.file_sha256(first / "cache_key_plugin.py")
        other = plugins.file_sha256(second / "cache_key_plugin.py")
        changed = [other if d == ours else d for d in digests]  # the same file, edited
        assert jax_setup.cache_dir(tmp_path / "cache", changed) != moved
    finally:
        monkeypatch.undo()
        jax_setup.enable_compilation_cache()  # back to the session's cache
