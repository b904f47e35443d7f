"""The `pimbot` command line.

    pimbot train ENV_ID [name=value ...] --learner lio --seeds 10 --iterations 50000 --out DIR
    pimbot sweep GRID.toml --out DIR [--backend local|ray] [--workers K] [--list]
    pimbot reproduce [--quick] --out DIR
    pimbot report DIR
    pimbot profile --env ENV_ID [name=value ...] --controller benign|admo --duration S --out DIR
    pimbot envs | learners | attacks | defenses

`train`, `sweep` and `reproduce` take `--log tensorboard|wandb|mlflow` (repeatable or
comma-separated) to stream every metrics row and the config to those trackers
(see `pimbot.experiment.tracking`).

Every command takes `--plugin MODULE` (repeatable; a module name or a .py
file) to load plugins that register more envs, learners, attacks or
defenses (see `pimbot.plugins`). Bad input prints one line naming the field
and the allowed values and exits with status 2, before anything is written.
"""

from __future__ import annotations

import argparse
import sys

import pimbot
from pimbot import jax_setup, plugins
from pimbot.defenses import cli as defense_cli
from pimbot.robot import cli as robot_cli

PLUGIN_DEST = "plugins:"
"""Prefix of the namespace attributes holding each (sub)parser's --plugin values."""


class UsageError(Exception):
    """A bad command line; the message is printed as one line."""


class _Parser(argparse.ArgumentParser):
    """Every parser and subparser of `pimbot`: one-line errors and a `--plugin` option."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.subcommands: dict[str, argparse.ArgumentParser] = {}
        # One dest per parser: a subparser's values would overwrite its parent's otherwise.
        self.add_argument(
            "--plugin",
            action="append",
            dest=PLUGIN_DEST + self.prog,
            default=argparse.SUPPRESS,
            metavar="MODULE",
            help="load a plugin first: a module name or a .py file (repeatable)",
        )

    def add_subparsers(self, **kwargs):
        action = super().add_subparsers(**kwargs)
        self.subcommands = action.choices
        return action

    def error(self, message: str):  # one clear line instead of usage + message
        raise UsageError(message)


def plugin_arguments(args: argparse.Namespace) -> list[str]:
    """Every `--plugin` value of a parsed command line, wherever it was given."""
    return [m for k, v in vars(args).items() if k.startswith(PLUGIN_DEST) for m in v]


def _int_arg(name: str, low: int):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise UsageError(f"{name}: must be an integer ≥ {low}, got {text!r}") from None
        if value < low:
            raise UsageError(f"{name}: must be an integer ≥ {low}, got {value}")
        return value

    return parse


def _float_arg(name: str, low: float):
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise UsageError(f"{name}: must be a number > {low:g}, got {text!r}") from None
        if not value > low:
            raise UsageError(f"{name}: must be a number > {low:g}, got {value:g}")
        return value

    return parse


def _cpu_list(text: str) -> tuple[int, ...]:
    """`0,2-3` -> (0, 2, 3)."""
    cpus: list[int] = []
    try:
        for part in text.split(","):
            low, _, high = part.partition("-")
            cpus += range(int(low), int(high or low) + 1)
    except ValueError:
        raise UsageError(f"pin_cpu: must be a CPU list like 0,2-3, got {text!r}") from None
    if not cpus or min(cpus) < 0:
        raise UsageError(f"pin_cpu: must be a CPU list like 0,2-3, got {text!r}")
    return tuple(cpus)


def _add_log_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--log",
        action="append",
        default=[],
        metavar="BACKEND",
        help="stream every metrics row and the config to tensorboard, wandb or mlflow "
        "(repeatable or comma-separated; pip install 'pimbot[tracking]')",
    )


def _log_backends(args: argparse.Namespace) -> tuple[str, ...]:
    """The --log backends, each with its client installed (else a one-line error)."""
    from pimbot.experiment import tracking

    backends = tracking.parse(args.log)
    tracking.require_clients(backends)
    return backends


def _add_profile_parser(commands) -> None:
    profile = commands.add_parser(
        "profile", help="decision latency, update cost and hardware traces (benign vs ADMO)"
    )
    profile.add_argument("--env", required=True, help="environment id (see `pimbot envs`)")
    profile.add_argument(
        "env_params", nargs="*", metavar="name=value", help="environment parameters"
    )
    profile.add_argument(
        "--controller", default="benign", help="benign (plain LIO) or admo (ADMO on agent 0)"
    )
    profile.add_argument(
        "--duration",
        type=_float_arg("duration", 0),
        default=20.0,
        help="steady-state seconds per controller",
    )
    profile.add_argument(
        "--hidden",
        type=_int_arg("hidden", 1),
        nargs="+",
        default=[256, 128],
        help="hidden widths of the policy and incentive MLPs",
    )
    profile.add_argument(
        "--action-repeat", type=_int_arg("action_repeat", 1), default=2, help="env steps/decision"
    )
    profile.add_argument(
        "--update-every",
        type=_int_arg("update_every", 1),
        default=100,
        help="decisions between learner update steps",
    )
    profile.add_argument("--pin-cpu", type=_cpu_list, default=None, help="CPU list, e.g. 0,2-3")
    profile.add_argument(
        "--sample-hz", type=_float_arg("sample_hz", 0), default=1.0, help="sensor sampling rate"
    )
    profile.add_argument("--seed", type=_int_arg("seed", 0), default=0, help="root PRNG seed")
    profile.add_argument(
        "--paired", action="store_true", help="benign then ADMO, everything else identical"
    )
    profile.add_argument(
        "--truncate-idle-gpu", action="store_true", help="cut long zero-GPU stretches in the figure"
    )
    profile.add_argument("--out", required=True, help="run directory (created)")


def _add_suite_options(parser: argparse.ArgumentParser, example: str) -> None:
    """The options `reproduce` and `sweep` share (how a suite runs, not what it runs)."""
    parser.add_argument(
        "--only",
        action="append",
        default=[],
        metavar="PATTERN",
        help=f"run only jobs whose <group>/<setting> name matches (repeatable), e.g. {example!r}",
    )
    parser.add_argument(
        "--backend", default="local", help="local (process pool, default) or ray (Ray tasks)"
    )
    parser.add_argument(
        "--workers",
        type=_int_arg("workers", 0),
        default=0,
        help="jobs at a time (default: one per CPU core locally, all at once on Ray)",
    )
    parser.add_argument(
        "--devices-per-job",
        type=_int_arg("devices_per_job", 0),
        default=0,
        help="CPU cores each job shards its seeds over (default: cores / workers)",
    )
    parser.add_argument(
        "--ray-address", default=None, help="Ray cluster: auto or HOST:PORT (default: start one)"
    )
    parser.add_argument("--list", action="store_true", help="print the plan and exit")
    parser.add_argument("--quiet", action="store_true", help="no progress display")
    _add_log_option(parser)
    parser.add_argument("--out", required=True, help="suite directory (rerun to resume)")


def _add_reproduce_parsers(commands) -> None:
    reproduce = commands.add_parser(
        "reproduce", help="run the paper's whole experiment suite into one directory (resumable)"
    )
    reproduce.add_argument(
        "--quick",
        action="store_true",
        help="3 seeds, a fifth of the iterations: every setting and figure, in minutes",
    )
    _add_suite_options(reproduce, "attacks/er21_*")

    sweep = commands.add_parser(
        "sweep",
        help="run a grid of envs × learners × attacks × defenses from a TOML file (resumable)",
    )
    sweep.add_argument("grid", help="grid file (TOML; see docs/examples/grid.toml)")
    _add_suite_options(sweep, "my_grid/*_clean")

    report = commands.add_parser(
        "report", help="report.md and report.html (figures, tables, claims) from a suite directory"
    )
    report.add_argument("suite_dir", help="directory written by `pimbot reproduce`")
    report.add_argument("--out", default=None, help="where to write (default: SUITE_DIR)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="pimbot",
        description=pimbot.__doc__,
        epilog="`pimbot COMMAND --help` shows a command's options.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {pimbot.__version__}")
    commands = parser.add_subparsers(
        dest="command", metavar="COMMAND", required=False, parser_class=_Parser
    )

    train = commands.add_parser("train", help="train one learner on one environment, S seeds")
    train.add_argument("env_id", help="environment id (see `pimbot envs`)")
    train.add_argument(
        "env_params",
        nargs="*",
        metavar="name=value",
        help="environment parameters, e.g. n_agents=4 min_at_lever=2",
    )
    train.add_argument("--learner", default="lio", help="learner (see `pimbot learners`)")
    train.add_argument("--seeds", type=_int_arg("seeds", 1), default=10, help="number of seeds")
    train.add_argument(
        "--first-seed", type=_int_arg("first_seed", 0), default=0, help="first seed value"
    )
    train.add_argument(
        "--iterations",
        type=_int_arg("iterations", 1),
        default=50_000,
        help="training iterations per seed",
    )
    train.add_argument(
        "--eval-period",
        type=_int_arg("eval_period", 1),
        default=None,
        help="iterations between evaluations (default: ER 100, others 1000)",
    )
    train.add_argument(
        "--eval-episodes",
        type=_int_arg("eval_episodes", 1),
        default=None,
        help="episodes per evaluation (default 10)",
    )
    train.add_argument(
        "--hp",
        action="append",
        default=[],
        metavar="name=value",
        help="override a learner hyperparameter (repeatable), e.g. --hp lr_policy=1e-3",
    )
    train.add_argument(
        "--attack", default=None, help="manipulate one agent (see `pimbot attacks`); default: none"
    )
    train.add_argument(
        "--attack-param",
        "--ap",
        action="append",
        default=[],
        metavar="name=value",
        help="attack parameter (repeatable), e.g. --ap adversary=1 --ap mode=stealthy",
    )
    train.add_argument("--out", required=True, help="run directory (created; rerun to resume)")
    train.add_argument(
        "--chunk-iterations",
        type=_int_arg("chunk_iterations", 1),
        default=2000,
        help="iterations between checkpoints (rounded to whole evaluation periods; does "
        "not change results)",
    )
    train.add_argument("--quiet", action="store_true", help="no progress display")
    _add_log_option(train)
    defense_cli.add_train_arguments(train)

    table = commands.add_parser("table", help="Markdown table of finished runs' final metrics")
    table.add_argument("run_dirs", nargs="+", help="run directories")
    plot = commands.add_parser("plot", help="learning curves of runs (mean ± 95 %% CI) as PNG")
    plot.add_argument("run_dirs", nargs="+", help="run directories")
    plot.add_argument("--out", required=True, help="PNG file to write")

    _add_profile_parser(commands)
    _add_reproduce_parsers(commands)
    commands.add_parser("envs", help="list environments and their parameters")
    commands.add_parser("learners", help="list learners and their hyperparameters")
    commands.add_parser("attacks", help="list attacks and their parameters")
    defense_cli.add_parser(commands)
    robot_cli.add_parser(commands)
    return parser


def cmd_envs() -> int:
    from pimbot import envs

    for env_id in envs.registered():
        entry = envs.spec(env_id)
        print(f"{env_id}: {entry.description}")
        for name, default in entry.parameters().items():
            print(f"    {name} = {default!r}")
    return 0


def cmd_learners() -> int:
    import dataclasses

    from pimbot import envs, learners

    for name in learners.registered():
        definition = learners.get(name)
        print(f"{name}: {definition.description}")
        print(f"    attack hooks: {', '.join(definition.attack_hooks) or 'none'}")
        print(f"    defense hooks: {', '.join(definition.defense_hooks) or 'none'}")
        base = dataclasses.replace(definition.config_cls(), **dict(definition.base_overrides))
        for f in dataclasses.fields(base):
            print(f"    {f.name} = {getattr(base, f.name)!r}")
        for env_id in envs.registered():
            declared = definition.default_config(envs.spec(env_id))
            changed = {
                f.name: getattr(declared, f.name)
                for f in dataclasses.fields(declared)
                if getattr(declared, f.name) != getattr(base, f.name)
            }
            if changed:
                values = ", ".join(f"{k}={v!r}" for k, v in changed.items())
                print(f"    on {env_id} (declared by the environment): {values}")
    return 0


def cmd_attacks() -> int:
    from pimbot import attacks

    for name in attacks.registered():
        cls = attacks.attack_class(name)
        doc = ((cls.__doc__ or "").strip().splitlines() or [""])[0]
        tags = [f"{cls.lever} lever"] if getattr(cls, "lever", None) else []
        if getattr(cls, "hooks", ()):
            tags.append("hooks: " + ", ".join(cls.hooks))
        print(f"{name} [{'; '.join(tags)}]: {doc}" if tags else f"{name}: {doc}")
        for param, default in attacks.parameters(name).items():
            print(f"    {param} = {default!r}")
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    from pathlib import Path

    from pimbot.experiment import runner
    from pimbot.experiment.config import (
        RunConfig,
        parse_attack_params,
        parse_env_params,
        parse_hparams,
        resolve,
    )

    if args.attack_param and args.attack is None:
        raise UsageError("attack_param: given without --attack NAME (see `pimbot attacks`)")
    log = _log_backends(args)

    run = RunConfig(
        env_id=args.env_id,
        env_params=parse_env_params(args.env_id, args.env_params),
        learner=args.learner,
        hparams=parse_hparams(args.learner, args.hp),
        seeds=args.seeds,
        first_seed=args.first_seed,
        iterations=args.iterations,
        eval_period=args.eval_period,
        eval_episodes=args.eval_episodes,
        attack=args.attack,
        attack_params=(parse_attack_params(args.attack, args.attack_param) if args.attack else ()),
        defenses=defense_cli.run_defenses(args),
    )
    runner.check_run_dir(Path(args.out), resolve(run))  # nothing written on a bad command
    on_chunk = defense_cli.chunk_logger(args.audit_log, run)
    result = runner.train(
        run,
        args.out,
        progress=not args.quiet,
        chunk_iterations=args.chunk_iterations,
        on_chunk=on_chunk,
        log=log,
    )
    if on_chunk is not None:
        print(f"audit log {args.audit_log}: head {on_chunk.log.last_hash}")
    if result.already_finished:
        print(f"{result.run_dir}: this run has already finished; nothing to do.")
    final = result.summary["final"]
    parts = [f"success {final['eval/success']['mean']:.3f}"]
    if "eval/return_ratio" in final:
        parts.append(f"return ratio {final['eval/return_ratio']['mean']:.3f}")
    conv = result.summary["convergence"]
    parts.append(
        f"converged seeds {conv['converged_seeds']}/{len(result.summary['seeds'])}"
        + (f", median convergence {conv['median']:.0f} it" if conv["median"] is not None else "")
    )
    print(f"{result.run_dir}: " + ", ".join(parts))
    return 0


def _finished_runs(paths: list[str]):
    from pathlib import Path

    from pimbot.experiment import store

    run_dirs = [Path(p) for p in paths]
    for run_dir in run_dirs:
        if not (run_dir / store.SUMMARY).exists():
            raise UsageError(f"run_dirs: {run_dir} is not a finished pimbot run (no summary.json)")
    return run_dirs


def cmd_table(args: argparse.Namespace) -> int:
    from pimbot.analysis.tables import summary_table

    print(summary_table(_finished_runs(args.run_dirs)), end="")
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    from pathlib import Path

    from pimbot.analysis.plots import plot_runs

    plot_runs(_finished_runs(args.run_dirs), Path(args.out))
    print(f"wrote {args.out}")
    return 0


def cmd_profile(args: argparse.Namespace) -> int:
    from pathlib import Path

    from pimbot.experiment.config import parse_env_params
    from pimbot.profiling import CONTROLLERS, ProfileConfig, profile, samplers

    if args.controller not in CONTROLLERS:
        raise UsageError(
            f"controller: unknown controller {args.controller!r}; allowed: {', '.join(CONTROLLERS)}"
        )
    config = ProfileConfig(
        env_id=args.env,
        env_params=parse_env_params(args.env, args.env_params),
        controller=args.controller,
        duration_s=args.duration,
        hidden=tuple(args.hidden),
        action_repeat=args.action_repeat,
        update_every=args.update_every,
        seed=args.seed,
    )
    if args.pin_cpu is not None:
        try:
            samplers.pin_cpus(list(args.pin_cpu))
        except OSError as error:
            raise UsageError(f"pin_cpu: cannot pin to {list(args.pin_cpu)}: {error}") from None
    summary = profile(
        config,
        Path(args.out),
        paired=args.paired,
        sample_hz=args.sample_hz,
        truncate_idle_gpu=args.truncate_idle_gpu,
    )
    runs = {c: summary[c] for c in CONTROLLERS} if args.paired else {args.controller: summary}
    for name, run in runs.items():
        lat, upd = run["latency_ms"], run["update_ms"]
        print(
            f"{name}: latency p50 {lat['p50']:.3f} ms, p95 {lat['p95']:.3f} ms, "
            f"p99 {lat['p99']:.3f} ms, max {lat['max']:.3f} ms (n={lat['count']}); "
            f"{run['decisions_per_s']:.0f} decisions/s; update p50 "
            + (f"{upd['p50']:.2f} ms (n={upd['count']})" if upd["count"] else "n/a")
            + f"; live sensors: {', '.join(run['live_sensors']) or 'none'}"
        )
    if args.paired:
        comp = summary["comparison"]
        parts = [
            f"{label} {comp[key]['diff']:+.3f} ms ({comp[key]['percent']:+.1f} %)"
            for key, label in (("latency_mean_ms", "decision"), ("update_p50_ms", "update step"))
            if comp[key] is not None
        ]
        if comp["update_per_decision_ms"] is not None:
            amortized = comp["update_per_decision_ms"]
            parts.append(
                f"update amortized per decision {amortized['ms']:+.4f} ms "
                f"({amortized['percent_of_decision']:+.1f} % of a benign decision)"
            )
        print("ADMO overhead: " + ", ".join(parts))
    print(f"wrote {args.out}")
    return 0


def _run_suite(jobs, args: argparse.Namespace, suite_name: str, loaded: tuple[str, ...]) -> int:
    """`--list` or run `jobs` into `args.out` (the machinery of reproduce and sweep)."""
    from pathlib import Path

    from pimbot.experiment import sweep
    from pimbot.experiment.jobs import KINDS

    if args.backend not in sweep.BACKENDS:
        raise UsageError(
            f"backend: unknown backend {args.backend!r}; allowed: {', '.join(sweep.BACKENDS)}"
        )
    if args.ray_address is not None and args.backend != "ray":
        raise UsageError("ray_address: given without --backend ray")
    log = _log_backends(args)
    try:
        jobs = sweep.select(jobs, args.only)
        if args.list:
            statuses = sweep.plan(jobs, Path(args.out))
            width = max([36] + [len(job.name) + 1 for job in jobs])
            for job in jobs:
                what = KINDS[job.kind].describe(job.spec)
                print(f"{job.name:<{width}} {job.kind:<10} {statuses[job.name]:<9} {what}")
            return 0
        options = sweep.SweepOptions(
            backend=args.backend,
            workers=args.workers,
            devices_per_job=args.devices_per_job,
            ray_address=args.ray_address,
            progress=not args.quiet,
            plugins=loaded,
            log=log,
        )
        result = sweep.run(jobs, args.out, suite_name, options)
    except sweep.SweepError as error:
        raise UsageError(str(error)) from None
    finished = sum(e["status"] == "finished" for e in result.index["jobs"])
    total = len(result.index["jobs"])
    if not result.ran:
        print(f"{args.out}: all {len(jobs)} selected jobs have already finished; nothing to do.")
    print(
        f"{args.out}: {finished}/{total} jobs finished "
        f"({result.wall_s / 60:.1f} min this session); next: pimbot report {args.out}"
    )
    if result.failed:
        print(f"failed: {', '.join(result.failed)} (see {args.out}/index.json)", file=sys.stderr)
        return 1
    return 0


def cmd_reproduce(args: argparse.Namespace, loaded: tuple[str, ...]) -> int:
    from pimbot.experiment import presets

    suite_name = "quick" if args.quick else "full"
    return _run_suite(presets.suite(quick=args.quick), args, suite_name, loaded)


def cmd_sweep(args: argparse.Namespace, loaded: tuple[str, ...]) -> int:
    from pimbot.experiment import grid

    spec, jobs = grid.load_jobs(args.grid)  # every job resolved: nothing written on bad input
    return _run_suite(jobs, args, spec.name, loaded)


def cmd_report(args: argparse.Namespace) -> int:
    from pathlib import Path

    from pimbot.analysis import report

    suite_dir = Path(args.suite_dir)
    if not suite_dir.is_dir():
        raise UsageError(f"suite_dir: {suite_dir} is not a directory")
    out = report.write_report(suite_dir, Path(args.out) if args.out else suite_dir)
    print(f"wrote {out / report.MARKDOWN} and {out / report.HTML}")
    return 0


def main(argv: list[str] | None = None) -> int:
    from pimbot.envs.core import InvalidParameter

    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if args.command is None:  # bare `pimbot`: the commands, not an error
            print(parser.format_help(), end="")
            return 0
        if args.command == "train":
            jax_setup.use_all_cpu_cores()  # before a plugin's first jax computation
        loaded = plugins.load_plugins(plugin_arguments(args))
        return _dispatch(args, loaded)
    except (UsageError, InvalidParameter, plugins.PluginError) as error:
        print(f"pimbot: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("pimbot: interrupted; rerun the same command to resume", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `pimbot envs | head`: the reader left, nothing to report
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1


def _dispatch(args: argparse.Namespace, loaded: tuple[str, ...]) -> int:
    """Runs the parsed command; plugins are loaded, so the registries are complete."""
    listings = {"envs": cmd_envs, "learners": cmd_learners, "attacks": cmd_attacks}
    if args.command in listings:
        return listings[args.command]()
    if args.command in ("defenses", "audit"):
        return defense_cli.run(args)
    if args.command == "robot":
        return robot_cli.run(args)
    if args.command == "table":
        return cmd_table(args)
    if args.command == "plot":
        return cmd_plot(args)
    if args.command == "profile":
        jax_setup.enable_compilation_cache()
        return cmd_profile(args)
    if args.command == "reproduce":
        return cmd_reproduce(args, loaded)
    if args.command == "sweep":
        return cmd_sweep(args, loaded)
    if args.command == "report":
        return cmd_report(args)
    jax_setup.enable_compilation_cache()
    return cmd_train(args)


if __name__ == "__main__":
    sys.exit(main())
