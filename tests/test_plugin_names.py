"""A plugin written against an earlier release keeps loading: every name docs/extending.md
documents imports from `pimbot.contracts.plugin_api`, and every moved module keeps an
alias that warns, naming its new place (`pimbot.moved`)."""

from __future__ import annotations

import importlib
import re
import subprocess
import sys
import tomllib
import warnings
from pathlib import Path

import pytest

import pimbot
from pimbot import moved
from pimbot.contracts import plugin_api

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "extending.md"
SECTION = "## The names a plugin uses"


def documented_names() -> list[str]:
    """The names in the first column of the guide's table of plugin names."""
    text = GUIDE.read_text(encoding="utf-8")
    assert SECTION in text, f"{GUIDE} has no section {SECTION!r}"
    section = text.split(SECTION, 1)[1].split("\n## ", 1)[0]
    names = []
    for line in section.splitlines():
        if line.startswith("| `"):
            names += re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", line.split("|")[1])
    return names


def test_every_documented_name_imports_from_the_plugin_module():
    names = documented_names()
    assert names, "no names found in the guide's table"
    for name in names:
        exec(f"from pimbot.contracts.plugin_api import {name}", {})
    assert sorted(names) == sorted(plugin_api.__all__), "the guide and __all__ differ"


def test_the_plugin_module_gives_the_defining_modules_objects():
    from pimbot import envs
    from pimbot.contracts import attack, defense, learner, rollout

    assert plugin_api.register_attack is attack.register
    assert plugin_api.register_defense is defense.register
    assert plugin_api.register_learner is learner.register
    assert plugin_api.register_env is envs.register
    assert plugin_api.ATTACK_HOOKS == attack.HOOKS and plugin_api.DEFENSE_HOOKS == defense.HOOKS
    assert plugin_api.rollout is rollout.rollout and plugin_api.Attack is attack.Attack


@pytest.mark.parametrize("old", sorted(moved.MOVED_MODULES))
def test_a_moved_module_keeps_an_alias_that_warns_naming_its_new_place(old):
    new = moved.MOVED_MODULES[old]
    for name in [n for n in sys.modules if n == old or n.startswith(old + ".")]:
        del sys.modules[name]
    if new is None:  # a package that only held modules: each of them warns
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            package = importlib.import_module(old)
        assert package.__path__ == [] and "pimbot.training" in package.__doc__
        with pytest.raises(AttributeError):
            package.no_such_name  # noqa: B018
        return
    with pytest.warns(moved.PimbotDeprecationWarning) as caught:
        alias = importlib.import_module(old)
    message = str(caught[0].message)
    assert message.startswith(f"{old} is deprecated: ") and moved.REMOVED_IN in message
    assert caught[0].filename == __file__ or "importlib" in caught[0].filename
    assert f"it moved to {new}" in message
    target = importlib.import_module(new)
    public = [n for n in vars(target) if not n.startswith("_")]
    assert public and all(getattr(alias, n) is getattr(target, n) for n in public)


def test_names_that_moved_to_another_module_follow_it():
    from pimbot.attacks import strategy_union

    sys.modules.pop("pimbot.experiment.programs", None)
    with pytest.warns(moved.PimbotDeprecationWarning):
        from pimbot.experiment.programs import Strategies, program_key  # noqa: F401
    assert Strategies is strategy_union.Strategies
    for module, name in moved.MOVED_NAMES:
        assert getattr(importlib.import_module(module), name) is getattr(
            importlib.import_module(moved.MOVED_NAMES[module, name]), name
        )


def test_a_plugin_of_the_previous_release_loads_and_is_told_where_names_went(tmp_path):
    """The learner plugin of issue 41 imported `pimbot.rollout`: it loads, and the warning
    points at the plugin's own line."""
    plugin = tmp_path / "old_learner_plugin.py"
    plugin.write_text(
        "from pimbot.rollout import episode_metrics, rollout\n"
        "from pimbot.experiment.runner import train\n"
    )
    code = (
        "import warnings, pimbot\n"
        "from pimbot import plugins\n"
        f"old = plugins.load({str(plugin)!r})\n"
        "import pimbot.contracts.rollout as new\n"
        "assert old.rollout is new.rollout\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    lines = [line for line in done.stderr.splitlines() if "PimbotDeprecationWarning" in line]
    assert len(lines) == 2, done.stderr
    assert lines[0].startswith(f"{plugin}:1: PimbotDeprecationWarning: pimbot.rollout is ")
    assert "it moved to pimbot.contracts.rollout in pimbot 0.2.0" in lines[0]
    assert lines[1].startswith(f"{plugin}:2: ")


def test_existing_modules_are_never_shadowed_by_an_alias():
    for old in moved.MOVED_MODULES:
        parent = old.rsplit(".", 1)[0]
        if parent in moved.MOVED_MODULES:
            continue
        assert importlib.util.find_spec(old) is not None
        spec = importlib.util.find_spec(old)
        assert spec.loader is moved._FINDER, f"{old} exists as a real module: no alias needed"


def test_the_version_is_one_and_bumped_by_semver():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["version"] == pimbot.__version__ == moved.SINCE
    major, minor, patch = (int(p) for p in pimbot.__version__.split("."))
    assert (major, minor, patch) > (0, 1, 0)


def test_deprecations_are_shown_to_plugin_authors_by_default():
    code = "import pimbot.rollout"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert "PimbotDeprecationWarning: pimbot.rollout is deprecated" in done.stderr
    quiet = [sys.executable, "-W", "ignore::DeprecationWarning", "-c", code]
    assert "Deprecation" not in subprocess.run(quiet, capture_output=True, text=True).stderr
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        importlib.import_module("pimbot.contracts.rollout")  # the new place never warns
