"""What each `pimbot` command does, given its parsed command object (`pimbot.cli.commands`:
each command's `run` calls its function here, in `listing`, `defenses` or `robot`)."""

from __future__ import annotations

import sys
from pathlib import Path

from pimbot.cli import defenses as defense_cli
from pimbot.cli.parsing import UsageError


def _log_backends(args) -> tuple[str, ...]:
    """The --log backends, each with its client installed (else a one-line error)."""
    from pimbot.training import tracking

    backends = tracking.parse(list(args.log))
    tracking.require_clients(backends)
    return backends


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


def check_writable(name: str, path: Path, *, directory: bool) -> None:
    """Fails (one line naming `name`) unless `path` can be created or written as a
    directory (or a file) — before anything is written."""
    import os

    if path.exists():
        if directory and not path.is_dir():
            raise UsageError(f"{name}: {path} exists and is not a directory")
        if not directory and path.is_dir():
            raise UsageError(f"{name}: {path} is a directory, not a file")
        if not os.access(path, os.W_OK | (os.X_OK if directory else 0)):
            raise UsageError(f"{name}: {path} is not writable")
        return
    parent = path.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise UsageError(f"{name}: cannot create {path}: {parent} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UsageError(f"{name}: cannot create {path}: {parent} is not writable")


def _run_config(args):
    """The `RunConfig` of the train options (InvalidParameter/UsageError on bad input)."""
    from pimbot.training.config import (
        RunConfig,
        parse_attack_params,
        parse_env_params,
        parse_hparams,
    )

    return RunConfig(
        env_id=args.env_id,
        env_params=parse_env_params(args.env_id, list(args.env_params)),
        learner=args.learner,
        hparams=parse_hparams(args.learner, list(args.hp)),
        seeds=args.seeds,
        first_seed=args.first_seed,
        iterations=args.iterations,
        eval_period=args.eval_period,
        eval_episodes=args.eval_episodes,
        attack=args.attack,
        attack_params=(
            parse_attack_params(args.attack, list(args.attack_param)) if args.attack else ()
        ),
        defenses=defense_cli.run_defenses(args),
    )


def check_from_plugins(run_dir: str | None, accept_changed_code: bool = False) -> None:
    """`train --from RUN_DIR`: every plugin the run's config.json records is loaded (by its
    file, or a file with its sha256), else one line naming the missing files and how each
    stands now (changed since, gone); and the code is the code the run was made with
    (`provenance.check`: the pimbot version, each plugin's sha256) unless
    `accept_changed_code`.

    Raises:
        UsageError: ``from: RUN_DIR/config.json: the run was made with plugin FILE (...),
        which is not loaded; add --plugin FILE``.
        provenance.CodeChanged: the run was made by other code (one line naming it).
    """
    from pimbot import plugins
    from pimbot.training import provenance, store

    if run_dir is None:
        return
    path = Path(run_dir) / store.CONFIG
    config = store.read_json(path) if path.is_file() else None
    recorded = config.get("plugins") if isinstance(config, dict) else None
    absent = plugins.missing(recorded if isinstance(recorded, list) else [])
    if absent:
        named = "; ".join(f"{file} ({state})" for file, state in absent)
        hint = " ".join(f"--plugin {file}" for file, _ in absent)
        raise UsageError(
            f"from: {path}: the run was made with plugin {named}, which "
            f"{'is' if len(absent) == 1 else 'are'} not loaded; add {hint}"
        )
    provenance.check(Path(run_dir), accept_changed_code, "rerun")


def cmd_train(args) -> int:
    from pimbot.training import memory, runner, store
    from pimbot.training.config import resolve

    if args.out is None:
        raise UsageError("--out: required: the run directory (or --from RUN_DIR to rerun one)")
    if args.attack_param and args.attack is None:
        raise UsageError("attack_param: given without --attack NAME (see `pimbot attacks`)")
    log = _log_backends(args)
    run = _run_config(args)
    out = Path(args.out)
    check_writable("out", out, directory=True)
    if args.audit_log is not None:
        check_writable("audit_log", Path(args.audit_log), directory=False)
    resolved = resolve(run)
    memory.check_fits(resolved)  # before anything is written
    with store.locked(out):
        if args.restart:
            store.clear_run(out)
        accept = args.accept_changed_code
        resolved, log = runner.check(resolved, out, log, accept)  # nothing written on bad input
        on_chunk = defense_cli.chunk_logger(args.audit_log, run, args.audit_key)
        result = runner.train(
            resolved,
            args.out,
            progress=not args.quiet,
            chunk_iterations=args.chunk_iterations,
            on_chunk=on_chunk,
            log=log,
            checked=True,
            accept_changed_code=accept,
        )
    if on_chunk is not None:
        print(f"audit log {args.audit_log}: head {on_chunk.log.last_hash}")
    _print_result(result)
    return 0


def _print_result(result) -> None:
    """`RUN_DIR: success …, return ratio …, converged seeds …` (a damaged summary fails)."""
    from pimbot.training import store

    final = result.summary.get("final") if isinstance(result.summary, dict) else None
    if not isinstance(final, dict) or "eval/success" not in final:
        raise UsageError(
            f"{result.run_dir}/summary.json: damaged (no final eval/success); {store.RESTART_HINT}"
        )
    if result.already_finished:
        print(f"{result.run_dir}: this run has already finished; nothing to do.")
    parts = [f"success {final['eval/success']['mean']:.3f}"]
    if "eval/return_ratio" in final:
        parts.append(f"return ratio {final['eval/return_ratio']['mean']:.3f}")
    conv = result.summary["convergence"]
    parts.append(
        f"converged seeds {conv['converged_seeds']}/{len(result.summary['seeds'])}"
        + (f", median convergence {conv['median']:.0f} it" if conv["median"] is not None else "")
    )
    print(f"{result.run_dir}: " + ", ".join(parts))


def _finished_runs(paths: list[str]):
    from pimbot.training import store

    run_dirs = [Path(p) for p in paths]
    for run_dir in run_dirs:
        if not (run_dir / store.SUMMARY).exists():
            raise UsageError(f"run_dirs: {run_dir} is not a finished pimbot run (no summary.json)")
    return run_dirs


def cmd_table(args) -> int:
    from pimbot.analysis.tables import summary_table

    print(summary_table(_finished_runs(args.run_dirs), tuple(args.metric)), end="")
    return 0


def cmd_plot(args) -> int:
    from pimbot.analysis.plots import plot_runs

    runs = _finished_runs(args.run_dirs)
    check_writable("out", Path(args.out), directory=False)
    plot_runs(runs, Path(args.out), tuple(args.metric))
    print(f"wrote {args.out}")
    return 0


def cmd_profile(args) -> int:
    from pimbot.profiling import CONTROLLERS, ProfileConfig, profile, samplers
    from pimbot.training.config import parse_env_params

    check_writable("out", Path(args.out), directory=True)
    config = ProfileConfig(
        env_id=args.env,
        env_params=parse_env_params(args.env, list(args.env_params)),
        controller=args.controller,
        duration_s=args.duration,
        hidden=tuple(args.hidden),
        action_repeat=args.action_repeat,
        cadences=tuple(args.update_every),
        seed=args.seed,
    )
    if args.pin_cpu is not None:
        cpus = list(_cpu_list(args.pin_cpu))
        try:
            samplers.pin_cpus(cpus)
        except OSError as error:
            raise UsageError(f"pin_cpu: cannot pin to {cpus}: {error}") from None
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


def _run_suite(jobs, args, suite_name: str, loaded: tuple[str, ...], skipped=()) -> int:
    """`--list` or run `jobs` into `args.out` (the machinery of reproduce and sweep); the
    grid cells `skipped` are listed, recorded in index.json and not run."""
    from pimbot.suites import sweep

    if args.ray_address is not None and args.backend != "ray":
        raise UsageError("ray_address: given without --backend ray")
    check_writable("out", Path(args.out), directory=True)
    log = _log_backends(args)
    try:
        jobs = sweep.select(jobs, list(args.only), skipped)
        skipped = sweep.matching(skipped, list(args.only))
        if args.list:
            statuses = sweep.plan(jobs, Path(args.out), args.accept_changed_code)
            _list_plan(jobs, skipped, statuses)
            return 0
        options = sweep.SweepOptions(
            backend=args.backend,
            workers=args.workers,
            devices_per_job=args.devices_per_job,
            ray_address=args.ray_address,
            progress=not args.quiet,
            plugins=loaded,
            log=log,
            accept_changed_code=args.accept_changed_code,
        )
        result = sweep.run(jobs, args.out, suite_name, options, skipped)
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
    if result.ran and result.programs and args.quiet:  # else the progress display shows it
        print(f"{args.out}: {sweep.programs_line(result.programs)}")
    if skipped:
        print(f"{args.out}: {len(skipped)} cells skipped (see --list or {args.out}/index.json)")
    if result.failed:
        print(f"failed: {', '.join(result.failed)} (see {args.out}/index.json)", file=sys.stderr)
        return 1
    return 0


def _list_plan(jobs, skipped, statuses: dict[str, str]) -> None:
    """`--list`: one line per job (name, kind, status, what it runs), then one per skipped
    cell (name, "skipped", why)."""
    from pimbot.suites.jobs import KINDS

    width = max([36] + [len(item.name) + 1 for item in [*jobs, *skipped]])
    for job in jobs:
        what = KINDS[job.kind].describe(job.spec)
        print(f"{job.name:<{width}} {job.kind:<10} {statuses[job.name]:<9} {what}")
    for cell in skipped:
        print(f"{cell.name:<{width}} {'train':<10} {'skipped':<9} {cell.reason}")


def cmd_reproduce(args, loaded: tuple[str, ...]) -> int:
    from pimbot.suites import presets

    suite_name = "quick" if args.quick else "full"
    return _run_suite(presets.suite(quick=args.quick), args, suite_name, loaded)


def cmd_sweep(args, loaded: tuple[str, ...]) -> int:
    from pimbot.suites import grid
    from pimbot.training.config import resolving

    with resolving():  # each job resolved once, for its check and its plan
        spec, jobs, skipped = grid.load_jobs(args.grid)  # nothing written on bad input
        loaded += tuple(p for p in spec.plugins if p not in loaded)  # the workers load them
        return _run_suite(jobs, args, spec.name, loaded, skipped)


def cmd_report(args) -> int:
    from pimbot.analysis import report
    from pimbot.suites.sweep import SweepError

    suite_dir = Path(args.suite_dir)
    if not suite_dir.is_dir():
        raise UsageError(f"suite_dir: {suite_dir} is not a directory")
    out = Path(args.out) if args.out else suite_dir
    check_writable("out", out, directory=True)
    try:
        out = report.write_report(suite_dir, out)
    except SweepError as error:
        raise UsageError(str(error)) from None
    print(f"wrote {out / report.MARKDOWN} and {out / report.HTML}")
    return 0
