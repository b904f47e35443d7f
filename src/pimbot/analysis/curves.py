"""Learning curves read back from run directories (plots and tables never use live state).

`read_curves` reads a run's metrics.csv once into `Curves`: every column per seed, in
iteration order. The report keeps one per run (`analysis.runs.RunRecord.curves`); every
figure, table and claim rule reads its columns from it.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from pimbot.training import store
from pimbot.training.summary import FINAL_WINDOW, convergence_point


@dataclasses.dataclass(frozen=True, eq=False)
class Curves:
    """One run's evaluation rows per seed: iterations [E] and every column's values [E]."""

    columns: tuple[str, ...]
    """metrics.csv's header, in its order."""
    seeds: tuple[int, ...]
    iterations: dict[int, np.ndarray]
    values: dict[int, dict[str, np.ndarray]]

    @property
    def horizon(self) -> int:
        """The last iteration every seed reached."""
        return int(min(its[-1] for its in self.iterations.values()))

    def has(self, column: str) -> bool:
        return bool(self.seeds) and column in self.values[self.seeds[0]]

    def matrix(self, column: str) -> tuple[np.ndarray, np.ndarray]:
        """(iterations [E], values [S, E]) of one column, seeds in ascending order; an
        iteration some seed did not reach is NaN for it."""
        if not self.has(column):
            raise ValueError(f"no column {column!r} in metrics.csv rows")
        iterations = np.array(sorted({int(i) for s in self.seeds for i in self.iterations[s]}))
        values = np.full((len(self.seeds), len(iterations)), np.nan)
        for k, seed in enumerate(self.seeds):
            at = np.searchsorted(iterations, self.iterations[seed])
            values[k, at] = self.values[seed][column]
        return iterations, values

    def final(self, column: str, until: int | None = None) -> np.ndarray:
        """Per seed, the mean of the last FINAL_WINDOW evaluations at or before `until`
        (None: the whole run); [] where the column is absent."""
        if not self.has(column):
            return np.array([])
        out = []
        for seed in self.seeds:
            keep = self.iterations[seed] <= (until if until is not None else np.inf)
            out.append(float(self.values[seed][column][keep][-FINAL_WINDOW:].mean()))
        return np.array(out)

    def first(self, column: str) -> np.ndarray:
        """Per seed, the first evaluation of `column`."""
        if not self.has(column):
            return np.array([])
        return np.array([float(self.values[s][column][0]) for s in self.seeds])

    def early_peak(self, column: str, fraction: float) -> float | None:
        """The highest seed-mean value over the first `fraction` of the horizon."""
        if not self.has(column):
            return None
        until = self.horizon * fraction
        mean = np.mean(
            [self.values[s][column][self.iterations[s] <= until] for s in self.seeds], axis=0
        )
        return float(mean.max()) if mean.size else None

    def convergence(self, column: str, until: int) -> tuple[list, list]:
        """(strict, first crossing) iteration per seed of `column` cut at `until`, None where
        never: the convergence criterion (smoothed over 10 evaluations, stays ≥ 0.9) and the
        first point the smoothed curve reaches 0.9."""
        strict, first = [], []
        for seed in self.seeds:
            keep = self.iterations[seed] <= until
            c, f = convergence_point(self.iterations[seed][keep], self.values[seed][column][keep])
            strict.append(c)
            first.append(f)
        return strict, first


def read_curves(run_dir: str | Path) -> Curves:
    """A run directory's metrics.csv, read once: per seed, its rows in iteration order."""
    return curves_of(store.read_metrics(Path(run_dir)))


def curves_of(rows: list[dict[str, str]]) -> Curves:
    """metrics.csv's rows (as `store.read_metrics` gives them) as `Curves`."""
    columns = tuple(rows[0]) if rows else ()
    by_seed: dict[int, list[dict[str, str]]] = {}
    for row in rows:
        by_seed.setdefault(int(row["seed"]), []).append(row)
    seeds = tuple(sorted(by_seed))
    iterations, values = {}, {}
    for seed in seeds:
        mine = sorted(by_seed[seed], key=lambda r: int(r["iteration"]))
        iterations[seed] = np.array([int(r["iteration"]) for r in mine])
        values[seed] = {k: np.array([float(r[k]) for r in mine]) for k in columns if k != "seed"}
    return Curves(columns, seeds, iterations, values)
