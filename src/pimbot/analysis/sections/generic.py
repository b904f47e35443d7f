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
    PER_AGENT,
    Table,
    difference,
    estimate,
    final_estimate,
)
from pimbot.contracts.attack import state_metric_prefix
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
            "or learner logged under their own names (`attack/NAME/…`, `defense/NAME/…`, "
            "`learner/NAME/…`: a plugin's, an attack's state metrics) have a table of their "
            "own per group; `pimbot plot --metric` and `pimbot table --metric` show any column."
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


def own_namespaces(run: RunRecord) -> tuple[str, ...]:
    """The metrics.csv prefixes of what `run`'s attack, defenses and learner log under their
    own names: `attack/NAME/` (where an attack's `metrics` go), `defense/NAME/`,
    `learner/NAME/`."""
    defenses = [name for name, _ in run.config.get("run_config", {}).get("defenses", ())]
    prefixes = [f"defense/{name}/" for name in defenses] + [f"learner/{run.learner}/"]
    if run.attack:
        prefixes.append(state_metric_prefix(run.attack))
    return tuple(prefixes)


def own_metrics(run: RunRecord) -> list[str]:
    """`run`'s metric columns in its parts' own namespaces (`own_namespaces`), without the
    per-agent ones (`pimbot plot --metric` draws those)."""
    prefixes = own_namespaces(run)
    return [c for c in run.curves.columns if c.startswith(prefixes) and not PER_AGENT.match(c)]


def own_metrics_table(runs: list[RunRecord], group: str) -> Table | None:
    """The final value, with its interval, of every metric the group's runs logged under
    their own names (`own_metrics`), per run; None where no run logged one."""
    logged = {run.name: own_metrics(run) for run in runs}
    columns = list(dict.fromkeys(c for names in logged.values() for c in names))
    if not columns:
        return None
    envs = distinct_env_labels(runs)
    rows = [
        [envs[run.env_key], learner_label(run), run.defenses, run.condition]
        + [final_estimate(run.curves, c) if c in logged[run.name] else None for c in columns]
        + [run.setting]
        for run in sorted(runs, key=lambda r: sort_key(r, envs))
    ]
    header = ["env", "learner", "defenses", "condition"]
    header += [f"final {c} {INTERVAL}" for c in columns] + ["run"]
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
