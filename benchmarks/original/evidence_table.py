"""Prints the runs of the original code made here, per seed, beside pimbot runs.

    .venv/bin/python benchmarks/original/evidence_table.py [--pimbot LABEL=RUN_DIR ...]
        [--column eval/success] [--root DIR]

For every run directory `pimbot.analysis.original_code.runs_made_here` finds under ROOT
(default: the packaged one), one line: the run, its seeds' final values of COLUMN (pimbot's
`summarize`: the mean of the last 10 evaluations), their mean and its interval
(`pimbot.statistics`), and the run time. Each ``--pimbot LABEL=RUN_DIR`` adds a pimbot run
directory's line the same way (``train/success`` is printed beside ``eval/success`` where
the run has it). benchmarks/original/README.md's "Runs imported as evidence" tables come
from this script.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from pimbot import statistics
from pimbot.analysis import original_code
from pimbot.training import store
from pimbot.training.summary import final_value, summarize


def finals(run_dir: Path, column: str) -> list[float] | None:
    """Per-seed final values of `column` (the mean of the last 10 evaluation rows, as
    `summarize` computes for eval/ columns); None where the run has no such column."""
    if column.startswith("eval/"):
        final = summarize(run_dir)["final"].get(column)
        return None if final is None else final["per_seed"]
    rows = store.read_metrics(run_dir)
    if not rows or column not in rows[0]:
        return None
    seeds = sorted({int(r["seed"]) for r in rows})
    return [
        final_value(np.array([float(r[column]) for r in rows if int(r["seed"]) == s if r[column]]))
        for s in seeds
    ]


def line(label: str, run_dir: Path, column: str) -> str:
    parts = [label]
    for name in (column, "train/success") if column == "eval/success" else (column,):
        per_seed = finals(run_dir, name)
        if per_seed is None:
            continue
        interval = statistics.mean_interval(per_seed)
        mean = sum(per_seed) / len(per_seed)
        estimate = statistics.text(mean, interval.lo, interval.hi, interval.kind)
        parts.append(f"{name} {estimate}: " + " ".join(f"{v:.3f}" for v in per_seed))
    return "  ".join(parts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pimbot", action="append", default=[], metavar="LABEL=RUN_DIR")
    parser.add_argument("--column", default="eval/success")
    parser.add_argument("--root", type=Path, default=original_code.ROOT)
    args = parser.parse_args()
    for run_dir in original_code.runs_made_here(root=args.root):
        info = original_code.original_info(run_dir)
        times = info["run_time"]
        label = f"{run_dir.relative_to(args.root)} ({len(info['seeds'])} seeds)"
        print(line(label, run_dir, args.column))
        print(
            f"    run time: {times['total_wall_s'] / 60:.1f} min wall, "
            f"{times['total_cpu_s'] / 60:.1f} min CPU; per seed wall "
            + " ".join(f"{w:.0f}" for w in times["per_seed_wall_s"])
            + " s"
        )
    for item in args.pimbot:
        label, _, path = item.partition("=")
        print(line(f"pimbot {label}", Path(path), args.column))


if __name__ == "__main__":
    main()
