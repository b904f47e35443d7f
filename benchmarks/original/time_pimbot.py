"""Times pimbot beside the original code: LIO on Escape Room, the Reciprocator on IPD.

    .venv/bin/python benchmarks/original/time_pimbot.py lio [--seeds 10] [--chunks 4]
        [--chunk-iterations 2000] [--n-agents 2] [--min-at-lever 1]
    .venv/bin/python benchmarks/original/time_pimbot.py reciprocator [--updates-per-chunk 4]
        [--chunks 3] [--preset original|defaults] [--hp NAME=VALUE ...]

What runs is `pimbot.training.runner.train`, the function behind `pimbot train`
(progress display off, into a temporary run directory), so whatever the learner
does today (a fast path included) is what is timed. Each chunk of training is one
`perf/seed_iters_per_s` row, measured by the runner itself around the compiled
calls (no CSV writing or checkpointing inside). The first chunk is a warm-up and is
left out when there are two or more; the figure is the median of the others.
`compile_s` is the runner's own compile time (cold: the persistent cache is not
turned on here). The CPU-time figure (`seed_iterations_per_cpu_s`) is the process
CPU time (`time.process_time`, all threads) between consecutive chunk callbacks
(so it includes the runner's CSV append and checkpoint, small next to a chunk), the
median over chunks 2…n: less distorted than wall time when the core is shared.

* `lio`: the original's ER config (pimbot's LIO defaults follow the original
  paper's ER hyperparameters), `--seeds` seeds at once, chunks of 2000 iterations
  (training's chunk) with an evaluation every 100 iterations as in training.
* `reciprocator`: `ipd-v0` at the original's batch, 2048 parallel games × 32 steps
  per update (`num_envs=2048`, `max_steps=32`), one seed; an evaluation after each
  chunk (`eval_period` = the chunk). `--preset original` asks for the original IPD
  agent (width-2 policy, exact tabular VoI, one-step grudge), `--preset general`
  for pimbot's general agent (64×64 networks, learned VoI models, accumulated
  balance), `--preset defaults` for this version's defaults on ipd-v0; of each
  preset only the hyperparameters that exist in this version's `ReciprocatorConfig`
  are passed (see PRESETS), so the script runs on older and newer versions alike.
  `--hp NAME=VALUE` adds or overrides any hyperparameter. The hyperparameters given
  and the learner config they resolve to are printed.

It prints one line `PIMBOT_RESULT {json}`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import sys
import tempfile
import time

from pimbot import jax_setup

jax_setup.use_all_cpu_cores()

import jax  # noqa: E402

from pimbot import learners  # noqa: E402
from pimbot.training import runner  # noqa: E402
from pimbot.training.config import RunConfig, resolve  # noqa: E402

MARKER = "PIMBOT_RESULT "
# Presets: the hyperparameters that express an agent, as names of pimbot versions old and
# new; only those that exist in the running version's ReciprocatorConfig are passed.
PRESETS = {
    # the original code's IPD agent: width-2 policy, exact tabular VoI, one-step grudge
    "original": {
        "policy_hidden": "2",
        "voi": "exact",
        "grudge": "one_step",
        "original_one_step_grudge": "true",
    },
    # pimbot's general agent: 64x64 networks, learned VoI models, accumulated balance
    "general": {
        "policy_hidden": "64,64",
        "voi_hidden": "64,64",
        "voi": "learned",
        "grudge": "accumulated",
        "original_one_step_grudge": "false",
    },
    # whatever this version's defaults for ipd-v0 are
    "defaults": {},
}


def timed_train(run: RunConfig, chunk_iterations: int) -> dict:
    """Trains `run` into a temporary directory; the runner's per-chunk throughput."""
    rows_per_chunk: list[dict] = []
    marks: list[tuple[int, float, float]] = []  # (iterations done, wall, CPU) per chunk

    def on_chunk(done, states, rows):
        rows_per_chunk.append(rows[0])
        marks.append((done, time.perf_counter(), time.process_time()))

    with tempfile.TemporaryDirectory(prefix="pimbot_timing_") as run_dir:
        t0 = time.perf_counter()
        result = runner.train(
            run, run_dir, progress=False, chunk_iterations=chunk_iterations, on_chunk=on_chunk
        )
        wall = time.perf_counter() - t0
    per_chunk = [float(r["perf/seed_iters_per_s"]) for r in rows_per_chunk]
    timed = per_chunk[1:] if len(per_chunk) > 1 else per_chunk
    rate = statistics.median(timed)
    seeds = run.seeds
    cpu_rates = [
        (d1 - d0) * seeds / (c1 - c0)
        for (d0, _, c0), (d1, _, c1) in zip(marks, marks[1:], strict=False)
    ]
    return {
        "seed_iterations_per_s": rate,
        "seed_iterations_per_cpu_s": statistics.median(cpu_rates) if cpu_rates else None,
        "per_chunk_seed_iterations_per_cpu_s": cpu_rates,
        "per_chunk_seed_iterations_per_s": per_chunk,
        "compile_s": float(result.summary.get("compile_s", float("nan"))),
        "wall_s": wall,
    }


def resolved_hparams(run: RunConfig) -> dict:
    cfg = resolve(run).learner_config
    return {f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg)}


def lio(args: argparse.Namespace) -> dict:
    run = RunConfig(
        "escape_room-v0",
        tuple(sorted({"n_agents": args.n_agents, "min_at_lever": args.min_at_lever}.items())),
        learner="lio",
        seeds=args.seeds,
        iterations=args.chunks * args.chunk_iterations,
    )
    out = timed_train(run, args.chunk_iterations)
    out.update(
        case="lio",
        config=f"ER({args.n_agents},{args.min_at_lever})",
        seeds=args.seeds,
        chunk_iterations=args.chunk_iterations,
        per_seed_iterations_per_s=out["seed_iterations_per_s"] / args.seeds,
    )
    return out


def reciprocator(args: argparse.Namespace) -> dict:
    fields = {f.name for f in dataclasses.fields(learners.get("reciprocator").config_cls)}
    hparams = {"num_envs": "2048"}
    hparams.update({k: v for k, v in PRESETS[args.preset].items() if k in fields})
    for pair in args.hp:
        name, _, value = pair.partition("=")
        hparams[name.strip().replace("-", "_")] = value.strip()
    n = args.updates_per_chunk
    run = RunConfig(
        "ipd-v0",
        (("max_steps", 32),),
        learner="reciprocator",
        hparams=tuple(sorted(hparams.items())),
        seeds=1,
        iterations=args.chunks * n,
        eval_period=n,
    )
    out = timed_train(run, n)
    out.update(
        case="reciprocator",
        preset=args.preset,
        updates_per_chunk=n,
        s_per_update=1.0 / out["seed_iterations_per_s"],
        hparams_given=hparams,
        learner_config=resolved_hparams(run),
    )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="case", required=True)
    p = sub.add_parser("lio")
    p.add_argument("--seeds", type=int, default=10)
    p.add_argument("--chunks", type=int, default=4)
    p.add_argument("--chunk-iterations", type=int, default=2000)
    p.add_argument("--n-agents", type=int, default=2)
    p.add_argument("--min-at-lever", type=int, default=1)
    p = sub.add_parser("reciprocator")
    p.add_argument("--updates-per-chunk", type=int, default=4)
    p.add_argument("--chunks", type=int, default=3)
    p.add_argument("--preset", choices=sorted(PRESETS), default="original")
    p.add_argument("--hp", nargs="*", default=[], metavar="NAME=VALUE")
    args = parser.parse_args()
    out = lio(args) if args.case == "lio" else reciprocator(args)
    out.update(
        backend=jax.default_backend(),
        devices=len(jax.devices()),
        jax=jax.__version__,
        affinity=sorted(os.sched_getaffinity(0)),
        python=sys.version.split()[0],
    )
    print(MARKER + json.dumps(out, default=str), flush=True)


if __name__ == "__main__":
    main()
