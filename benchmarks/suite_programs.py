"""How many compiled programs a suite's training jobs need, and what each costs.

    python benchmarks/suite_programs.py [--full] [--devices 1] [--verify] [--compile]

For every training job of `pimbot reproduce [--quick]` it prints the job's
program key (`programs.program_key`: what the compiled chunk depends on, the
attack's and defenses' numbers left out) and its group key
(`programs.share_key`: the same after folding the strategy attacks into one
`strategy_union.Strategies` program, which is how `pimbot reproduce` now plans its
tasks). Then the groups, what tells them apart, and the relative training cost
of each.

--groups I,J limits what is lowered, compiled or timed to those groups.
--verify lowers every job's chunk as the sweep would run it (the group's
`Strategies` form where the group mixes strategy attacks) and checks that the
jobs of a group lower to one program text and different groups to different
ones. --compile compiles one job per group and prints each compile time and the
init and trace+lower time before it (the persistent cache is off for it).
--train-time (implies --compile) also calls each group's compiled chunk and prints
its time per call and the group's training time (calls its jobs need × that), and
at the end the suite's floor on two workers: (init, lowering, compile and training
of every group) / 2, without the profile and robot jobs and process start-up. Pin
it to one core (`taskset -c 0`), as each of the sweep's two workers has one.
--flops counts each group's flops per call (`throughput.jaxpr_flops`: scan bodies
times their length, a `cond` as its cheapest branch) and prints the suite's
training flops and the time they would take at the fp32 AVX2 peak of both cores
(`throughput.core_peak`, 32 flops per cycle): a floor no implementation of these
programs gets under on an AVX2 machine (on an AVX-512 one with two FMA units, half
of it).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import time

os.environ.setdefault("PIMBOT_CACHE_DIR", "off")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="the published suite (10 seeds)")
    parser.add_argument("--devices", type=int, default=1, help="devices per job (sweep default)")
    parser.add_argument("--chunk-iterations", type=int, default=2000)
    parser.add_argument("--verify", action="store_true", help="lower every job and compare")
    parser.add_argument("--compile", action="store_true", help="compile one job per group")
    parser.add_argument(
        "--train-time", action="store_true", help="also time each group's chunk (see above)"
    )
    parser.add_argument("--flops", action="store_true", help="count each group's flops")
    parser.add_argument(
        "--groups", metavar="I,J", help="compile/time only these groups (numbers as printed)"
    )
    parser.add_argument(
        "--timings", metavar="DIR", help="instead: where a finished suite directory's time went"
    )
    args = parser.parse_args()
    args.compile = args.compile or args.train_time
    if args.timings:
        timings(args.timings)
        return

    from throughput import core_peak, jaxpr_flops

    from pimbot import jax_setup
    from pimbot.attacks import strategy_union
    from pimbot.suites import presets
    from pimbot.suites.jobs import JobOptions, train_strategies
    from pimbot.suites.sweep import groups
    from pimbot.training import programs, runner
    from pimbot.training.config import resolve

    jax_setup.unroll_cpu_threefry()  # the programs `pimbot train` and the sweep compile

    jobs = [j for j in presets.suite(quick=not args.full) if j.kind == "train"]
    options = JobOptions(chunk_iterations=args.chunk_iterations)
    resolved = {j.name: resolve(j.spec) for j in jobs}
    shape = {
        n: runner.program_shape(r, args.chunk_iterations, False, args.devices)
        for n, r in resolved.items()
    }
    own = {n: programs.program_key(r, *shape[n], args.devices) for n, r in resolved.items()}
    tasks = groups(jobs, options, args.devices)
    suite = "full" if args.full else "quick"
    print(f"{suite} suite: {len(jobs)} training jobs")
    print(f"  distinct programs, one per structure (before): {len(set(own.values()))}")
    print(f"  programs after folding the strategy attacks (tasks): {len(tasks)}")
    total = sum(j.spec.iterations * j.spec.seeds for j in jobs)
    print(f"  seed-iterations in all: {total:,}")
    print()

    def describe(job) -> str:
        r = resolved[job.name]
        env = r.run.env_id + "".join(f" {k}={v}" for k, v in r.run.env_params)
        defenses = "+".join(d.name for d in r.defenses) or "-"
        periods, seeds = shape[job.name]
        return (
            f"{r.run.learner:<12} {env:<42} defenses {defenses:<50} "
            f"{periods}×{r.eval_period} it/call, {seeds} seeds"
        )

    compile_s: list[float] = []
    before_s: list[float] = []  # init + trace + lower of each group's first job
    train_s: list[float] = []  # each group's training: its jobs' calls × one call's time
    flops: list[float] = []  # each group's training flops: its jobs' calls × one call's
    texts: dict[str, str] = {}
    for number, task in enumerate(tasks):
        strategies = train_strategies([j.spec for j in task]) if len(task) > 1 else None
        kinds = sorted({resolved[j.name].attack.name for j in task})
        cost = sum(j.spec.iterations * j.spec.seeds for j in task)
        head = f"[{number:2d}] {len(task)} job(s), {cost / total:5.1%} of the work"
        print(f"{head}: {describe(task[0])}")
        print(f"     attacks: {', '.join(kinds)}")
        print(f"     jobs: {', '.join(j.name for j in task)}")
        chosen = args.groups is None or number in {int(g) for g in args.groups.split(",")}
        if chosen and (args.verify or args.compile or args.flops):
            for job in task if args.verify else task[:1]:
                r = resolved[job.name]
                r = programs.with_attack(r, r.attack.program_form())
                if strategies and strategy_union.shareable(r.attack):
                    r = programs.with_attack(r, strategy_union.shared_attack(r.attack, strategies))
                lowered, jaxpr, init_s, lower_s, call_args = lower(runner, r, *shape[job.name])
                digest = hashlib.sha256(lowered.as_text().encode()).hexdigest()[:16]
                texts[job.name] = digest
                line = (
                    f"     {job.name}: program text {digest}, init (compiled and run) "
                    f"{init_s:.1f} s, traced+lowered in {lower_s:.1f} s"
                )
                if job is not task[0]:  # --verify: the others are only lowered and compared
                    print(line, flush=True)
                    continue
                before_s.append(init_s + lower_s)
                periods = shape[job.name][0]
                calls = sum(-(-j.spec.iterations // (periods * r.eval_period)) for j in task)
                if args.flops:
                    per_call = sum(jaxpr_flops(jaxpr.jaxpr, branch=min))
                    flops.append(calls * per_call)
                    line += f", {per_call / 1e9:.1f} GFLOP a call"
                if args.compile:
                    t0 = time.perf_counter()
                    compiled = lowered.compile()
                    compile_s.append(time.perf_counter() - t0)
                    line += f", compiled in {compile_s[-1]:.1f} s"
                    if args.train_time:
                        call = call_seconds(compiled, call_args)
                        train_s.append(calls * call)
                        line += f"; a call {call:.2f} s, {calls} calls: {train_s[-1]:.0f} s"
                print(line, flush=True)
    if args.verify:
        by_task = [{texts[j.name] for j in task} for task in tasks]
        one_each = all(len(t) == 1 for t in by_task)
        distinct = len(set().union(*by_task)) == len(tasks)
        print(f"\nverify: every group one program text: {one_each}; groups distinct: {distinct}")
        if not (one_each and distinct):
            sys.exit(1)
    if compile_s:
        print(
            f"\ncompile (one per group, persistent cache off): {len(compile_s)} programs, "
            f"sum {sum(compile_s):.0f} s, mean {sum(compile_s) / len(compile_s):.1f} s; "
            f"before it (init compiled and run, chunk traced and lowered) sum "
            f"{sum(before_s):.0f} s, mean {sum(before_s) / len(before_s):.1f} s"
        )
    if train_s:
        work = sum(before_s) + sum(compile_s) + sum(train_s)
        print(
            f"training (each group's calls × its measured call): sum {sum(train_s):.0f} s; "
            f"with init, lowering and compile {work:.0f} s of one core: on two workers at "
            f"least {work / 2 / 60:.1f} min (profile and robot jobs and start-up not counted)"
        )
    if flops:
        peak, peak_desc = core_peak()
        line = f"training flops (each group's calls × a call's): {sum(flops) / 1e12:.1f} TFLOP"
        if peak:
            line += (
                f"; at the fp32 peak of two cores ({peak_desc} each) "
                f"{sum(flops) / (2 * peak) / 60:.1f} min"
            )
        print(line)
    print("\nwhat tells the groups apart (distinct values over the groups):")
    first = [resolved[t[0].name] for t in tasks]
    fields = {
        "learner": {r.run.learner for r in first},
        "learner config": {repr(r.learner_config) for r in first},
        "env and its parameters": {(r.run.env_id, r.run.env_params) for r in first},
        "attack structure (strategies folded; learning attacks by mode)": {
            "strategies"
            if strategy_union.shareable(r.attack)
            else strategy_union.member_kind(r.attack)
            for r in first
        },
        "defense sets": {"+".join(d.name for d in r.defenses) for r in first},
        "periods per call × eval period, seeds": {
            (shape[t[0].name], r.eval_period) for t, r in zip(tasks, first, strict=True)
        },
    }
    for name, values in fields.items():
        print(f"  {len(values):3d} {name}")


def timings(suite_dir: str) -> None:
    """Sums over a finished suite's jobs: compile (trace, lower, compile: summary.json),
    training proper (the chunks' times, from metrics.csv perf/iters_per_s) and the rest
    of each job's wall time (init, checkpoints, metrics, summaries, locks), by kind."""
    import csv
    import json
    from pathlib import Path

    root = Path(suite_dir)
    index = json.loads((root / "index.json").read_text())
    sums: dict[str, list[float]] = {}
    for entry in index["jobs"]:
        wall = entry.get("wall_s")
        if wall is None:
            continue
        kind = entry["kind"]
        compile_s = train_s = 0.0
        if kind == "train":
            summary = json.loads((root / entry["name"] / "summary.json").read_text())
            compile_s = summary.get("compile_s", 0.0)
            first_seed = str(summary["seeds"][0])
            with open(root / entry["name"] / "metrics.csv", newline="") as f:
                rows = [r for r in csv.DictReader(f) if r["seed"] == first_seed]
            train_s = chunk_seconds(rows)
        total = sums.setdefault(kind, [0, 0.0, 0.0, 0.0, 0.0])
        total[0] += 1
        total[1] += wall
        total[2] += compile_s
        total[3] += train_s
        total[4] += wall - compile_s - train_s
    programs = index.get("programs")
    print(f"{suite_dir}: sums over jobs (seconds; jobs ran side by side)")
    print(f"  {'kind':<11} {'jobs':>5} {'wall':>8} {'compile':>8} {'train':>8} {'other':>8}")
    for kind, (n, wall, comp, train, other) in sums.items():
        print(f"  {kind:<11} {n:>5} {wall:>8.0f} {comp:>8.0f} {train:>8.0f} {other:>8.0f}")
    if programs:
        from pimbot.suites.sweep import programs_line

        print("  " + programs_line(programs))


def chunk_seconds(rows: list[dict]) -> float:
    """Training seconds of one seed's rows: every chunk's rows share its perf/iters_per_s,
    so a chunk's time is its iterations over that rate."""
    seconds, chunk_start, rate, last = 0.0, 0, None, 0
    for row in rows:
        value, iteration = float(row["perf/iters_per_s"]), int(row["iteration"])
        if rate is not None and value != rate:
            seconds += (last - chunk_start) / rate
            chunk_start = last
        rate, last = value, iteration
    if rate is not None:
        seconds += (last - chunk_start) / rate
    return seconds


def call_seconds(compiled, call_args) -> float:
    """Seconds of one call of the compiled chunk: the faster of two, or the first alone
    where it took over 10 s (the states are donated: each call takes the last one's)."""
    import jax

    states, roots, args = call_args
    times = []
    while not times or (len(times) < 2 and times[0] < 10.0):
        t0 = time.perf_counter()
        states, metrics = compiled(states, roots, *args)
        jax.block_until_ready((states, metrics))
        times.append(time.perf_counter() - t0)
    return min(times)


def lower(runner, resolved, periods: int, seeds: int):
    """(the lowered chunk, its traced jaxpr, seconds to compile and run the init, seconds
    to trace and lower the chunk, (states, evaluation roots, program args) to call it with)."""
    import jax

    keys = runner.seed_keys(resolved.run.first_seed, seeds)
    args = runner.program_args(resolved)
    t0 = time.perf_counter()
    states = jax.block_until_ready(runner.make_init_fn(resolved)(keys, *args))
    t1 = time.perf_counter()
    roots = jax.vmap(lambda k: jax.random.fold_in(k, 1))(keys)
    traced = runner.make_chunk_fn(resolved, periods).trace(states, roots, *args)
    lowered = traced.lower()
    return lowered, traced.jaxpr, t1 - t0, time.perf_counter() - t1, (states, roots, args)


if __name__ == "__main__":
    main()
