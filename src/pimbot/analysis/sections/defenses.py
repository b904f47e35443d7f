"""Defenses against every attack: success, adversary margin, detection and cost tables.

Each defended run (group `defenses`) is a cell (env, condition, defense set); the
no-defense cell of the same env, learner and condition is the undefended run
(the attack group's) read up to the defended runs' iteration, since a run's
first N iterations do not depend on how long it goes on. Defense sets are
named as the suite names them (`presets.DEFENSE_SETS`), any other by its
derived label. Iteration times are read from `defenses/iteration_time.json`
({env label: {defense set: ms}}) where a timing run left one.
"""

from __future__ import annotations

import numpy as np

from pimbot import statistics
from pimbot.analysis import plots
from pimbot.analysis.document import Context, Section, count_text, iterations_text
from pimbot.analysis.runs import CLEAN, NO_DEFENSE, RunRecord, RunTable, condition_key, natural_key
from pimbot.analysis.tables import INTERVAL, Table, estimate
from pimbot.suites import presets
from pimbot.training import store
from pimbot.training.summary import convergence_point, final_value

GROUP = "defenses"
TIMING = "iteration_time.json"
SET_NAMES = {"+".join(names): label for label, names in presets.DEFENSE_SETS.items()}


def defense_name(run: RunRecord) -> str:
    return SET_NAMES.get(run.defenses, run.defenses)


def section(table: RunTable, ctx: Context) -> Section | None:
    defended = [r for r in table.group(GROUP) if r.defenses != NO_DEFENSE]
    if not defended:
        return None
    ctx.claim(table.group(GROUP))
    cells = collect(table, defended)
    timing_path = ctx.suite_dir / GROUP / TIMING
    timing = store.read_json(timing_path) if timing_path.exists() else {}
    seeds = count_text((len(c["seeds"]) for c in cells.values()), "seeds")
    path, figure = ctx.figure(
        "fig_defenses.png",
        f"Defenses: final success and adversary margin per defense set and attack (mean over "
        f"{seeds}, {statistics.interval_text(len(c['seeds']) for c in cells.values())})",
    )
    plot(cells, path, table.colors)
    return Section(
        "Defenses against every attack",
        text=[
            "Each attack (and clean) × {no defense, each training-time defense, all}; the "
            "no-defense column is the attack group's runs read up to the same iteration. "
            "Receiver-side defenses cannot stop pure policy attacks in a non-redundant task "
            "(bypass in ER(2,1), ER(4,3)): no incentive is involved, by design. Settings, "
            "interpretation and what no defense can stop: docs/defenses.md.",
        ],
        figures=[figure],
        tables=metric_tables(cells) + [detection_table(cells), cost_table(cells, timing)],
    )


def collect(table: RunTable, defended: list[RunRecord]) -> dict:
    """cells[(env, condition, defense)]; the no-defense cell truncated to the defended runs."""
    cells = {}
    for run in defended:
        cells[(run.env, run.condition, defense_name(run))] = cell(run, None)
    for key in sorted({(r.env_key, r.learner, r.hparams, r.condition) for r in defended}):
        mine = [r for r in defended if (r.env_key, r.learner, r.hparams, r.condition) == key]
        base = next(
            (
                r
                for r in sorted(table.records, key=lambda r: r.group != GROUP)
                if r.defenses == NO_DEFENSE
                and (r.env_key, r.learner, r.hparams, r.condition) == key
            ),
            None,
        )
        if base is not None:
            until = min(cells[(r.env, r.condition, defense_name(r))]["iterations"] for r in mine)
            cells[(base.env, base.condition, NO_DEFENSE)] = cell(base, until)
    return cells


def _first(its: np.ndarray, hits: np.ndarray) -> float:
    return its[np.argmax(hits > 0)] if (hits > 0).any() else np.inf


def cell(run: RunRecord, until: int | None) -> dict:
    """Per-seed final success, adversary env margin, convergence and defense counters, from
    the evaluations at or before `until` (None: all)."""
    curves = run.curves
    kept = {
        s: curves.iterations[s] <= (until if until is not None else np.inf) for s in curves.seeds
    }
    seeds = [s for s in curves.seeds if kept[s].any()]

    def column(seed: int, name: str) -> np.ndarray:
        return curves.values[seed][name][kept[seed]]

    first = curves.iterations[seeds[0]][kept[seeds[0]]]
    curve = "eval/return_ratio" if curves.has("eval/return_ratio") else "eval/success"
    out: dict = {"seeds": seeds, "iterations": int(first[-1])}
    for key, name in (("success", "eval/success"), ("margin", "eval/adversary_margin_env")):
        out[key] = np.array([final_value(column(s, name)) for s in seeds])
    conv = []
    for s in seeds:
        c, _ = convergence_point(column(s, "iteration"), column(s, curve))
        conv.append(np.inf if c is None else c)
    out["convergence"] = np.array(conv)
    period = int(first[1]) - int(first[0]) if len(first) > 1 else 1
    for counter in ("clipped", "dropped"):
        if curves.has(f"defense/guard_{counter}"):
            out[f"{counter}_per_it"] = np.mean(
                [column(s, f"defense/guard_{counter}").mean() for s in seeds]
            )
    givers = sorted(k for k in curves.columns if k.startswith("defense/monitor_alarms_by_giver/"))
    adversary = f"defense/monitor_alarms_by_giver/agent_{run.adversary}"
    if adversary in givers:
        on_adv, on_others, any_alarm = [], [], []
        for s in seeds:
            its = column(s, "iteration")
            adv = column(s, adversary) * period  # alarms raised in each evaluation period
            others = sum(column(s, g) * period for g in givers if g != adversary)
            on_adv.append(_first(its, adv))
            on_others.append(_first(its, others))
            any_alarm.append(_first(its, adv + others))
        out["alarm_on_adversary"] = np.array(on_adv)  # detected by (end of the eval period)
        out["alarm_on_honest_giver"] = np.array(on_others)
        out["alarm_any"] = np.array(any_alarm)
        out["alarms_per_seed"] = np.mean(
            [column(s, "defense/monitor_alarms").sum() * period for s in seeds]
        )
    return out


def axes(cells: dict) -> tuple[list[str], list[str], list[str]]:
    """(envs, conditions, defense sets) present, in order; no defense first."""
    envs = sorted({e for e, _, _ in cells}, key=natural_key)
    conditions = sorted({c for _, c, _ in cells}, key=condition_key)
    order = [NO_DEFENSE, *presets.DEFENSE_SETS]
    present = {d for _, _, d in cells}
    return envs, conditions, [d for d in order if d in present] + sorted(present - set(order))


def iterations(cells: dict, env: str) -> int:
    return next(c["iterations"] for (e, _, _), c in cells.items() if e == env)


def metric_tables(cells: dict) -> list[Table]:
    envs, conditions, sets = axes(cells)
    out = []
    for metric, title, digits in (
        ("success", "Final success rate", 2),
        ("margin", "Adversary's env-return margin", 1),
    ):
        for env in envs:
            rows = [
                [attack]
                + [
                    estimate(cells[(env, attack, d)][metric], digits)
                    if (env, attack, d) in cells
                    else None
                    for d in sets
                ]
                for attack in conditions
                if any((env, attack, d) in cells for d in sets)
            ]
            seeds = count_text(
                (len(c["seeds"]) for (e, _, _), c in cells.items() if e == env), "seeds"
            )
            heading = f"{title}: {env}, {iterations_text(iterations(cells, env))}, {seeds}"
            counts = (len(c["seeds"]) for c in cells.values())
            note = f"Mean over {seeds}; {statistics.interval_text(counts)}." if not out else ""
            name = f"defenses_{metric}_{env}"
            out.append(Table(["attack", *sets], rows, heading, note, name))
    return out


def _rate(c: dict, field: str) -> str:
    hits = np.isfinite(c[field])
    return f"{hits.sum()}/{hits.size}"


def detection_table(cells: dict) -> Table:
    envs, conditions, sets = axes(cells)
    rows = []
    for env in envs:
        for attack in conditions:
            for d in sets:
                c = cells.get((env, attack, d))
                if c is None or "alarm_on_adversary" not in c:
                    continue
                hits = c["alarm_on_adversary"][np.isfinite(c["alarm_on_adversary"])]
                clean = attack == CLEAN
                rows.append(
                    [
                        env,
                        attack,
                        d,
                        f"false alarm {_rate(c, 'alarm_any')}"
                        if clean
                        else _rate(c, "alarm_on_adversary"),
                        _rate(c, "alarm_on_honest_giver"),
                        f"{np.median(hits):.0f}" if hits.size and not clean else None,
                        f"{c['alarms_per_seed']:.1f}",
                    ]
                )
    header = ["env", "attack", "defense", "detection", "alarm on an honest giver"]
    header += ["median time to detection", "alarms per seed"]
    note = (
        "Detection rate: seeds whose monitor raised an alarm on the adversary during "
        "training; false-alarm rate: clean seeds with any alarm, and attacked seeds with an "
        "alarm on an honest giver; time to detection: the end of the evaluation period in "
        "which the first alarm on the adversary fell (median over detecting seeds)."
    )
    return Table(header, rows, "Health monitor: detection per attack", note, "defenses_detection")


def cost_table(cells: dict, timing: dict) -> Table:
    envs, _, sets = axes(cells)
    rows = []
    for env in envs:
        base = cells.get((env, CLEAN, NO_DEFENSE))
        for d in sets:
            c = cells.get((env, CLEAN, d))
            if c is None:
                continue
            delta = None
            if base is not None and d != NO_DEFENSE and c["seeds"] == base["seeds"]:
                delta = estimate(c["success"] - base["success"], 2, signed=True)  # paired
            guard = None
            if "clipped_per_it" in c:
                guard = f"{c['clipped_per_it']:.3f} / {c['dropped_per_it']:.3f}"
            ms = timing.get(env, {}).get(d)
            med = np.median(c["convergence"])
            rows.append(
                [
                    env,
                    d,
                    estimate(c["success"], 2),
                    delta,
                    f"{np.isfinite(c['convergence']).sum()}/{c['convergence'].size}",
                    "never" if not np.isfinite(med) else f"{med / 1000:.1f}k",
                    guard,
                    None if ms is None else f"{ms:.2f}",
                ]
            )
    header = ["env", "defense", f"success {INTERVAL}", f"Δ success vs none {INTERVAL}"]
    header += ["converged seeds", "median convergence", "clipped / dropped per iteration"]
    note = (
        "Success and convergence (median iteration from which the smoothed return ratio — "
        "IPD: success — stays ≥ 0.9; 'never' when the median seed does not converge) on "
        f"clean runs, Δ paired by seed; guard counters per iteration; iteration time from "
        f"{GROUP}/{TIMING} where present."
    )
    return Table(header + ["ms per iteration"], rows, "Cost on clean runs", note, "defenses_cost")


def plot(cells: dict, path, colors: dict) -> None:
    """Final success and adversary margin per defense set, one bar per attack in the
    attack's colour (the report's one condition mapping), with their intervals."""
    envs, conditions, sets = axes(cells)
    fig, grid = plots.plt.subplots(2, len(envs), figsize=(5.2 * len(envs), 7.5), squeeze=False)
    width = 0.8 / len(conditions)
    drawn = []
    for col, env in enumerate(envs):
        for row, (metric, ylabel) in enumerate(
            (("success", "final success"), ("margin", "adversary env margin"))
        ):
            ax = grid[row][col]
            for a, attack in enumerate(conditions):
                xs, means, errs = [], [], []
                for k, d in enumerate(sets):
                    c = cells.get((env, attack, d))
                    if c is None:
                        continue
                    interval = statistics.mean_interval(c[metric])
                    drawn.append((interval.kind, interval.n))
                    lo, hi = interval.lo, interval.hi
                    m = c[metric].mean()
                    xs.append(k + (a - (len(conditions) - 1) / 2) * width)
                    means.append(m)
                    errs.append([m - lo, hi - m])
                if xs:
                    yerr = np.array(errs).T
                    color = colors.get(attack)
                    ax.bar(xs, means, width, yerr=yerr, color=color, label=attack, capsize=2)
                    plots.mark_zero_bars(ax, xs, means, color)
            ax.set_xticks(range(len(sets)), sets)
            ax.set_xlabel("defense")
            ax.set_ylabel(ylabel)
            if row == 0:
                ax.set_title(f"{env} ({iterations_text(iterations(cells, env))})")
                ax.set_ylim(0, 1.05)
            ax.axhline(0, color="black", lw=0.5)
            ax.grid(axis="y", alpha=0.3)
    bars = plots.band_text(drawn, "error bar")
    error_bar = plots.Line2D([], [], color="black", marker="|", ls="", label=bars)
    plots.legend_below(fig, grid.flat, [error_bar], title="attack")
    seeds = count_text((len(c["seeds"]) for c in cells.values()), "seeds")
    fig.suptitle(f"LIO under attack with each defense (mean over {seeds})", fontsize=9)
    plots.save(fig, path, dpi=120)
