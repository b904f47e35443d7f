"""Attacks on LIO: the results table, claims C1–C5 and figures 1–5 (group `attacks`)."""

from __future__ import annotations

import numpy as np

from pimbot.analysis import plots
from pimbot.analysis.curves import columns, load_curve
from pimbot.analysis.document import Claim, Context, Section, verdict
from pimbot.analysis.runs import CLEAN, RunRecord, RunTable, condition_key, natural_key
from pimbot.analysis.tables import Table, difference, estimate, fmt

GROUP = "attacks"
CLAIMS_LEARNER = "lio"
"""C1–C5 are about LIO; the group's runs of other learners go to the generic section."""
ADMO_COLUMN = "admo/alpha_1"
"""Runs that log it are ADMO runs (Fig. 5)."""


def section(table: RunTable, ctx: Context) -> Section | None:
    runs = [r for r in table.group(GROUP) if r.learner == CLAIMS_LEARNER]
    if not runs:
        return None
    ctx.claim(runs)
    colors = table.colors
    rows = results_rows(table, runs)
    envs = sorted({r.env for r in runs}, key=natural_key)
    teams = [e for e in envs if any(r.env == e and has_return_ratio(r) for r in runs)]
    others = [e for e in envs if e not in teams]
    out = Section(
        "Attacks on LIO (C1–C5)",
        text=[
            "Final = mean of the last 10 evaluation points per seed, [95 % bootstrap CI over "
            "seeds]; Δ = attacked − clean with a bootstrap CI. Adversary = agent 0; margin = "
            "its env return minus the mean of the others'. N ≥ 3 runs use the original shared "
            "incentive updates."
        ],
    )
    panels = plots.condition_panels(runs, teams, colors)
    if teams:
        path, figure = ctx.figure(
            "fig1_success.png", "Fig. 1: success vs iterations per ER config, clean and attacks"
        )
        plots.curve_panels(panels, "eval/success", "success", path)
        out.figures.append(figure)
        path, figure = ctx.figure(
            "fig2_agent_returns.png", "Fig. 2: per-agent env returns (adversary in red)"
        )
        fig_agent_returns(runs, teams, path)
        out.figures.append(figure)
        path, figure = ctx.figure("fig3_steps.png", "Fig. 3: steps per episode")
        plots.curve_panels(panels, "eval/steps", "steps per episode", path)
        out.figures.append(figure)
    if teams and any(r.condition == "self_centered" for r in runs):
        path, figure = ctx.figure(
            "fig4_convergence.png", "Fig. 4: convergence, clean vs self-centered"
        )
        fig_convergence(runs, teams, colors, path)
        out.figures.append(figure)
    admo = [r for r in runs if ADMO_COLUMN in columns(r.path)]
    if teams and admo:
        path, figure = ctx.figure(
            "fig5_admo.png", "Fig. 5: ADMO vs LIO: success, margin, α1, c1/c2"
        )
        fig_admo(runs, admo, teams, colors, path)
        out.figures.append(figure)
    if others:
        path, figure = ctx.figure("fig1b_ipd_cooperation.png", "Fig. 1b: IPD cooperation rate")
        panels = plots.condition_panels(runs, others, colors)
        plots.curve_panels(panels, "eval/success", "cooperation rate", path)
        out.figures.append(figure)
    out.tables = [convergence_table(runs), results_table(rows)]
    out.claims = claims(rows)
    return out


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
    header = ["env", "condition", "seeds", "success [CI]", "Δ success [CI]", "return ratio"]
    header += ["steps", "adversary margin [CI]", "Δ margin [CI]"]
    cells = [
        [r["env"], r["condition"], r["seeds"], r["success"], r["d_success"], r["return_ratio"]]
        + [f"{r['steps']:.2f}", r["margin"], r["d_margin"]]
        for r in rows
    ]
    return Table(header, cells, name="attacks")


def claims(rows: list[dict]) -> list[Claim]:
    """C1–C5, judged on the rows."""
    by = {(r["env"], r["condition"]): r for r in rows}
    out = []
    # C1
    parts, ok = [], True
    for env in ("ER(2,1)", "ER(4,2)", "IPD(2)"):
        r = by.get((env, "self_centered"))
        if r is None or r["margin"] is None:
            ok = False
            parts.append(f"{env}: not run")
            continue
        ok &= r["margin"].lo > 0
        parts.append(f"{env}: margin {r['margin'].mean:+.2f} (CI low {r['margin'].lo:+.2f})")
    for env in ("ER(2,1)", "ER(4,2)"):
        c, s = by.get((env, CLEAN)), by.get((env, "self_centered"))
        if c and s:
            parts.append(
                f"{env}: first crossing {fmt(c['first_crossing_median'], 0)} → "
                f"{fmt(s['first_crossing_median'], 0)}, convergence "
                f"{fmt(c['convergence_median'], 0)} → {fmt(s['convergence_median'], 0)}"
            )
    out.append(
        Claim(
            "C1",
            "self-centered: adversary above the others; ER converges faster",
            "margin: 95 % CI of the adversary's final env-return margin over the mean of the "
            "others > 0 in ER(2,1), ER(4,2), IPD; speed reported, not judged (medians of 10 seeds)",
            "; ".join(parts),
            verdict(ok) + " (margin)",
        )
    )
    # C2
    rooms = ("ER(2,1)", "ER(4,2)", "ER(4,3)")
    parts, ok = [], True
    for env in rooms:
        r = by.get((env, "fake_incentive"))
        if r is None:
            ok, parts = False, parts + [f"{env}: not run"]
            continue
        ok &= r["success"].mean <= 0.05
        parts.append(f"{env}: {r['success'].mean:.3f}")
    out.append(
        Claim(
            "C2",
            "fake incentive (C = 50): success collapses to ~0 in ER",
            "final success ≤ 0.05 in every ER config",
            "; ".join(parts),
            verdict(ok),
        )
    )
    # C3, C4
    for cid, cond, label in (("C3", "bypass", "bypass"), ("C4", "reverse", "reverse")):
        parts, ok = [], True
        for env, want_low in (("ER(2,1)", True), ("ER(4,3)", True), ("ER(4,2)", False)):
            r = by.get((env, cond))
            if r is None:
                ok, parts = False, parts + [f"{env}: not run"]
                continue
            success = r["success"].mean
            ok &= success <= 0.05 if want_low else success >= 0.9
            parts.append(f"{env}: {success:.3f}")
        out.append(
            Claim(
                cid,
                f"{label}: 0 success in ER(2,1), ER(4,3); ER(4,2) still solved",
                "final success ≤ 0.05 in ER(2,1) and ER(4,3), ≥ 0.9 in ER(4,2)",
                "; ".join(parts),
                verdict(ok),
            )
        )
    # C5
    parts, ok = [], True
    for env in rooms:
        s, d = by.get((env, "admo_stealthy")), by.get((env, "admo_disrupt"))
        if s is None or d is None or s["d_margin"] is None or d["d_success"] is None:
            ok, parts = False, parts + [f"{env}: not run"]
            continue
        ok &= s["d_margin"].lo > 0 and d["d_success"].hi < 0
        parts.append(f"{env}: stealthy Δmargin {s['d_margin']}, disrupt Δsuccess {d['d_success']}")
    ratios = [
        f"{r['env']} {r['condition'].removeprefix('admo_')} {r['time_ratio']:.2f}"
        for r in rows
        if r["condition"].startswith("admo") and "time_ratio" in r
    ]
    parts.append(
        "iteration time ADMO / clean, from the runs' it/s (the sweep's own timing; "
        "benchmarks/throughput.py --attack admo measures it cleanly): " + ", ".join(ratios)
    )
    out.append(
        Claim(
            "C5",
            "ADMO: stealthy raises the adversary's margin, disrupt lowers team success",
            "ER: 95 % CI of Δ margin (stealthy − clean) > 0 and of Δ success (disrupt − clean) < 0 "
            "in every ER config",
            "; ".join(parts),
            verdict(ok),
        )
    )
    return out


# --- figures ---------------------------------------------------------------------------


def fig_agent_returns(runs: list[RunRecord], envs: list[str], path) -> None:
    conditions = sorted({r.condition for r in runs}, key=condition_key)
    fig, axes = plots.plt.subplots(
        len(conditions),
        len(envs),
        figsize=(4.6 * len(envs), 2.3 * len(conditions)),
        squeeze=False,
        sharex="col",
    )
    for i, cond in enumerate(conditions):
        for j, env in enumerate(envs):
            ax = axes[i][j]
            run = next((r for r in runs if r.env == env and r.condition == cond), None)
            for agent in range(run.num_agents if run else 0):
                adv = agent == run.adversary
                plots.band(
                    ax,
                    run.path,
                    f"eval/return_env/agent_{agent}",
                    f"agent {agent}" + (" (adversary)" if adv else ""),
                    "tab:red" if adv else None,
                    lw=2.0 if adv else 0.9,
                )
            if i == 0:
                ax.set_title(env)
            if j == 0:
                ax.set_ylabel(f"{cond}\nenv return")
            ax.grid(alpha=0.3)
            if i == 0 and j == 0:
                ax.legend(fontsize=6)
    for ax in axes[-1]:
        ax.set_xlabel("iteration")
    plots.save(fig, path, dpi=100)


def fig_convergence(runs: list[RunRecord], envs: list[str], colors: dict, path) -> None:
    fig, ax = plots.plt.subplots(figsize=(6.5, 3.8))
    labels = []
    for env in envs:
        for cond in (CLEAN, "self_centered"):
            run = next((r for r in runs if r.env == env and r.condition == cond), None)
            if run is None:
                continue
            conv = run.summary["convergence"]
            for key, marker in (("first_crossing_per_seed", "o"), ("per_seed", "s")):
                values = [v for v in conv[key] if v is not None]
                jitter = np.linspace(-0.12, 0.12, len(values)) + (0.18 if marker == "s" else -0.18)
                x = len(labels) + jitter
                ax.scatter(x, values, marker=marker, s=18, color=colors[cond], alpha=0.8)
            labels.append(f"{env}\n{cond}")
    ax.set_xticks(range(len(labels)), labels, fontsize=8)
    ax.set_ylabel("iteration")
    ax.set_title("per-seed convergence: ○ first crossing, □ stays ≥ 0.9 (smoothed return ratio)")
    ax.title.set_fontsize(8)
    ax.grid(alpha=0.3)
    plots.save(fig, path)


def fig_admo(runs, admo: list[RunRecord], envs: list[str], colors: dict, path) -> None:
    panels = [
        ("eval/success", "success"),
        ("eval/adversary_margin_env", "adversary env margin"),
        ("admo/alpha_1", "α1 (incentive objective)"),
        ("admo/c_1", "bounds c1 (solid), c2 (dashed)"),
    ]
    fig, axes = plots.plt.subplots(
        len(envs), len(panels), figsize=(4.4 * len(panels), 3 * len(envs)), squeeze=False
    )
    shown = {r.name for r in admo} | {r.name for r in runs if r.condition == CLEAN}
    for i, env in enumerate(envs):
        for j, (column, title) in enumerate(panels):
            ax = axes[i][j]
            for run in plots.runs_of(runs, env):
                own = column.startswith("admo/")
                if run.name not in shown or (own and run not in admo):
                    continue
                plots.band(ax, run.path, column, run.condition, colors[run.condition])
                if column == "admo/c_1":
                    iterations, values = load_curve(run.path, "admo/c_2")
                    ax.plot(iterations, values.mean(axis=0), ls="--", color=colors[run.condition])
            ax.set_title(f"{env}: {title}", fontsize=9)
            ax.grid(alpha=0.3)
            if i == len(envs) - 1:
                ax.set_xlabel("iteration")
        axes[i][0].legend(fontsize=7)
    plots.save(fig, path, dpi=100)
