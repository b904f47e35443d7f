"""Runs the original Reciprocator IPD trainer (johnlyzhou/reciprocator) for one seed and logs
its mutual-cooperation rate per update.

    REC_VENV/bin/python benchmarks/original/run_original_reciprocator_ipd.py CHECKOUT
        --seed S [--updates 100] [--config configs/ipd.yaml] --out DIR

Runs in the venv made by setup_reciprocator.sh, on the CPU, one seed per process. It
builds the original's own `src.training.ipd_trainer.IPDTrainer` from its
`configs/ipd.yaml` (two Reciprocators, 2048 parallel games × 32 steps) and calls its own
`train(updates)`. Config values changed: ``random_seed`` = S (the trainer stores it and
never uses it; this script calls ``torch.manual_seed(S)`` before the trainer is built, the
only seeding there is), ``name``, and ``logs.checkpoint_interval`` past the end (only the
final save runs, into DIR). Nothing of the algorithm is changed and no file of the
checkout is edited.

What is logged, per update (one episode of the original's loop = one update):

- the trainer's own episode log (``IPDStats.logs``: each player's mean reward per step and
  p(cooperate), and the Reciprocator's extra fields), saved by its own ``save()`` as
  ``out_<updates>.json`` in DIR;
- ``updates.csv`` in DIR, one row per update: ``update`` (1-based), ``mutual_cooperation``
  (the share of the 2048 games × 32 steps in which both players cooperate, i.e. action
  0 for both), each player's ``p_cooperate_i`` and ``reward_i`` (per step, as the original
  logs them), and the wall and CPU seconds of the update. ``mutual_cooperation`` is not in
  the original's log: the script wraps the trainer's ``logs.update(actions)`` on the
  instance, counts the rows of ``actions`` that are all 0, then calls the original.
  These are the training episodes' own actions (sampled from the current policies),
  the same rollouts the original's p(cooperate) is computed from.

It prints one line ``ORIGINAL_RECIPROCATOR_IPD_RUN {json}`` with the seed's totals.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import sys
import time
from pathlib import Path

MARKER = "ORIGINAL_RECIPROCATOR_IPD_RUN "
COLUMNS = (
    "update",
    "mutual_cooperation",
    "p_cooperate_0",
    "p_cooperate_1",
    "reward_0",
    "reward_1",
    "wall_s",
    "cpu_s",
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkout", help="checkout of johnlyzhou/reciprocator")
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--updates", type=int, default=100)
    parser.add_argument("--config", default="configs/ipd.yaml", help="relative to the checkout")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()

    checkout = os.path.abspath(args.checkout)
    sys.path.insert(0, checkout)
    os.environ["TQDM_DISABLE"] = "1"

    import torch
    from omegaconf import OmegaConf
    from src.training.ipd_trainer import IPDTrainer

    torch.set_num_threads(len(os.sched_getaffinity(0)))
    config = OmegaConf.load(os.path.join(checkout, args.config))
    config.random_seed = args.seed
    config.name = f"ipd_seed{args.seed}"
    config.logs.checkpoint_interval = args.updates + 1
    torch.manual_seed(args.seed)

    args.out.mkdir(parents=True, exist_ok=True)
    wall0, cpu0 = time.perf_counter(), time.process_time()
    trainer = IPDTrainer(config, torch.device("cpu"), str(args.out))
    counts = {"both": 0.0, "steps": 0}
    rows: list[dict] = []
    stamps = {}
    original_update = trainer.logs.update
    original_start, original_end = trainer.episode_start, trainer.episode_end

    def counted_update(actions):
        counts["both"] += (actions == 0).all(dim=1).float().mean().item()
        counts["steps"] += 1
        original_update(actions)

    def timed_start():
        counts.update(both=0.0, steps=0)
        stamps["wall"], stamps["cpu"] = time.perf_counter(), time.process_time()
        original_start()

    def timed_end():
        mutual = counts["both"] / max(counts["steps"], 1)
        original_end()  # logs the episode (resets IPDStats), then updates both agents
        log = trainer.logs.logs[-1]
        rows.append(
            {
                "update": len(rows) + 1,
                "mutual_cooperation": f"{mutual:.6g}",
                **{f"p_cooperate_{i}": f"{log[f'player_{i}']['p(cooperate)']:.6g}" for i in (0, 1)},
                **{f"reward_{i}": f"{log[f'player_{i}']['reward']:.6g}" for i in (0, 1)},
                "wall_s": f"{time.perf_counter() - stamps['wall']:.4f}",
                "cpu_s": f"{time.process_time() - stamps['cpu']:.4f}",
            }
        )

    trainer.logs.update = counted_update
    trainer.episode_start, trainer.episode_end = timed_start, timed_end
    with contextlib.redirect_stdout(sys.stderr):
        trainer.train(args.updates)
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0

    with open(args.out / "updates.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    result = {
        "seed": args.seed,
        "updates": len(rows),
        "final_mutual_cooperation": float(rows[-1]["mutual_cooperation"]),
        "wall_s": wall,
        "cpu_s": cpu,
        "batch_size": config.environment.batch_size,
        "max_steps": config.environment.max_steps,
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "python": sys.version.split()[0],
        "affinity": sorted(os.sched_getaffinity(0)),
    }
    (args.out / "run.json").write_text(json.dumps(result, indent=2) + "\n")
    print(MARKER + json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
