"""Claims C1–C5 judged as the paper states them, at the paper's budget, from the attack
group's LIO runs (and the original code's logs where they cover a run's exact settings:
`analysis.runs.RunTable.original_for`; logs of the same attack at other parameters are
named, never compared).

A number only where the paper gives one; otherwise the stated direction, tested over
seeds (an interval, a sign-flip permutation test or a Mann–Whitney U test).

- C1a: the self-centered adversary's env-return margin over the others is above 0.
- C1b: self-centered ER converges faster than clean, by first crossing and by the strict
  criterion, both runs cut at their common horizon (paper: ER(2,1) 20k → 12.5k,
  ER(4,2) 14k → 10.5k); a one-sided Mann–Whitney U test per criterion, the original
  code's logs of both runs pooled at their common horizon for the cause.
- C2: fake incentive: some success during the exploration period (LIO's ε schedule), then
  ~0; at the original code's C = 10 per step per recipient (greedy_agent,
  lio/alg/lio_agent_greedy.py `give_reward`), and at the paper's C = 50 as a second row.
- C3: bypass: the parts the environment's rules decide (an idle agent makes a task in
  which every agent is needed impossible) and the part that is evidence (ER(4,2) still
  solved).
- C4: reverse judged at the paper's 25k iterations; what happens later is a note.
- C5: ADMO: the adversary's margin against the symmetric baseline (0) and its own exit
  success against the clean team's mean per agent, elevated in ER; disrupt lowers success
  where the task is non-redundant; IPD cooperation and steps per episode shown as
  measurements (the paper gives no size for "nearly flat" and "modestly").
  `admo` and `admo_code` (the published code's scheduler) side by side where both ran.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from pimbot.analysis import judging, verdicts
from pimbot.analysis.claims import Claim, Comparison, deciding_part, summarized
from pimbot.analysis.document import count_text
from pimbot.analysis.judging import PAPER_ATTACK_BUDGET, iteration_text
from pimbot.analysis.runs import CLEAN, RunRecord, RunTable, pooled, settings_difference
from pimbot.analysis.tables import Table, difference, estimate
from pimbot.analysis.verdicts import Verdict
from pimbot.statistics import difference_p_value, sign_p_value
from pimbot.training.summary import FINAL_WINDOW

ROOMS = ("ER(2,1)", "ER(4,2)", "ER(4,3)")
C1_ENVS = ("ER(2,1)", "ER(4,2)", "IPD(2)")
PAPER_SPEED = {"ER(2,1)": (20_000, 12_500), "ER(4,2)": (14_000, 10_500)}
"""Iterations to converge, clean → self-centered, as the paper states them."""
SOLVED = 0.9
"""C3's "still solved": the convergence criterion's level (docs/experiments.md)."""
FAKE_INCENTIVE = "fake_incentive"
CODE_AMOUNT = 10.0
"""The original code's fake incentive per step per recipient (greedy_agent,
lio/alg/lio_agent_greedy.py `give_reward`); its logs were made at it; the paper's text says 50."""
ADMO_ATTACKS = ("admo", "admo_code")


@dataclasses.dataclass
class Runs:
    """The attack group's LIO runs by (env label, condition)."""

    table: RunTable
    by: dict[tuple[str, str], RunRecord]
    reachable_cache: dict[tuple, bool] = dataclasses.field(default_factory=dict)

    def get(self, env: str, condition: str) -> RunRecord | None:
        return self.by.get((env, condition))

    def original(self, run: RunRecord, horizon: int | None = None) -> RunRecord | None:
        """The original code's logs a cause may rest on: at `run`'s exact settings, each
        recording its attack in its name (`RunTable.original_for`, `recorded`)."""
        return self.table.original_for(run, horizon, recorded=True)

    def inferred(self, run: RunRecord) -> str | None:
        """The original code's logs at `run`'s settings whose attack is only inferred, named
        (None: there are none): shown, never the ground of a cause."""
        logs = [r for r in self.table.originals_for(run) if r.attack_inferred]
        if not logs:
            return None
        names = ", ".join(r.setting for r in logs)
        why = logs[0].config["original"].get("attack_evidence", "")
        return (
            f"the original code's logs {names}, whose names do not record their attack "
            f"(inferred: {why})"
        )

    def elsewhere(self, run: RunRecord) -> str | None:
        """What the original code's logs of `run`'s attack at other settings differ in
        (None: there are none); they are named, never compared."""
        others = self.table.originals_elsewhere(run)
        if not others:
            return None
        diffs = "; ".join(sorted({settings_difference(o, run) for o in others}))
        return f"the original code's logs of this attack are at other settings ({diffs})"

    def cause(
        self,
        run: RunRecord,
        reason: str,
        agrees: bool | None,
        ours: np.ndarray | None = None,
        theirs: np.ndarray | None = None,
        rank: bool = False,
    ) -> Verdict:
        """`judging.disagreement`, naming the original code's logs at other settings where
        none matches `run`: a comparison across attack parameters is only inconclusive;
        logs at its settings whose attack is inferred are named, never tested."""
        inferred = self.inferred(run)
        other = (inferred or self.elsewhere(run)) if agrees is None else None
        if other is not None:
            return verdicts.inconclusive(
                f"{reason}; {other}: not comparable, so no cause can be named"
            )
        verdict = judging.disagreement(reason, agrees, ours, theirs, rank)
        if inferred is None:
            return verdict
        return dataclasses.replace(
            verdict, reason=f"{verdict.reason}; not tested against {inferred}"
        )

    def compare(
        self,
        quantity: str,
        paper: str,
        run: RunRecord,
        column: str,
        until: int | None = None,
        **fmt,
    ) -> Comparison:
        """The paper | original code | pimbot row of `column`'s final value: pimbot's run and
        the original code's logs at its exact settings (every one, marked where its attack
        is inferred), both cut at their common horizon (≤ `until`)."""
        ours = run.curves
        limit = min(ours.horizon, until if until is not None else ours.horizon)
        original = self.table.original_for(run, limit)
        theirs = original.curves if original is not None else None
        if theirs is None or not theirs.has(column):
            value = estimate(ours.final(column, limit), **fmt)
            text = None
            if original is not None:
                text = "not logged"
            elif self.elsewhere(run) is not None:
                text = "not compared: " + self.elsewhere(run)
            return Comparison(quantity, f"{limit:,} it", paper, text, str(value))
        common = min(limit, theirs.horizon)
        value = estimate(theirs.final(column, common), **fmt)
        seeds = f", {count_text([original.seeds], 'original seeds')}"
        if self.inferred(run) is not None:
            seeds += ", attack inferred"
        return Comparison(
            quantity,
            f"{common:,} it",
            paper,
            f"{value}{seeds}",
            str(estimate(ours.final(column, common), **fmt)),
        )

    def finals(
        self, run: RunRecord, column: str, until: int
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Per seed (per log), `column`'s final value of `run` and of the original code's
        logs a cause may rest on (`original`), both at their common horizon (≤ `until`);
        None for the original without such a log that has the column."""
        ours = run.curves
        limit = min(ours.horizon, until)
        log = self.original(run, limit)
        if log is None or not log.curves.has(column):
            return ours.final(column, limit), None
        common = min(limit, log.curves.horizon)
        return ours.final(column, common), log.curves.final(column, common)

    def success_reachable(self, run: RunRecord) -> bool:
        """Whether the env's rules let the others succeed with `run`'s adversary idle."""
        key = (
            run.identity["env_id"],
            tuple(sorted(run.identity["env_params"].items())),
            run.adversary,
        )
        if key not in self.reachable_cache:
            self.reachable_cache[key] = judging.success_reachable_with_idle(
                key[0], dict(key[1]), key[2]
            )
        return self.reachable_cache[key]


def claims(table: RunTable, runs: list[RunRecord]) -> list[Claim]:
    data = Runs(table, {(r.env, r.condition): r for r in runs})
    return [c1a(data), c1b(data), *c2(data), c3(data), c4(data), c5(data)]


def _missing() -> Verdict:
    return verdicts.not_run("no run")


# --- C1 ---------------------------------------------------------------------------------


def c1a(data: Runs) -> Claim:
    parts, numbers, margins = {}, [], {}
    for env in C1_ENVS:
        run = data.get(env, "self_centered")
        if run is None:
            parts[env] = _missing()
            continue
        margin = estimate(run.per_seed("eval/adversary_margin_env"), 2, signed=True)
        margins[env] = margin
        judged = judging.above(margin, 0.0, "margin")
        row = data.compare(
            f"{env} self-centered margin",
            "> 0",
            run,
            "eval/adversary_margin_env",
            digits=2,
            signed=True,
        )
        if judged is None:
            ours, theirs = data.finals(run, "eval/adversary_margin_env", run.curves.horizon)
            agrees = None if theirs is None else estimate(theirs).lo > 0
            judged = data.cause(run, f"margin {margin} not above 0", agrees, ours, theirs)
        parts[env] = judged
        numbers.append(row)
    return Claim(
        "C1a",
        "self-centered: the adversary's return is above the others'",
        "the interval of the self-centered adversary's final env-return margin (its return − "
        "the others' mean) lies above 0 in ER(2,1), ER(4,2), IPD",
        _parts_text(parts),
        verdicts.combine(parts),
        _short(parts),
        numbers,
        jobs_of="C1",
        **summarized(
            verdicts.combine(parts),
            {env: f"{env} margin {m}" for env, m in margins.items() if m is not None},
            weakest=_lowest(margins),
            agreed="the self-centered adversary's return is above the others' mean in "
            f"{_envs(margins)} (the lowest interval shown)",
        ),
    )


def _lowest(estimates: dict) -> str:
    """The key of the estimate whose interval reaches lowest ("" without one)."""
    known = {k: e for k, e in estimates.items() if e is not None}
    return min(known, key=lambda k: known[k].lo) if known else ""


def _highest(estimates: dict) -> str:
    """The key of the estimate whose interval reaches highest ("" without one)."""
    known = {k: e for k, e in estimates.items() if e is not None}
    return max(known, key=lambda k: known[k].hi) if known else ""


def _envs(names) -> str:
    """ "ER(2,1), ER(4,2) and IPD(2)"."""
    names = list(names)
    return ", ".join(names[:-1]) + f" and {names[-1]}" if len(names) > 1 else "".join(names)


CRITERIA = ("first crossing", "strict")


def crossings(curves, column: str, until: int) -> dict[str, list]:
    """Per criterion, the per-seed iteration (None: never) of `column` cut at `until`."""
    strict, first = curves.convergence(column, until)
    return {"first crossing": first, "strict": strict}


def c1b(data: Runs) -> Claim:
    parts, numbers, measured, headlines, whys = {}, [], [], {}, {}
    for env, paper in PAPER_SPEED.items():
        clean, selfish = data.get(env, CLEAN), data.get(env, "self_centered")
        if clean is None or selfish is None:
            parts[env] = _missing()
            continue
        a, b = clean.curves, selfish.curves
        column = "eval/return_ratio" if a.has("eval/return_ratio") else "eval/success"
        horizon = min(a.horizon, b.horizon)
        ours = {
            k: (crossings(a, column, horizon)[k], crossings(b, column, horizon)[k])
            for k in CRITERIA
        }
        listed = max(len(a.seeds), len(b.seeds)) <= LISTED_SEEDS
        measured.append(
            f"{env} at {horizon:,} it ({len(a.seeds)}+{len(b.seeds)} seeds; "
            f"{'per seed' if listed else 'quartiles over seeds'} clean "
            f"{_iters(ours['first crossing'][0])} / {_iters(ours['strict'][0])}, self-centered "
            f"{_iters(ours['first crossing'][1])} / {_iters(ours['strict'][1])}, first "
            f"crossing / strict): {_speed_text(ours)}"
        )
        logs = _pooled_logs(data, (clean, selfish), column, horizon)
        numbers += _speed_rows(env, (a, b), column, horizon, paper, logs)
        judged = _speed_verdict(data, (clean, selfish), column, ours, horizon, paper[0], logs)
        parts[env] = verdicts.stated_at(judged, horizon, paper[0])  # the paper's clean speed
        clean_at, selfish_at = ours["first crossing"]
        faster = judging.earlier(selfish_at, clean_at)[0]
        headlines[env] = (
            f"{env} first crossing of 0.9 {iteration_text(judging.median_iteration(clean_at))} → "
            f"{iteration_text(judging.median_iteration(selfish_at))}, p = {faster:.3f} earlier"
        )
        if horizon < paper[0]:
            whys[env] = (
                f"the runs stop at {horizon:,} it, before the paper's clean run converges "
                f"({paper[0]:,} it), so the two speeds cannot be compared there"
            )
    verdict = verdicts.combine(parts)
    found = deciding_part(verdict)
    return Claim(
        "C1b",
        "self-centered: ER converges faster than clean LIO (20k → 12.5k, 14k → 10.5k)",
        "per criterion (first crossing of 0.9; strict: smoothed over 10 evaluations, stays "
        "≥ 0.9), the self-centered seeds' iterations are earlier than the clean seeds' by a "
        f"one-sided Mann–Whitney U test, p < {judging.DIFFERS_P:g} (a seed that never gets "
        "there counts as +∞), both runs cut at their common horizon; significantly later by "
        "the same test is evidence against, classified by the original code's logs of both "
        "runs (pooled over the log directories that reach the horizon); neither: inconclusive",
        "; ".join(measured) or _parts_text(parts),
        verdict,
        _short(parts),
        numbers,
        jobs_of="C1",
        **summarized(
            verdict,
            headlines,
            agreed=f"the self-centered runs cross 0.9 earlier in {_envs(headlines)}",
            why=whys.get(found[0], "") if found else "",
        ),
    )


LISTED_SEEDS = 10
"""Up to this many seeds a speed part lists every seed's iteration; above, the quartiles
(Fig. 4 and the convergence table show the seeds)."""


def _iters(values: list) -> str:
    """Each seed's iteration ("8.4k/never/…"), or above LISTED_SEEDS seeds the lower and
    upper quartile over seeds (a seed that never gets there ranks last) and how many never
    do ("5.3k–10.2k, never 1")."""
    if len(values) <= LISTED_SEEDS:
        return "/".join(iteration_text(v) for v in values)
    ranked = sorted(values, key=lambda v: (v is None, v or 0))
    low, high = (ranked[round(q * (len(ranked) - 1))] for q in (0.25, 0.75))
    never = sum(iteration_text(v) == "never" for v in values)
    return f"{iteration_text(low)}–{iteration_text(high)}, never {never}"


def _speed_text(pairs: dict[str, tuple[list, list]]) -> str:
    """ "first crossing 5.5k → 6.2k (Mann–Whitney p = 0.73 earlier, 0.29 later); …"."""
    out = []
    for kind, (clean, selfish) in pairs.items():
        faster, slower = judging.earlier(selfish, clean)
        out.append(
            f"{kind} {iteration_text(judging.median_iteration(clean))} → "
            f"{iteration_text(judging.median_iteration(selfish))} (one-sided Mann–Whitney "
            f"p = {faster:.3f} earlier, {slower:.3f} later)"
        )
    return "; ".join(out)


def _pooled_logs(data: Runs, pair, column: str, horizon: int):
    """The original code's logs at both runs' exact settings that record their attack
    (not `RunRecord.attack_inferred`), every log directory that reaches the common horizon
    (≤ `horizon`: the longest directory of each run bounds it) pooled: (horizon,
    {criterion: (clean, self-centered) per-seed iterations}, seeds); None where either run
    has no log with `column`."""
    logs = [
        [r for r in data.table.originals_for(run) if r.curves.has(column) and not r.attack_inferred]
        for run in pair
    ]
    if not all(logs):
        return None
    common = min([horizon] + [max(r.curves.horizon for r in found) for found in logs])
    by_criterion = {k: ([], []) for k in CRITERIA}
    counts = []
    for side, found in enumerate(logs):
        reach = [r for r in found if r.curves.horizon >= common]
        logs_of_side = pooled(sorted(reach, key=lambda r: r.name))  # reruns count once
        counts.append(logs_of_side.seeds)
        for k, values in crossings(logs_of_side.curves, column, common).items():
            by_criterion[k][side].extend(values)
    return common, by_criterion, counts


def _speed_verdict(data: Runs, pair, column, ours, horizon, paper_clean, logs) -> Verdict:
    """Reproduced where the self-centered run is significantly earlier by every
    criterion; where it is significantly later by one, the original code's logs say
    whose the difference is; else inconclusive."""
    text = _speed_text(ours)
    tests = {k: judging.earlier(s, c) for k, (c, s) in ours.items()}
    if all(faster < judging.DIFFERS_P for faster, _ in tests.values()):
        return verdicts.reproduced(text)
    later = [k for k, (_, slower) in tests.items() if slower < judging.DIFFERS_P]
    never = all(judging.median_iteration(c) is None for c, _ in ours.values())
    if horizon < paper_clean and never:
        return verdicts.inconclusive(f"{horizon:,} it < the paper's {paper_clean:,}: {text}")
    if not later:
        return verdicts.inconclusive(
            f"{text}: the seeds cannot tell the runs apart (p ≥ {judging.DIFFERS_P:g})"
            + (f"; the original code's logs: {_logs_text(logs)}" if logs else "")
        )
    reason = f"self-centered later by {' and '.join(later)}: {text}"
    if logs is None:
        return data.cause(pair[1], reason, None)
    common, pooled, _ = logs
    kind = later[0]
    faster, slower = judging.earlier(pooled[kind][1], pooled[kind][0])
    reason += f"; the original code's logs: {_logs_text(logs)}"
    if slower < judging.DIFFERS_P:
        return data.cause(pair[1], reason, False)
    if faster >= judging.DIFFERS_P:
        return verdicts.inconclusive(f"{reason}: they cannot tell either, no cause can be named")
    verdict = None
    for side, run in enumerate(pair):  # our implementation only where a run differs
        mine = crossings(run.curves, column, common)[kind]
        theirs = pooled[kind][side]
        v = data.cause(
            run,
            f"{reason}; {run.condition} at {common:,} it",
            True,
            _as_inf(mine),
            _as_inf(theirs),
            rank=True,
        )
        if verdict is None or v.kind == verdicts.REFUTED:
            verdict = v
    return verdict


def _as_inf(values: list) -> np.ndarray:
    return np.array([np.inf if v is None else v for v in values], dtype=float)


def _logs_text(logs) -> str:
    common, pooled, counts = logs
    return f"{counts[0]}+{counts[1]} logs at {common:,} it, {_speed_text(pooled)}"


def _speed_rows(env, ours, column, horizon, paper, logs) -> list[Comparison]:
    """paper | original code | pimbot rows of both speed criteria, clean → self-centered, at
    the horizon pimbot's two runs and the original code's pooled logs share."""
    common = horizon if logs is None else logs[0]
    rows = []
    for kind in CRITERIA:
        mine = [crossings(c, column, common)[kind] for c in ours]
        original = None
        if logs is not None:
            theirs = logs[1][kind]
            original = " → ".join(iteration_text(judging.median_iteration(v)) for v in theirs)
            original += f" ({logs[2][0]}+{logs[2][1]} logs)"
        rows.append(
            Comparison(
                f"{env} convergence clean → self-centered ({kind})",
                f"{common:,} it",
                f"{paper[0] / 1000:g}k → {paper[1] / 1000:g}k",
                original,
                " → ".join(iteration_text(judging.median_iteration(v)) for v in mine),
            )
        )
    return rows


# --- C2 ---------------------------------------------------------------------------------


def exploration_end(run: RunRecord) -> int | None:
    """The last iteration of LIO's exploration period: its ε schedule decays over
    `epsilon_decay_iters` (the original's `epsilon_div`); None for a learner without one."""
    value = run.identity.get("learner_config", {}).get("epsilon_decay_iters")
    return int(value) if value else None


def window_mean(curves, column: str, until: int) -> np.ndarray:
    """Per seed, the mean of `column` over the evaluations at or before `until` ([] where
    the column is absent or no evaluation falls in the window)."""
    if not curves.has(column):
        return np.array([])
    out = [curves.values[s][column][curves.iterations[s] <= until] for s in curves.seeds]
    return np.array([v.mean() for v in out]) if all(v.size for v in out) else np.array([])


def resolution(run: RunRecord) -> float:
    """The smallest nonzero final success a seed can log: one success in the final
    window's evaluation episodes."""
    return 1.0 / (FINAL_WINDOW * int(run.identity.get("eval_episodes", 1)))


def amount(run: RunRecord) -> float:
    return float(run.identity["attack_params"].get("amount", float("nan")))


def falls(run: RunRecord, until: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(early, final) success per seed of `run`: the mean over the exploration period and
    the final value at `until` (None: the whole run); [] without an exploration period."""
    end = exploration_end(run)
    if end is None:
        return np.array([]), np.array([])
    return window_mean(run.curves, "eval/success", end), run.curves.final("eval/success", until)


def c2(data: Runs) -> list[Claim]:
    """C2 at the original code's C = 10 (the main row) and the paper's C = 50 (a second
    row); each compared only with the original code's logs at the same C."""
    runs_by_amount: dict[float, dict[str, RunRecord]] = {}
    for run in data.by.values():
        if run.attack == FAKE_INCENTIVE and run.env in ROOMS:
            runs_by_amount.setdefault(amount(run), {})[run.env] = run
    amounts = sorted(set(runs_by_amount) | {CODE_AMOUNT}, key=lambda c: (c != CODE_AMOUNT, c))
    return [_c2_row(data, c, runs_by_amount.get(c, {})) for c in amounts]


def _c2_row(data: Runs, c: float, found: dict[str, RunRecord]) -> Claim:
    parts, numbers, changes, falls_p = {}, [], {}, {}
    for env in ROOMS:
        run = found.get(env)
        if run is None:
            parts[env] = _missing()
            continue
        quantity = f"{env} fake-incentive (C = {c:g}) success"
        row = data.compare(quantity, "~0", run, "eval/success")
        numbers.append(row)
        parts[env] = _c2_part(data, run)
        early, final = falls(run)
        if early.size and final.size:
            changes[env] = estimate(final - early, signed=True)
            falls_p[env] = sign_p_value(final - early, "less")
    where = "the original code's" if c == CODE_AMOUNT else "the paper's text's"
    return Claim(
        "C2" if c == CODE_AMOUNT else f"C2 (C = {c:g})",
        f"fake incentive at {where} C = {c:g} per step: early, unstable successes, then ~0 "
        "success in ER",
        "early: the mean success per seed over LIO's exploration period (its ε decay, "
        "iterations ≤ epsilon_decay_iters) is > 0 (the interval over seeds above 0); then "
        "~0: the final success is below the early success (sign-flip permutation test of "
        f"final − early per seed, one-sided p < {judging.DIFFERS_P:g}) and its interval reaches "
        "down to the metric's resolution (one success in the final window's evaluation "
        "episodes); in every ER config; a refutation is classified only by the original "
        "code's logs at the same C",
        _parts_text(parts),
        verdicts.combine(parts),
        _short(parts),
        numbers,
        jobs_of="C2",
        **summarized(
            verdicts.combine(parts),
            {
                env: f"{env} final − early success {d}, p = {falls_p[env]:.3f} for a fall"
                for env, d in changes.items()
            },
            weakest=_highest(changes),
            agreed=f"success falls from its early level to ≈ 0 in {_envs(changes)} (the "
            "smallest fall shown)",
        ),
    )


def _c2_verdict(early: np.ndarray, final: np.ndarray, res: float) -> tuple[Verdict | None, str]:
    """C2's rule on per-seed (early, final) success: (verdict, or None for evidence against;
    which part failed: "early" or "final")."""
    some = judging.above(estimate(early), 0.0, "early success")
    if some is None:
        return None, "early"
    fall = judging.falls_to_zero(early, final, res)
    if fall is None:
        return None, "final"
    if some.kind != verdicts.REPRODUCED:
        return some, "early"
    return fall, "final"


def _c2_part(data: Runs, run: RunRecord) -> Verdict:
    end = exploration_end(run)
    if end is None:
        return verdicts.inconclusive("the learner has no exploration schedule")
    early, final = falls(run)
    verdict, failed = _c2_verdict(early, final, resolution(run))
    text = f"exploration ≤ {end:,} it: early success {estimate(early)}, final {estimate(final)}"
    if verdict is not None:  # a fall's reason carries both numbers, the early part's one
        detail = verdict.reason
        if failed == "early":
            detail += f", final {estimate(final)}"
        return dataclasses.replace(verdict, reason=f"exploration ≤ {end:,} it: {detail}")
    reason = (
        f"{text}: no early success"
        if failed == "early"
        else f"{text}: " + judging.falls_text(early, final, resolution(run))
    )
    log = data.original(run, run.iterations)
    if log is None or not log.curves.has("eval/success"):
        return data.cause(run, reason, None)
    common = min(log.curves.horizon, run.curves.horizon)
    theirs = falls(log, common)
    logged = _c2_verdict(*theirs, resolution(log))[0]
    if logged is not None and logged.kind != verdicts.REPRODUCED:
        return verdicts.inconclusive(
            f"{reason}; the original code's logs at the same C cannot tell either "
            f"({logged.reason}): no cause can be named"
        )
    pick = 0 if failed == "early" else 1
    return data.cause(
        run,
        f"{reason}; at {common:,} it",
        logged is not None,
        falls(run, common)[pick],
        theirs[pick],
    )


# --- C3 ---------------------------------------------------------------------------------


def c3(data: Runs) -> Claim:
    parts, lines, numbers, finals, forbidden, solved = {}, [], [], {}, [], []
    for env in ROOMS:
        run = data.get(env, "bypass")
        if run is None:
            parts[env] = _missing()
            continue
        params = run.identity["env_params"]
        reachable = data.success_reachable(run)
        structure = judging.structure_text(params, run.adversary, reachable)
        final = estimate(run.per_seed("eval/success"))
        finals[env] = f"{env} bypass success {final}"
        (solved if reachable else forbidden).append(env)
        claimed = "solved" if reachable else "0"
        row = data.compare(f"{env} bypass success", claimed, run, "eval/success")
        numbers.append(row)
        if not reachable:  # structural: the env's rules decide; the runs must agree
            lines.append(f"{env} structural: {structure}; measured {final}")
            if final.hi > 0:  # shown by the run: our env's rules and our run contradict
                parts[env] = verdicts.refuted(
                    verdicts.IMPLEMENTATION,
                    f"the env's rules forbid success ({structure}), yet success {final} was "
                    f"measured in {run.seeds} seeds",
                    structural=True,
                )
            else:
                parts[env] = verdicts.reproduced(f"structural, measured {final}")
        else:  # evidence: the redundant team must learn it
            lines.append(f"{env} evidence: {structure}; measured {final}")
            if final.mean >= SOLVED:
                parts[env] = verdicts.reproduced(f"evidence, solved: {final}")
            else:
                ours, theirs = data.finals(run, "eval/success", run.curves.horizon)
                agrees = None if theirs is None else float(np.mean(theirs)) >= SOLVED
                parts[env] = data.cause(
                    run, f"evidence: success {final} not ≥ {SOLVED:g}", agrees, ours, theirs
                )
    return Claim(
        "C3",
        "bypass: 0 success in ER(2,1), ER(4,3); ER(4,2) still solved (redundancy)",
        "structural part: where the env's rules leave no joint action of the others that "
        "succeeds with the adversary idle (every agent is needed), success must be 0 in "
        f"every seed; evidence part: where they leave one, the mean final success ≥ {SOLVED:g}",
        "; ".join(lines) or _parts_text(parts),
        verdicts.combine(parts),
        _short(parts),
        numbers,
        **summarized(
            verdicts.combine(parts),
            finals,
            weakest=solved[0] if solved else "",
            agreed=(
                f"the rules leave {_envs(forbidden)} no success with the adversary idle "
                f"(measured 0)"
                * bool(forbidden)
                + "; " * bool(forbidden and solved)
                + f"{_envs(solved)}'s redundant team still solves it" * bool(solved)
            ),
        ),
    )


# --- C4 ---------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Reverse:
    """C4's measurement of one env's reverse run."""

    at_budget: Verdict
    """The rule at the paper's budget."""
    line: str
    """The measured values, for the claim's text."""
    late: str | None
    """What the run did after the paper's budget, a note (None: not longer)."""
    number: Comparison


def _reverse_rule(run: RunRecord, want_low: bool, cut: int) -> tuple[Verdict | None, str]:
    """C4's rule on one run cut at `cut`: success falls to ≈ 0 (`judging.falls_to_zero`),
    or in ER(4,2) it does not (the final's interval lies above the metric's resolution).
    (verdict, None for evidence against; the words of the failure)."""
    early, final = falls(run, cut)
    res = resolution(run)
    if want_low:
        verdict = judging.falls_to_zero(early, final, res)
        return verdict, "" if verdict else judging.falls_text(early, final, res)
    est = estimate(final)
    if est is None:
        return verdicts.inconclusive("success not logged by these runs"), ""
    if est.lo > res:
        return verdicts.reproduced(f"final success {est} above 0 (resolution {res:g})"), ""
    return None, f"final success {est} reaches 0 (resolution {res:g})"


def reverse(data: Runs, env: str, run: RunRecord) -> Reverse:
    """C4 in one env at the paper's budget; a refutation is classified by the original
    code's log at the run's settings. What happens after the budget is a note."""
    curves = run.curves
    want_low = env != "ER(4,2)"
    cut = min(curves.horizon, PAPER_ATTACK_BUDGET)
    budget = estimate(curves.final("eval/success", PAPER_ATTACK_BUDGET))
    longer_run = curves.horizon > PAPER_ATTACK_BUDGET
    full = estimate(curves.final("eval/success"))
    line = f"{env}: at {cut:,} it {budget}" + (
        f", at {curves.horizon:,} it {full}" if longer_run else ""
    )
    verdict, failure = _reverse_rule(run, want_low, cut)
    if verdict is None and curves.horizon < PAPER_ATTACK_BUDGET:
        verdict = verdicts.inconclusive(
            f"{curves.horizon:,} it < the paper's {PAPER_ATTACK_BUDGET:,}: {failure}"
        )
    elif verdict is None:
        ours, original = data.finals(run, "eval/success", cut)
        log = data.original(run, cut)
        agrees = None
        if log is not None and original is not None:
            common = min(cut, log.curves.horizon)
            logged = _reverse_rule(log, want_low, common)[0]
            agrees = logged is not None and logged.kind == verdicts.REPRODUCED
            if logged is not None and not agrees:
                verdict = verdicts.inconclusive(
                    f"{failure} at {cut:,} it; the original code's logs cannot tell either "
                    f"({logged.reason}): no cause can be named"
                )
        if verdict is None:
            verdict = data.cause(run, f"{failure} at {cut:,} it", agrees, ours, original)
    late = None
    if longer_run:
        late = f"{env} {full.mean - budget.mean:+.3f} from {cut:,} to {curves.horizon:,} it"
    claimed = "0" if want_low else "not 0"
    number = data.compare(f"{env} reverse success", claimed, run, "eval/success", cut)
    return Reverse(verdict, line, late, number)


def c4(data: Runs) -> Claim:
    at_budget, numbers, lines, late, finals = {}, [], [], [], {}
    for env in ROOMS:
        run = data.get(env, "reverse")
        if run is None:
            at_budget[env] = _missing()
            continue
        measured = reverse(data, env, run)
        at_budget[env] = verdicts.stated_at(
            measured.at_budget, run.curves.horizon, PAPER_ATTACK_BUDGET
        )
        lines.append(measured.line)
        numbers.append(measured.number)
        finals[env] = f"{env} final {measured.number.pimbot} at {measured.number.horizon}"
        if measured.late is not None:
            late.append(measured.late)
    note = (
        "; note (not judged: the paper ran no longer than "
        f"{PAPER_ATTACK_BUDGET:,} it): after it, " + ", ".join(late)
        if late
        else ""
    )
    return Claim(
        "C4",
        "reverse: success → 0 except ER(4,2), at the paper's budget",
        f"at {PAPER_ATTACK_BUDGET:,} it: in ER(2,1) and ER(4,3) the success falls to ≈ 0 "
        "(the final success per seed below its mean over LIO's exploration period, "
        f"sign-flip permutation test, one-sided p < {judging.DIFFERS_P:g}, and the final's "
        "interval reaches down to the metric's resolution); in ER(4,2) it does not (the "
        "final's interval lies above the resolution); a refutation is classified by the "
        "original code's logs at the run's settings (permutation test of the finals)",
        "; ".join(lines) + note if lines else _parts_text(at_budget),
        verdicts.combine(at_budget),
        _short(at_budget) + (" (later: " + ", ".join(late) + ")" if late else ""),
        numbers,
        **summarized(
            verdicts.combine(at_budget),
            finals,
            weakest="ER(2,1)",
            agreed="success falls to ≈ 0 in ER(2,1) and ER(4,3) and stays above 0 in ER(4,2), "
            f"at the paper's {PAPER_ATTACK_BUDGET:,} it",
        ),
    )


# --- C5 ---------------------------------------------------------------------------------


def exit_success_margin(run: RunRecord, base: RunRecord | None):
    """(the adversary's own final exit success, that minus the symmetric baseline: the clean
    team's mean exit success per agent) per seed; (None, None) where not logged."""
    own = run.per_seed(f"eval/exit_success/agent_{run.adversary}")
    if own.size == 0 or base is None:
        return None, None
    per_agent = [base.per_seed(f"eval/exit_success/agent_{i}") for i in range(base.num_agents)]
    if any(v.size == 0 for v in per_agent):
        return estimate(own), None
    return estimate(own), difference(own, np.mean(per_agent, axis=0))


def mode_of(run: RunRecord) -> str:
    """An ADMO run's mode (its attack parameter; "" where the attack has none)."""
    return str(run.identity["attack_params"].get("mode", ""))


def admo_parts(data: Runs, attack: str) -> tuple[dict[str, Verdict], list, list[str]]:
    """The C5 parts for one ADMO attack (its runs found by the attack name in their
    configs, whatever their labels); an attack run in one mode only is judged on every part
    in it. Returns (parts, table rows, measurements shown without a verdict: IPD
    cooperation and steps per episode)."""
    mine = [r for r in data.by.values() if r.attack == attack]
    single = len({mode_of(r) for r in mine}) == 1
    parts, rows, notes = {}, [], []
    for env in ROOMS:
        base = data.get(env, CLEAN)
        for run in sorted((r for r in mine if r.env == env), key=lambda r: r.condition):
            if base is None:
                continue
            row, judged = admo_run(data, run, base, single)
            rows.append(row)
            parts.update(judged)
    for run in sorted((r for r in mine if r.env == "IPD(2)"), key=lambda r: r.condition):
        curves = run.curves
        change = estimate(curves.final("eval/success") - curves.first("eval/success"), signed=True)
        notes.append(f"IPD {run.condition} cooperation change over training {change}")
    for row in rows:
        notes.append(f"{row[0]} {row[1]} steps {row[-1]}")
    return parts, rows, notes


def admo_run(
    data: Runs, run: RunRecord, base: RunRecord, single: bool
) -> tuple[list, dict[str, Verdict]]:
    """One ER ADMO run against its env's clean run: (its table row, its C5 parts). The
    margin and own-success parts judge the stealthy mode, disruption the disrupt mode
    where the task is non-redundant (every part where the attack ran in one mode only);
    steps are a measurement in the row."""
    mode, name = mode_of(run), f"{run.env} {run.condition}"
    margins = run.per_seed("eval/adversary_margin_env")
    margin = estimate(margins, 2, signed=True)
    own, own_gain = exit_success_margin(run, base)
    d_success = difference(run.per_seed("eval/success"), base.per_seed("eval/success"))
    row = [run.env, run.condition, run.seeds, margin, own, own_gain, d_success]
    row.append(steps_text(run, base))
    parts = {}
    if mode == "stealthy" or single:
        parts[f"{name} margin"] = judging.above_zero(margins, "margin") or data.cause(
            run, f"margin {margin} significantly below 0", None
        )
        parts[f"{name} own success"] = own_success_part(data, run, base, own, own_gain)
    if mode == "disrupt" and not data.success_reachable(run):
        parts[f"{name} disrupts"] = (
            verdicts.reproduced(f"Δ success {d_success}")
            if d_success.hi < 0
            else data.cause(run, f"non-redundant task, Δ success {d_success} not below 0", None)
        )
    return row, parts


def steps_text(run: RunRecord, base: RunRecord) -> str:
    """Steps per episode against clean, a measurement: "2.10 (Δ +0.30 [+0.1, +0.5], +17 %)"."""
    steps, clean = run.per_seed("eval/steps"), base.per_seed("eval/steps")
    if not steps.size or not clean.size:
        return "–"
    delta = difference(steps, clean, digits=2)
    return f"{steps.mean():.2f} (Δ {delta}, {delta.mean / clean.mean():+.0%} of clean)"


def own_success_part(data: Runs, run: RunRecord, base: RunRecord, own, own_gain) -> Verdict:
    """The adversary's own exit success above the clean team's mean per agent: a one-sided
    permutation test of the two runs' means (independent seeds)."""
    if own_gain is None:
        return verdicts.inconclusive("per-agent exit success not logged by these runs")
    mine = run.per_seed(f"eval/exit_success/agent_{run.adversary}")
    per_agent = np.mean(
        [base.per_seed(f"eval/exit_success/agent_{i}") for i in range(base.num_agents)], axis=0
    )
    up = difference_p_value(mine, per_agent, alternative="greater")
    down = difference_p_value(mine, per_agent, alternative="less")
    text = (
        f"own exit success {own} − clean per-agent mean = {own_gain} (one-sided permutation "
        f"p = {up:.3f} above, {down:.3f} below)"
    )
    if up < judging.DIFFERS_P:
        return verdicts.reproduced(text)
    if down < judging.DIFFERS_P:
        return data.cause(run, text, None)
    return verdicts.inconclusive(f"{text}: the seeds cannot tell it from the clean mean")


C5_CLAIM = (
    "ADMO vs LIO: adversary's reward and success elevated in ER; IPD nearly flat; steps "
    "change modestly"
)


def c5(data: Runs) -> Claim:
    attacks = {}
    for attack in ADMO_ATTACKS:
        if any(r.attack == attack for r in data.by.values()):
            attacks[attack] = admo_parts(data, attack)
    if "admo" not in attacks:
        return Claim("C5", C5_CLAIM, "–", "no ADMO run", verdicts.not_run("no ADMO run"))
    parts, rows, notes = attacks["admo"]
    code_parts = attacks.get("admo_code", ({}, [], []))[0]
    parts = {name: _classified(name, v, code_parts) for name, v in parts.items()}
    shapes, met = [], {}
    for attack, (mine, _, _) in attacks.items():
        met[attack] = sum(v.kind == verdicts.REPRODUCED for v in mine.values()) / max(len(mine), 1)
        shapes.append(f"{attack} {met[attack]:.0%} of its parts")
    measured = _parts_text(parts)
    if "admo_code" in attacks:
        closer = max(met, key=met.get) if len(set(met.values())) > 1 else "neither"
        measured += (
            f"; admo_code: {_parts_text(code_parts)}; closer to the paper's shapes: {closer}"
        )
    else:
        measured += "; admo_code (the published code's scheduler): no runs in this suite"
    measured += "; measured, not judged (the paper gives no size): " + "; ".join(notes)
    return Claim(
        "C5",
        C5_CLAIM,
        "ER: the stealthy adversary's margin > 0 (the symmetric baseline; sign-flip "
        f"permutation test over seeds, one-sided p < {judging.DIFFERS_P:g}) and its own exit "
        "success > the clean team's mean per agent (permutation test of the two runs' means, "
        f"one-sided p < {judging.DIFFERS_P:g}); disrupt lowers success (Δ interval < 0) where "
        "the task is non-redundant (env rules); IPD cooperation over training and steps per "
        "episode against clean are shown with their intervals, not judged: the paper gives "
        'no size for "nearly flat" or "modestly"',
        measured,
        verdicts.combine(parts),
        "paper's shapes: " + ", ".join(shapes) + "; " + _short(parts),
        **summarized(
            verdicts.combine(parts),
            _c5_numbers(rows),
            agreed="the stealthy adversary's margin and own exit success are above the "
            "clean team's, and disrupt lowers success where every agent is needed",
        ),
    )


def _c5_numbers(rows: list[list]) -> dict[str, str]:
    """The number of each C5 part (by part name), from the ADMO table's rows."""
    out = {}
    for env, condition, _, margin, _, own_gain, d_success, _ in rows:
        name = f"{env} {condition}"
        out[f"{name} margin"] = f"{name} margin {margin}"
        out[f"{name} own success"] = f"{name} own exit success − clean per agent {own_gain}"
        out[f"{name} disrupts"] = f"{name} Δ success {d_success}"
    return out


def _classified(name: str, verdict: Verdict, code_parts: dict[str, Verdict]) -> Verdict:
    """A refuted part of our ADMO: where the published code's scheduler gives it, the cause
    is our spec's ADMO; where the scheduler fails it too, the paper's own code."""
    if verdict.kind != verdicts.REFUTED:
        return verdict
    code_name = next(
        (
            k
            for k in code_parts
            if k.split(" ")[0] == name.split(" ")[0] and k.split(" ")[-1] == name.split(" ")[-1]
        ),
        None,
    )
    if code_name is None:
        return verdict
    code = code_parts[code_name]
    if code.kind == verdicts.REPRODUCED:
        return verdicts.refuted(verdicts.SPEC, f"{verdict.reason}; admo_code gives it")
    if code.kind == verdicts.REFUTED:
        return verdicts.refuted(verdicts.PAPER_CODE, f"{verdict.reason}; admo_code neither")
    return verdict


def admo_table(data: Runs) -> Table | None:
    rows = []
    for attack in ADMO_ATTACKS:
        rows += admo_parts(data, attack)[1]
    if not rows:
        return None
    header = ["env", "condition", "seeds", "adversary margin [interval]"]
    header += ["adversary's own exit success", "own exit success − clean per-agent mean"]
    header += ["Δ success vs clean", "steps (Δ vs clean, a measurement)"]
    return Table(
        header,
        rows,
        "ADMO (ours) vs admo_code (the published code's scheduler)",
        "The adversary's margin against the symmetric baseline 0 and its own exit success "
        "against the clean team's mean per agent (clean agent 0's margin is ±10 by which "
        "agent took the door, so clean is no baseline for one agent).",
        "attacks_admo",
    )


# --- text -------------------------------------------------------------------------------


def _parts_text(parts: dict[str, Verdict]) -> str:
    return "; ".join(f"{name}: {v.reason or v.label}" for name, v in parts.items())


def _short(parts: dict[str, Verdict]) -> str:
    counts = {}
    for v in parts.values():
        counts[v.kind] = counts.get(v.kind, 0) + 1
    return ", ".join(f"{n} {verdicts.LABELS[k].split(' (')[0]}" for k, n in counts.items()) + (
        f" of {len(parts)} parts"
    )
