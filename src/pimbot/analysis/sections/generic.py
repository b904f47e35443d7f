"""Training runs no paper section reported (a user's `pimbot sweep`, say): one section per
group with success curves per condition, final metrics and attack effects vs clean."""

from __future__ import annotations

import re

from pimbot.analysis import plots
from pimbot.analysis.document import Context, Section, final_window_text, seeds_text
from pimbot.analysis.runs import (
    CLEAN,
    NO_DEFENSE,
    RunRecord,
    RunTable,
    condition_key,
    distinct_env_labels,
    natural_key,
)
from pimbot.analysis.tables import (
    INTERVAL,
    Table,
    difference,
    estimate,
    final_estimate,
)
from pimbot.statistics import interval_text

STYLES = ("-", "--", ":", "-.")
"""Line style per defense set within a panel (colour is the condition)."""


def section(table: RunTable, ctx: Context) -> Section | None:
    """Every training run no other section claimed: a figure and a table per group."""
    rest = [r for r in table.records if r.name not in ctx.claimed]
    if not rest:
        return None
    out = Section(
        "Other training runs",
        text=[
            "Runs no paper section reads (a `pimbot sweep` grid, say), labelled from their "
            f"configs. Final = mean of the last {final_window_text(rest)} per seed over "
            f"{seeds_text(rest)}; {interval_text(r.seeds for r in rest)}; margin = the "
            "adversary's env return minus "
            "the mean of the others'; Δ = this run − the clean run of the same env, learner "
            "and defenses (seeds resampled independently). Metrics a run's attack, defenses "
            "or learner logged under their own names (`attack/…`, `defense/…`, `learner/…`: "
            "a plugin's, an attack's state metrics, the defenses' counters) have a table of "
            "their own per group, one row per metric with what wrote it; `pimbot plot "
            "--metric` and `pimbot table --metric` show any column."
        ],
    )
    for group in sorted({r.group for r in rest}):
        mine = [r for r in rest if r.group == group]
        figure, result = group_results(table, mine, group, ctx)
        if figure is not None:
            out.figures.append(figure)
        out.tables.append(result)
        logged = own_metrics_table(mine, group)
        if logged is not None:
            out.tables.append(logged)
    return out


OWN_PREFIXES = ("attack/", "defense/", "learner/")
"""Where an attack, a defense or a learner logs under its own name (a plugin's metrics, an
attack's state metrics, the built-in defenses' `defense/guard_*`, `defense/monitor_*`)."""


def writer(run: RunRecord, column: str) -> str:
    """What wrote `column` of `run`: "attack NAME", "defense NAME" (where the column names
    it, else every defense of the run), or "learner NAME"."""
    kind, _, rest = column.partition("/")
    if kind == "attack":
        return f"attack {run.attack or rest.split('/')[0]}"
    if kind == "learner":
        return f"learner {run.learner}"
    names = [name for name, _ in run.config.get("run_config", {}).get("defenses", ())]
    named = [name for name in names if rest.startswith(f"{name}/")]
    return "defense " + "+".join(named or names or [rest.split("/")[0]])


def own_metrics(run: RunRecord) -> list[str]:
    """`run`'s metric columns that its attack, defenses or learner wrote under their own
    names (`OWN_PREFIXES`), per-agent ones included, in metrics.csv's order."""
    return [c for c in run.curves.columns if c.startswith(OWN_PREFIXES)]


def own_metrics_table(runs: list[RunRecord], group: str) -> Table | None:
    """One row per run and metric its attack, defenses or learner logged under their own
    names (`own_metrics`): what wrote it and its final value with its interval; None where
    no run logged one."""
    envs = distinct_env_labels(runs)
    rows = [
        [envs[run.env_key], learner_label(run), run.defenses, run.condition]
        + [writer(run, column), column, final_estimate(run.curves, column), run.setting]
        for run in sorted(runs, key=lambda r: sort_key(r, envs))
        for column in own_metrics(run)
    ]
    if not rows:
        return None
    header = ["env", "learner", "defenses", "condition", "written by", "metric"]
    header += [f"final {INTERVAL}", "run"]
    title = f"{group}: metrics the runs' attacks, defenses and learners logged"
    slug = re.sub(r"[^A-Za-z0-9_.-]+", "_", group)
    return Table(header, rows, title, name=f"{slug}_own_metrics")


def learner_label(run: RunRecord) -> str:
    return run.learner + (f" ({run.hparams})" if run.hparams else "")


def sort_key(run: RunRecord, envs: dict) -> tuple:
    return (
        natural_key(envs[run.env_key]),
        learner_label(run),
        run.defenses != NO_DEFENSE,
        run.defenses,
        condition_key(run.condition),
        run.name,
    )


def group_results(table: RunTable, runs: list[RunRecord], group: str, ctx: Context):
    """(success curves or None where no run logged success, final-metric table) of one
    group's runs."""
    ctx.claim(runs)
    envs = distinct_env_labels(runs)
    runs = sorted(runs, key=lambda r: sort_key(r, envs))
    colors = table.colors
    slug = re.sub(r"[^A-Za-z0-9_.-]+", "_", group)
    panels: dict[str, list] = {}
    for run in runs:
        lines = panels.setdefault(f"{envs[run.env_key]} · {learner_label(run)}", [])
        sets = sorted({r.defenses for r in runs if r.cell[:3] == run.cell[:3]})
        label = run.condition if run.defenses == NO_DEFENSE else f"{run.condition} | {run.defenses}"
        if any(label == line[1] for line in lines):  # same labels: tell them apart by setting
            label += f" [{run.setting}]"
        style = STYLES[sets.index(run.defenses) % len(STYLES)]
        lines.append((run, label, colors[run.condition], style))
    path, figure = ctx.figure(f"{slug}_success.png")
    bands = plots.curve_panels(
        list(panels.items()), "eval/success", "success", path, min(3, len(panels))
    )
    figure.caption = f"{group}: success per condition (mean over {seeds_text(runs)}, {bands})"
    if not bands:
        figure = None
    rows = []
    for run in runs:
        success = run.per_seed("eval/success")
        margin = run.per_seed("eval/adversary_margin_env")
        base = table.clean_for(run) if run.condition != CLEAN else None
        rows.append(
            [
                envs[run.env_key],
                learner_label(run),
                run.defenses,
                run.condition,
                run.seeds,
                run.iterations,
                estimate(success),
                estimate(margin, 2, signed=True),
                None if base is None else difference(success, base.per_seed("eval/success")),
                None
                if base is None
                else difference(margin, base.per_seed("eval/adversary_margin_env"), 2),
                run.setting,
            ]
        )
    header = ["env", "learner", "defenses", "condition", "seeds", "iterations"]
    header += [f"final success {INTERVAL}", f"adversary margin {INTERVAL}"]
    header += [f"Δ success vs clean {INTERVAL}", f"Δ margin vs clean {INTERVAL}", "run"]
    title = f"{group}: {len(runs)} run(s), final metrics and effects vs clean"
    return figure, Table(header, rows, title, name=slug)
