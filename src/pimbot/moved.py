"""Public modules and names that moved, and the aliases that keep old imports working.

A moved module keeps an alias for one release: importing it by its old name warns once
(`PimbotDeprecationWarning`, a `DeprecationWarning`, naming the new place and the release
that removes the alias) and gives a module whose names are the new module's. `import
pimbot` puts the alias finder last on `sys.meta_path` (`install`), so a module that
exists is never shadowed; no alias is a file of its own.

    import pimbot.rollout                       # warns: moved to pimbot.contracts.rollout
    from pimbot.experiment.runner import train  # warns: moved to pimbot.training.runner

CHANGELOG.md lists every entry of `MOVED_MODULES` and `MOVED_NAMES`;
tests/test_plugin_names.py imports each old name and checks its warning.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import types
import warnings


class PimbotDeprecationWarning(DeprecationWarning):
    """A pimbot name that moved or changed: it still works, and goes in the release named.

    Shown by default (`import pimbot` adds a "default" filter for this category unless
    the interpreter was given -W options), since a plugin is not `__main__`, where
    Python shows a `DeprecationWarning` by default."""


SINCE = "0.2.0"
"""The release in which the names below moved (their aliases were added)."""
REMOVED_IN = "0.3.0"
"""The release that removes the aliases."""

MOVED_MODULES: dict[str, str | None] = {
    "pimbot.rollout": "pimbot.contracts.rollout",
    "pimbot.experiment": None,  # split into pimbot.training and pimbot.suites (below)
    "pimbot.experiment.config": "pimbot.training.config",
    "pimbot.experiment.memory": "pimbot.training.memory",
    "pimbot.experiment.programs": "pimbot.training.programs",
    "pimbot.experiment.progress": "pimbot.training.progress",
    "pimbot.experiment.runner": "pimbot.training.runner",
    "pimbot.experiment.runs": "pimbot.training.runs",
    "pimbot.experiment.store": "pimbot.training.store",
    "pimbot.experiment.summary": "pimbot.training.summary",
    "pimbot.experiment.tracking": "pimbot.training.tracking",
    "pimbot.experiment.grid": "pimbot.suites.grid",
    "pimbot.experiment.jobs": "pimbot.suites.jobs",
    "pimbot.experiment.presets": "pimbot.suites.presets",
    "pimbot.experiment.sweep": "pimbot.suites.sweep",
    "pimbot.analysis.statistics": "pimbot.statistics",
    "pimbot.defenses.cli": "pimbot.cli.defenses",
    "pimbot.robot.cli": "pimbot.cli.robot",
}
"""Old module -> the module that holds its names now (None: a package that only held
modules, each listed on its own)."""

MOVED_NAMES: dict[tuple[str, str], str] = {
    ("pimbot.experiment.programs", "Strategies"): "pimbot.attacks.strategy_union",
    ("pimbot.experiment.programs", "member_kind"): "pimbot.attacks.strategy_union",
    ("pimbot.experiment.programs", "shareable"): "pimbot.attacks.strategy_union",
    ("pimbot.experiment.programs", "shared_attack"): "pimbot.attacks.strategy_union",
}
"""(old module, name) -> the module that holds the name now, where it is not the module
`MOVED_MODULES` gives."""


def _message(old: str, new: str | None) -> str:
    if new is None:
        children = sorted(
            {v.rsplit(".", 1)[0] for k, v in MOVED_MODULES.items() if v and k.startswith(old + ".")}
        )
        where = f"its modules moved to {' and '.join(children)}"
    else:
        where = f"it moved to {new}"
    return f"{old} is deprecated: {where} in pimbot {SINCE}; this alias goes in {REMOVED_IN}"


class AliasModule(types.ModuleType):
    """The module an old name imports: every attribute is read from the new module (or,
    for a name in `MOVED_NAMES`, from the module that holds it now)."""

    def __init__(self, old: str, new: str | None) -> None:
        super().__init__(old, _message(old, new))
        self._pimbot_new = new

    def __getattr__(self, name: str):
        if name.startswith("__"):
            raise AttributeError(name)
        target = MOVED_NAMES.get((self.__name__, name), self._pimbot_new)
        if target is None:
            raise AttributeError(f"module {self.__name__!r} has no attribute {name!r}")
        return getattr(importlib.import_module(target), name)

    def __dir__(self) -> list[str]:
        names = set(super().__dir__())
        if self._pimbot_new is not None:
            names |= set(dir(importlib.import_module(self._pimbot_new)))
        return sorted(names | {n for m, n in MOVED_NAMES if m == self.__name__})


class _AliasFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds the old names of `MOVED_MODULES` (after every real finder has not)."""

    def find_spec(self, name, path=None, target=None):
        if name not in MOVED_MODULES:
            return None
        return importlib.machinery.ModuleSpec(name, self, is_package=MOVED_MODULES[name] is None)

    def create_module(self, spec):
        new = MOVED_MODULES[spec.name]
        if new is not None:  # a package of modules only: each module warns, not it too
            # stacklevel 2 is the importing code: warnings skips the import system's frames
            warnings.warn(_message(spec.name, new), PimbotDeprecationWarning, stacklevel=2)
        return AliasModule(spec.name, new)

    def exec_module(self, module) -> None:
        if module._pimbot_new is not None:  # a missing target fails at the import
            importlib.import_module(module._pimbot_new)


_FINDER = _AliasFinder()


def install() -> None:
    """Puts the alias finder last on `sys.meta_path` (once) and, unless the interpreter was
    given -W options, shows `PimbotDeprecationWarning` by default."""
    if not any(isinstance(f, _AliasFinder) for f in sys.meta_path):
        sys.meta_path.append(_FINDER)
    if not sys.warnoptions:
        warnings.filterwarnings("default", category=PimbotDeprecationWarning)
