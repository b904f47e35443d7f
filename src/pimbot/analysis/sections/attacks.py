"""Attacks on LIO: the results table, claims C1–C5 and figures 1–5 (group `attacks`)."""

from __future__ import annotations

import numpy as np

from pimbot.analysis import plots
from pimbot.analysis.document import Context, Figure, Section, final_window_text, seeds_text
from pimbot.analysis.runs import (
    CLEAN,
    RunRecord,
    RunTable,
    condition_key,
    incentive_updates,
    natural_key,
)
from pimbot.analysis.sections import attack_claims
from pimbot.analysis.tables import INTERVAL, Table, difference, estimate, fmt
from pimbot.statistics import interval_text

GROUP = "attacks"
CLAIMS_LEARNER = "lio"
"""C1–C5 are about LIO; the group's runs of other learners go to the generic section."""
ADMO_COLUMN = "admo/alpha_1"
"""Runs that log it are ADMO runs (Fig. 5)."""
AGENT_COLOURS = ("#4d4d4d", "#1b9e77", "#7570b3", "#e6ab02", "#66a61e", "#a6761d", "#666666")
"""Per-agent lines of Fig. 2 (agents, not conditions: a palette of its own)."""
ADVERSARY_COLOUR = "#d62728"


def section(table: RunTable, ctx: Context) -> Section | None:
    runs = [r for r in table.group(GROUP) if r.learner == CLAIMS_LEARNER]
    if not runs:
        return None
    ctx.claim(runs)
    out = Section("Attacks on LIO (C1–C5)", text=[intro(runs)], figures=figures(table, runs, ctx))
    out.tables = [convergence_table(runs), results_table(results_rows(table, runs))]
    admo = attack_claims.admo_table(
        attack_claims.Runs(table, {(r.env, r.condition): r for r in runs})
    )
    if admo is not None:
        out.tables.append(admo)
    out.claims = attack_claims.claims(table, runs)
    return out


def figures(table: RunTable, runs: list[RunRecord], ctx: Context) -> list[Figure]:
    """Figs. 1–5 of the team tasks (runs that log the return ratio) and Fig. 1b of the
    others (the IPD); a figure without data is left out."""
    colors, seeds = table.colors, seeds_text(runs)
    envs = sorted({r.env for r in runs}, key=natural_key)
    teams = [e for e in envs if any(r.env == e and has_return_ratio(r) for r in runs)]
    others = [e for e in envs if e not in teams]
    out = []
    if teams:
        panels = plots.condition_panels(runs, teams, colors)
        path, figure = ctx.figure("fig1_success.png")
        if bands := plots.curve_panels(panels, "eval/success", "success", path):
            figure.caption = (
                "Fig. 1: success vs iterations per ER config, clean and attacks (mean over "
                f"{seeds}, {bands}; dotted: a random team)"
            )
            out.append(figure)
        path, figure = ctx.figure("fig2_agent_returns.png")
        if bands := fig_agent_returns(runs, teams, path):
            figure.caption = (
                f"Fig. 2: per-agent env returns (mean over {seeds}, {bands}); the adversary's "
                "curve is the thick red one"
            )
            out.append(figure)
        path, figure = ctx.figure("fig3_steps.png")
        if bands := plots.curve_panels(panels, "eval/steps", "steps per episode", path):
            figure.caption = f"Fig. 3: steps per episode (mean over {seeds}, {bands})"
            out.append(figure)
    if teams and any(r.condition == "self_centered" for r in runs):
        path, figure = ctx.figure(
            "fig4_convergence.png", "Fig. 4: convergence per seed, clean vs self-centered"
        )
        if fig_convergence(runs, teams, colors, path):
            out.append(figure)
    admo = [r for r in runs if r.curves.has(ADMO_COLUMN)]
    admo_envs = [e for e in teams if any(r.env == e for r in admo)]
    if admo_envs:
        path, figure = ctx.figure("fig5_admo.png")
        bands = fig_admo(runs, admo, admo_envs, colors, path)
        figure.caption = (
            f"Fig. 5: ADMO vs LIO: success, margin, α1, c1/c2 (mean over {seeds_text(admo)}, "
            f"{bands})"
        )
        out.append(figure)
    if others:
        path, figure = ctx.figure("fig1b_ipd_cooperation.png")
        panels = plots.condition_panels(runs, others, colors)
        if bands := plots.curve_panels(panels, "eval/success", "cooperation rate", path):
            figure.caption = f"Fig. 1b: IPD cooperation rate (mean over {seeds}, {bands})"
            out.append(figure)
    return out


def intro(runs: list[RunRecord]) -> str:
    """What the numbers are, with the counts read from the runs."""
    attacked = sorted({r.adversary for r in runs if r.attack is not None})
    adversary = ", ".join(f"agent {a}" for a in attacked) or "none (no attacked run)"
    by_updates = {
        kind: sorted({r.env for r in runs if incentive_updates(r.config) == kind}, key=natural_key)
        for kind in ("shared", "own")
    }
    text = (
        f"Final = mean of the last {final_window_text(runs)} per seed over {seeds_text(runs)}; "
        f"{interval_text(r.seeds for r in runs)}; Δ = attacked − clean, the two runs' seeds "
        "resampled independently. Adversary = "
        f"{adversary} (the runs' attack parameters); margin = its env return minus the mean "
        "of the others'."
    )
    if by_updates["shared"]:
        text += (
            f" {', '.join(by_updates['shared'])} runs use the original code's shared incentive "
            "updates (each giver's step also moves the other givers' incentive nets)."
        )
    if by_updates["own"]:
        text += f" {', '.join(by_updates['own'])} runs: each giver updates only its own."
    return text


def has_return_ratio(run: RunRecord) -> bool:
    return run.per_seed("eval/return_ratio").size > 0


def results_rows(table: RunTable, runs: list[RunRecord]) -> list[dict]:
    rows = []
    for run in sorted(runs, key=lambda r: (natural_key(r.env), condition_key(r.condition))):
        success = run.per_seed("eval/success")
        margin = run.per_seed("eval/adversary_margin_env")
        ratio = run.per_seed("eval/return_ratio")
        conv = run.summary["convergence"]
        row = {
            "env": run.env,
            "condition": run.condition,
            "seeds": success.size,
            "success": estimate(success),
            "return_ratio": float(ratio.mean()) if ratio.size else None,
            "steps": float(run.per_seed("eval/steps").mean()),
            "margin": estimate(margin, digits=2, signed=True),
            "convergence_median": conv["median"],
            "first_crossing_median": conv["first_crossing_median"],
            "d_success": None,
            "d_margin": None,
        }
        base = table.clean_for(run)
        if base is not None and run.condition != CLEAN:
            row["d_success"] = difference(success, base.per_seed("eval/success"))
            row["d_margin"] = difference(
                margin, base.per_seed("eval/adversary_margin_env"), digits=2
            )
            row["time_ratio"] = base.summary["iters_per_s_mean"] / run.summary["iters_per_s_mean"]
        rows.append(row)
    return rows


def convergence_table(runs: list[RunRecord]) -> Table:
    """Fig. 4's table: convergence iteration per seed summary, clean vs self-centered."""
    rows = []
    for run in sorted(runs, key=lambda r: (natural_key(r.env), condition_key(r.condition))):
        if run.condition not in (CLEAN, "self_centered") or not has_return_ratio(run):
            continue
        conv = run.summary["convergence"]
        iqr = conv["iqr"]
        rows.append(
            [
                run.env,
                run.condition,
                f"{conv['converged_seeds']}/{run.seeds}",
                fmt(conv["median"], 0),
                f"{fmt(iqr[0], 0)}–{fmt(iqr[1], 0)}",
                fmt(conv["first_crossing_median"], 0),
            ]
        )
    header = ["env", "condition", "converged seeds", "median convergence (it)", "IQR"]
    return Table(header + ["median first crossing"], rows, name="attacks_convergence")


def results_table(rows: list[dict]) -> Table:
    header = ["env", "condition", "seeds", f"success {INTERVAL}", f"Δ success {INTERVAL}"]
    header += ["return ratio", "steps", f"adversary margin {INTERVAL}", f"Δ margin {INTERVAL}"]
    cells = [
        [r["env"], r["condition"], r["seeds"], r["success"], r["d_success"], r["return_ratio"]]
        + [f"{r['steps']:.2f}", r["margin"], r["d_margin"]]
        for r in rows
    ]
    return Table(header, cells, name="attacks")


# --- figures ---------------------------------------------------------------------------


def agent_colour(agent: int) -> str:
    return AGENT_COLOURS[agent % len(AGENT_COLOURS)]


def fig_agent_returns(runs: list[RunRecord], envs: list[str], path) -> str:
    """Per-agent env return curves, one row per condition and one column per env; the
    adversary of an attacked run is the thick red curve. One legend under the panels
    names every agent and what the bands are. Returns that ("" where nothing was drawn)."""
    cells = {
        (r.condition, r.env): r
        for r in runs
        if r.env in envs and r.curves.has("eval/return_env/agent_0")
    }
    conditions = sorted({c for c, _ in cells}, key=condition_key)
    if not conditions:
        return ""
    fig, axes = plots.plt.subplots(
        len(conditions),
        len(envs),
        figsize=(4.6 * len(envs), 2.3 * len(conditions) + 0.6),
        squeeze=False,
        sharex="col",
    )
    drawn, agents, adversaries = [], 0, set()
    for i, cond in enumerate(conditions):
        for j, env in enumerate(envs):
            run = cells.get((cond, env))
            if run is None:
                axes[i][j].remove()
                continue
            agents = max(agents, run.num_agents)
            drawn += _agent_curves(axes[i][j], run, adversaries)
            rows = [k for k, c in enumerate(conditions) if (c, env) in cells]
            if i == rows[0]:
                axes[i][j].set_title(env)
            if i == rows[-1]:
                axes[i][j].set_xlabel("iteration")
                axes[i][j].tick_params(labelbottom=True)
            if j == min(envs.index(e) for c, e in cells if c == cond):
                axes[i][j].set_ylabel(f"{cond}\nenv return")
            axes[i][j].grid(alpha=0.3)
    handles = [
        plots.Line2D([], [], color=agent_colour(a), lw=1.2, label=f"agent {a}")
        for a in range(agents)
    ]
    handles += [
        plots.Line2D([], [], color=ADVERSARY_COLOUR, lw=2.4, label=f"agent {a} as adversary")
        for a in sorted(adversaries)
    ]
    bands = plots.band_text(drawn)
    plots.legend_below(fig, [], handles + [plots.band_handle(bands)])
    plots.save(fig, path, dpi=100)
    return bands


def _agent_curves(ax, run: RunRecord, adversaries: set) -> list[tuple[str, int]]:
    """Every agent's env return curve of `run` in `ax` (the adversary's thick and red,
    added to `adversaries`); the bands drawn."""
    drawn = []
    for agent in range(run.num_agents):
        adv = run.attack is not None and agent == run.adversary
        if adv:
            adversaries.add(agent)
        drawn.append(
            plots.band(
                ax,
                run.curves,
                f"eval/return_env/agent_{agent}",
                None,
                ADVERSARY_COLOUR if adv else agent_colour(agent),
                lw=2.2 if adv else 0.9,
            )
        )
    return drawn


def fig_convergence(runs: list[RunRecord], envs: list[str], colors: dict, path) -> bool:
    fig, ax = plots.plt.subplots(figsize=(6.5, 3.8))
    labels, shown = [], []
    for env in envs:
        for cond in (CLEAN, "self_centered"):
            run = next((r for r in runs if r.env == env and r.condition == cond), None)
            if run is None:
                continue
            _convergence_points(ax, run, len(labels), colors[cond])
            shown.append(cond)
            labels.append(f"{env}\n{cond}")
    if not labels:
        plots.plt.close(fig)
        return False
    ax.set_xticks(range(len(labels)), labels, fontsize=8)
    ax.set_xlim(-0.5, len(labels) - 0.5)
    ax.set_ylabel("iteration")
    ax.set_title("per-seed convergence: ○ first crossing, □ stays ≥ 0.9 (smoothed return ratio)")
    ax.title.set_fontsize(8)
    ax.grid(alpha=0.3)
    handles = [
        plots.Line2D([], [], ls="", marker="s", color=colors[c], label=c)
        for c in dict.fromkeys(shown)
    ]
    plots.legend_below(fig, [], handles)
    plots.save(fig, path)
    return True


def _convergence_points(ax, run: RunRecord, x: int, color: str) -> None:
    """One run's per-seed first crossings (○, left) and strict convergence (□, right) at
    `x`; a note where no seed reached 0.9."""
    conv = run.summary["convergence"]
    points = 0
    for key, marker in (("first_crossing_per_seed", "o"), ("per_seed", "s")):
        values = [v for v in conv[key] if v is not None]
        jitter = np.linspace(-0.12, 0.12, len(values)) + (0.18 if marker == "s" else -0.18)
        ax.scatter(x + jitter, values, marker=marker, s=18, color=color, alpha=0.8)
        points += len(values)
    if not points:
        ax.annotate(
            f"none of\n{run.seeds} seeds\nreached 0.9",
            (x, 0.5),
            xycoords=("data", "axes fraction"),
            ha="center",
            va="center",
            fontsize=7,
            color="0.4",
        )


ADMO_PANELS = (
    ("eval/success", "success"),
    ("eval/adversary_margin_env", "adversary env margin"),
    ("admo/alpha_1", "α1 (incentive objective)"),
    ("admo/c_1", "bounds c1 (solid), c2 (dashed)"),
)
"""Fig. 5's columns: (metric, panel title)."""


def fig_admo(runs, admo: list[RunRecord], envs: list[str], colors: dict, path) -> str:
    """Fig. 5: one row per env, one column per `ADMO_PANELS` metric, the ADMO runs and the
    clean one; the legend under the panels. Returns what the bands are."""
    fig, axes = plots.plt.subplots(
        len(envs), len(ADMO_PANELS), figsize=(4.4 * len(ADMO_PANELS), 3 * len(envs)), squeeze=False
    )
    shown = {r.name for r in admo} | {r.name for r in runs if r.condition == CLEAN}
    drawn = []
    for i, env in enumerate(envs):
        for j, (column, title) in enumerate(ADMO_PANELS):
            ax = axes[i][j]
            lines = [
                run
                for run in plots.runs_of(runs, env)
                if run.name in shown
                and (run in admo or not column.startswith("admo/"))
                and run.curves.has(column)
            ]
            if not lines:
                ax.remove()
                continue
            for run in lines:
                color = colors[run.condition]
                drawn.append(plots.band(ax, run.curves, column, run.condition, color))
                if column == "admo/c_1" and run.curves.has("admo/c_2"):
                    iterations, values = run.curves.matrix("admo/c_2")
                    ax.plot(iterations, values.mean(axis=0), ls="--", color=color)
            ax.set_title(f"{env}: {title}", fontsize=9)
            ax.grid(alpha=0.3)
            if i == len(envs) - 1:
                ax.set_xlabel("iteration")
    bands = plots.band_text(drawn)
    plots.legend_below(fig, fig.axes, [plots.band_handle(bands)])
    plots.save(fig, path, dpi=100)
    return bands
