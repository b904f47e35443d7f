"""Field docstrings of dataclasses (the string literal under a field), for listings."""

from __future__ import annotations

import ast
import dataclasses
import functools
import inspect
import textwrap

from pimbot.contracts.params import describe_range


@functools.cache
def _own_field_docs(cls: type) -> dict[str, str]:
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):  # built in a REPL, or no source file
        return {}
    tree = ast.parse(source)
    body = next((n.body for n in ast.walk(tree) if isinstance(n, ast.ClassDef)), [])
    docs = {}
    for node, following in zip(body, body[1:], strict=False):
        is_doc = isinstance(following, ast.Expr) and isinstance(
            getattr(following, "value", None), ast.Constant
        )
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and is_doc:
            value = following.value.value
            if isinstance(value, str):
                docs[node.target.id] = " ".join(value.split())
    return docs


def field_docs(cls: type) -> dict[str, str]:
    """name -> docstring of every documented field of `cls`, base classes included."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if dataclasses.is_dataclass(klass):
            docs.update(_own_field_docs(klass))
    return docs


def describe(
    cls: type, values: dict, indent: str = "    ", ranges: dict | None = None
) -> list[str]:
    """`name = value` lines (with the allowed range, where `ranges` gives one), each
    followed by the field's docstring when it has one."""
    docs = field_docs(cls)
    lines = []
    for name, value in values.items():
        bounds = (ranges or {}).get(name)
        allowed = f"  (allowed: {describe_range(bounds)})" if bounds else ""
        lines.append(f"{indent}{name} = {value!r}{allowed}")
        if docs.get(name):
            lines += textwrap.wrap(
                docs[name], 92, initial_indent=indent + "    ", subsequent_indent=indent + "    "
            )
    return lines
