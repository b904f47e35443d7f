"""From a command line to a command object: --config/--from defaults, then tyro; every
parse error becomes one line (`UsageError`).

tyro parses (https://brentyi.github.io/tyro/); when it refuses a command line, its own
report (a box of several lines) is kept from the terminal and `explain` names the problem
in one line from the command class itself: the option, what it needs and, for a name, the
allowed values and the closest ones. Only tyro's public API is used (`tyro.cli`, `tyro.conf`
markers), so any tyro from 1.0 on (pyproject's lower bound) works the same.
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import io
import os
import types
import typing
from pathlib import Path
from typing import Any

import tyro

from pimbot.cli.options import PAIRS, FromRun, Registered, Spelling
from pimbot.errors import InvalidParameter

HELP = ("-h", "--help")


class UsageError(Exception):
    """A bad command line; the message is printed as one line."""


def unknown_name(field: str, what: str, value: Any, allowed, source: str | None = None) -> str:
    """`field: [source: ]unknown WHAT 'value'; allowed: a, b; did you mean 'a'?` (the
    closest allowed names, by difflib's ratio, when any is close)."""
    allowed = [str(name) for name in allowed]
    where = f"{source}: " if source else ""
    text = f"{field}: {where}unknown {what} {value!r}; allowed: {', '.join(allowed)}"
    close = difflib.get_close_matches(str(value), allowed, n=3)
    if close:
        text += f"; did you mean {' or '.join(repr(name) for name in close)}?"
    return text


def registry_names(registry: str) -> tuple[str, ...]:
    """The names registry `registry` holds now (plugins included); imports the registries."""
    from pimbot import attacks, defenses, envs, learners

    modules = {"envs": envs, "learners": learners, "attacks": attacks, "defenses": defenses}
    return tuple(modules[registry].registered())


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


def _marker(metadata: tuple, kind: type):
    """The first metadata item of type `kind`, or None."""
    return next((item for item in metadata if isinstance(item, kind)), None)


def _fields(cls: type) -> list[tuple[dataclasses.Field, Any, tuple]]:
    """(field, type, Annotated metadata) of each field of command class `cls`."""
    hints = typing.get_type_hints(cls, include_extras=True)
    return [(field, *_strip(hints[field.name])) for field in dataclasses.fields(cls)]


def _without_none(kind) -> tuple[Any, bool]:
    """(`kind` without None, whether None was allowed) of an `X | None` annotation."""
    if typing.get_origin(kind) in (typing.Union, types.UnionType):
        args = typing.get_args(kind)
        if type(None) in args:
            (kind,) = [a for a in args if a is not type(None)]
            return kind, True
    return kind, False


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
    if isinstance(value, list | tuple) and all(
        isinstance(v, tuple) and len(v) == 2 for v in value
    ):  # a saved run's sorted (name, value) pairs
        value = dict(value)
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
    """A file value as the field's type, or a one-line UsageError naming the field.

    Registry names are checked later, once the plugins have loaded (`check_names`).
    """
    kind, metadata = _strip(hint)
    if PAIRS in metadata:
        return _pairs(field, value, source)
    kind, optional = _without_none(kind)
    if value is None and optional:
        return None
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if origin is typing.Literal:
        if value not in args:
            raise UsageError(unknown_name(field, "value", value, args, source))
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


def _option_name(field: dataclasses.Field, metadata: tuple) -> str:
    """The option's name as the command line spells it, without `--` (`from` for from_run)."""
    spelling = _marker(metadata, Spelling)
    return spelling.name if spelling is not None and spelling.name else field.name


def defaults(cls: type, values: dict[str, Any], source: str):
    """An instance of command `cls` whose fields are `values` (checked), other fields their
    defaults, and required fields without a value `tyro.MISSING` (still required)."""
    hints = typing.get_type_hints(cls, include_extras=True)
    fields = {field.name: (field, meta) for field, _, meta in _fields(cls)}
    names = {_option_name(f, meta): name for name, (f, meta) in fields.items()}
    kwargs = {}
    for key, value in values.items():
        name = names.get(key, key if key in fields else None)  # `from` or `from_run`
        if name is None or name == "config":
            allowed = ", ".join(n for n in names if n != "config")
            raise UsageError(f"config: {source}: {key!r} is not an option; allowed: {allowed}")
        kwargs[name] = _convert(name, hints[name], value, source)
    for name, (field, _) in fields.items():
        required = field.default is dataclasses.MISSING and field.default_factory is (
            dataclasses.MISSING
        )
        if required and name not in kwargs:
            kwargs[name] = tyro.MISSING
    instance = cls(**kwargs)
    try:
        instance.check()
    except InvalidParameter as error:
        raise UsageError(f"{error} ({source})") from None
    return instance


def saved_values(cls: type, run_config) -> dict[str, Any]:
    """The options of command `cls` that a saved `RunConfig` gives (`--from RUN_DIR`): each
    field named like a RunConfig field, and each marked `FromRun`."""
    saved = {field.name for field in dataclasses.fields(run_config)}
    values = {}
    for field, _, metadata in _fields(cls):
        source = _marker(metadata, FromRun)
        if source is not None:
            values[field.name] = source.convert(getattr(run_config, source.field))
        elif field.name in saved:
            values[field.name] = getattr(run_config, field.name)
    return values


def check_names(command, source: str | None = None) -> None:
    """Raises UsageError unless every registry name in `command` is registered (plugins
    loaded first); the message lists the allowed names and the closest ones."""
    for field, _, metadata in _fields(type(command)):
        marker = _marker(metadata, Registered)
        value = getattr(command, field.name)
        if marker is None or value is None or value is tyro.MISSING:
            continue
        allowed = registry_names(marker.registry)
        for name in value if isinstance(value, tuple) else (value,):
            if name not in allowed:
                raise UsageError(unknown_name(field.name, "value", name, allowed, source))


@dataclasses.dataclass(frozen=True)
class _Option:
    """What `explain` knows of one option of a command class."""

    field: str
    label: str  # how a message names it: --out, or env_id for a positional
    flags: tuple[str, ...]  # every spelling; () for a positional
    kind: Any  # the type of one value: bool, int, float, str or a Literal
    arity: str  # flag (bool), one, many (nargs *), append (one per occurrence)
    optional: bool  # the value may be None
    required: bool


def _grammar(cls: type, default) -> list[_Option]:
    """The options of command `cls` as tyro spells them (`--name-with-hyphens` or
    underscores, aliases, `--no-name` for a bool); a field is required if it has no default
    here nor in `default` (a --config/--from instance)."""
    options = []
    for field, kind, metadata in _fields(cls):
        kind, optional = _without_none(kind)
        many = typing.get_origin(kind) is tuple
        element = typing.get_args(kind)[0] if many else kind
        if kind is bool:
            arity = "flag"
        elif many:
            arity = "append" if tyro.conf.UseAppendAction in metadata else "many"
        else:
            arity = "one"
        spelling = _marker(metadata, Spelling)
        names = [_option_name(field, metadata), *(spelling.aliases if spelling else ())]
        names = [n.lstrip("-") for n in names]
        names += [f"no-{n}" for n in names] if arity == "flag" else []
        flags = tuple(f"--{n.replace(s, r)}" for n in names for s, r in (("_", "-"), ("-", "_")))
        positional = tyro.conf.Positional in metadata
        no_default = field.default is dataclasses.MISSING and (
            field.default_factory is dataclasses.MISSING
        )
        given = default is not None and getattr(default, field.name) is not tyro.MISSING
        options.append(
            _Option(
                field=field.name,
                label=field.name if positional else flags[0],
                flags=() if positional else flags,
                kind=element,
                arity=arity,
                optional=optional,
                required=no_default and not given,
            )
        )
    return options


def _is_flag(token: str) -> bool:
    if not token.startswith("-") or token == "-":
        return False
    try:
        float(token)  # a negative number is a value
    except ValueError:
        return True
    return False


def _value_problem(option: _Option, value: str) -> str | None:
    """One line on why `value` does not parse as `option`'s type, or None."""
    if option.optional and value == "None":
        return None
    if typing.get_origin(option.kind) is typing.Literal:
        allowed = [str(a) for a in typing.get_args(option.kind)]
        return None if value in allowed else unknown_name(option.field, "value", value, allowed)
    converters = {int: (int, "an integer"), float: (float, "a number")}
    if option.kind in converters:
        convert, what = converters[option.kind]
        try:
            convert(value)
        except ValueError:
            return f"{option.field}: must be {what}, got {value!r}"
    return None


def _read_flags(options: list[_Option], args: list[str], prog: str):
    """Walks `args`: (a problem with a flag or its values or None, the unknown flags,
    the positional tokens, the fields given)."""
    by_flag = {flag: option for option in options for flag in option.flags}
    unknown, loose, given = [], [], set()
    i = 0
    while i < len(args):
        token, i = args[i], i + 1
        if not _is_flag(token):
            loose.append(token)
            continue
        flag, has_value, inline = token.partition("=")
        option = by_flag.get(flag)
        if option is None:
            unknown.append(token)
            continue
        given.add(option.field)
        if option.arity == "flag":
            continue
        if has_value:
            values = [inline]
        else:
            end = i
            while end < len(args) and not _is_flag(args[end]):
                end += 1
                if option.arity != "many":
                    break
            values, i = args[i:end], end
        if not values and option.arity != "many":
            return f"{option.label}: expects a value (see `{prog} --help`)", unknown, loose, given
        problem = next(filter(None, (_value_problem(option, v) for v in values)), None)
        if problem:
            return problem, unknown, loose, given
    return None, unknown, loose, given


def explain(cls: type, args: list[str], default=None, prog: str = "pimbot") -> str | None:
    """One line naming what is wrong with `args` for command `cls`, or None where this
    reading finds nothing (tyro's own reason is used then)."""
    options = _grammar(cls, default)
    problem, unknown, loose, given = _read_flags(options, args, prog)
    if problem:
        return problem
    for option in (o for o in options if not o.flags):
        taken, loose = (loose, []) if option.arity != "one" else (loose[:1], loose[1:])
        if taken:
            given.add(option.field)
        problem = next(filter(None, (_value_problem(option, v) for v in taken)), None)
        if problem:
            return problem
    if unknown or loose:
        return f"unrecognized arguments: {' '.join(unknown + loose)} (see `{prog} --help`)"
    missing = [o.label for o in options if o.required and o.field not in given]
    return f"{', '.join(missing)}: required (see `{prog} --help`)" if missing else None


def _tyro_reason(report: str) -> str:
    """tyro's error report (a box of lines) as one line: its message, without the title,
    the rules and the help it quotes."""
    lines = [line.strip(" │╭╮╰╯─-|") for line in report.splitlines()]
    lines = [line for line in lines if line][1:]  # the first is the box's title
    ends = ("Argument helptext", "For full helptext", "Missing from")
    kept = []
    for line in lines:
        if line.startswith(ends):
            break
        kept.append(line)
    return " ".join(" ".join(kept).split())


def parse_command(cls: type, prog: str, args: list[str], default=None):
    """`tyro.cli` of one command class; a refused command line is one UsageError line.

    With -h/--help tyro prints the help and exits 0. Otherwise tyro's own report is
    captured (not shown) and replaced by `explain`'s line.
    """
    columns = os.environ.get("COLUMNS")
    if columns is None:
        os.environ["COLUMNS"] = "100"  # help boxes a readable width when piped
    try:
        if any(arg in HELP for arg in args):
            return tyro.cli(cls, prog=prog, args=args, default=default)
        report = io.StringIO()
        try:
            with contextlib.redirect_stdout(report), contextlib.redirect_stderr(report):
                return tyro.cli(cls, prog=prog, args=args, default=default, console_outputs=False)
        except SystemExit as exit:
            if exit.code in (0, None):
                raise
            reason = explain(cls, args, default, prog)
            if reason is None:
                tyro_reason = _tyro_reason(report.getvalue()) or "invalid command line"
                reason = f"{tyro_reason} (see `{prog} --help`)"
            raise UsageError(reason) from None
    finally:
        if columns is None:
            os.environ.pop("COLUMNS", None)
