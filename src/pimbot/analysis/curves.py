"""Learning curves read back from run directories (plots and tables never use live state)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pimbot import statistics
from pimbot.training import store


def load_curve(run_dir: str | Path, column: str) -> tuple[np.ndarray, np.ndarray]:
    """(iterations [E], values [S, E]) of one metric column, seeds in ascending order."""
    rows = store.read_metrics(Path(run_dir))
    if not rows:
        raise ValueError(f"{run_dir}: no metrics.csv rows")
    if column not in rows[0]:
        raise ValueError(f"{run_dir}: no column {column!r}")
    seeds = sorted({int(r["seed"]) for r in rows})
    iterations = np.array(sorted({int(r["iteration"]) for r in rows}))
    index = {it: k for k, it in enumerate(iterations)}
    values = np.full((len(seeds), len(iterations)), np.nan)
    for row in rows:
        values[seeds.index(int(row["seed"])), index[int(row["iteration"])]] = float(row[column])
    return iterations, values


def mean_and_band(values: np.ndarray, seed: int = 0):
    """Mean over seeds and the band of the mean per evaluation point: the 95 % BCa
    bootstrap band at ≥ 5 seeds, the seeds' min–max below (statistics.band)."""
    mean, lo, hi, _ = statistics.band(values, seed)
    return mean, lo, hi


def columns(run_dir: str | Path) -> list[str]:
    """The metric columns a run directory's metrics.csv has (its header)."""
    path = Path(run_dir) / store.METRICS
    if not path.exists():
        return []
    with open(path) as f:
        return f.readline().strip().split(",")
