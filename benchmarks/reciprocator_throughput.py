"""Reciprocator time per update and compile time: the original IPD configuration and the
learned-VoI path.

    taskset -c 0 python benchmarks/reciprocator_throughput.py [--configs ipd_matrix ...]
        [--seeds 1] [--updates 10] [--repeats 3] [--original-s 0.85]

Configurations (2-player IPD at the original's batch: 2048 games × 32 steps per update):

* `ipd_matrix`  — the matrix-game default, the original's IPD agent: exact VoI, one-step
  grudge, width-2 networks (what `pimbot train ipd-v0 max_steps=32 --learner
  reciprocator` runs);
* `ipd_learned` — the same batch with the learned VoI models, 64×64 networks and the
  spec's accumulated balance (`--hp voi=learned ...`);
* `er21`        — Escape Room ER(2,1) with its default (learned VoI, 128 episodes/update).

It times the runner's compiled chunk (`make_chunk_fn`: `updates` training iterations
and one evaluation), built as `pimbot train` builds it, and prints the median time per
update per seed (call time / updates / seeds; with one seed, the time of one update),
the compile time, and with `--original-s` the ratio to the original code's time per
update (the issue's measurement of the original torch code on one pinned core: 0.85 s;
benchmarks/original/ measures it side by side). Pin to one core (`taskset -c 0`) for a
per-core figure. "(cpu)" columns are the process's CPU time instead of wall time: on a
machine other processes load, wall time counts the waits for the core and CPU time does
not (pinned to one core, the two agree on an idle machine).
"""

from __future__ import annotations

import argparse
import statistics
import time

from pimbot import jax_setup

jax_setup.use_all_cpu_cores()

import jax  # noqa: E402

from pimbot.suites.presets import SPEC_BALANCE  # noqa: E402
from pimbot.training.config import RunConfig, resolve  # noqa: E402
from pimbot.training.runner import (  # noqa: E402
    init_states,
    make_chunk_fn,
    program_args,
    seed_keys,
    seed_sharding,
)

IPD32 = (("max_steps", 32),)
LEARNED = SPEC_BALANCE  # the spec's general agent: learned VoI, accumulated balance
CONFIGS = {
    "ipd_matrix": ("ipd-v0", IPD32, ()),
    "ipd_learned": ("ipd-v0", IPD32, LEARNED + (("num_envs", 2048),)),
    "er21": ("escape_room-v0", (), ()),
}


def measure(name: str, seeds: int, updates: int, repeats: int) -> dict:
    env_id, params, hparams = CONFIGS[name]
    run = RunConfig(
        env_id,
        params,
        learner="reciprocator",
        hparams=hparams,
        seeds=seeds,
        iterations=updates,
        eval_period=updates,
    )
    resolved = resolve(run)
    sharding, padded = seed_sharding(seeds)
    keys = seed_keys(0, padded)
    states = init_states(resolved, jax.vmap(lambda k: jax.random.fold_in(k, 0))(keys))
    hooks = program_args(resolved)
    roots = jax.vmap(lambda k: jax.random.fold_in(k, 1))(keys)
    if sharding is not None:
        states, roots = jax.device_put(states, sharding), jax.device_put(roots, sharding)
    t0, c0 = time.perf_counter(), time.process_time()
    chunk = make_chunk_fn(resolved, 1).lower(states, roots, *hooks).compile()
    compile_s, compile_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    states, _ = jax.block_until_ready(chunk(states, roots, *hooks))  # warm-up
    times, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        states, _ = jax.block_until_ready(chunk(states, roots, *hooks))
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    cfg = resolved.learner_config
    return {
        "config": name,
        "T": resolved.env.max_steps,
        "num_envs": cfg.num_envs,
        "voi": cfg.voi,
        "hidden": "x".join(map(str, cfg.policy_hidden)),
        "compile_s": compile_s,
        "compile_cpu_s": compile_cpu_s,
        "update_s": statistics.median(times) / updates / seeds,
        "update_cpu_s": statistics.median(cpu) / updates / seeds,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=CONFIGS)
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--updates", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--original-s", type=float, default=None, help="the original's seconds per update"
    )
    args = parser.parse_args()
    print(f"backend {jax.default_backend()}, {len(jax.devices())} device(s), seeds {args.seeds}")
    print(
        f"{'config':12} {'T':>3} {'envs':>5} {'voi':>8} {'hidden':>6} {'compile s':>9} "
        f"{'(cpu)':>6} {'s/update':>9} {'(cpu)':>7}"
        + (f" {'× original':>10} {'(cpu)':>6}" if args.original_s else "")
    )
    for name in args.configs:
        r = measure(name, args.seeds, args.updates, args.repeats)
        line = (
            f"{r['config']:12} {r['T']:>3} {r['num_envs']:>5} {r['voi']:>8} {r['hidden']:>6} "
            f"{r['compile_s']:>9.1f} {r['compile_cpu_s']:>6.1f} {r['update_s']:>9.4f} "
            f"{r['update_cpu_s']:>7.4f}"
        )
        if args.original_s:
            line += f" {args.original_s / r['update_s']:>10.1f}"
            line += f" {args.original_s / r['update_cpu_s']:>6.1f}"
        print(line, flush=True)


if __name__ == "__main__":
    main()
