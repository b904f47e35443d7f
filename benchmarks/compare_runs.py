"""Compare the metrics of two suites (or two run directories), column by column.

    python benchmarks/compare_runs.py BEFORE_DIR AFTER_DIR [--tolerance 1e-6]

A change that must not move results (a refactor, a number made a traced argument of a
shared program) is checked here on real runs: for every training run present in both
directories (a suite's `<group>/<setting>` runs, or the two directories themselves when
they are runs), every column of metrics.csv except the `perf/` timings. It prints, per
run, the columns that differ and their largest relative difference, and at the end the
largest over all runs. It exits 1 where a success, count or iteration column differs at
all (`EXACT`), a float column differs by more than `--tolerance` (relative), a run or a
column is missing on one side, or the rows differ in number.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

EXACT = ("iteration", "seed", "success", "exit_success", "optimal_rate", "count", "steps")
"""Columns whose names contain one of these must be identical (counts and successes)."""


def run_dirs(root: Path) -> dict[str, Path]:
    """name -> run directory of every run under `root` (`root` itself if it is one)."""
    if (root / "metrics.csv").exists():
        return {".": root}
    return {str(p.parent.relative_to(root)): p.parent for p in sorted(root.rglob("metrics.csv"))}


def read_columns(path: Path) -> tuple[dict[str, np.ndarray], int]:
    """metrics.csv as column -> float values (an empty cell is NaN), and its row count."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    names = list(rows[0]) if rows else []
    columns = {n: np.array([float(r[n]) if r[n] else np.nan for r in rows]) for n in names}
    return columns, len(rows)


def compare_run(before: Path, after: Path, tolerance: float) -> tuple[list[str], float]:
    """(problems, largest relative difference) of one run's metrics.csv."""
    a, a_rows = read_columns(before / "metrics.csv")
    b, b_rows = read_columns(after / "metrics.csv")
    columns = [c for c in a if not c.startswith("perf/")]
    problems = [f"column {c} missing after" for c in columns if c not in b]
    problems += [f"column {c} new after" for c in b if c not in a and "perf/" not in c]
    if a_rows != b_rows:
        return [*problems, f"{a_rows} rows before, {b_rows} after"], float("inf")
    largest = 0.0
    for column in (c for c in columns if c in b):
        x, y = a[column], b[column]
        same = (x == y) | (np.isnan(x) & np.isnan(y))
        if same.all():
            continue
        scale = np.maximum(np.abs(x), np.abs(y))
        relative = float(np.max(np.abs(x - y)[~same] / np.where(scale > 0, scale, 1)[~same]))
        largest = max(largest, relative)
        exact = any(word in column for word in EXACT)
        if exact or relative > tolerance:
            problems.append(f"{column}: {int((~same).sum())} rows differ, relative {relative:.2e}")
        else:
            print(f"    {column}: {int((~same).sum())} rows within {relative:.2e}")
    return problems, largest


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before", type=Path)
    parser.add_argument("after", type=Path)
    parser.add_argument("--tolerance", type=float, default=1e-6)
    args = parser.parse_args()
    before, after = run_dirs(args.before), run_dirs(args.after)
    missing = sorted(set(before) ^ set(after))
    failed = bool(missing)
    for name in missing:
        print(f"{name}: only in {'before' if name in before else 'after'}")
    largest = 0.0
    for name in sorted(set(before) & set(after)):
        problems, relative = compare_run(before[name], after[name], args.tolerance)
        largest = max(largest, relative)
        status = "identical" if relative == 0 and not problems else f"largest {relative:.2e}"
        print(f"{name}: {status}")
        for problem in problems:
            print(f"    {problem}")
        failed = failed or bool(problems)
    common = len(set(before) & set(after))
    print(f"\n{common} runs compared; largest relative difference {largest:.2e}")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
