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

What was loaded is recorded with every run (`provenance`: each plugin's file and sha256 in
config.json "plugins"; the same digests key the compilation cache's directory,
`jax_setup.cache_dir`), and a run reloaded from its directory (`pimbot train --from`)
names a recorded plugin that this process has not loaded (`missing`).

A plugin that fails is one line naming its file and line: one that cannot be imported
(`PluginError`), one whose registration breaks its contract (an error that says where,
`pimbot.contracts.conformance.ContractError`, passed on as it is), and an exception raised
in a plugin's code later (`failure_line`). Its full traceback is printed only when asked
for (`debug_enabled`: ``PIMBOT_DEBUG=1``; `full_traceback`).
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.metadata
import importlib.util
import os
import re
import sys
import traceback
from collections.abc import Iterable
from pathlib import Path
from types import ModuleType

GROUP = "pimbot.plugins"
"""The entry-point group installed packages register their plugin modules under."""
ENV_VAR = "PIMBOT_PLUGINS"
"""Comma-separated plugin modules to load in every `pimbot` process."""
DEBUG_VAR = "PIMBOT_DEBUG"
"""Set to 1 for the full traceback of a plugin's failure (besides its one line)."""

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


def _reason(error: BaseException, path: str | None = None) -> str:
    """`Type: first line`, after ``FILE:LINE: `` where the plugin file `path` raised it."""
    text = str(error).strip().splitlines()
    reason = f"{type(error).__name__}: {text[0]}" if text else type(error).__name__
    at = _line_in(error, [path]) if path else None
    return f"{at}: {reason}" if at else reason


def _stopped(error: SystemExit | KeyboardInterrupt, path: str | None = None) -> str:
    """Why an import ended without an ordinary exception: the plugin called exit() (with its
    status) or was interrupted; ``FILE:LINE: `` where the plugin file `path` did it. Either
    way the plugin is not loaded, and the command ends with its one line and status 2 rather
    than with the plugin's status or a traceback."""
    if isinstance(error, SystemExit):
        code = error.code
        status = "" if code is None else f" {code!r}" if not isinstance(code, int) else f" {code}"
        reason = f"it called exit{status and '(' + status.strip() + ')'} while being imported"
    else:
        reason = "interrupted (KeyboardInterrupt) while being imported"
    at = _line_in(error, [path]) if path else None
    return f"{at}: {reason}" if at else reason


def _line_in(error: BaseException, files: Iterable[str]) -> str | None:
    """``FILE:LINE`` of the innermost frame of `error`'s traceback in one of `files` (a
    syntax error: where the parser stopped), or None."""
    wanted = {str(Path(f).resolve()) for f in files if f}
    syntax = isinstance(error, SyntaxError) and error.filename
    if syntax and str(Path(error.filename).resolve()) in wanted:
        return f"{error.filename}:{error.lineno}"
    frames = traceback.extract_tb(error.__traceback__)
    found = [f for f in frames if str(Path(f.filename).resolve()) in wanted]
    return f"{found[-1].filename}:{found[-1].lineno}" if found else None


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
        if getattr(error, "located", False):  # one line that says where already
            raise
        path = key if is_path(key) else _module_file(key)
        raise PluginError(f"plugin: cannot import {module}: {_reason(error, path)}") from error
    except (SystemExit, KeyboardInterrupt) as error:  # exit(), Ctrl-C or a raise at import
        path = key if is_path(key) else _module_file(key)
        raise PluginError(f"plugin: cannot import {module}: {_stopped(error, path)}") from None
    _LOADED[key] = loaded
    _loaded_new()
    return loaded


def _loaded_new() -> None:
    """After a new plugin: a compilation cache this process enabled moves to the directory
    of the plugin files loaded now (`jax_setup.refresh_compilation_cache`)."""
    from pimbot import jax_setup

    jax_setup.refresh_compilation_cache()


def _module_file(name: str) -> str | None:
    try:
        found = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None
    return found.origin if found is not None else None


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
    before = len(_LOADED)
    for entry in _entry_points():
        key = f"entry point {entry.name} ({entry.value})"
        if key in _LOADED:
            continue
        try:
            _LOADED[key] = entry.load()
        except (Exception, SystemExit, KeyboardInterrupt) as error:
            reason = _reason(error) if isinstance(error, Exception) else _stopped(error)
            raise PluginError(
                f"plugin: cannot import {entry.value} (entry point {entry.name}): {reason}"
            ) from None
    if len(_LOADED) != before:
        _loaded_new()
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


def loaded_files() -> list[str]:
    """The source files of the plugins this process has loaded."""
    files = [getattr(module, "__file__", None) for module in _LOADED.values()]
    return [f for f in files if f]


def file_sha256(path: str | Path) -> str | None:
    """The sha256 (hex) of a file's bytes; None if it cannot be read."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def provenance() -> list[dict[str, str | None]]:
    """What this process has loaded, for a run's config.json: one record per plugin, in
    load order: ``{"plugin": how it was named (entry point, module or path), "file": its
    source file, "sha256": the file's digest}`` (file and sha256 None where unknown)."""
    records = []
    for key, module in _LOADED.items():
        file = getattr(module, "__file__", None)
        file = str(Path(file).resolve()) if file else None
        records.append({"plugin": key, "file": file, "sha256": file_sha256(file) if file else None})
    return records


def missing(recorded: Iterable[dict]) -> list[tuple[str, str]]:
    """The plugins in `recorded` (a run's config.json "plugins") that this process has not
    loaded, neither from the recorded file nor from a file with the recorded sha256: (the
    file, or the plugin's name where none was recorded; how that file stands now:
    unchanged, changed since (its sha256 then and now), or gone)."""
    now = provenance()
    files = {r["file"] for r in now if r["file"]}
    digests = {r["sha256"] for r in now if r["sha256"]}
    absent = []
    for record in recorded:
        if not isinstance(record, dict):
            continue
        file, digest = record.get("file"), record.get("sha256")
        if (file and file in files) or (digest and digest in digests):
            continue
        absent.append((str(file or record.get("plugin") or "?"), _file_state(file, digest)))
    return absent


def _file_state(file: str | None, digest: str | None) -> str:
    """How a recorded plugin file stands now: unchanged, changed (sha256 then → now), gone."""
    if not file:
        return "no file recorded"
    current = file_sha256(file)
    if current is None:
        return "the file no longer exists"
    if digest and current != digest:
        return f"the file has changed since: sha256 {digest[:12]}… then, {current[:12]}… now"
    return f"sha256 {current[:12]}…, unchanged"


def failure_line(error: BaseException) -> str | None:
    """One line for an exception raised in a loaded plugin's code (at any time: making its
    env, its attack's parameters, tracing its hooks): ``FILE:LINE: Type: message`` at the
    innermost frame of its traceback in a plugin file; None when none of its frames is
    in one (pimbot's own error, reported as such)."""
    at = _line_in(error, loaded_files())
    if at is None:
        return None
    hint = f"; {DEBUG_VAR}=1 shows the traceback" if not debug_enabled() else ""
    return f"{at}: {_reason(error)} (in plugin code{hint})"


def debug_enabled(flag: bool = False) -> bool:
    """Whether a failure's full traceback is wanted: `flag` (a caller's own switch) or
    ``PIMBOT_DEBUG`` set to anything but empty, 0, false or no."""
    return flag or os.environ.get(DEBUG_VAR, "").strip().lower() not in ("", "0", "false", "no")


def full_traceback(error: BaseException) -> str:
    """The full traceback of `error` and of the exceptions it was raised from (a plugin's
    one-line error keeps the original as its cause)."""
    return "".join(traceback.format_exception(error))
