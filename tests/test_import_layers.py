"""Inside each folder of the package the modules import one way: no import cycle.

tests/test_layers.py keeps the folders' graph acyclic; this keeps each folder's own
graph acyclic too, counting the imports inside functions as well as those at the top
(a cycle of function-level imports still ties the modules into one, and bites in the
order a later edit imports them). An import under `if TYPE_CHECKING:` runs nowhere and
is not counted. Pure `ast`: nothing of pimbot is imported.

A cycle is removed by moving the piece both sides use to the lower module it belongs
to, never by moving an import into a function.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from graphlib import CycleError, TopologicalSorter
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
FOLDERS = sorted(
    path.name for path in (SRC / "pimbot").iterdir() if (path / "__init__.py").is_file()
)

Edges = dict[str, dict[str, int]]
"""module -> {module of the same folder it imports: the line of the first such import}."""


def module_files(folder: Path, package: str) -> dict[str, Path]:
    """Every module under `folder` (the package `package`, its subpackages included)."""
    files = {}
    for path in sorted(folder.rglob("*.py")):
        parts = path.relative_to(folder).with_suffix("").parts
        parts = parts[:-1] if parts[-1] == "__init__" else parts
        files[".".join((package, *parts))] = path
    return files


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def import_statements(node: ast.AST) -> Iterator[ast.Import | ast.ImportFrom]:
    """The imports anywhere in `node` (functions, classes, `try` and `if` blocks included),
    but those under `if TYPE_CHECKING:`."""
    if isinstance(node, ast.Import | ast.ImportFrom):
        yield node
        return
    type_checking = isinstance(node, ast.If) and _is_type_checking(node)
    for child in node.orelse if type_checking else ast.iter_child_nodes(node):
        yield from import_statements(child)


def _base(module: str, is_package: bool, statement: ast.ImportFrom) -> str:
    """The module a `from` import names, its dots resolved against `module`."""
    if not statement.level:
        return statement.module or ""
    parts = module.split(".")
    parts = parts if is_package else parts[:-1]
    parts = parts[: len(parts) - (statement.level - 1)]
    return ".".join([*parts, *([statement.module] if statement.module else [])])


def imported_names(module: str, path: Path, known: set[str]) -> Iterator[tuple[str, int]]:
    """(module of `known`, line) for each import in `module`'s file: `from X import Y`
    imports X.Y where that is a module, else X."""
    for statement in import_statements(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(statement, ast.Import):
            for alias in statement.names:
                yield alias.name, statement.lineno
            continue
        base = _base(module, path.name == "__init__.py", statement)
        for alias in statement.names:
            submodule = f"{base}.{alias.name}"
            yield (submodule if submodule in known else base), statement.lineno


def import_graph(folder: Path, package: str) -> Edges:
    """Each module of `package` -> the modules of `package` it imports, at any depth."""
    files = module_files(folder, package)
    graph: Edges = {name: {} for name in files}
    for name, path in files.items():
        for target, line in imported_names(name, path, set(files)):
            if target in files and target != name:
                graph[name].setdefault(target, line)
    return graph


def find_cycle(graph: Edges) -> str | None:
    """One import cycle of `graph`, each edge with its line ("a -> b (line 3) -> a (line
    9)"); None where there is none."""
    try:
        TopologicalSorter(graph).prepare()
    except CycleError as error:
        cycle = list(reversed(error.args[1]))  # graphlib lists it against the edges
        steps = [
            f"{after} (line {graph[before][after]})"
            for before, after in zip(cycle, cycle[1:], strict=False)
        ]
        return " -> ".join([cycle[0], *steps])
    return None


@pytest.mark.parametrize("folder", FOLDERS)
def test_the_modules_of_a_folder_import_without_a_cycle(folder):
    graph = import_graph(SRC / "pimbot" / folder, f"pimbot.{folder}")
    cycle = find_cycle(graph)
    assert cycle is None, f"import cycle in pimbot.{folder}: {cycle}"


def _write(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    return root


def test_a_cycle_through_an_import_inside_a_function_is_named(tmp_path):
    folder = _write(
        tmp_path / "pkg",
        {
            "__init__.py": "",
            "low.py": "def f():\n    from pkg.high import g\n",
            "high.py": "from . import low\n",
            "typed.py": "import typing\nif typing.TYPE_CHECKING:\n    import pkg.user\n",
            "user.py": "from pkg import typed\n",
        },
    )
    graph = import_graph(folder, "pkg")
    assert graph["pkg.low"] == {"pkg.high": 2}
    assert graph["pkg.high"] == {"pkg.low": 1}
    assert graph["pkg.typed"] == {}  # a TYPE_CHECKING import runs nowhere
    assert find_cycle(graph) in (
        "pkg.low -> pkg.high (line 2) -> pkg.low (line 1)",
        "pkg.high -> pkg.low (line 1) -> pkg.high (line 2)",
    )


def test_a_name_of_a_package_is_an_import_of_its_init_and_a_submodule_of_its_own(tmp_path):
    folder = _write(
        tmp_path / "pkg",
        {
            "__init__.py": "from pkg.a import A\n",
            "a.py": "A = 1\n",
            "b.py": "from pkg import A, a\nimport pkg.a\n",
        },
    )
    graph = import_graph(folder, "pkg")
    assert graph["pkg.b"] == {"pkg": 1, "pkg.a": 1}
    assert find_cycle(graph) is None
