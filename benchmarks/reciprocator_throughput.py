"""Training throughput of the Reciprocator learner: seed-updates/s and parallel episodes/s.

    python benchmarks/reciprocator_throughput.py [--configs ipd er21 sh2] [--seeds 10]
        [--num-envs 128] [--updates 20] [--repeats 3]

Times the runner's compiled chunk (`make_chunk_fn`: `updates` training
iterations, then one evaluation), built exactly as `pimbot train` builds it
(seed keys, `jit(vmap(init))`, seed sharding over the host devices). One update
= one batch of `num_envs` parallel episodes per seed, a VoI-model refit every
`voi_refit_period` updates and one PPO update, so

* seed-updates/s = updates × seeds / median call time,
* parallel episodes/s = seed-updates/s × num_envs (environment steps/s = that × T).

Timings taken while other processes load the machine are distorted.
"""

from __future__ import annotations

import argparse
import statistics
import time

from pimbot import jax_setup

jax_setup.use_all_cpu_cores()

import jax  # noqa: E402

from pimbot.experiment.config import RunConfig, resolve  # noqa: E402
from pimbot.experiment.runner import (  # noqa: E402
    init_states,
    make_chunk_fn,
    seed_keys,
    seed_sharding,
)

CONFIGS = {
    "ipd": ("ipd-v0", ()),
    "ipd32": ("ipd-v0", (("max_steps", 32),)),
    "er21": ("escape_room-v0", ()),
    "er43": ("escape_room-v0", (("min_at_lever", 3), ("n_agents", 4))),
    "sh2": ("stag_hunt-v0", ()),
    "sh4": ("stag_hunt-v0", (("n_players", 4),)),
}


def measure(name: str, seeds: int, num_envs: int, updates: int, repeats: int) -> dict:
    env_id, params = CONFIGS[name]
    run = RunConfig(
        env_id,
        params,
        learner="reciprocator",
        hparams=(("num_envs", num_envs),),
        seeds=seeds,
        iterations=updates,
        eval_period=updates,
    )
    resolved = resolve(run)
    env = resolved.env
    sharding, padded = seed_sharding(seeds)
    keys = seed_keys(0, padded)
    states = init_states(resolved, jax.vmap(lambda k: jax.random.fold_in(k, 0))(keys))
    hooks = (resolved.attack, resolved.defenses)
    roots = jax.vmap(lambda k: jax.random.fold_in(k, 1))(keys)
    if sharding is not None:
        states, roots = jax.device_put(states, sharding), jax.device_put(roots, sharding)
    t0 = time.perf_counter()
    chunk = make_chunk_fn(resolved, 1).lower(states, roots, *hooks).compile()
    compile_s = time.perf_counter() - t0
    states, _ = jax.block_until_ready(chunk(states, roots, *hooks))  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        states, metrics = jax.block_until_ready(chunk(states, roots, *hooks))
        times.append(time.perf_counter() - t0)
    call_s = statistics.median(times)
    seed_updates = updates * seeds / call_s
    return {
        "config": name,
        "agents": env.num_agents,
        "T": env.max_steps,
        "seeds": seeds,
        "num_envs": num_envs,
        "compile_s": compile_s,
        "call_s": call_s,
        "seed_updates_per_s": seed_updates,
        "episodes_per_s": seed_updates * num_envs,
        "env_steps_per_s": seed_updates * num_envs * env.max_steps,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", nargs="+", default=["ipd", "er21", "sh2"], choices=CONFIGS)
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--num-envs", type=int, default=128)
    parser.add_argument("--updates", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(f"backend {jax.default_backend()}, {len(jax.devices())} device(s)")
    header = (
        f"{'config':7} {'N':>2} {'T':>3} {'seeds':>5} {'envs':>5} {'compile s':>9} "
        f"{'call s':>7} {'seed-upd/s':>10} {'episodes/s':>11} {'env steps/s':>12}"
    )
    print(header)
    for name in args.configs:
        r = measure(name, args.seeds, args.num_envs, args.updates, args.repeats)
        print(
            f"{r['config']:7} {r['agents']:>2} {r['T']:>3} {r['seeds']:>5} {r['num_envs']:>5} "
            f"{r['compile_s']:>9.1f} {r['call_s']:>7.2f} {r['seed_updates_per_s']:>10.1f} "
            f"{r['episodes_per_s']:>11.0f} {r['env_steps_per_s']:>12.0f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
