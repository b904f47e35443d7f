"""The package's folders are its layers: each imports downward only, the import graph
between folders has no cycle, and every module imports on its own.

Folders, lowest layer first (a module may import its own folder and lower layers):
  0 pimbot (its own modules)     the ground floor: errors, statistics, jax setup, nets,
                                 the plugin loader
  1 envs                         the pure environments and their registry
  2 contracts                    the episode (rollout) and the protocols plugins implement
  3 attacks, defenses, learners  the built-in plugins (registered like a user's)
  4 training                     configs, runs, the compiled training loop, run directories
  5 profiling, robot             applications of trained runs
  6 suites                       job kinds, grids, the paper's suite, the sweep engine
  7 analysis                     reports from run directories
  8 cli                          every command's command line
"""

from __future__ import annotations

import ast
import os
import sys
from graphlib import CycleError, TopologicalSorter
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = SRC / "pimbot"

LAYERS = {  # folder -> layer; a module belongs to the top folder it sits in
    "pimbot": 0,
    "pimbot.envs": 1,
    "pimbot.contracts": 2,
    "pimbot.attacks": 3,
    "pimbot.defenses": 3,
    "pimbot.learners": 3,
    "pimbot.training": 4,
    "pimbot.profiling": 5,
    "pimbot.robot": 5,
    "pimbot.suites": 6,
    "pimbot.analysis": 7,
    "pimbot.cli": 8,
}


def folder(module: str) -> str:
    """The top folder `module` sits in: `pimbot` for the package's own modules."""
    parts = module.split(".")
    if len(parts) == 1 or not (SRC / "pimbot" / parts[1]).is_dir():
        return "pimbot"
    return ".".join(parts[:2])


def layer(module: str) -> int:
    return LAYERS[folder(module)]


def modules() -> list[str]:
    names = []
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(SRC).with_suffix("").parts
        names.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return names


def _is_module(name: str) -> bool:
    path = SRC.joinpath(*name.split("."))
    return path.is_dir() or path.with_suffix(".py").exists()


def imported(module: str) -> set[str]:
    """Every pimbot module `module` imports, at the top or inside functions."""
    parts = module.split(".")
    path = SRC.joinpath(*parts)
    path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("pimbot"):
            found.add(node.module)
            found |= {f"{node.module}.{a.name}" for a in node.names}
        elif isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("pimbot")}
    return {name for name in found if _is_module(name)}


def _module_level(statements: list[ast.stmt]):
    """The statements a module runs on import: its body, into `try`/`with`/`if` blocks,
    not into functions or classes."""
    for node in statements:
        yield node
        if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            for field in ("body", "orelse", "finalbody", "handlers"):
                yield from _module_level(getattr(node, field, []))


def third_party() -> list[str]:
    """The non-standard modules the package imports when one of its modules is imported
    (imports inside functions are left to the calls that need them), and the names
    `from` imports take from them (some are modules, e.g. `from scipy import stats`)."""
    names = set()
    for path in PACKAGE.rglob("*.py"):
        for node in _module_level(ast.parse(path.read_text()).body):
            if isinstance(node, ast.ImportFrom) and node.module and not node.level:
                names.add(node.module)  # and what it names, where that is a module
                names |= {f"{node.module}.{a.name}" for a in node.names}
            elif isinstance(node, ast.Import):
                names |= {a.name for a in node.names}
    standard = set(sys.stdlib_module_names) | {"pimbot", "__future__"}
    return sorted(n for n in names if n.split(".")[0] not in standard)


def folder_graph() -> dict[str, set[str]]:
    """folder -> the other folders its modules import (at the top or inside functions)."""
    graph: dict[str, set[str]] = {name: set() for name in LAYERS}
    for module in modules():
        graph.setdefault(folder(module), set()).update(
            folder(dep) for dep in imported(module) if folder(dep) != folder(module)
        )
    return graph


def test_the_layer_table_names_exactly_the_folders():
    folders = {"pimbot"} | {
        f"pimbot.{path.name}" for path in PACKAGE.iterdir() if (path / "__init__.py").exists()
    }
    assert folders == set(LAYERS)


def test_the_import_graph_between_folders_has_no_cycle():
    graph = folder_graph()
    for name in sorted(graph, key=lambda n: (LAYERS.get(n, -1), n)):
        print(f"{name} -> {', '.join(sorted(graph[name])) or '(nothing)'}")
    try:
        order = list(TopologicalSorter(graph).static_order())
    except CycleError as error:
        pytest.fail(f"import cycle between folders: {' -> '.join(error.args[1])}")
    assert set(order) == set(graph)


def test_every_module_has_a_layer_and_no_import_goes_up():
    upward = [
        f"{module} (layer {layer(module)}) imports {dep} (layer {layer(dep)})"
        for module in modules()
        for dep in sorted(imported(module))
        if layer(dep) > layer(module)
    ]
    assert not upward, "\n".join(upward)


def test_contracts_import_no_plugin():
    for module in modules():
        if module.startswith("pimbot.contracts"):
            plugins = [d for d in imported(module) if layer(d) > LAYERS["pimbot.contracts"]]
            assert not plugins, f"{module} imports {plugins}"


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs fork")
def test_every_module_imports_first_in_a_fresh_interpreter():
    """Each module is the first pimbot module a fresh process imports (an import cycle
    that only bites in some import order fails here). One parent process pre-imports
    the third-party modules (those the package imports on import that are installed and
    start no JAX backend, tried each library in a child first); each module is imported in
    a forked child of it."""
    import subprocess

    script = f"""
import os, sys, importlib, traceback
sys.path.insert(0, {str(SRC)!r})
from jax._src import xla_bridge
def preload(names):  # the third-party modules that import without starting a JAX backend
    for name in names:
        try:
            importlib.import_module(name)
        except ImportError:  # not a module, or an optional extra that is not installed
            pass
    return not xla_bridge.backends_are_initialized()  # forking a started backend can hang
by_library = {{}}
for name in {third_party()!r}:
    by_library.setdefault(name.split(".")[0], []).append(name)
for names in by_library.values():
    pid = os.fork()
    if pid == 0:  # a trial in a child
        try:
            os._exit(0 if preload(names) else 1)
        except BaseException:
            os._exit(1)
    if os.waitpid(pid, 0)[1] == 0:
        preload(names)
assert not [m for m in sys.modules if m == "pimbot" or m.startswith("pimbot.")]
failed = []
for name in {modules()!r}:
    pid = os.fork()
    if pid == 0:
        try:
            importlib.import_module(name)
        except BaseException:
            traceback.print_exc()
            os._exit(1)
        os._exit(0)
    _, status = os.waitpid(pid, 0)
    if status != 0:
        failed.append(name)
print("FAILED:", failed)
sys.exit(1 if failed else 0)
"""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=600
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
