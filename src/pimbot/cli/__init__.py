"""The `pimbot` command line.

    pimbot train ENV_ID [NAME=VALUE ...] --learner lio --seeds 10 --iterations 50000 --out DIR
    pimbot train --from RUN_DIR [--out NEW_DIR] [options that change it]
    pimbot sweep GRID.toml --out DIR [--backend local|ray] [--workers K] [--list]
    pimbot reproduce [--quick] --out DIR
    pimbot report DIR
    pimbot profile --env ENV_ID [NAME=VALUE ...] --controller benign|admo --duration S --out DIR
    pimbot envs | learners | attacks | defenses

Each command is a frozen dataclass (`pimbot.cli.commands`) parsed by tyro: its
`--help` shows every option's docstring, default and allowed values. Every
command takes `--plugin MODULE` (repeatable; a module name or a .py file,
loaded before the command line is read, so its names are allowed values) and
`--config FILE` (TOML or YAML: the command's options, overridden by the command
line). Bad input prints one line naming the field and the allowed values and
exits with status 2, before anything is written.
"""

from __future__ import annotations

import sys

import pimbot
from pimbot import jax_setup, plugins
from pimbot.cli import commands
from pimbot.cli.parsing import UsageError, defaults, option_values, parse_command, read_config_file

__all__ = ["UsageError", "command_paths", "main", "parse"]

HELP = ("-h", "--help")


def choices() -> commands.Choices:
    """The allowed names, from the registries as they are now (plugins loaded)."""
    from pimbot import attacks, defenses, envs, learners
    from pimbot.cli.robot import RENDERERS
    from pimbot.profiling.decision_loop import CONTROLLERS
    from pimbot.suites import sweep
    from pimbot.training import tracking

    return commands.Choices(
        env_ids=tuple(envs.registered()),
        learners=tuple(learners.registered()),
        attacks=tuple(attacks.registered()),
        defenses=tuple(defenses.registered()),
        controllers=tuple(CONTROLLERS),
        backends=tuple(sweep.BACKENDS),
        trackers=tuple(tracking.BACKENDS),
        renderers=tuple(RENDERERS),
    )


def command_paths(tree: dict | None = None, prefix: tuple[str, ...] = ()):
    """Every command and subcommand, e.g. ("train",), ("robot",), ("robot", "eval")."""
    tree = commands.build(choices()) if tree is None else tree
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


def parse(argv: list[str]) -> tuple[tuple[str, ...], object] | None:
    """(command path, command object); None after printing a listing of commands.

    Raises:
        UsageError: one line naming the field and the allowed values.
        SystemExit: 0 after printing a command's --help.
    """
    argv = list(argv)
    config_files = option_values(argv, "--config")
    if len(config_files) > 1:
        raise UsageError("config: given more than once")
    file_values = read_config_file(config_files[0]) if config_files else {}
    file_plugins = file_values.get("plugin", [])
    file_plugins = [file_plugins] if isinstance(file_plugins, str) else list(file_plugins)
    plugins.load_plugins([*file_plugins, *option_values(argv, "--plugin")])
    tree = commands.build(choices())
    # `pimbot --plugin X train ...`: options before the command belong to the command.
    leading: list[str] = []
    while argv and argv[0].startswith("-") and argv[0] not in (*HELP, "--version"):
        take = 1 if "=" in argv[0] or len(argv) == 1 else 2
        leading, argv = leading + argv[:take], argv[take:]
    path: tuple[str, ...] = ()
    node: object = tree
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
            allowed = ", ".join(n for n in node if n)
            raise UsageError(f"{what}: unknown {what} {name!r}; allowed: {allowed}")
        path, node = (*path, name), node[name]
    argv = leading + argv
    cls = node
    values = dict(_from_run(argv) if path == ("train",) else {})
    values.update(file_values)
    default = (
        defaults(cls, values, config_files[0] if file_values else "--from") if values else None
    )
    prog = " ".join(("pimbot", *path))
    return path, parse_command(cls, prog, argv, default)


def _from_run(argv: list[str]) -> dict:
    """`pimbot train --from RUN_DIR`: the saved run's options (and RUN_DIR as --out)."""
    runs = option_values(argv, "--from")
    if not runs:
        return {}
    from pathlib import Path

    from pimbot.training.runs import saved_run_config

    run_dir = Path(runs[-1])
    if not (run_dir / "config.json").is_file():
        raise UsageError(f"from: {run_dir} is not a pimbot run directory (no config.json)")
    saved = saved_run_config(run_dir)
    defense_params = {name: dict(params) for name, params in saved.defenses if params}
    values = {
        "env_id": saved.env_id,
        "env_params": dict(saved.env_params),
        "learner": saved.learner,
        "hp": dict(saved.hparams),
        "seeds": saved.seeds,
        "first_seed": saved.first_seed,
        "iterations": saved.iterations,
        "eval_period": saved.eval_period,
        "eval_episodes": saved.eval_episodes,
        "attack": saved.attack,
        "attack_param": dict(saved.attack_params),
        "defense": [name for name, _ in saved.defenses],
        "defense_param": defense_params,
    }
    if "--out" not in argv and not any(a.startswith("--out=") for a in argv):
        values["out"] = str(run_dir)
    return values


def main(argv: list[str] | None = None) -> int:
    from pimbot.cli import handlers
    from pimbot.envs.core import InvalidParameter

    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        if argv[:1] == ["train"]:
            jax_setup.use_all_cpu_cores()  # before a plugin's first jax computation
        parsed = parse(argv)
        if parsed is None:
            return 0
        path, command = parsed
        loaded = plugins.load_plugins(command.plugin)
        return handlers.dispatch(path, command, loaded)
    except (UsageError, InvalidParameter, plugins.PluginError) as error:
        print(f"pimbot: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("pimbot: interrupted; rerun the same command to resume", file=sys.stderr)
        return 130
    except RuntimeError as error:
        from pimbot.training.runner import Diverged

        if not isinstance(error, Diverged):
            raise
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
