"""A run's summary from its files: final values per seed and convergence.

The statistics of evaluation curves (final values, smoothed convergence) and
`summarize`, which applies them to a run directory's metrics.csv; used by training,
the analyses and the robot case study. A final value is its mean and its per-seed
values, no interval: every interval printed (the report, `pimbot table`, the robot
results) is computed from those per-seed values by `pimbot.statistics`, a 95 % BCa CI
at ≥ 5 seeds and the min–max range below, never a CI of two seeds.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from pimbot.training import store

CONVERGENCE_THRESHOLD = 0.9
SMOOTHING_WINDOW = 10
FINAL_WINDOW = 10


def smooth(values: np.ndarray, window: int = SMOOTHING_WINDOW) -> np.ndarray:
    """Trailing moving average over the last `window` points (fewer at the start)."""
    values = np.asarray(values, dtype=float)
    csum = np.cumsum(np.insert(values, 0, 0.0))
    idx = np.arange(1, len(values) + 1)
    start = np.maximum(idx - window, 0)
    return (csum[idx] - csum[start]) / (idx - start)


def convergence_point(
    iterations: np.ndarray,
    values: np.ndarray,
    threshold: float = CONVERGENCE_THRESHOLD,
    window: int = SMOOTHING_WINDOW,
) -> tuple[float | None, float | None]:
    """(converged, first_crossing) iterations of one seed's curve, None where never.

    `converged` is the first evaluation point from which the smoothed curve stays
    ≥ threshold until the end; `first_crossing` the first point where it is ≥ threshold.
    """
    smoothed = smooth(values, window)
    above = smoothed >= threshold
    if not above.any():
        return None, None
    first = float(iterations[int(np.argmax(above))])
    if not above[-1]:
        return None, first
    below = np.flatnonzero(~above)
    start = 0 if below.size == 0 else int(below[-1]) + 1
    return float(iterations[start]), first


def final_value(values: np.ndarray, window: int = FINAL_WINDOW) -> float:
    """Mean over the last `window` evaluation points."""
    values = np.asarray(values, dtype=float)
    return float(values[-window:].mean())


def summarize(run_dir: str | Path) -> dict[str, Any]:
    """Final metrics (mean of the last evaluation points, per seed and their mean) and
    convergence, from the run directory's files."""
    run_dir = Path(run_dir)
    return summarize_rows(store.read_metrics(run_dir), store.read_json(run_dir / store.CONFIG))


def summarize_rows(rows: list[dict[str, str]], config: dict[str, Any]) -> dict[str, Any]:
    """`summarize` of metrics.csv's rows and config.json's contents, already read."""
    seeds = sorted({int(r["seed"]) for r in rows})
    by_seed = {s: [r for r in rows if int(r["seed"]) == s] for s in seeds}
    columns = [c for c in rows[0] if c.startswith("eval/")] if rows else []
    final: dict[str, Any] = {}
    for column in columns:
        per_seed = [final_value(np.array([float(r[column]) for r in by_seed[s]])) for s in seeds]
        final[column] = {"mean": float(np.mean(per_seed)), "per_seed": per_seed}
    curve = "eval/return_ratio" if "eval/return_ratio" in columns else "eval/success"
    converged, first = [], []
    for s in seeds:
        its = np.array([int(r["iteration"]) for r in by_seed[s]])
        values = np.array([float(r[curve]) for r in by_seed[s]])
        c, f = convergence_point(its, values)
        converged.append(c)
        first.append(f)
    reached = [c for c in converged if c is not None]
    # Seeds that never converge count as +inf: a median or quartile that falls on
    # one of them is "never" (None), not the largest finite value.
    ranked = np.array([c if c is not None else np.inf for c in converged], dtype=float)

    def finite_or_none(value: float) -> float | None:
        return float(value) if np.isfinite(value) else None

    with np.errstate(invalid="ignore"):
        median = finite_or_none(np.median(ranked)) if ranked.size else None
        quartiles = np.quantile(ranked, [0.25, 0.75]) if ranked.size else [np.inf, np.inf]
    perf = [float(r["perf/iters_per_s"]) for r in rows if "perf/iters_per_s" in r]
    return {
        "finished": True,
        "env_id": config["env"]["id"],
        "learner": config["identity"]["learner"],
        "seeds": seeds,
        "iterations": config["identity"]["iterations"],
        "final_window_evals": FINAL_WINDOW,
        "final": final,
        "convergence": {
            "curve": curve,
            "threshold": CONVERGENCE_THRESHOLD,
            "smoothing_window_evals": SMOOTHING_WINDOW,
            "per_seed": converged,
            "first_crossing_per_seed": first,
            "converged_seeds": len(reached),
            "median": median,
            "iqr": [finite_or_none(q) for q in quartiles],
            "first_crossing_median": finite_or_none(
                np.median([f if f is not None else np.inf for f in first])
            )
            if first
            else None,
        },
        "iters_per_s_mean": float(np.mean(perf)) if perf else None,
    }
