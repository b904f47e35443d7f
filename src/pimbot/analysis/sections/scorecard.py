"""The robustness scorecard of every training run of the report (a user's sweep or the
paper's suite groups alike): attacked vs clean paired by seed, across envs, each defense's
recovery; two figures (paired effects with their intervals, success performance profiles);
the runs exported as marl-eval JSON. The computation is analysis.scorecard; this module
lays it out. It claims no run: the sections that show curves still show them."""

from __future__ import annotations

import json

import matplotlib.pyplot as plt

from pimbot import statistics
from pimbot.analysis import plots
from pimbot.analysis import scorecard as sc
from pimbot.analysis.document import TABLES, Context, Section
from pimbot.analysis.runs import (
    CLEAN,
    NO_DEFENSE,
    RunRecord,
    RunTable,
    condition_key,
    distinct_env_labels,
    natural_key,
)
from pimbot.analysis.sections.generic import learner_label
from pimbot.analysis.tables import INTERVAL, Estimate, Table
from pimbot.training import store

TITLE = "Robustness scorecard"
MARL_EVAL = "scorecard_marl_eval.json"
"""The runs as marl-eval raw experiment data, in the report's tables/ folder."""


def section(table: RunTable, ctx: Context) -> Section | None:
    export = ctx.out / TABLES / MARL_EVAL
    card = sc.scorecard(table.records)
    if not card.comparisons:
        export.unlink(missing_ok=True)  # an earlier report's export must not outlive its runs
        note = sc.unmatched_note(card)  # attacked runs without a clean one are named
        return Section(TITLE, text=[note]) if note else None
    export.parent.mkdir(parents=True, exist_ok=True)
    store.write_atomic(
        export, json.dumps(sc.marl_eval(table.records), separators=(",", ":")).encode()
    )
    envs = distinct_env_labels(list(table.records))
    out = Section(TITLE, text=intro(card))
    if card.of(sc.ATTACK):
        out.figures.append(effects_figure(card, envs, table.colors, ctx))
        out.figures.append(profiles_figure(card, table.colors, ctx))
    tables = [attack_table(card, envs), across_envs_table(card), recovery_table(card, envs)]
    out.tables += [t for t in tables if t.rows]
    return out


def intro(card: sc.Scorecard) -> list[str]:
    attacks = card.of(sc.ATTACK)
    text = [
        f"{len(attacks)} attacked run(s), each paired with the clean run of the same env, "
        "learner (and configuration) and defenses; a pair is one seed run clean and attacked, "
        "each run's final value (mean of the last evaluation points) read at the two runs' "
        "common iteration. Δ = attacked − clean, the mean of the per-seed differences; IQM = "
        "interquartile mean over seeds; P(clean > attacked) = the probability that a clean "
        "seed beats an attacked one (ties count ½), rliable's probability of improvement; "
        "[…] = 95 % stratified percentile bootstrap CI over pairs (seeds resampled with "
        f"their pair, {statistics.RESAMPLES} resamples, strata = envs) at ≥ "
        f"{statistics.MIN_SEEDS_FOR_CI} pairs per env, (range …) = min … max over seeds "
        "below (a probability of improvement then has no interval). Estimators: rliable "
        "(Agarwal et al. 2021), computed as pimbot.analysis.scorecard documents.",
        f"Skipped, never silently: {card.unpaired_seeds} seed(s) that only one of two compared "
        f"runs has (summed over the {len(card.comparisons)} comparisons); "
        f"{len(card.unmatched)} run(s) without the run they are compared with"
        + "".join(f"; {name} ({why})" for name, why in card.unmatched)
        + ".",
        f"Every training run is also in {TABLES}/{MARL_EVAL}, marl-eval's raw experiment "
        "format (environment = env id, task = env label, algorithm = learner|defenses|"
        "condition, run = seed_<s>, step_count = training iteration, absolute_metrics = the "
        "final values). marl-eval's aggregate plots need the same algorithms, seeds and "
        "evaluation steps in every task of an env: select such a subset where a sweep mixes.",
    ]
    return text


def short(text: str, chars: int = 40) -> str:
    """`text` cut to `chars` characters (a figure's label; the tables have it in full)."""
    return text if len(text) <= chars else text[: chars - 1] + "…"


def _labels(c: sc.Comparison, envs: dict) -> list:
    run = c.treated
    return [envs[run.env_key], learner_label(run), run.defenses, run.condition]


def attack_table(card: sc.Scorecard, envs: dict) -> Table:
    rows = []
    for c in sorted(card.of(sc.ATTACK), key=lambda c: order(c, envs)):
        for column, name in sc.METRICS.items():
            p = c.pairs.get(column)
            if p is None:
                continue
            digits = 3 if column == sc.SUCCESS else 2
            rows.append(
                _labels(c, envs)
                + [name, len(p.seeds), p.unpaired, p.horizon]
                + [sc.iqm_estimate([p.base], digits, column != sc.SUCCESS)]
                + [sc.iqm_estimate([p.treated], digits, column != sc.SUCCESS)]
                + [sc.effect_estimate([p], digits), sc.improvement_estimate([p])]
                + [c.base.name]
            )
    header = ["env", "learner", "defenses", "attack", "metric", "pairs", "skipped seeds"]
    header += ["at iteration", f"IQM clean {INTERVAL}", f"IQM attacked {INTERVAL}"]
    header += [f"Δ attacked − clean {INTERVAL}", improvement_header(rows, 11), "clean run"]
    return Table(header, rows, "Scorecard: every attack vs clean, paired by seed", "", "scorecard")


def improvement_header(rows: list[list], index: int) -> str:
    """ "P(clean > attacked)", with the interval suffix where some row has an interval."""
    with_interval = any(isinstance(row[index], Estimate) for row in rows)
    return "P(clean > attacked)" + (f" {INTERVAL}" if with_interval else "")


def order(c: sc.Comparison, envs: dict) -> tuple:
    run = c.treated
    return (
        learner_label(run),
        run.defenses != NO_DEFENSE,
        run.defenses,
        natural_key(envs[run.env_key]),
        condition_key(run.condition),
        run.name,
    )


def across_envs_table(card: sc.Scorecard) -> Table:
    """Success per (learner, defenses, attack) over every env it ran in (≥ 2), each env a
    stratum of the bootstrap and weighted equally in Δ and P(clean > attacked)."""
    groups: dict[tuple, list[sc.Paired]] = {}
    for c in card.of(sc.ATTACK):
        key = (learner_label(c.treated), c.treated.defenses, c.treated.condition)
        groups.setdefault(key, []).append(c.pairs[sc.SUCCESS])
    rows = []
    for key, pairs in sorted(groups.items(), key=lambda kv: (kv[0][:2], condition_key(kv[0][2]))):
        if len(pairs) < 2:
            continue
        rows.append(
            [*key, len(pairs), sum(len(p.seeds) for p in pairs)]
            + [
                sc.iqm_estimate([p.base for p in pairs]),
                sc.iqm_estimate([p.treated for p in pairs]),
            ]
            + [sc.effect_estimate(pairs), sc.improvement_estimate(pairs)]
        )
    header = ["learner", "defenses", "attack", "envs", "pairs", f"IQM clean {INTERVAL}"]
    header += [f"IQM attacked {INTERVAL}", f"Δ attacked − clean {INTERVAL}"]
    header.append(improvement_header(rows, 8))
    note = (
        "Final success pooled over envs (IQM over every seed of every env; Δ and P(clean > "
        "attacked) the mean of the per-env values), envs as bootstrap strata."
    )
    return Table(header, rows, "Scorecard across envs (success)", note, "scorecard_across_envs")


def recovery_table(card: sc.Scorecard, envs: dict) -> Table:
    """Per defended run: Δ vs the same attack without defense (what the defense recovers)
    and vs the clean run without defense (what is still lost); a defended clean run's Δ
    vs clean is what the defense costs when nobody attacks."""
    by_run: dict[str, dict[str, sc.Comparison]] = {}
    for c in card.comparisons:
        if c.kind != sc.ATTACK:
            by_run.setdefault(c.treated.name, {})[c.kind] = c
    rows = []
    for kinds in sorted(by_run.values(), key=lambda k: order(next(iter(k.values())), envs)):
        first = next(iter(kinds.values()))
        for column, name in sc.METRICS.items():
            cells = [_delta(kinds.get(sc.RECOVERY), column)]
            cells.append(_delta(kinds.get(sc.CLEAN_RUN) or kinds.get(sc.BENIGN), column))
            if cells == [None, None]:
                continue
            runs = ", ".join(sorted({c.base.name for c in kinds.values()}))
            rows.append(_labels(first, envs) + [name, *cells, runs])
    header = ["env", "learner", "defenses", "attack", "metric"]
    header += [f"Δ vs attack without defense {INTERVAL}", f"Δ vs clean without defense {INTERVAL}"]
    header += ["compared with"]
    note = (
        "Paired by seed as above. Δ vs attack without defense > 0: the defense recovers "
        "success (or, for the margin, < 0: it takes the adversary's edge away); Δ vs clean "
        "without defense: what remains lost; on a clean run (attack clean) the cost of the "
        "defense when nobody attacks."
    )
    return Table(header, rows, "Defense recovery", note, "scorecard_recovery")


def _delta(c: sc.Comparison | None, column: str) -> Estimate | None:
    if c is None or column not in c.pairs:
        return None
    return sc.effect_estimate([c.pairs[column]], 3 if column == sc.SUCCESS else 2)


# --- figures ------------------------------------------------------------------------------


def effects_figure(card: sc.Scorecard, envs: dict, colors: dict, ctx: Context):
    """Δ attacked − clean per attack with its interval, success and margin side by side."""
    found = sorted(card.of(sc.ATTACK), key=lambda c: order(c, envs))
    path, figure = ctx.figure("scorecard_effects.png")
    fig, axes = plt.subplots(1, 2, figsize=(13, 1.4 + 0.24 * len(found)), sharey=True)
    drawn = []
    for ax, (column, name) in zip(axes, sc.METRICS.items(), strict=True):
        for y, c in enumerate(found):
            p = c.pairs.get(column)
            if p is None:
                continue
            e = sc.effect_estimate([p])
            err = [[e.mean - e.lo], [e.hi - e.mean]]
            color = colors[c.treated.condition]
            ax.errorbar(e.mean, y, xerr=err, fmt="o", ms=4, color=color, label=c.treated.condition)
            drawn.append((e.kind, len(p.seeds)))
        ax.axvline(0, color="grey", lw=1)
        ax.set_xlabel(f"Δ {name}")
        ax.set_title(f"{name}: attacked − clean", fontsize=9)
        ax.grid(alpha=0.3, axis="x")
    labels = [" · ".join(short(x) for x in _labels(c, envs)) for c in found]
    axes[0].set_yticks(range(len(found)), labels, fontsize=7)
    axes[0].invert_yaxis()
    bars = plots.band_text(drawn, "bars").replace("BCa", "percentile")
    plots.legend_below(fig, axes, [plots.band_handle(bars)])
    plots.save(fig, path)
    figure.caption = f"Scorecard: paired effect of every attack per seed pair ({bars})"
    return figure


def profiles_figure(card: sc.Scorecard, colors: dict, ctx: Context):
    """Success performance profiles per (learner, defenses): per condition, the fraction of
    seeds (pooled over envs) whose final success exceeds τ."""
    panels: dict[str, dict[str, dict]] = {}
    for c in card.of(sc.ATTACK):
        title = f"{short(learner_label(c.treated))} · {short(c.treated.defenses)}"
        panel = panels.setdefault(title, {})
        for run in (c.base, c.treated):
            panel.setdefault(run.condition, {})[run.name] = run
    cols = min(3, len(panels))
    rows = (len(panels) + cols - 1) // cols
    path, figure = ctx.figure("scorecard_profiles.png")
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 3.6 * rows), squeeze=False)
    banded = []
    for ax, (title, conditions) in zip(axes.flat, sorted(panels.items()), strict=False):
        for condition in sorted(conditions, key=condition_key):
            banded.append(_profile(ax, list(conditions[condition].values()), condition, colors))
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("τ (final success)")
        ax.set_ylabel("fraction of seeds > τ")
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(panels) :]:
        ax.remove()
    notes = ["band: 95 % stratified bootstrap CI"] if any(banded) else []
    if not all(banded):
        notes.append(f"no band below {statistics.MIN_SEEDS_FOR_CI} seeds per env")
    note = "; ".join(notes)
    plots.legend_below(fig, axes.flat[: len(panels)], [plots.band_handle(note)])
    plots.save(fig, path)
    figure.caption = f"Scorecard: success performance profiles per learner and defenses ({note})"
    return figure


def _profile(ax, runs: list[RunRecord], condition: str, colors: dict) -> bool:
    """One condition's profile over its runs (one stratum per run: one env); whether it has
    a band."""
    values = [run.per_seed(sc.SUCCESS) for run in runs]
    color = colors[condition]
    style = "-" if condition == CLEAN else "--"
    ax.step(sc.TAUS, sc.profile(values), where="post", color=color, ls=style, label=condition)
    band = sc.profile_band(values)
    if band is not None:
        ax.fill_between(sc.TAUS, *band, step="post", color=color, alpha=plots.BAND_ALPHA, lw=0)
    return band is not None
