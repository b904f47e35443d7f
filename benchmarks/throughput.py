"""Training throughput, compile time and memory of `pimbot train`, per env × seed count.

    python benchmarks/throughput.py [--seeds 10 100 1000] [--configs er21 er43]
        [--iterations N] [--repeats 3] [--learner lio] [--json OUT]

What runs is the real training path of `pimbot.training.runner.train`, not a
re-implementation: for every case (Escape Room config × number of seeds S) the
learner states are built exactly as the runner builds them — per-seed keys from
`seed_keys` (padded to a multiple of the device count), `fold_in(key, 0)` for
init and `fold_in(key, 1)` for the evaluation roots, `jit(vmap(learner.init))`,
then `device_put` onto the `seed_sharding` — and the timed function is the
runner's `make_chunk_fn(resolved, num_periods)`: `num_periods` evaluation
periods of `eval_period` training iterations each, every period followed by the
evaluation (`eval_episodes` episodes, `reduce_eval`) exactly as in training.
Before jax is imported, `pimbot.jax_setup.use_all_cpu_cores()` exposes one XLA
host device per CPU core, as `pimbot train` does, so on a CPU the seed axis is
sharded over the cores; on a GPU it runs on the (single) GPU.

Per case it reports:

* compile time — ahead-of-time `jit(...).lower(states, eval_roots).compile()`,
  timed as the runner times it (tracing + lowering + XLA compilation). JAX's
  persistent compilation cache is switched off, so this is a cold compile (what
  a first `pimbot train` pays); `--compilation-cache` turns on pimbot's cache
  (`jax_setup.enable_compilation_cache`, as `pimbot train` does), and a second
  such run then shows the compile time of a rerun or resume;
* steady-state throughput — one warm-up call of the compiled chunk, then
  `--repeats` timed calls (`jax.block_until_ready` on the returned states and
  metrics), chaining the states as training does; the median call time gives
  seed-iterations/s = iterations per call × S / time (S = requested seeds, not
  the padded count, as in the runner's `perf/seed_iters_per_s`) and per-seed
  iterations/s;
* memory — on GPU the allocator's `peak_bytes_in_use` from
  `device.memory_stats()` (summed over the devices used); on CPU the peak
  resident set size of the process (`resource.getrusage().ru_maxrss`) and its
  growth during the case (from just before the states are built to the end of
  the timed calls); plus the size of the learner state of all (padded) seeds
  and XLA's compiled temp-buffer estimate (`compiled.memory_analysis()`);
* the backend, device kind and the number of devices the seed axis is sharded
  over.

By default each case runs in a fresh subprocess (`--in-process` turns this off)
so that the peak memory, which only ever grows within a process, belongs to that
case alone, and a GPU run starts from an empty allocator.

Not measured: the host-side work between chunks in `train` (metric rows to CSV,
checkpoint) — small next to the chunk — and the chunk length: training runs
chunks of up to `--chunk-iterations` (default 2000) iterations, the default
here is one evaluation period (100 iterations for Escape Room) per call so that
1000 seeds stay quick on a CPU; the per-iteration cost is the same, as a chunk
is a `lax.scan` over identical periods (use `--iterations 2000` to time
training's chunk exactly; on an H100, ER(2,1) × 10 seeds ran at 2414 it/s per
seed with 100-iteration calls and 2444 with 2000). Timings taken while other
processes load the machine (another `pimbot train`, say) are distorted; the
script warns when it sees one.

Finally it extrapolates the wall time of the 10-seed, 50 000-iteration ER(2,1)
run (compile + 50 000 iterations at the measured 10-seed rate) when that case
was measured.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import re
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ENV_ID = "escape_room-v0"
RESULT_MARKER = "THROUGHPUT_RESULT "
EXTRAPOLATE = {"config": "er21", "seeds": 10, "iterations": 50_000}


def parse_config(name: str) -> tuple[int, int]:
    """`er21` / `er4,3` / `er4_3` -> (n_agents, min_at_lever)."""
    match = re.fullmatch(r"er(\d)(\d)|er(\d+)[,_-](\d+)", name.lower())
    if not match:
        raise ValueError(f"expected erNM such as er21 or er43, got {name!r}")
    n, m = (int(g) for g in match.groups() if g is not None)
    return n, m


def config_arg(name: str) -> str:
    """argparse type of --configs: a valid config name, lower-cased."""
    try:
        parse_config(name)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return name.lower()


def config_label(name: str) -> str:
    n, m = parse_config(name)
    return f"ER({n},{m})"


def other_trainings() -> list[str]:
    """Command lines of other running `pimbot train` processes (Linux /proc)."""
    found = []
    proc = Path("/proc")
    if not proc.is_dir():
        return found
    for entry in proc.iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            argv = (entry / "cmdline").read_bytes().decode(errors="replace").split("\0")
        except OSError:
            continue
        words = [Path(a).name for a in argv if a]
        if "train" in words and any(w == "pimbot" or w.startswith("pimbot") for w in words):
            found.append(f"{entry.name}: {' '.join(a for a in argv if a)}")
    return found


def peak_rss_bytes() -> int:
    """Peak resident set size of this process so far (ru_maxrss: KiB on Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak if sys.platform == "darwin" else peak * 1024


def run_config(config: str, num_seeds: int, args: argparse.Namespace):
    """The `RunConfig` of one case; its `iterations` are those of one timed call."""
    from pimbot.training.config import RunConfig

    n, m = parse_config(config)
    run = RunConfig(
        env_id=ENV_ID,
        env_params=tuple(sorted({"n_agents": n, "min_at_lever": m}.items())),
        learner=args.learner,
        seeds=num_seeds,
        eval_period=args.eval_period,
        eval_episodes=args.eval_episodes,
        attack=args.attack,
    )
    eval_period, _ = run.resolved_eval()
    iterations = args.iterations if args.iterations is not None else eval_period
    return dataclasses.replace(run, iterations=iterations)


def run_case(config: str, num_seeds: int, args: argparse.Namespace) -> dict[str, Any]:
    """Builds, compiles and times one case in this process (jax imported here, lazily)."""
    from pimbot import jax_setup

    jax_setup.use_all_cpu_cores()  # before jax is imported, as `pimbot train` does

    import jax

    if args.compilation_cache:
        cache_dir = jax_setup.enable_compilation_cache()
    else:  # time a cold compile, whatever JAX_COMPILATION_CACHE_DIR says
        jax.config.update("jax_enable_compilation_cache", False)
        cache_dir = None
    if not args.rolled_threefry:
        jax_setup.unroll_cpu_threefry()  # as `pimbot train` does (enable_compilation_cache)

    from pimbot.training import runner
    from pimbot.training.config import resolve

    run = run_config(config, num_seeds, args)
    iterations = run.iterations
    resolved = resolve(run)
    num_periods = iterations // resolved.eval_period
    devices = jax.devices()
    rss_before = peak_rss_bytes()

    # States exactly as runner.train builds them.
    sharding, padded = runner.seed_sharding(run.seeds)
    keys = runner.seed_keys(run.first_seed, padded)
    init_keys = jax.vmap(lambda k: jax.random.fold_in(k, 0))(keys)
    eval_roots = jax.vmap(lambda k: jax.random.fold_in(k, 1))(keys)
    states = runner.init_states(resolved, init_keys)
    hooks = runner.program_args(resolved)
    if sharding is not None:
        states = jax.device_put(states, sharding)
        eval_roots = jax.device_put(eval_roots, sharding)
    jax.block_until_ready((states, eval_roots))
    state_bytes = sum(leaf.nbytes for leaf in jax.tree.leaves(states))

    t0 = time.perf_counter()
    chunk_fn = runner.make_chunk_fn(resolved, num_periods)
    chunk_fn = chunk_fn.lower(states, eval_roots, *hooks).compile()
    compile_s = time.perf_counter() - t0
    rss_compiled = peak_rss_bytes()
    try:
        analysis = chunk_fn.memory_analysis()
        xla_temp = int(analysis.temp_size_in_bytes) if analysis is not None else None
    except Exception:  # not every backend implements it
        xla_temp = None

    states, chunk_metrics = chunk_fn(states, eval_roots, *hooks)  # warm-up
    jax.block_until_ready((states, chunk_metrics))
    call_s = []
    for _ in range(args.repeats):
        t = time.perf_counter()
        states, chunk_metrics = chunk_fn(states, eval_roots, *hooks)
        jax.block_until_ready((states, chunk_metrics))
        call_s.append(time.perf_counter() - t)

    used = list(sharding.mesh.devices.flat) if sharding is not None else devices[:1]
    gpu_peak = None
    stats = [d.memory_stats() for d in used]
    if all(s and "peak_bytes_in_use" in s for s in stats):
        gpu_peak = sum(int(s["peak_bytes_in_use"]) for s in stats)
    rss_peak = peak_rss_bytes()

    median_s = statistics.median(call_s)
    return {
        "config": config,
        "label": config_label(config),
        "env_id": ENV_ID,
        "env_params": dict(run.env_params),
        "learner": args.learner,
        "seeds": num_seeds,
        "padded_seeds": padded,
        "backend": jax.default_backend(),
        "device_kind": devices[0].device_kind,
        "num_devices": len(used),
        "iterations_per_call": iterations,
        "eval_period": resolved.eval_period,
        "eval_episodes": resolved.eval_episodes,
        "repeats": args.repeats,
        "compile_s": compile_s,
        "compilation_cache": str(cache_dir) if cache_dir is not None else None,
        "call_s": call_s,
        "median_call_s": median_s,
        "seed_iters_per_s": iterations * num_seeds / median_s,
        "iters_per_s_per_seed": iterations / median_s,
        "memory_kind": "gpu_peak_bytes_in_use" if gpu_peak is not None else "cpu_peak_rss",
        "gpu_peak_bytes_in_use": gpu_peak,
        "peak_rss_bytes": rss_peak,
        "rss_growth_bytes": rss_peak - rss_before,
        "rss_growth_compile_bytes": rss_compiled - rss_before,
        "rss_growth_run_bytes": rss_peak - rss_compiled,
        "state_bytes": state_bytes,
        "xla_temp_bytes": xla_temp,
        "jax_version": jax.__version__,
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
    }


def run_isolated(config: str, num_seeds: int, args: argparse.Namespace) -> dict[str, Any]:
    """Runs one case in a fresh interpreter and returns its result."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--case", config, str(num_seeds)]
    cmd += ["--learner", args.learner, "--repeats", str(args.repeats)]
    if args.attack:
        cmd += ["--attack", args.attack]
    if args.compilation_cache:
        cmd.append("--compilation-cache")
    if args.rolled_threefry:
        cmd.append("--rolled-threefry")
    for flag, value in (
        ("--iterations", args.iterations),
        ("--eval-period", args.eval_period),
        ("--eval-episodes", args.eval_episodes),
    ):
        if value is not None:
            cmd += [flag, str(value)]
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, text=True)
    for line in proc.stdout.splitlines():
        if line.startswith(RESULT_MARKER):
            return json.loads(line[len(RESULT_MARKER) :])
    raise RuntimeError(f"case {config} × {num_seeds} seeds failed (exit status {proc.returncode})")


def mib(value: int | None) -> str:
    return "-" if value is None else f"{value / 2**20:,.1f}"


def duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.1f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.2f} h"


def table(results: list[dict[str, Any]]) -> str:
    gpu = any(r["memory_kind"] == "gpu_peak_bytes_in_use" for r in results)
    header = ["config", "seeds", "devices", "compile s", "call s", "seed-it/s", "it/s/seed"]
    header += ["GPU peak MiB"] if gpu else ["peak RSS MiB", "ΔRSS compile", "ΔRSS run"]
    header += ["state MiB", "XLA temp MiB"]
    rows = []
    for r in results:
        seeds = str(r["seeds"])
        if r["padded_seeds"] != r["seeds"]:
            seeds += f" ({r['padded_seeds']})"
        row = [
            r["label"],
            seeds,
            str(r["num_devices"]),
            f"{r['compile_s']:.2f}",
            f"{r['median_call_s']:.3f}",
            f"{r['seed_iters_per_s']:,.0f}",
            f"{r['iters_per_s_per_seed']:,.1f}",
        ]
        if gpu:
            row.append(mib(r["gpu_peak_bytes_in_use"]))
        else:
            row += [
                mib(r["peak_rss_bytes"]),
                mib(r["rss_growth_compile_bytes"]),
                mib(r["rss_growth_run_bytes"]),
            ]
        row += [mib(r["state_bytes"]), mib(r["xla_temp_bytes"])]
        rows.append(row)
    widths = [max(len(x[i]) for x in [header, *rows]) for i in range(len(header))]

    def fmt(cells: list[str]) -> str:
        first = cells[0].ljust(widths[0])
        rest = [c.rjust(w) for c, w in zip(cells[1:], widths[1:], strict=True)]
        return "  ".join([first, *rest])

    rule = "  ".join("-" * w for w in widths)
    return "\n".join([fmt(header), rule, *(fmt(row) for row in rows)])


def legend(results: list[dict[str, Any]]) -> str:
    r = results[0]
    gpu = any(x["memory_kind"] == "gpu_peak_bytes_in_use" for x in results)
    memory = (
        "GPU peak MiB = device.memory_stats()['peak_bytes_in_use'] (summed over devices)"
        if gpu
        else "peak RSS MiB = the case's process ru_maxrss (high-water mark); its growth in the "
        "case: ΔRSS compile = states + compile, ΔRSS run = the timed calls on top (CPU backend: "
        "no device allocator stats)"
    )
    per_case = "one fresh process per case" if r.get("isolated") else "all cases in one process"
    return "\n".join(
        [
            f"seeds: requested (padded to a multiple of the devices); devices: seed-axis shards; "
            f"{per_case}",
            f"call s: median of {r['repeats']} calls after a warm-up, each "
            f"{r['iterations_per_call']} iterations = "
            f"{r['iterations_per_call'] // r['eval_period']} × (eval_period {r['eval_period']} "
            f"+ evaluation of {r['eval_episodes']} episodes)",
            "compile s: jit(make_chunk_fn).lower(...).compile(), "
            + (
                f"persistent cache {r['compilation_cache']}"
                if r.get("compilation_cache")
                else "cold (no persistent cache)"
            )
            + "; seed-it/s = iterations × seeds / call s",
            memory,
            "state = learner state of all padded seeds; XLA temp = compiled.memory_analysis() "
            "temp buffers (per device program)",
        ]
    )


def extrapolation(results: list[dict[str, Any]]) -> str:
    target = EXTRAPOLATE
    match = [
        r for r in results if r["config"] == target["config"] and r["seeds"] == target["seeds"]
    ]
    if not match:
        return (
            "extrapolation: measure ER(2,1) at 10 seeds (--configs er21 --seeds 10) to extrapolate "
            "the 10-seed 50 000-iteration run"
        )
    r = match[0]
    train_s = target["iterations"] / r["iters_per_s_per_seed"]
    return (
        f"extrapolated 10-seed {target['iterations']:,}-iteration ER(2,1) {r['learner']} run: "
        f"{duration(r['compile_s'] + train_s)} (compile {r['compile_s']:.1f} s + "
        f"{target['iterations']:,} it at {r['iters_per_s_per_seed']:,.0f} it/s; "
        "excludes process start-up and per-chunk CSV/checkpoint writes)"
    )


# --- `--lio-report`: per-iteration cost of LIO, clean vs ADMO, growth with N, flops ---------

REPORT_CONFIGS = ("er21", "er42", "er43", "er84")
"""Cost growth with N is measured on these; the ADMO ratio on RATIO_CONFIGS."""
RATIO_CONFIGS = ("er21", "er43")
PEAK_FLOPS_PER_CYCLE = 32
"""fp32 AVX2 peak per core: 2 FMA units × 8 lanes × 2 flops (AVX-512 on Zen 4 is double-pumped
256-bit, the same per cycle)."""
ELEMENTWISE = {
    "add", "sub", "mul", "div", "neg", "max", "min", "exp", "log", "log1p", "expm1", "tanh",
    "logistic", "sqrt", "rsqrt", "pow", "integer_pow", "abs", "sign", "square", "exp2",
    "reduce_sum", "reduce_max", "reduce_min", "cumsum", "cumlogsumexp", "cummax", "erf",
    "select_n", "clamp", "ge", "gt", "le", "lt", "eq", "ne", "and", "or", "not",
}  # fmt: skip
"""Primitives counted as one flop per element (reductions per input element), as XLA's
cost analysis counts them; data movement (broadcast, reshape, slices, gathers) is free."""


def jaxpr_flops(jaxpr, branch=max) -> tuple[float, float]:
    """(matmul flops, other arithmetic flops) of a jaxpr, scan bodies times their length, a
    `cond` as its `branch` (max: the costliest branch; min: a lower bound).

    XLA's own cost analysis counts a loop body once; LIO's rollouts are `lax.scan`s over
    the episode's steps, so the count is taken on the jaxpr instead (same conventions:
    2·M·N·K per matmul, one flop per element of an arithmetic op).
    """
    import math

    dots = other = 0.0
    for eqn in jaxpr.eqns:
        name = eqn.primitive.name
        params = eqn.params
        subs = [v for v in params.values() if hasattr(v, "jaxpr") or hasattr(v, "eqns")]
        subs += [
            b for v in params.values() if isinstance(v, tuple) for b in v if hasattr(b, "jaxpr")
        ]
        if name == "scan":
            d, o = jaxpr_flops(params["jaxpr"].jaxpr, branch)
            dots, other = dots + params["length"] * d, other + params["length"] * o
        elif name == "cond":
            costs = [jaxpr_flops(b.jaxpr, branch) for b in params["branches"]]
            d, o = branch(costs, key=sum)
            dots, other = dots + d, other + o
        elif subs:
            for sub in subs:
                d, o = jaxpr_flops(getattr(sub, "jaxpr", sub), branch)
                dots, other = dots + d, other + o
        elif name == "dot_general":
            (contract, _), _ = params["dimension_numbers"]
            lhs = eqn.invars[0].aval.shape
            k = math.prod(lhs[i] for i in contract)
            dots += 2.0 * math.prod(eqn.outvars[0].aval.shape) * k
        elif name in ELEMENTWISE:
            sizes = [
                math.prod(v.aval.shape) for v in (*eqn.invars, *eqn.outvars) if hasattr(v, "aval")
            ]
            other += float(max(sizes, default=0))
    return dots, other


def core_peak() -> tuple[float | None, str]:
    """(fp32 peak flop/s of one core, description) from /proc/cpuinfo's current clock."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return None, "unknown CPU"
    model = re.search(r"model name\s*:\s*(.*)", text)
    mhz = re.search(r"cpu MHz\s*:\s*([\d.]+)", text)
    if not mhz:
        return None, model.group(1) if model else "unknown CPU"
    ghz = float(mhz.group(1)) / 1000
    desc = (
        f"{model.group(1) if model else 'CPU'} at {ghz:.2f} GHz × {PEAK_FLOPS_PER_CYCLE} flop/cycle"
    )
    return ghz * 1e9 * PEAK_FLOPS_PER_CYCLE, desc


def update_case(config: str, attack_name: str | None, seeds: int, iterations: int):
    """A compiled program of `iterations` LIO iterations for `seeds` seeds (one device), its
    states, and the flops of one seed-iteration. The learner's own `update`, scanned and
    vmapped over seeds as training does, metrics averaged as in a training period;
    no evaluation episodes (identical with and without the attack)."""
    import jax

    from pimbot.training.config import RunConfig, resolve

    n, m = parse_config(config)
    run = RunConfig(
        env_id=ENV_ID,
        env_params=tuple(sorted({"n_agents": n, "min_at_lever": m}.items())),
        learner="lio",
        seeds=seeds,
        attack=attack_name,
    )
    r = resolve(run)
    env, learner, cfg = r.env, r.learner, r.learner_config

    def init(key):
        return learner.init(key, env, cfg, r.attack, r.defenses)

    def step(state, attack, defenses):
        return learner.update(state, env, cfg, attack, defenses)

    def chunk(states, attack, defenses):
        def body(states, _):
            return jax.vmap(step, in_axes=(0, None, None))(states, attack, defenses)

        states, metrics = jax.lax.scan(body, states, None, length=iterations)
        return states, jax.tree.map(lambda x: x.mean(axis=0), metrics)

    states = jax.jit(jax.vmap(init))(jax.random.split(jax.random.PRNGKey(0), seeds))
    t0 = time.perf_counter()
    compiled = jax.jit(chunk).lower(states, r.attack, r.defenses).compile()
    compile_s = time.perf_counter() - t0
    one = jax.tree.map(lambda x: x[0], states)
    dots, other = jaxpr_flops(jax.make_jaxpr(step)(one, r.attack, r.defenses).jaxpr)
    xla = jax.jit(step).lower(one, r.attack, r.defenses).cost_analysis()  # HLO, not compiled
    xla = xla[0] if isinstance(xla, list) else xla
    return {
        "config": config,
        "attack": attack_name,
        "fn": lambda s: compiled(s, r.attack, r.defenses),
        "states": states,
        "compile_s": compile_s,
        "flops": dots + other,
        "matmul_flops": dots,
        "xla_flops_loops_once": float(xla.get("flops", 0.0)) if xla else None,
    }


def time_interleaved(cases: list[dict], repeats: int) -> None:
    """Warm-up, then `repeats` rounds calling every case once in turn (shared-machine noise
    hits the cases alike); stores the per-call times in each case."""
    import jax

    for case in cases:
        case["states"], _ = jax.block_until_ready(case["fn"](case["states"]))
        case["call_s"] = []
    for _ in range(repeats):
        for case in cases:
            t = time.perf_counter()
            case["states"], metrics = jax.block_until_ready(case["fn"](case["states"]))
            case["call_s"].append(time.perf_counter() - t)


def lio_report(args: argparse.Namespace) -> int:
    """Prints the LIO per-iteration report (see `--lio-report`)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    import jax

    jax.config.update("jax_enable_compilation_cache", False)
    if not args.rolled_threefry:
        from pimbot import jax_setup

        jax_setup.unroll_cpu_threefry()  # as `pimbot train` does
    seeds, iterations = args.report_seeds, args.report_iterations
    peak, peak_desc = core_peak()
    wanted = [(c, None) for c in REPORT_CONFIGS] + [(c, "admo") for c in RATIO_CONFIGS]
    cases = []
    for config, attack in wanted:
        print(
            f"  compiling {config_label(config)} {attack or 'clean'} …", file=sys.stderr, flush=True
        )
        cases.append(update_case(config, attack, seeds, iterations))
    time_interleaved(cases, args.repeats)
    for case in cases:
        case["iter_s"] = statistics.median(case["call_s"]) / iterations
        case["seed_it_s"] = seeds / case["iter_s"]
    clean = {c["config"]: c for c in cases if c["attack"] is None}
    admo = {c["config"]: c for c in cases if c["attack"] == "admo"}
    print(
        f"\nLIO on {ENV_ID}: {seeds} seeds, {iterations} iterations per call, median of "
        f"{args.repeats} interleaved calls, {cores} core(s) in this process's affinity, "
        f"jax {jax.__version__} {jax.default_backend()}"
    )
    print("\nADMO vs clean iteration time (target ≤ ×1.3)")
    print(f"{'config':<8} {'clean ms/it':>12} {'ADMO ms/it':>12} {'ratio':>7}")
    for config in RATIO_CONFIGS:
        c, a = clean[config], admo[config]
        print(
            f"{config_label(config):<8} {1e3 * c['iter_s']:>12.3f} {1e3 * a['iter_s']:>12.3f} "
            f"{a['iter_s'] / c['iter_s']:>6.2f}×"
        )
    print("\nClean LIO: throughput, cost growth with N, flops (per seed-iteration)")
    header = f"{'config':<8} {'seed-it/s':>10} {'per core':>10} {'µs/seed-it':>11} {'MFLOP':>7}"
    header += f" {'matmul %':>9} {'GFLOP/s':>8} {'% peak':>7} {'XLA MFLOP*':>11}"
    print(header)
    base = clean[REPORT_CONFIGS[0]]
    for config in REPORT_CONFIGS:
        c = clean[config]
        rate = c["flops"] * c["seed_it_s"]
        share = f"{100 * rate / (peak * cores):.1f}" if peak else "-"
        xla = c["xla_flops_loops_once"]
        print(
            f"{config_label(config):<8} {c['seed_it_s']:>10,.0f} {c['seed_it_s'] / cores:>10,.0f} "
            f"{1e6 / c['seed_it_s']:>11.2f} {c['flops'] / 1e6:>7.3f} "
            f"{100 * c['matmul_flops'] / c['flops']:>8.0f}% {rate / 1e9:>8.2f} {share:>7} "
            f"{(xla or 0) / 1e6:>11.3f}"
        )
    import math

    print("\ncost growth: time per seed-iteration relative to ER(2,1) (exponent of N)")
    for config in REPORT_CONFIGS[1:]:
        n = parse_config(config)[0]
        ratio = base["seed_it_s"] / clean[config]["seed_it_s"]
        print(f"  {config_label(config)}: ×{ratio:.2f} (N^{math.log(ratio) / math.log(n / 2):.2f})")
    print(
        f"\npeak: {peak_desc}"
        + (f" = {peak / 1e9:.1f} GFLOP/s per core" if peak else "")
        + "; MFLOP from the jaxpr of one iteration (scan bodies × their length, 2·M·N·K per "
        "matmul, one flop per element otherwise); XLA MFLOP* = XLA's cost_analysis() of one "
        "iteration (lowered HLO), which counts each loop body (the rollout's steps) once"
    )
    return 0


def positive_int(text: str) -> int:
    """argparse type: an integer ≥ 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer ≥ 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer ≥ 1, got {value}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        description="Throughput, compile time and memory of pimbot training (see module docstring)."
    )
    parser.add_argument(
        "--seeds", type=positive_int, nargs="+", default=[10, 100, 1000], help="seed counts S"
    )
    parser.add_argument(
        "--configs",
        nargs="+",
        type=config_arg,
        default=["er21", "er43"],
        help="Escape Room configs erNM = ER(N agents, M at the lever)",
    )
    parser.add_argument("--learner", default="lio", help="learner (see `pimbot learners`)")
    parser.add_argument(
        "--attack", default=None, help="attack with default parameters (see `pimbot attacks`)"
    )
    parser.add_argument(
        "--iterations",
        type=positive_int,
        default=None,
        help="training iterations per timed call, a multiple of eval_period "
        "(default: one eval period, 100 for Escape Room; `pimbot train` uses chunks of up to "
        "--chunk-iterations, default 2000)",
    )
    parser.add_argument(
        "--repeats", type=positive_int, default=3, help="timed calls after the warm-up"
    )
    parser.add_argument(
        "--eval-period", type=positive_int, default=None, help="default: as in training"
    )
    parser.add_argument(
        "--eval-episodes", type=positive_int, default=None, help="default: as in training"
    )
    parser.add_argument("--json", type=Path, default=None, help="also write the results here")
    parser.add_argument(
        "--compilation-cache",
        action="store_true",
        help="use pimbot's persistent compilation cache as `pimbot train` does "
        "(default: off, cold compiles)",
    )
    parser.add_argument(
        "--rolled-threefry",
        action="store_true",
        help="keep JAX's CPU lowering of the PRNG (a five-trip loop per random call) instead "
        "of the unrolled one `pimbot train` uses (jax_setup.unroll_cpu_threefry; same results)",
    )
    parser.add_argument(
        "--in-process",
        action="store_true",
        help="run all cases in this process (faster; peak memory then accumulates across cases)",
    )
    parser.add_argument(
        "--lio-report",
        action="store_true",
        help="instead: LIO clean vs ADMO iteration time on ER(2,1), ER(4,3) with the ratio, "
        "seed-iterations/s per core and cost growth over ER(2,1), ER(4,2), ER(4,3), ER(8,4), "
        "flops and fraction of peak (pin it: taskset -c 0 python benchmarks/throughput.py "
        "--lio-report)",
    )
    parser.add_argument("--report-seeds", type=positive_int, default=10, help="--lio-report seeds")
    parser.add_argument(
        "--report-iterations", type=positive_int, default=200, help="--lio-report iterations/call"
    )
    parser.add_argument("--case", nargs=2, metavar=("CONFIG", "SEEDS"), help=argparse.SUPPRESS)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.case:  # child process of an isolated run
        result = run_case(args.case[0], int(args.case[1]), args)
        print(RESULT_MARKER + json.dumps(result), flush=True)
        return 0

    from pimbot import jax_setup

    jax_setup.use_all_cpu_cores()  # before anything imports jax (cases in this process use it)
    if args.lio_report:
        return lio_report(args)
    from pimbot.envs.core import InvalidParameter
    from pimbot.training.config import resolve

    try:  # fail on bad options before running anything
        for config in args.configs:
            resolve(run_config(config, min(args.seeds), args))
    except InvalidParameter as error:
        parser.error(str(error))

    busy = other_trainings()
    if busy:
        print("warning: other `pimbot train` processes are running; timings are distorted:")
        for line in busy:
            print(f"  {line}")
        sys.stdout.flush()
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()

    results = []
    for config in args.configs:
        for num_seeds in sorted(args.seeds):
            print(f"  {config_label(config)} × {num_seeds} seeds …", file=sys.stderr, flush=True)
            if args.in_process:
                result = run_case(config, num_seeds, args)
            else:
                try:
                    result = run_isolated(config, num_seeds, args)
                except RuntimeError as error:
                    print(f"throughput: {error}", file=sys.stderr)
                    return 1
            result["isolated"] = not args.in_process
            results.append(result)

    first = results[0]
    under = f" under {args.attack}" if args.attack else ""
    header = (
        f"{args.learner} on {ENV_ID}{under}: backend {first['backend']} ({first['device_kind']}), "
        f"jax {first['jax_version']}, {cores} CPU cores"
    )
    if load:
        header += f", load average {load[0]:.2f} at start"
    print(f"\n{header}")
    print(table(results))
    print()
    print(legend(results))
    print(extrapolation(results))

    if args.json:
        payload = {
            "benchmark": "throughput",
            "host": {
                "platform": platform.platform(),
                "python": platform.python_version(),
                "cpu_cores": cores,
                "load_average_at_start": load,
                "other_pimbot_train_processes": busy,
            },
            "args": {k: v for k, v in vars(args).items() if k not in ("json", "case")},
            "results": results,
            "extrapolation": extrapolation(results),
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(payload, indent=2, default=str) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
