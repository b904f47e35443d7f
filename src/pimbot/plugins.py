"""Plugins: modules that register environments, learners, attacks or defenses.

A plugin is an ordinary module that calls the same registration functions the
built-ins use (`pimbot.envs.register`, `pimbot.attacks.register`, ...) when it
is imported. `load_plugins` imports, once each per process:

1. every entry point of the group `pimbot.plugins` (installed packages:
   ``[project.entry-points."pimbot.plugins"] my_plugin = "my_package.pimbot_plugin"``),
2. the modules named in the environment variable ``PIMBOT_PLUGINS=mod1,mod2``,
3. the modules given on the command line (``pimbot ... --plugin MODULE``).

A module is a dotted module name or a path to a ``.py`` file; a file is
imported under a stable name derived from its absolute path, so a spawned
sweep worker that loads the same list gets the same module. `load_plugins`
returns that list (paths made absolute) for the workers.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.metadata
import importlib.util
import os
import re
import sys
from collections.abc import Iterable
from pathlib import Path
from types import ModuleType

GROUP = "pimbot.plugins"
"""The entry-point group installed packages register their plugin modules under."""
ENV_VAR = "PIMBOT_PLUGINS"
"""Comma-separated plugin modules to load in every `pimbot` process."""

_LOADED: dict[str, ModuleType] = {}


class PluginError(Exception):
    """A plugin that cannot be imported; the message is one line."""


def is_path(module: str) -> bool:
    """Whether `module` names a .py file rather than a dotted module name."""
    return module.endswith(".py") or os.sep in module or "/" in module


def canonical(module: str) -> str:
    """The name a plugin is loaded (and deduplicated) under: file paths made absolute."""
    module = module.strip()
    return str(Path(module).expanduser().resolve()) if is_path(module) else module


def from_environment() -> list[str]:
    """The plugin modules named in ``PIMBOT_PLUGINS``."""
    return [m.strip() for m in os.environ.get(ENV_VAR, "").split(",") if m.strip()]


def file_module_name(path: str) -> str:
    """The stable module name a plugin file is imported under."""
    stem = re.sub(r"\W", "_", Path(path).stem)
    digest = hashlib.sha1(path.encode()).hexdigest()[:10]
    return f"pimbot_plugin_{stem}_{digest}"


def _reason(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    return f"{type(error).__name__}: {text[0]}" if text else type(error).__name__


def _import_file(path: str) -> ModuleType:
    name = file_module_name(path)
    if name in sys.modules:
        return sys.modules[name]
    if not Path(path).is_file():
        raise FileNotFoundError(f"no such file {path}")
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"{path} is not a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses and pickle look classes up here
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def load(module: str) -> ModuleType:
    """Imports one plugin (a module name or a .py path) unless it is already loaded.

    Raises:
        PluginError: ``plugin: cannot import MODULE: <reason>``.
    """
    key = canonical(module)
    if key in _LOADED:
        return _LOADED[key]
    try:
        loaded = _import_file(key) if is_path(key) else importlib.import_module(key)
    except Exception as error:  # a plugin's own bug is reported in one line too
        raise PluginError(f"plugin: cannot import {module}: {_reason(error)}") from None
    _LOADED[key] = loaded
    return loaded


def _entry_points() -> Iterable[importlib.metadata.EntryPoint]:
    return importlib.metadata.entry_points(group=GROUP)


def load_plugins(extra: Iterable[str] = (), *, from_env: bool = True) -> tuple[str, ...]:
    """Loads the entry-point plugins, then ``PIMBOT_PLUGINS`` (if `from_env`), then `extra`.

    Returns:
        The non-entry-point plugins loaded, canonical and in order: what a spawned
        worker passes back in (with `from_env=False`) to load the same ones.

    Raises:
        PluginError: the first plugin that cannot be imported, in one line.
    """
    for entry in _entry_points():
        key = f"entry point {entry.name} ({entry.value})"
        if key in _LOADED:
            continue
        try:
            _LOADED[key] = entry.load()
        except Exception as error:
            raise PluginError(
                f"plugin: cannot import {entry.value} (entry point {entry.name}): {_reason(error)}"
            ) from None
    names = (from_environment() if from_env else []) + list(extra)
    resolved: list[str] = []
    for module in names:
        load(module)
        if canonical(module) not in resolved:
            resolved.append(canonical(module))
    return tuple(resolved)


def loaded() -> list[str]:
    """What this process has loaded (entry points, module names and file paths)."""
    return list(_LOADED)
