"""The `pimbot` command line.

    pimbot train ENV_ID [NAME=VALUE ...] --learner lio --seeds 10 --iterations 50000 --out DIR
    pimbot train --from RUN_DIR [--out NEW_DIR] [options that change it]
    pimbot sweep GRID.toml --out DIR [--backend local|ray] [--workers K] [--list]
    pimbot reproduce [--quick] --out DIR
    pimbot report DIR
    pimbot profile --env ENV_ID [NAME=VALUE ...] --controller benign|admo --duration S --out DIR
    pimbot envs | learners | attacks | defenses

Each command is a frozen dataclass (`pimbot.cli.commands`) parsed by tyro: its `--help`
shows every option's docstring and default (and the allowed values of a fixed set; the
listing commands name the registries' environments, learners, attacks and defenses), and
answers without importing JAX. Every command takes `--plugin MODULE` (repeatable; a module
name or a .py file) and `--config FILE` (TOML or YAML: the command's options, overridden by
the command line). An invocation finds its command, parses its options, loads the plugins
once (entry points, $PIMBOT_PLUGINS, the config's `plugin` key, --plugin), checks the names
against the registries, then runs the command. Bad input prints one line naming the field
and the allowed values and exits with status 2, before anything is written.
"""

from __future__ import annotations

import dataclasses
import signal
import sys

import pimbot
from pimbot import plugins
from pimbot.cli import commands
from pimbot.cli.interrupts import Terminated, raise_terminated
from pimbot.cli.parsing import (
    HELP,
    UsageError,
    check_names,
    defaults,
    option_values,
    parse_command,
    read_config_file,
    registry_names,
    saved_values,
    unknown_name,
)
from pimbot.errors import InvalidParameter

__all__ = ["UsageError", "command_paths", "main", "parse"]


def choices() -> dict[str, tuple[str, ...]]:
    """The registries' names as they are now (plugins loaded): registry -> names."""
    return {name: registry_names(name) for name in ("envs", "learners", "attacks", "defenses")}


def command_paths(tree: dict | None = None, prefix: tuple[str, ...] = ()):
    """Every command and subcommand, e.g. ("train",), ("robot",), ("robot", "eval")."""
    tree = commands.build() if tree is None else tree
    for name, node in tree.items():
        if not name:  # a group's description
            continue
        yield (*prefix, name)
        if isinstance(node, dict):
            yield from command_paths(node, (*prefix, name))


def _listing(path: tuple[str, ...], tree: dict) -> str:
    prog = " ".join(("pimbot", *path))
    version = " [--version]" if not path else ""
    lines = [f"usage: {prog}{version} COMMAND [OPTIONS]", ""]
    if not path:
        lines += [(pimbot.__doc__ or "").strip(), ""]
    lines.append("commands:")
    width = max(len(name) for name in tree) + 2
    lines += [f"  {name:<{width}}{commands.summary(node)}" for name, node in tree.items() if name]
    lines += [
        "",
        f"`{prog} COMMAND --help` shows a command's options, defaults and allowed values;",
        "every command takes --plugin MODULE and --config FILE.",
    ]
    return "\n".join(lines) + "\n"


def find_command(argv: list[str]) -> tuple[tuple[str, ...], type, list[str]] | None:
    """(command path, command class, the rest of `argv`); None after printing a listing of
    commands. Options before the command (`pimbot --plugin X train ...`) belong to it.

    Raises:
        UsageError: an unknown command, with the allowed ones and the closest.
        SystemExit: 0 after printing the version.
    """
    argv = list(argv)
    leading: list[str] = []
    while argv and argv[0].startswith("-") and argv[0] not in (*HELP, "--version"):
        take = 1 if "=" in argv[0] or len(argv) == 1 else 2
        leading, argv = leading + argv[:take], argv[take:]
    path: tuple[str, ...] = ()
    node: object = commands.build()
    while isinstance(node, dict):
        if not argv or argv[0] in HELP:
            print(_listing(path, node), end="")
            return None
        name, argv = argv[0], argv[1:]
        if name == "--version" and not path:
            print(f"pimbot {pimbot.__version__}")
            raise SystemExit(0)
        if name not in node or not name:
            what = "command" if not path else f"{' '.join(path)} command"
            raise UsageError(unknown_name(what, what, name, [n for n in node if n]))
        path, node = (*path, name), node[name]
    return path, node, leading + argv


@dataclasses.dataclass(frozen=True)
class Parsed:
    """A parsed command line: the command, and the --config/--from values it started from."""

    path: tuple[str, ...]
    command: commands.Command
    defaults: commands.Command | None = None
    """The --config/--from values (other fields their defaults); None without either."""
    source: str | None = None
    """Where `defaults` came from: the config file, or --from."""

    def check(self) -> None:
        """Raises UsageError unless every registry name is registered (plugins loaded) and
        InvalidParameter on a value out of range; a bad name from a file says so."""
        if self.defaults is not None:
            from pimbot.cli.handlers import check_from_plugins

            command = self.command  # before its names: its plugins, the code it was made with
            check_from_plugins(
                getattr(command, "from_run", None), getattr(command, "accept_changed_code", False)
            )
            check_names(self.defaults, self.source)
        check_names(self.command)
        self.command.check()


def parse_options(path: tuple[str, ...], cls: type, args: list[str]) -> Parsed:
    """The options `args` of command `cls`, over --config FILE and --from RUN_DIR values.

    Raises:
        UsageError: one line naming the field and the allowed values.
        SystemExit: 0 after printing the command's --help.
    """
    config_files = option_values(args, "--config")
    if len(config_files) > 1:
        raise UsageError("config: given more than once")
    file_values = read_config_file(config_files[0]) if config_files else {}
    takes_from = any(field.name == "from_run" for field in dataclasses.fields(cls))
    values = {**(_from_run(cls, args) if takes_from else {}), **file_values}
    source = config_files[0] if file_values else "--from"
    default = defaults(cls, values, source) if values else None
    prog = " ".join(("pimbot", *path))
    command = parse_command(cls, prog, args, default)
    return Parsed(path, command, default, source if values else None)


def parse(argv: list[str]) -> tuple[tuple[str, ...], object] | None:
    """(command path, command object); None after printing a listing of commands. Loads
    no plugin and checks no registry name (`main` does both).

    Raises:
        UsageError: one line naming the field and the allowed values.
        SystemExit: 0 after printing a command's --help.
    """
    found = find_command(argv)
    if found is None:
        return None
    parsed = parse_options(*found)
    return parsed.path, parsed.command


def _from_run(cls: type, argv: list[str]) -> dict:
    """`pimbot train --from RUN_DIR`: the saved run's options (and RUN_DIR as --out)."""
    runs = option_values(argv, "--from")
    if not runs:
        return {}
    from pathlib import Path

    from pimbot.training.runs import saved_run_config

    run_dir = Path(runs[-1])
    if not (run_dir / "config.json").is_file():
        raise UsageError(f"from: {run_dir} is not a pimbot run directory (no config.json)")
    values = saved_values(cls, saved_run_config(run_dir))
    if "--out" not in argv and not any(a.startswith("--out=") for a in argv):
        values["out"] = str(run_dir)
    return values


def run(argv: list[str]) -> int:
    """Finds, parses, checks and runs the command `argv` names; its exit status."""
    found = find_command(argv)
    if found is None:
        return 0
    path, cls, args = found
    if cls.all_cpu_cores and not any(arg in HELP for arg in args):  # --help runs nothing
        from pimbot import jax_setup

        jax_setup.use_all_cpu_cores()  # before --from, a plugin or the command imports jax
    parsed = parse_options(path, cls, args)
    loaded = plugins.load_plugins(parsed.command.plugin)  # the one load of this invocation
    if cls.compiles:  # keyed by the plugins just loaded; before a check compiles anything
        from pimbot import jax_setup

        jax_setup.enable_compilation_cache()
    if plugins.loaded():  # a plugin is checked for what it does before any work
        from pimbot import learners  # noqa: F401 (the built-ins a plugin's defaults name)
        from pimbot.contracts import preflight

        preflight.check_plugins()
    parsed.check()
    return parsed.command.run(loaded)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:  # not inside a host's own handler
        signal.signal(signal.SIGTERM, raise_terminated)
    try:
        return run(argv)
    except (UsageError, InvalidParameter, plugins.PluginError) as error:
        print(f"pimbot: error: {error}", file=sys.stderr)
        if plugins.debug_enabled() and error.__cause__ is not None:
            print(plugins.full_traceback(error), file=sys.stderr)
        return 2
    except KeyboardInterrupt as interrupt:
        what = "terminated" if isinstance(interrupt, Terminated) else "interrupted"
        print(f"pimbot: {what}; rerun the same command to resume", file=sys.stderr)
        return 143 if isinstance(interrupt, Terminated) else 130
    except RuntimeError as error:
        from pimbot.training.runner import Diverged

        if not isinstance(error, Diverged):
            return _plugin_failure(error)
        print(f"pimbot: error: {error}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # `pimbot envs | head`: the reader left, nothing to report
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except OSError as error:  # a place the checks could not foresee (e.g. /proc, a full disk)
        where = f"{error.filename}: " if error.filename else ""
        print(f"pimbot: error: {where}{error.strerror or error}", file=sys.stderr)
        return 1
    except Exception as error:  # an exception in a plugin's code: one line at its file
        return _plugin_failure(error)


def _plugin_failure(error: Exception) -> int:
    """Exit status 2 and one line at the plugin's file:line for an exception raised in a
    loaded plugin's code (the traceback with PIMBOT_DEBUG=1); pimbot's own errors re-raise."""
    line = plugins.failure_line(error)
    if line is None or plugins.debug_enabled():
        raise error
    print(f"pimbot: error: {line} (PIMBOT_DEBUG=1 shows the traceback)", file=sys.stderr)
    return 2
