"""Intervals over seeds: scipy's BCa bootstrap, or the range below 5 seeds.

The one definition of an interval over seeds, for every place that prints one: the
report and `pimbot table` (analysis), the robot case study's results. Run summaries
(summary.json) hold the per-seed values these are computed from, no interval.

A mean over seeds is reported with a 95 % BCa bootstrap confidence interval
(`scipy.stats.bootstrap`, method "BCa") when it rests on at least `MIN_SEEDS_FOR_CI`
seeds; below that a bootstrap interval means little, so the range of the seeds
(min to max) is printed instead, never called a CI. A difference of two runs' means
resamples the two runs' seeds independently (different runs' seeds are not paired);
below the threshold its range is the span of all pairwise differences.

Where a claim's rule is a direction rather than an interval, the tests are here too: a
permutation test of two runs' means (`difference_p_value`), a sign-flip permutation test
of one run's mean against 0 (`sign_p_value`) and a Mann–Whitney U test of per-seed
iterations, "never" counted as +∞ (`rank_p_value`).

Samples whose values are all equal have a zero-width interval (BCa is undefined on
degenerate data); where BCa cannot be computed on other data (its acceleration has no
value) the percentile bootstrap of the same resamples is used.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
from scipy import stats

MIN_SEEDS_FOR_CI = 5
"""Below this many seeds an interval is the min–max range, not a confidence interval."""
LEVEL = 0.95
RESAMPLES = 9_999
BAND_RESAMPLES = 999
"""Resamples per evaluation point of a figure's band (one vectorized call per curve)."""
CI = "ci"
RANGE = "range"


@dataclasses.dataclass(frozen=True)
class Interval:
    lo: float
    hi: float
    kind: str
    """CI (95 % BCa bootstrap) or RANGE (min–max over seeds)."""
    n: int
    """Seeds it rests on (the smaller run's count for a difference)."""


def _mean(x, axis=-1):
    return np.mean(x, axis=axis)


def _mean_difference(x, y, axis=-1):
    return np.mean(x, axis=axis) - np.mean(y, axis=axis)


def _bootstrap(samples: tuple[np.ndarray, ...], statistic, resamples: int, seed: int):
    """(lo, hi) of scipy's BCa interval, the percentile interval where BCa has no value."""
    for method in ("BCa", "percentile"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # degenerate-data and divide warnings: handled
            result = stats.bootstrap(
                samples,
                statistic,
                n_resamples=resamples,
                confidence_level=LEVEL,
                method=method,
                vectorized=True,
                rng=np.random.default_rng(seed),
            )
        lo, hi = float(result.confidence_interval.low), float(result.confidence_interval.high)
        if np.isfinite(lo) and np.isfinite(hi):
            return lo, hi
    return float("nan"), float("nan")


def mean_interval(samples, seed: int = 0) -> Interval:
    """The interval of the mean of per-seed `samples` (at least one)."""
    x = np.asarray(samples, dtype=float)
    if x.size == 0:
        raise ValueError("mean_interval: no samples")
    if x.size < MIN_SEEDS_FOR_CI:
        return Interval(float(x.min()), float(x.max()), RANGE, x.size)
    if np.ptp(x) == 0:
        return Interval(float(x[0]), float(x[0]), CI, x.size)
    return Interval(*_bootstrap((x,), _mean, RESAMPLES, seed), CI, x.size)


def text(
    mean: float, lo: float, hi: float, kind: str, digits: int = 3, signed: bool = False
) -> str:
    """A mean with its interval: "m [lo, hi]" for a CI, "m (range lo … hi)" for a RANGE;
    `signed` writes every number with its sign (differences, margins)."""
    spec = f"{'+' if signed else ''}.{digits}f"
    if kind == RANGE:
        return f"{mean:{spec}} (range {lo:{spec}} … {hi:{spec}})"
    return f"{mean:{spec}} [{lo:{spec}}, {hi:{spec}}]"


def difference_interval(a, b, seed: int = 0) -> Interval:
    """The interval of mean(a) − mean(b), the two runs' seeds resampled independently."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.size == 0 or b.size == 0:
        raise ValueError("difference_interval: no samples")
    n = min(a.size, b.size)
    if n < MIN_SEEDS_FOR_CI:
        return Interval(float(a.min() - b.max()), float(a.max() - b.min()), RANGE, n)
    if np.ptp(a) == 0 and np.ptp(b) == 0:
        d = float(a[0] - b[0])
        return Interval(d, d, CI, n)
    return Interval(*_bootstrap((a, b), _mean_difference, RESAMPLES, seed), CI, n)


def difference_p_value(a, b, seed: int = 0, alternative: str = "two-sided") -> float:
    """Permutation p-value of mean(a) − mean(b) (`scipy.stats.permutation_test`,
    independent samples; exact where the pooled sample has at most RESAMPLES splits);
    two-sided, or "greater" / "less" for mean(a) above / below mean(b).

    Unlike a bootstrap interval it stays meaningful for a handful of runs where one side
    has no spread, e.g. 10 seeds of which 2 solve a task against 5 logs of which none do
    (a bootstrap of the 5 zeros has zero width)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.size == 0 or b.size == 0:
        raise ValueError("difference_p_value: no samples")
    if np.ptp(np.concatenate([a, b])) == 0:
        return 1.0
    result = stats.permutation_test(
        (a, b),
        _mean_difference,
        permutation_type="independent",
        alternative=alternative,
        n_resamples=RESAMPLES,
        vectorized=True,
        rng=np.random.default_rng(seed),
    )
    return float(result.pvalue)


RANK_ASYMPTOTIC_SEEDS = 20
"""From this many seeds per side a rank test uses the normal approximation (permutations of
40 + 40 seeds take a second per test)."""


def rank_p_value(a, b, alternative: str = "two-sided") -> float:
    """Mann–Whitney U p-value of `a` against `b` (`scipy.stats.mannwhitneyu`, independent
    samples; "less": `a` tends to be smaller), its null distribution by permutation (exact
    where the splits are at most RESAMPLES) below RANK_ASYMPTOTIC_SEEDS per side: ties,
    which the normal approximation mistreats at a few seeds, are common here. +∞ is a
    value like any other, so a seed that never reached a point (its iteration +∞) ranks
    above every seed that did."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.size == 0 or b.size == 0:
        raise ValueError("rank_p_value: no samples")
    if np.all(np.concatenate([a, b]) == a[0]):
        return 1.0
    method = (
        "asymptotic"  # with its tie correction, close to the permutation's at this size
        if min(a.size, b.size) >= RANK_ASYMPTOTIC_SEEDS
        else stats.PermutationMethod(n_resamples=RESAMPLES, rng=np.random.default_rng(0))
    )
    return float(stats.mannwhitneyu(a, b, alternative=alternative, method=method).pvalue)


def sign_p_value(x, alternative: str = "greater", seed: int = 0) -> float:
    """Permutation p-value of mean(x) against 0 (`scipy.stats.permutation_test` flipping the
    sign of each value; exact where 2^n ≤ RESAMPLES); "greater": the mean is above 0."""
    x = np.asarray(x, dtype=float)
    if x.size == 0:
        raise ValueError("sign_p_value: no samples")
    if not np.any(x):
        return 1.0
    result = stats.permutation_test(
        (x,),
        _mean,
        permutation_type="samples",
        alternative=alternative,
        n_resamples=RESAMPLES,
        vectorized=True,
        rng=np.random.default_rng(seed),
    )
    return float(result.pvalue)


def band(values: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """(mean, lo, hi, kind) per evaluation point of `values` [S, E]: the BCa band of the
    mean at ≥ MIN_SEEDS_FOR_CI seeds, else the seeds' min–max. Points where every seed
    agrees have zero width; NaNs (a seed without that point) are left out of the range."""
    values = np.asarray(values, dtype=float)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns
        mean = np.nanmean(values, axis=0)
        if values.shape[0] < MIN_SEEDS_FOR_CI or np.isnan(values).any():
            return mean, np.nanmin(values, axis=0), np.nanmax(values, axis=0), RANGE
    lo, hi = mean.copy(), mean.copy()
    varying = np.ptp(values, axis=0) > 0
    if varying.any():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = stats.bootstrap(
                (values[:, varying],),
                _mean,
                n_resamples=BAND_RESAMPLES,
                confidence_level=LEVEL,
                method="BCa",
                axis=0,
                vectorized=True,
                rng=np.random.default_rng(seed),
            )
        low, high = result.confidence_interval.low, result.confidence_interval.high
        # BCa without a value at a point (degenerate resamples): the seeds' range there.
        low = np.where(np.isfinite(low), low, values[:, varying].min(axis=0))
        high = np.where(np.isfinite(high), high, values[:, varying].max(axis=0))
        lo[varying], hi[varying] = low, high
    return mean, lo, hi, CI


def interval_text(seed_counts) -> str:
    """What the intervals of a table are, from the seed counts of its runs."""
    counts = sorted(set(int(n) for n in seed_counts))
    if not counts:
        return "no seeds"
    few = [n for n in counts if n < MIN_SEEDS_FOR_CI]
    many = [n for n in counts if n >= MIN_SEEDS_FOR_CI]
    ci = f"95 % BCa bootstrap CI over seeds (scipy.stats.bootstrap, {RESAMPLES} resamples)"
    rng = "the range (min … max) over seeds, no CI"
    if not few:
        return f"[…] = {ci}"
    if not many:
        return f"(range …) = {rng}: fewer than {MIN_SEEDS_FOR_CI} seeds"
    return f"[…] = {ci} for runs of ≥ {MIN_SEEDS_FOR_CI} seeds; (range …) = {rng} for runs of fewer"
