"""Times the original Reciprocator code (johnlyzhou/reciprocator, torch) on 2-player IPD.

    REC_VENV/bin/python benchmarks/original/time_original_reciprocator.py CHECKOUT
        [--updates 10] [--warmup 2] [--config configs/ipd.yaml]

Runs in the venv made by setup_reciprocator.sh, on the CPU. It builds the original's
own `src.training.ipd_trainer.IPDTrainer` from the original's `configs/ipd.yaml`
(two Reciprocators, 2048 parallel games × 32 steps, width-2 policy, K_epochs 10) and
calls its own `train(warmup + updates)`, changing only config values, never its logic:
`logs.checkpoint_interval` goes past the end, so the only checkpoint is the final
save, which is not timed. The trainer keeps `random_seed` in its config but never
seeds torch; this script calls `torch.manual_seed(random_seed)` first.

One update = one episode of the original's loop: `episode_start`, 32 `step`s of the
2048 games (both agents act, observe), `episode_end` (the episode log, then each
agent's `update`: the exact tabular VoI, the reciprocal reward and `K_epochs` PPO
epochs). To time episodes without editing the loop, the trainer's `episode_start` and
`episode_end` are wrapped on the instance: the wrappers record the time and call the
originals. s per update = (end of the last episode − start of episode `warmup`) /
`updates`; the first `warmup` episodes are excluded. The same span is also measured
in process CPU time (`time.process_time`, all threads), less distorted than wall
time when the core is shared. tqdm's progress bars are turned
off (TQDM_DISABLE=1) and the trainer's per-episode log print goes to stderr.
It prints one line `ORIGINAL_RECIPROCATOR_RESULT {json}`.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import tempfile
import time

MARKER = "ORIGINAL_RECIPROCATOR_RESULT "


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkout", help="checkout of johnlyzhou/reciprocator")
    parser.add_argument("--updates", type=int, default=10)
    parser.add_argument("--warmup", type=int, default=2)
    parser.add_argument("--config", default="configs/ipd.yaml", help="relative to the checkout")
    args = parser.parse_args()

    checkout = os.path.abspath(args.checkout)
    sys.path.insert(0, checkout)
    os.environ["TQDM_DISABLE"] = "1"

    import torch
    from omegaconf import OmegaConf
    from src.training.ipd_trainer import IPDTrainer

    torch.set_num_threads(len(os.sched_getaffinity(0)))
    config = OmegaConf.load(os.path.join(checkout, args.config))
    total = args.warmup + args.updates
    config.logs.checkpoint_interval = total + 1
    config.name = "ipd_timing"
    torch.manual_seed(config.random_seed)

    out_dir = tempfile.mkdtemp(prefix="reciprocator_timing_")
    trainer = IPDTrainer(config, torch.device("cpu"), out_dir)
    starts: list[float] = []
    ends: list[float] = []
    cpu_starts: list[float] = []
    cpu_ends: list[float] = []
    original_start, original_end = trainer.episode_start, trainer.episode_end

    def timed_start():
        starts.append(time.perf_counter())
        cpu_starts.append(time.process_time())
        original_start()

    def timed_end():
        original_end()
        ends.append(time.perf_counter())
        cpu_ends.append(time.process_time())

    trainer.episode_start, trainer.episode_end = timed_start, timed_end
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(sys.stderr):
        trainer.train(total)
    wall = time.perf_counter() - t0

    assert len(starts) == len(ends) == total, (len(starts), len(ends), total)
    per_update = (ends[-1] - starts[args.warmup]) / args.updates
    episodes = [ends[i] - starts[i] for i in range(args.warmup, total)]
    env = config.environment
    result = {
        "updates_timed": args.updates,
        "warmup": args.warmup,
        "s_per_update": per_update,
        "cpu_s_per_update": (cpu_ends[-1] - cpu_starts[args.warmup]) / args.updates,
        "min_episode_s": min(episodes),
        "max_episode_s": max(episodes),
        "setup_and_warmup_s": starts[args.warmup] - t0,
        "wall_s": wall,
        "batch_size": env.batch_size,
        "max_steps": env.max_steps,
        "n_latent_var": config.agents.n_latent_var,
        "K_epochs": config.agents.K_epochs,
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "python": sys.version.split()[0],
        "affinity": sorted(os.sched_getaffinity(0)),
    }
    print(MARKER + json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
