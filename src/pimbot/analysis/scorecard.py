"""The robustness scorecard of a sweep: does an attack hurt a learner, by how much, how sure
are we, and does a defense recover it; computed from the runs' files only.

Every attacked run is paired with the clean run of the same setting (env id and every
parameter, learner and its configuration) and the same defenses, and each seed the two
share is one pair: both runs start from that seed's key, so a pair differs only in the
attack. A pair's value is each run's final value (mean of the last evaluation points) at
the two runs' common horizon, so runs of different length are compared at the same
iteration. Seeds present in only one run of a pair are skipped and counted
(`Paired.unpaired`); an attacked run without a clean run of its setting is listed
(`Scorecard.unmatched`), never dropped in silence. A defended run is further paired with
the same attack without defense and with the clean run without defense (its recovery),
and a defended clean run with the clean run without defense (what the defense costs when
nobody attacks: the benign control).

The estimators are those of rliable (Agarwal et al. 2021, "Deep Reinforcement Learning at
the Edge of the Statistical Precipice", NeurIPS; github.com/google-research/rliable,
`rliable/metrics.py` and `rliable/library.py`), computed with numpy and scipy:

- IQM: the mean of the middle 50 % of the runs (`scipy.stats.trim_mean(x, 0.25)`);
- probability of improvement P(X > Y): the Mann–Whitney statistic, P(x > y) + ½ P(x = y)
  over every pair of runs of one task, averaged over tasks;
- performance profile: the fraction of runs whose score exceeds τ;
- intervals: the stratified percentile bootstrap (runs resampled within each task, here
  each env, 95 %, `statistics.RESAMPLES` resamples), with the seeds of a pair resampled
  together (the design is paired). Below `statistics.MIN_SEEDS_FOR_CI` pairs in a task a
  bootstrap means little: the interval is then the range over seeds (as everywhere in the
  report) and a probability of improvement has no interval.

rliable itself is not a dependency: its only release (1.2.0) requires arch < 8, and arch
7.x fails to import next to pandas 3 (`deprecate_kwarg() missing 1 required positional
argument`), so it cannot be installed beside pimbot's other tools.

The runs are exported as marl-eval JSON (InstaDeep's marl-eval, github.com/instadeepai/
marl-eval, README "Data Structure for Raw Experiment data" and
`marl_eval/json_tools/json_logger.py`): `{env: {task: {algorithm: {"seed_<s>": {"step_<k>":
{"step_count": iteration, metric: [value]}, …, "absolute_metrics": {metric: [final]}}}}}}`,
`absolute_metrics` last (`marl_eval/utils/data_processing_utils.py`,
`create_matrices_for_rliable`, reads a run's last key as its absolute metrics).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Iterable

import numpy as np
from scipy import stats

from pimbot import statistics
from pimbot.analysis.runs import CLEAN, NO_DEFENSE, RunRecord, distinct_env_labels
from pimbot.analysis.tables import Estimate

SUCCESS = "eval/success"
MARGIN = "eval/adversary_margin_env"
METRICS = {SUCCESS: "success", MARGIN: "adversary margin"}
"""metrics.csv column -> its name in the scorecard: final success, and the adversary's
env return minus the mean of the others' where the run logged it."""
TAUS = np.linspace(0.0, 1.0, 21)
"""Thresholds of the success performance profiles."""
CHUNK = 1000
"""Bootstrap resamples computed at once."""
SETUP_KEYS = ("env_id", "env_params", "learner", "learner_config")
"""config.json identity fields two runs must share to be compared (besides the attack and
the defenses that tell them apart)."""
ATTACK, RECOVERY, CLEAN_RUN, BENIGN = "attack", "recovery", "vs clean", "benign"
"""Comparison kinds: attacked vs clean (same defenses); attacked + defense vs attacked
without; attacked + defense vs clean without; clean + defense vs clean without."""


@dataclasses.dataclass(frozen=True)
class Paired:
    """One metric's final values of two runs, matched by seed, at their common horizon."""

    seeds: tuple[int, ...]
    base: np.ndarray
    """[S] the reference run's values (clean, or the attack without defense)."""
    treated: np.ndarray
    """[S] the other run's values (attacked, or defended)."""
    horizon: int
    unpaired: int
    """Seeds only one of the two runs has: skipped."""

    @property
    def effect(self) -> np.ndarray:
        """[S] treated − base per seed."""
        return self.treated - self.base


@dataclasses.dataclass(frozen=True)
class Comparison:
    kind: str
    treated: RunRecord
    base: RunRecord
    pairs: dict[str, Paired]
    """Per metrics.csv column that both runs logged."""


@dataclasses.dataclass(frozen=True)
class Scorecard:
    comparisons: list[Comparison]
    unmatched: list[tuple[str, str]]
    """(run name, the counterpart it lacks) for every run that could not be paired."""

    def of(self, kind: str) -> list[Comparison]:
        return [c for c in self.comparisons if c.kind == kind]

    @property
    def unpaired_seeds(self) -> int:
        """Seeds skipped, summed over comparisons (a comparison's metrics share its seeds)."""
        return sum(c.pairs[SUCCESS].unpaired for c in self.comparisons)


# --- pairing ---------------------------------------------------------------------------


def setup(run: RunRecord) -> str:
    """What two compared runs share: env, learner and learner configuration."""
    return json.dumps({k: run.identity.get(k) for k in SETUP_KEYS}, sort_keys=True)


def paired(base: RunRecord, treated: RunRecord, column: str) -> Paired | None:
    """`column`'s final values of the two runs per shared seed at their common horizon
    (None: a run did not log the column, or they share no seed)."""
    if not (base.curves.has(column) and treated.curves.has(column)):
        return None
    horizon = min(base.curves.horizon, treated.curves.horizon)
    a = dict(zip(base.curves.seeds, base.curves.final(column, horizon), strict=True))
    b = dict(zip(treated.curves.seeds, treated.curves.final(column, horizon), strict=True))
    seeds = tuple(sorted(set(a) & set(b)))
    if not seeds:
        return None
    unpaired = len(set(a) ^ set(b))
    base_values = np.array([a[s] for s in seeds])
    return Paired(seeds, base_values, np.array([b[s] for s in seeds]), horizon, unpaired)


def counterpart(
    run: RunRecord, records: Iterable[RunRecord], condition: str, defenses: str
) -> RunRecord | None:
    """The run of `run`'s setup with this condition and defenses: of several, the one in
    `run`'s group, then of the same length, then sharing the most seeds, then by name."""
    key = setup(run)
    found = [
        r
        for r in records
        if r is not run and r.condition == condition and r.defenses == defenses
        if setup(r) == key
    ]
    if not found:
        return None

    def preference(r: RunRecord) -> tuple:
        shared = len(set(r.curves.seeds) & set(run.curves.seeds))
        return r.group != run.group, r.iterations != run.iterations, -shared, r.name

    return min(found, key=preference)


def compare(kind: str, base: RunRecord, treated: RunRecord) -> Comparison | None:
    pairs = {c: p for c in METRICS if (p := paired(base, treated, c)) is not None}
    return Comparison(kind, treated, base, pairs) if SUCCESS in pairs else None


def wanted(run: RunRecord) -> list[tuple[str, str, str]]:
    """(kind, condition, defenses) of every reference `run` is compared with."""
    if run.condition == CLEAN:
        return [] if run.defenses == NO_DEFENSE else [(BENIGN, CLEAN, NO_DEFENSE)]
    out = [(ATTACK, CLEAN, run.defenses)]
    if run.defenses != NO_DEFENSE:
        out += [(RECOVERY, run.condition, NO_DEFENSE), (CLEAN_RUN, CLEAN, NO_DEFENSE)]
    return out


def scorecard(records: Iterable[RunRecord]) -> Scorecard:
    """Every comparison the runs allow, and every run left without its reference."""
    records = list(records)
    comparisons, unmatched = [], []
    for run in records:
        for kind, condition, defenses in wanted(run):
            base = counterpart(run, records, condition, defenses)
            found = None if base is None else compare(kind, base, run)
            if found is None:
                why = f"no {condition} run with defenses {defenses}"
                if base is not None:
                    why = f"no seed or success column shared with {base.name}"
                unmatched.append((run.name, why))
            else:
                comparisons.append(found)
    return Scorecard(comparisons, unmatched)


def unmatched_note(card: Scorecard) -> str | None:
    """One sentence naming every run the scorecard could not pair and what it lacks; None
    when every run was paired. A report says it whether or not anything was paired: a sweep
    of attacked runs only has no comparison, and its runs must not vanish unnamed."""
    if not card.unmatched:
        return None
    listed = "; ".join(f"{name} ({why})" for name, why in card.unmatched)
    return f"{len(card.unmatched)} run(s) without the run they are compared with: {listed}."


# --- estimators (rliable's, see the module docstring) -------------------------------------


def iqm(values: np.ndarray, axis: int = -1) -> np.ndarray:
    """Interquartile mean: the mean of the middle 50 % along `axis`."""
    return stats.trim_mean(values, 0.25, axis=axis)


def improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """P(X > Y) of one task: P(x > y) + ½ P(x = y) over every (x, y); x [..., n], y [..., m]."""
    greater = (x[..., :, None] > y[..., None, :]).mean(axis=(-1, -2))
    ties = (x[..., :, None] == y[..., None, :]).mean(axis=(-1, -2))
    return greater + 0.5 * ties


def stratified_bootstrap(
    strata: list[np.ndarray],
    statistic: Callable[[list[np.ndarray]], np.ndarray],
    seed: int = 0,
    resamples: int = statistics.RESAMPLES,
) -> tuple[np.ndarray, np.ndarray]:
    """95 % percentile interval (lo, hi) of `statistic` with each stratum's rows resampled
    with replacement within the stratum. A stratum is [n_k, ...] (a seed's pair is one row,
    so pairs stay together); `statistic` takes the list of strata, each [B, n_k, ...] (a
    leading batch axis), and returns [B] or [B, T]."""
    rng = np.random.default_rng(seed)
    values = []
    for start in range(0, resamples, CHUNK):  # bounded memory: P(X > Y) compares n × n
        size = min(CHUNK, resamples - start)
        values.append(statistic([s[rng.integers(0, len(s), size=(size, len(s)))] for s in strata]))
    lo, hi = np.percentile(np.concatenate(values), [2.5, 97.5], axis=0)
    return lo, hi


def _estimate(strata, statistic, flat: np.ndarray, digits: int, signed: bool) -> Estimate:
    """The point value of `statistic` with its stratified interval, or the range of `flat`
    (the per-seed values) below MIN_SEEDS_FOR_CI pairs in some stratum."""
    point = float(statistic([s[None] for s in strata])[0])
    if min(len(s) for s in strata) < statistics.MIN_SEEDS_FOR_CI:
        lo, hi, kind = float(flat.min()), float(flat.max()), statistics.RANGE
    else:
        lo, hi = map(float, stratified_bootstrap(strata, statistic))
        kind = statistics.CI
    return Estimate(point, lo, hi, digits, signed, kind)


def effect_estimate(pairs: list[Paired], digits: int = 3) -> Estimate:
    """Mean paired effect (treated − base), averaged over strata (envs) with equal weight."""
    strata = [p.effect for p in pairs]
    statistic = lambda s: np.mean([x.mean(axis=-1) for x in s], axis=0)  # noqa: E731
    return _estimate(strata, statistic, np.concatenate(strata), digits, True)


def iqm_estimate(values: list[np.ndarray], digits: int = 3, signed: bool = False) -> Estimate:
    """IQM of every run's value, pooled over strata (rliable's aggregate IQM)."""
    statistic = lambda s: iqm(np.concatenate(s, axis=-1))  # noqa: E731
    return _estimate(values, statistic, np.concatenate(values), digits, signed)


def improvement_estimate(pairs: list[Paired]) -> Estimate | float:
    """P(base > treated) averaged over strata; an interval at ≥ MIN_SEEDS_FOR_CI pairs in
    every stratum, else the point value alone."""
    strata = [np.stack([p.base, p.treated], axis=-1) for p in pairs]

    def statistic(s: list[np.ndarray]) -> np.ndarray:
        return np.mean([improvement(x[..., 0], x[..., 1]) for x in s], axis=0)

    point = float(statistic([s[None] for s in strata])[0])
    if min(len(s) for s in strata) < statistics.MIN_SEEDS_FOR_CI:
        return point
    lo, hi = stratified_bootstrap(strata, statistic)
    return Estimate(point, float(lo), float(hi), 2, False, statistics.CI)


def profile(values: list[np.ndarray], taus: np.ndarray = TAUS) -> np.ndarray:
    """[T] the fraction of runs (pooled over strata) whose value exceeds each τ."""
    pooled = np.concatenate(values)
    return (pooled[:, None] > taus[None, :]).mean(axis=0)


def profile_band(values: list[np.ndarray], taus: np.ndarray = TAUS) -> tuple | None:
    """(lo [T], hi [T]) of the performance profile, stratified bootstrap; None below
    MIN_SEEDS_FOR_CI runs in some stratum."""
    if min(len(v) for v in values) < statistics.MIN_SEEDS_FOR_CI:
        return None

    def statistic(s: list[np.ndarray]) -> np.ndarray:
        pooled = np.concatenate(s, axis=-1)
        return (pooled[..., None] > taus).mean(axis=-2)

    return stratified_bootstrap(values, statistic)


# --- marl-eval export ---------------------------------------------------------------------


def algorithm_name(run: RunRecord) -> str:
    """A run's algorithm in marl-eval's sense: learner (its changed hyperparameters),
    defenses and condition."""
    learner = run.learner + (f"({run.hparams})" if run.hparams else "")
    return f"{learner}|{run.defenses}|{run.condition}"


def marl_eval_run(run: RunRecord, seed: int) -> dict:
    """One seed's evaluations as marl-eval steps, then its final values as absolute metrics
    (the last key, where marl-eval's processing looks for them)."""
    columns = [(c, name.replace(" ", "_")) for c, name in METRICS.items() if run.curves.has(c)]
    out: dict = {}
    for k, iteration in enumerate(run.curves.iterations[seed]):
        step: dict = {"step_count": int(iteration)}
        for column, name in columns:
            step[name] = [float(run.curves.values[seed][column][k])]
        out[f"step_{k}"] = step
    k = run.curves.seeds.index(seed)
    out["absolute_metrics"] = {name: [float(run.per_seed(c)[k])] for c, name in columns}
    return out


def marl_eval(records: Iterable[RunRecord]) -> dict:
    """Every run as marl-eval raw experiment data: environment = the env id, task = the
    env label, algorithm = `algorithm_name` (the run's name added where two runs would
    share one), run = "seed_<s>", steps by training iteration (`step_count`)."""
    records = sorted(records, key=lambda r: r.name)
    labels = distinct_env_labels(records)
    out: dict = {}
    for run in records:
        tasks = out.setdefault(run.identity["env_id"].lower(), {})
        algorithms = tasks.setdefault(labels[run.env_key].lower(), {})
        name = algorithm_name(run)
        if name in algorithms:
            name += f"[{run.name}]"
        algorithms[name] = {f"seed_{s}": marl_eval_run(run, s) for s in run.curves.seeds}
    return out
