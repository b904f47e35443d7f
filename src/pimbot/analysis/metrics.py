"""Metrics computed from evaluation curves: final values, convergence, confidence intervals."""

from __future__ import annotations

import numpy as np

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


def bootstrap_ci(
    samples: np.ndarray, level: float = 0.95, resamples: int = 10_000, seed: int = 0
) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of the mean."""
    samples = np.asarray(samples, dtype=float)
    if samples.size == 0:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    means = rng.choice(samples, size=(resamples, samples.size), replace=True).mean(axis=1)
    alpha = (1.0 - level) / 2
    return float(np.quantile(means, alpha)), float(np.quantile(means, 1 - alpha))


def diff_ci(
    a: np.ndarray, b: np.ndarray, resamples: int = 10_000, seed: int = 0
) -> tuple[float, float, float]:
    """Mean of a − mean of b and its 95 % bootstrap CI (the two samples resampled
    independently: different runs' seeds are not paired)."""
    rng = np.random.default_rng(seed)
    da = rng.choice(a, (resamples, a.size)).mean(axis=1)
    db = rng.choice(b, (resamples, b.size)).mean(axis=1)
    diff = da - db
    return (
        float(a.mean() - b.mean()),
        float(np.quantile(diff, 0.025)),
        float(np.quantile(diff, 0.975)),
    )
