"""From a command line to a command object: plugins first, then --config/--from defaults,
then tyro; every parse error becomes one line (`UsageError`)."""

from __future__ import annotations

import dataclasses
import os
import types
import typing
from pathlib import Path
from typing import Any

import tyro

from pimbot.cli import commands
from pimbot.envs.core import InvalidParameter

try:  # tyro's parse-error hook (tyro >= 1.0.17, pinned in pyproject.toml)
    from tyro._errors import (
        BadValue,
        InstantiationFailure,
        InvalidChoice,
        MissingArgs,
        UnrecognizedArgs,
        on_parse_error,
    )
except ImportError:  # pragma: no cover - another tyro: its own (multi-line) messages
    on_parse_error = None


class UsageError(Exception):
    """A bad command line; the message is printed as one line."""


def option_values(argv: list[str], flag: str) -> list[str]:
    """The values of `flag` (`--flag V` or `--flag=V`) anywhere in `argv`."""
    values = []
    for i, token in enumerate(argv):
        if token == flag and i + 1 < len(argv):
            values.append(argv[i + 1])
        elif token.startswith(flag + "="):
            values.append(token[len(flag) + 1 :])
    return values


def read_config_file(path: str) -> dict[str, Any]:
    """A --config file's table (TOML or YAML), or a one-line UsageError."""
    file = Path(path)
    if not file.is_file():
        raise UsageError(f"config: {path} is not a file")
    suffix = file.suffix.lower()
    try:
        text = file.read_text(encoding="utf-8")
        if suffix == ".toml":
            import tomllib

            table = tomllib.loads(text)
        elif suffix in (".yaml", ".yml"):
            import yaml

            table = yaml.safe_load(text)
        else:
            raise UsageError(f"config: {path} must end in .toml, .yaml or .yml")
    except UsageError:
        raise
    except Exception as error:  # tomllib/yaml syntax, encoding
        reason = " ".join(str(error).split())
        raise UsageError(f"config: cannot read {path}: {reason}") from None
    if table is None:
        return {}
    if not isinstance(table, dict):
        raise UsageError(f"config: {path} must hold a table of options, got {type(table).__name__}")
    return {str(k).replace("-", "_"): v for k, v in table.items()}


def _strip(hint) -> tuple[Any, tuple]:
    """(type, Annotated metadata) of a field annotation."""
    metadata: tuple = ()
    while typing.get_origin(hint) is typing.Annotated:
        metadata += hint.__metadata__
        hint = hint.__origin__
    return hint, metadata


def _pair_text(name: str, value: Any) -> str:
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, list | tuple):
        text = ",".join(str(v) for v in value)
    else:
        text = str(value)
    return f"{name}={text}"


def _pairs(field: str, value: Any, source: str) -> tuple[str, ...]:
    if isinstance(value, str):
        return (value,)
    if isinstance(value, dict):
        pairs = []
        for key, item in value.items():
            if isinstance(item, dict):  # defense_param: {defense: {param: value}}
                pairs += [_pair_text(f"{key}.{k}", v) for k, v in item.items()]
            else:
                pairs.append(_pair_text(str(key), item))
        return tuple(pairs)
    if isinstance(value, list | tuple) and all(isinstance(v, str) for v in value):
        return tuple(value)
    raise UsageError(f"{field}: {source}: must be a table or a list of NAME=VALUE strings")


def _convert(field: str, hint, value: Any, source: str) -> Any:
    """A file value as the field's type, or a one-line UsageError naming the field."""
    kind, metadata = _strip(hint)
    if commands.PAIRS in metadata:
        return _pairs(field, value, source)
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        (kind,) = [a for a in args if a is not type(None)]
        return _convert(field, kind, value, source)
    if origin is typing.Literal:
        if value not in args:
            raise UsageError(
                f"{field}: {source}: unknown value {value!r}; allowed: {', '.join(map(str, args))}"
            )
        return value
    if origin is tuple:
        items = value if isinstance(value, list | tuple) else [value]
        return tuple(_convert(field, args[0], item, source) for item in items)
    ok = {
        bool: isinstance(value, bool),
        int: isinstance(value, int) and not isinstance(value, bool),
        float: isinstance(value, int | float) and not isinstance(value, bool),
        str: isinstance(value, str),
    }.get(kind, True)
    if not ok:
        what = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}
        raise UsageError(f"{field}: {source}: must be {what[kind]}, got {value!r}")
    return float(value) if kind is float else value


def defaults(cls: type, values: dict[str, Any], source: str):
    """An instance of command `cls` whose fields are `values` (checked), other fields their
    defaults, and required fields without a value `tyro.MISSING` (still required)."""
    hints = typing.get_type_hints(cls, include_extras=True)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    aliases = {"from": "from_run"}
    names = {v: k for k, v in aliases.items()}
    kwargs = {}
    for key, value in values.items():
        name = aliases.get(key, key)
        if name not in fields or name in ("config",):
            allowed = ", ".join(names.get(n, n) for n in fields if n != "config")
            raise UsageError(f"config: {source}: {key!r} is not an option; allowed: {allowed}")
        kwargs[name] = _convert(name, hints[name], value, source)
    for name, field in fields.items():
        required = field.default is dataclasses.MISSING and field.default_factory is (
            dataclasses.MISSING
        )
        if required and name not in kwargs:
            kwargs[name] = tyro.MISSING
    try:
        return cls(**kwargs)
    except InvalidParameter as error:
        raise UsageError(f"{error} ({source})") from None


def _argument_name(argument) -> str:
    field = argument.field
    if tyro.conf.Positional in field.markers:
        return field.intern_name
    return "--" + {"from_run": "from"}.get(field.intern_name, field.intern_name).replace("_", "-")


def _one_line(event) -> None:
    """tyro's parse-error hook: raise the event as one UsageError line."""
    if isinstance(event, InvalidChoice):
        name = event.argument.field.intern_name
        raise UsageError(
            f"{name}: unknown value {event.value!r}; allowed: {', '.join(event.choices)}"
        )
    if isinstance(event, InstantiationFailure):
        message = " ".join(event.message.split())
        if event.argument is not None and not message.startswith(event.argument.field.intern_name):
            name = event.argument.field.intern_name
            kind = _strip(event.argument.field.type)[0]
            expected = {int: "an integer", float: "a number"}.get(kind)
            if expected:
                message = f"must be {expected}, got {message.rpartition(': ')[2]}"
            message = f"{name}: {message}"
        raise UsageError(message)
    if isinstance(event, MissingArgs):
        names = [_argument_name(a.arg) for a in event.missing_arguments]
        raise UsageError(f"{', '.join(names)}: required (see `{event.prog} --help`)")
    if isinstance(event, BadValue):
        raise UsageError(
            f"{_argument_name(event.argument)}: expects a value (see `{event.prog} --help`)"
        )
    if isinstance(event, UnrecognizedArgs):
        raise UsageError(
            f"unrecognized arguments: {' '.join(event.tokens)} (see `{event.prog} --help`)"
        )
    prog = getattr(event, "prog", "pimbot")
    raise UsageError(f"invalid command line (see `{prog} --help`)")


def parse_command(cls: type, prog: str, args: list[str], default=None):
    """`tyro.cli` of one command class with one-line errors."""
    columns = os.environ.get("COLUMNS")
    if columns is None:
        os.environ["COLUMNS"] = "100"  # help boxes a readable width when piped
    try:
        if on_parse_error is None:  # pragma: no cover
            return tyro.cli(cls, prog=prog, args=args, default=default)
        with on_parse_error(_one_line):
            return tyro.cli(cls, prog=prog, args=args, default=default)
    finally:
        if columns is None:
            os.environ.pop("COLUMNS", None)
