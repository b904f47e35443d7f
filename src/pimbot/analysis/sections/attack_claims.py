"""Claims C1–C5 judged as the paper states them, at the paper's budget, from the attack
group's LIO runs (and the original code's runs where its logs cover a setting).

- C1a: the self-centered adversary's env-return margin over the others is above 0.
- C1b: self-centered ER converges faster than clean, by first crossing and by the strict
  criterion, both runs cut at their common horizon (paper: ER(2,1) 20k → 12.5k,
  ER(4,2) 14k → 10.5k).
- C2: fake incentive: early successes, then ~0.
- C3: bypass: the parts the environment's rules decide (an idle agent makes a task in
  which every agent is needed impossible) and the part that is evidence (ER(4,2) still
  solved).
- C4: reverse judged at the paper's 25k iterations; C4b the same rule at our longer horizon.
- C5: ADMO: the adversary's margin against the symmetric baseline (0) and its own exit
  success against the clean team's mean per agent, elevated in ER; disrupt lowers success
  where the task is non-redundant; IPD nearly flat; steps per episode change modestly.
  `admo` and `admo_code` (the published code's scheduler) side by side where both ran.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from pimbot.analysis import judging, verdicts
from pimbot.analysis.claims import Claim, Comparison
from pimbot.analysis.document import count_text
from pimbot.analysis.judging import PAPER_ATTACK_BUDGET, iteration_text
from pimbot.analysis.runs import CLEAN, RunRecord, RunTable
from pimbot.analysis.tables import Estimate, Table, difference, estimate
from pimbot.analysis.verdicts import Verdict

ROOMS = ("ER(2,1)", "ER(4,2)", "ER(4,3)")
C1_ENVS = ("ER(2,1)", "ER(4,2)", "IPD(2)")
PAPER_SPEED = {"ER(2,1)": (20_000, 12_500), "ER(4,2)": (14_000, 10_500)}
"""Iterations to converge, clean → self-centered, as the paper states them."""
LOW, SOLVED = 0.05, 0.9
"""Success "~0" and "solved"."""
EARLY_FRACTION, EARLY_PEAK = 0.2, 0.1
"""C2's early successes: the seed-mean success peaks ≥ EARLY_PEAK in the first fifth."""
FLAT = 0.1
"""C5's "IPD nearly flat": the ADMO run's cooperation changes by less than this over training."""
MODEST = 0.25
"""C5's "steps change modestly": |Δ steps| / clean steps ≤ this."""
ADMO_ATTACKS = ("admo", "admo_code")


@dataclasses.dataclass
class Runs:
    """The attack group's LIO runs by (env label, condition)."""

    table: RunTable
    by: dict[tuple[str, str], RunRecord]
    reachable_cache: dict[tuple, bool] = dataclasses.field(default_factory=dict)

    def get(self, env: str, condition: str) -> RunRecord | None:
        return self.by.get((env, condition))

    def original(self, env: str, condition: str, horizon: int | None = None) -> RunRecord | None:
        run = self.get(env, condition)
        attack = run.attack if run is not None else None
        return self.table.original_for(env, condition, horizon=horizon, attack=attack)

    def compare(
        self,
        quantity: str,
        paper: str,
        run: RunRecord,
        column: str,
        until: int | None = None,
        **fmt,
    ) -> tuple[Comparison, Estimate | None]:
        """The paper | original code | pimbot row of `column`'s final value: pimbot's run and
        the original code's log of the same env and condition, both cut at their common
        horizon (≤ `until`); and the original's value (None without a log)."""
        ours = run.curves
        limit = min(ours.horizon, until if until is not None else ours.horizon)
        original = self.original(run.env, run.condition, limit)
        theirs = original.curves if original is not None else None
        if theirs is None or not theirs.has(column):
            value = estimate(ours.final(column, limit), **fmt)
            text = None if original is None else "not logged"
            return Comparison(quantity, f"{limit:,} it", paper, text, str(value)), None
        common = min(limit, theirs.horizon)
        value = estimate(theirs.final(column, common), **fmt)
        label = "" if original.condition == run.condition else f" ({original.condition})"
        seeds = f", {count_text([original.seeds], 'distinct logs')}"
        row = Comparison(
            quantity,
            f"{common:,} it",
            paper,
            f"{value}{label}{seeds}",
            str(estimate(ours.final(column, common), **fmt)),
        )
        return row, value

    def finals(
        self, run: RunRecord, column: str, until: int
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Per seed (per log), `column`'s final value of `run` and of the original code's
        log of the same env and condition, both at their common horizon (≤ `until`); None
        for the original without a log that has the column."""
        ours = run.curves
        limit = min(ours.horizon, until)
        log = self.original(run.env, run.condition, limit)
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
    return [c1a(data), c1b(data), c2(data), c3(data), *c4(data), c5(data)]


def _missing() -> Verdict:
    return verdicts.not_run("no run")


# --- C1 ---------------------------------------------------------------------------------


def c1a(data: Runs) -> Claim:
    parts, numbers = {}, []
    for env in C1_ENVS:
        run = data.get(env, "self_centered")
        if run is None:
            parts[env] = _missing()
            continue
        margin = estimate(run.per_seed("eval/adversary_margin_env"), 2, signed=True)
        judged = judging.above(margin, 0.0, "margin")
        row, original = data.compare(
            f"{env} self-centered margin",
            "> 0",
            run,
            "eval/adversary_margin_env",
            digits=2,
            signed=True,
        )
        if judged is None:
            agrees = None if original is None else original.lo > 0
            ours, theirs = data.finals(run, "eval/adversary_margin_env", run.curves.horizon)
            judged = judging.disagreement(f"margin {margin} not above 0", agrees, ours, theirs)
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
    )


def c1b(data: Runs) -> Claim:
    parts, numbers, measured = {}, [], []
    for env, (paper_clean, paper_selfish) in PAPER_SPEED.items():
        clean, selfish = data.get(env, CLEAN), data.get(env, "self_centered")
        if clean is None or selfish is None:
            parts[env] = _missing()
            continue
        a, b = clean.curves, selfish.curves
        column = "eval/return_ratio" if a.has("eval/return_ratio") else "eval/success"
        horizon = min(a.horizon, b.horizon)
        strict_a, first_a = a.convergence(column, horizon)
        strict_b, first_b = b.convergence(column, horizon)
        medians = {
            "first crossing": (
                judging.median_iteration(first_a),
                judging.median_iteration(first_b),
            ),
            "strict": (judging.median_iteration(strict_a), judging.median_iteration(strict_b)),
        }
        text = ", ".join(
            f"{k} {iteration_text(c)} → {iteration_text(s)}" for k, (c, s) in medians.items()
        )
        measured.append(
            f"{env} at {horizon:,} it ({len(a.seeds)}+{len(b.seeds)} seeds; per seed clean "
            f"{_iters(first_a)} / {_iters(strict_a)}, self-centered {_iters(first_b)} / "
            f"{_iters(strict_b)}, first crossing / strict): {text}"
        )
        numbers += _speed_rows(data, env, column, (a, b), horizon, (paper_clean, paper_selfish))
        parts[env] = _speed_verdict(env, medians, horizon, paper_clean, len(a.seeds), len(b.seeds))
    return Claim(
        "C1b",
        "self-centered: ER converges faster than clean LIO (20k → 12.5k, 14k → 10.5k)",
        "median iteration (a seed that never gets there counts as ∞) of self-centered < "
        "clean by first crossing of 0.9 and by the strict criterion (smoothed over 10 "
        "evaluations, stays ≥ 0.9), both runs cut at their common horizon",
        "; ".join(measured) or _parts_text(parts),
        verdicts.combine(parts),
        _short(parts),
        numbers,
        jobs_of="C1",
    )


def _iters(values: list) -> str:
    return "/".join(iteration_text(v) for v in values)


def _speed_verdict(env, medians, horizon, paper_clean, n_clean, n_selfish) -> Verdict:
    faster = {k: s is not None and (c is None or s < c) for k, (c, s) in medians.items()}
    text = "; ".join(
        f"{k} {iteration_text(c)} → {iteration_text(s)}" for k, (c, s) in medians.items()
    )
    if all(faster.values()):
        return verdicts.reproduced(text)
    if not judging.enough_seeds(n_clean, n_selfish):
        return verdicts.inconclusive(f"{n_clean}+{n_selfish} seeds: {text}")
    if horizon < paper_clean and all(c is None for c, _ in medians.values()):
        return verdicts.inconclusive(f"{horizon:,} it < the paper's {paper_clean:,}: {text}")
    slower = [k for k, ok in faster.items() if not ok]
    return judging.disagreement(f"not faster by {' and '.join(slower)}: {text}", None)


def _speed_rows(data: Runs, env, column, ours, horizon, paper) -> list[Comparison]:
    """paper | original code | pimbot rows of both speed criteria, clean → self-centered, at
    the horizon pimbot's two runs and the original code's two logs share."""
    logs = [data.original(env, c, horizon) for c in (CLEAN, "self_centered")]
    theirs = [r.curves if r is not None else None for r in logs]
    usable = all(t is not None and t.has(column) for t in theirs)
    common = min([horizon] + ([t.horizon for t in theirs] if usable else []))
    rows = []
    for k, kind in enumerate(("first crossing", "strict")):

        def medians(curves, k=k):
            out = []
            for c in curves:
                strict, first = c.convergence(column, common)
                out.append(iteration_text(judging.median_iteration((first, strict)[k])))
            return " → ".join(out)

        original = medians(theirs) if usable else (None if logs == [None, None] else "no pair")
        rows.append(
            Comparison(
                f"{env} convergence clean → self-centered ({kind})",
                f"{common:,} it",
                f"{paper[0] / 1000:g}k → {paper[1] / 1000:g}k",
                original,
                medians(ours),
            )
        )
    return rows


# --- C2 ---------------------------------------------------------------------------------


def c2(data: Runs) -> Claim:
    parts, numbers = {}, []
    for env in ROOMS:
        run = data.get(env, "fake_incentive")
        if run is None:
            parts[env] = _missing()
            continue
        curves = run.curves
        final = estimate(run.per_seed("eval/success"))
        peak = curves.early_peak("eval/success", EARLY_FRACTION)
        text = f"early peak {peak:.2f}, final {final}"
        row, _ = data.compare(f"{env} fake-incentive success", "~0", run, "eval/success")
        numbers.append(row)
        if peak is not None and peak >= EARLY_PEAK and final.mean <= LOW:
            parts[env] = verdicts.reproduced(text)
        else:
            parts[env] = judging.disagreement(text, _original_c2(data, run))
    return Claim(
        "C2",
        "fake incentive (C = 50): early, unstable successes, then ~0 success in ER",
        f"the seed-mean success peaks ≥ {EARLY_PEAK:g} in the first "
        f"{EARLY_FRACTION * 100:g} % of the run and the final success is ≤ {LOW:g}, in every "
        "ER config",
        _parts_text(parts),
        verdicts.combine(parts),
        _short(parts),
        numbers,
    )


def _original_c2(data: Runs, run: RunRecord) -> bool | None:
    """Whether the original code's log meets C2's rule (early peak, then ~0) up to the
    horizon it shares with `run`; None without a log."""
    log = data.original(run.env, run.condition, run.iterations)
    if log is None or not log.curves.has("eval/success"):
        return None
    curves = log.curves
    common = min(curves.horizon, run.curves.horizon)
    peak = curves.early_peak("eval/success", EARLY_FRACTION * common / curves.horizon)
    final = curves.final("eval/success", common).mean()
    return peak is not None and peak >= EARLY_PEAK and final <= LOW


# --- C3 ---------------------------------------------------------------------------------


def c3(data: Runs) -> Claim:
    parts, lines, numbers = {}, [], []
    for env in ROOMS:
        run = data.get(env, "bypass")
        if run is None:
            parts[env] = _missing()
            continue
        params = run.identity["env_params"]
        reachable = data.success_reachable(run)
        structure = judging.structure_text(params, run.adversary, reachable)
        final = estimate(run.per_seed("eval/success"))
        claimed = "solved" if reachable else "0"
        row, original = data.compare(f"{env} bypass success", claimed, run, "eval/success")
        numbers.append(row)
        if not reachable:  # structural: the env's rules decide; the runs must agree
            lines.append(f"{env} structural: {structure}; measured {final}")
            if final.hi > 0:  # shown by the run: our env's rules and our run contradict
                parts[env] = verdicts.refuted(
                    verdicts.IMPLEMENTATION,
                    f"the env's rules forbid success ({structure}), yet success {final} was "
                    f"measured in {run.seeds} seeds",
                )
            else:
                parts[env] = verdicts.reproduced(f"structural, measured {final}")
        else:  # evidence: the redundant team must learn it
            lines.append(f"{env} evidence: {structure}; measured {final}")
            if final.mean >= SOLVED:
                parts[env] = verdicts.reproduced(f"evidence, solved: {final}")
            else:
                agrees = None if original is None else original.mean >= SOLVED
                ours, theirs = data.finals(run, "eval/success", run.curves.horizon)
                parts[env] = judging.disagreement(
                    f"evidence: success {final} not ≥ {SOLVED:g}", agrees, ours, theirs
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
    )


# --- C4 ---------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Reverse:
    """C4's measurement of one env's reverse run."""

    at_budget: Verdict
    """The rule at the paper's budget."""
    longer: Verdict | None
    """The rule at the end of a run longer than the paper's budget (None: not longer)."""
    line: str
    """The measured values, for the claim's text."""
    late: str | None
    """The change of success after the paper's budget (None: not longer)."""
    number: Comparison


def reverse(data: Runs, env: str, run: RunRecord) -> Reverse:
    """C4 in one env: success ~0 (≥ SOLVED in ER(4,2)) at the paper's budget and at the
    end of our run; a refutation at the budget is classified by the original code's log."""
    curves = run.curves
    want_low = env != "ER(4,2)"
    budget = estimate(curves.final("eval/success", PAPER_ATTACK_BUDGET))
    full = estimate(curves.final("eval/success"))
    rule = f"≤ {LOW:g}" if want_low else f"≥ {SOLVED:g}"
    cut = min(curves.horizon, PAPER_ATTACK_BUDGET)
    longer_run = curves.horizon > PAPER_ATTACK_BUDGET

    def holds(e):
        return e.mean <= LOW if want_low else e.mean >= SOLVED

    line = f"{env}: at {cut:,} it {budget}" + (
        f", at {curves.horizon:,} it {full}" if longer_run else ""
    )
    if curves.horizon < PAPER_ATTACK_BUDGET and not holds(budget):
        at_budget = verdicts.inconclusive(
            f"{curves.horizon:,} it < the paper's {PAPER_ATTACK_BUDGET:,}: {budget}"
        )
    elif holds(budget):
        at_budget = verdicts.reproduced(f"{budget} at {cut:,} it")
    else:
        ours, original = data.finals(run, "eval/success", cut)
        agrees = None if original is None else bool(holds(estimate(original)))
        at_budget = judging.disagreement(
            f"{budget} at {cut:,} it, not {rule}", agrees, ours, original
        )
    longer = late = None
    if longer_run:
        rise = full.mean - budget.mean
        late = f"{env} {rise:+.3f} from {cut:,} to {curves.horizon:,} it"
        longer = (
            verdicts.reproduced(f"{full} at {curves.horizon:,} it")
            if holds(full)
            else verdicts.refuted(
                verdicts.BUDGET,
                f"{full} at our {curves.horizon:,} it, not {rule}: a late change of "
                f"{rise:+.3f} after the paper's {PAPER_ATTACK_BUDGET:,}",
            )
        )
    claimed = "0" if want_low else "solved"
    number = data.compare(f"{env} reverse success", claimed, run, "eval/success", cut)[0]
    return Reverse(at_budget, longer, line, late, number)


def c4(data: Runs) -> list[Claim]:
    at_budget, longer, numbers, lines, late = {}, {}, [], [], []
    for env in ROOMS:
        run = data.get(env, "reverse")
        if run is None:
            at_budget[env] = _missing()
            continue
        measured = reverse(data, env, run)
        at_budget[env] = measured.at_budget
        lines.append(measured.line)
        numbers.append(measured.number)
        if measured.longer is not None:
            longer[env] = measured.longer
            late.append(measured.late)
    main = verdicts.combine(at_budget)
    if main.kind == verdicts.REPRODUCED and any(
        v.kind == verdicts.REFUTED for v in longer.values()
    ):
        main = verdicts.at_budget(main.reason + "; not at our longer horizon (C4b)")
    out = [
        Claim(
            "C4",
            "reverse: success → 0 except ER(4,2), at the paper's budget",
            f"final success (mean of the last 10 evaluations at or before "
            f"{PAPER_ATTACK_BUDGET:,} it), mean over seeds, ≤ {LOW:g} in ER(2,1), ER(4,3) and "
            f"≥ {SOLVED:g} in ER(4,2)",
            "; ".join(lines) or _parts_text(at_budget),
            main,
            _short(at_budget),
            numbers,
        )
    ]
    if longer:
        out.append(
            Claim(
                "C4b",
                "reverse at our longer horizon (robustness row)",
                "the same rule at the end of runs longer than the paper's budget",
                "; ".join(lines) + ("; late change: " + ", ".join(late) if late else ""),
                verdicts.combine(longer),
                "late change: " + ", ".join(late),
                jobs_of="C4",
            )
        )
    return out


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


def admo_parts(data: Runs, attack: str) -> tuple[dict[str, Verdict], list]:
    """The C5 parts for one ADMO attack (its runs found by the attack name in their
    configs, whatever their labels); an attack run in one mode only is judged on every part
    in it. Returns (parts, table rows)."""
    mine = [r for r in data.by.values() if r.attack == attack]
    single = len({mode_of(r) for r in mine}) == 1
    parts, rows = {}, []
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
        flat = change.lo >= -FLAT and change.hi <= FLAT
        parts[f"IPD {run.condition} flat"] = (
            verdicts.reproduced(f"cooperation change {change}")
            if flat
            else judging.disagreement(f"cooperation change {change} beyond ±{FLAT:g}", None)
        )
    return parts, rows


def admo_run(
    data: Runs, run: RunRecord, base: RunRecord, single: bool
) -> tuple[list, dict[str, Verdict]]:
    """One ER ADMO run against its env's clean run: (its table row, its C5 parts). The
    margin and own-success parts judge the stealthy mode, disruption the disrupt mode
    where the task is non-redundant, steps the stealthy mode (every part where the attack
    ran in one mode only)."""
    mode, name = mode_of(run), f"{run.env} {run.condition}"
    margin = estimate(run.per_seed("eval/adversary_margin_env"), 2, signed=True)
    own, own_gain = exit_success_margin(run, base)
    d_success = difference(run.per_seed("eval/success"), base.per_seed("eval/success"))
    steps, clean_steps = (
        float(run.per_seed("eval/steps").mean()),
        float(base.per_seed("eval/steps").mean()),
    )
    row = [run.env, run.condition, run.seeds, margin, own, own_gain, d_success]
    row.append(f"{steps:.2f} ({(steps - clean_steps) / clean_steps:+.0%})")
    parts = {}
    if mode == "stealthy" or single:
        parts[f"{name} margin"] = judging.above(margin, 0.0, "margin") or judging.disagreement(
            f"margin {margin} not above 0", None
        )
        if own_gain is None:
            parts[f"{name} own success"] = verdicts.inconclusive(
                "per-agent exit success not logged by these runs"
            )
        else:
            parts[f"{name} own success"] = judging.above(
                own_gain, 0.0, "exit success − clean per-agent mean"
            ) or judging.disagreement(
                f"own exit success {own} not above the clean per-agent mean "
                f"(difference {own_gain})",
                None,
            )
    if mode == "disrupt" and not data.success_reachable(run):
        parts[f"{name} disrupts"] = (
            verdicts.reproduced(f"Δ success {d_success}")
            if d_success.hi < 0
            else judging.disagreement(
                f"non-redundant task, Δ success {d_success} not below 0", None
            )
        )
    if mode == "disrupt" and not single:
        return row, parts  # the paper's ADMO raises its own gain: steps judged on that mode
    change = abs(steps - clean_steps) / clean_steps
    parts[f"{name} steps"] = (
        verdicts.reproduced(f"steps {change:.0%} from clean")
        if change <= MODEST
        else judging.disagreement(f"steps change {change:.0%} > {MODEST:.0%}", None)
    )
    return row, parts


def c5(data: Runs) -> Claim:
    attacks = {}
    for attack in ADMO_ATTACKS:
        if any(r.attack == attack for r in data.by.values()):
            attacks[attack] = admo_parts(data, attack)
    if "admo" not in attacks:
        return Claim(
            "C5",
            "ADMO vs LIO: adversary's reward and success elevated in ER; IPD nearly flat; "
            "steps change modestly",
            "–",
            "no ADMO run",
            verdicts.not_run("no ADMO run"),
        )
    parts, _ = attacks["admo"]
    code_parts = attacks.get("admo_code", ({}, []))[0]
    parts = {name: _classified(name, v, code_parts) for name, v in parts.items()}
    shapes, met = [], {}
    for attack, (mine, _) in attacks.items():
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
    return Claim(
        "C5",
        "ADMO vs LIO: adversary's reward and success elevated in ER; IPD nearly flat; "
        "steps change modestly",
        "ER: the stealthy adversary's margin > 0 (the symmetric baseline) and its own exit "
        "success > the clean team's mean per agent (intervals); disrupt lowers success "
        f"(Δ interval < 0) where the task is non-redundant (env rules); IPD: ADMO cooperation "
        f"changes by < ±{FLAT:g} over training; stealthy |Δ steps| / clean ≤ {MODEST:.0%}",
        measured,
        verdicts.combine(parts),
        "paper's shapes: " + ", ".join(shapes) + "; " + _short(parts),
    )


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
    header += ["Δ success vs clean", "steps (vs clean)"]
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
