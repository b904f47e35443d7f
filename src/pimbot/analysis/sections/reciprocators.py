"""Reciprocators vs ADMO (claim C7, Fig. 7) and the 2-player IPD fidelity runs (Fig. 7b)."""

from __future__ import annotations

from pimbot.analysis import plots
from pimbot.analysis.curves import load_curve
from pimbot.analysis.document import Claim, Context, Section, seeds_text, verdict
from pimbot.analysis.runs import CLEAN, RunRecord, RunTable, condition_key, natural_key
from pimbot.analysis.tables import Table, difference, estimate
from pimbot.experiment import store

GROUP = "reciprocators"
LEARNER = "reciprocator"
ATTACKED = "admo_disrupt"
C7_ENVS = ["ER(2,1)", "ER(4,2)", "ER(4,3)", "IPD(2)", "IPD(3)", "IPD(4)", "SH(2)", "SH(3)", "SH(4)"]
C7_TARGETS = {  # env label -> published upper bound on ADMO (disrupt) success
    "ER(4,3)": 0.1,
    "ER(4,2)": 0.3,
    "IPD(2)": 0.1,
    "IPD(3)": 0.1,
    "IPD(4)": 0.1,
    "SH(2)": 0.1,
    "SH(3)": 0.1,
    "SH(4)": 0.1,
}
CAPTURES_FILE = "stag_captures.json"
"""Stag captures per episode of each seed's final policy, replayed from the checkpoint
(success counts hares too); read when a run directory holds it."""
C7_TEXT = (
    "Reciprocators: baseline 80–90 % → ADMO near 0 (ER(4,3), Stag Hunt), < 30 % "
    "(ER(4,2)), < 10 % (IPD)"
)


def variant(run: RunRecord) -> str:
    """The balance, where it is not the one-step grudge of the C7 runs: "spec balance" (the
    accumulated credit − debit). Runs stored before the option was named `grudge` carry
    `original_one_step_grudge` instead."""
    if run.learner != LEARNER:
        return ""  # NL: weight 0, no balance
    config = run.identity["learner_config"]
    legacy = "one_step" if config.get("original_one_step_grudge") else "accumulated"
    return "" if config.get("grudge", legacy) == "one_step" else "spec balance"


def voi_kind(run: RunRecord) -> str:
    """ "exact" (matrix games: the original IPD agent) or "learned" VoI."""
    return run.identity["learner_config"].get("voi", "learned")


VOI_ROLES = {  # column label -> metric; ER actions: 0 lever, 1 start, 2 door
    "lever → door": "train/voi_role/action_0_to_action_2",
    "door → lever": "train/voi_role/action_2_to_action_0",
}


def learner_label(run: RunRecord) -> str:
    return run.learner + (f" ({variant(run)})" if variant(run) else "")


def section(table: RunTable, ctx: Context) -> Section | None:
    runs = table.group(GROUP)
    if not runs:
        return None
    ctx.claim(runs)
    rows = results_rows(runs)
    envs = [e for e in C7_ENVS if any(r.env == e for r in runs)]
    envs += sorted({r.env for r in runs} - set(envs), key=natural_key)
    out = Section(
        "Reciprocators: baseline vs ADMO (C7) and IPD fidelity",
        text=[
            "Reciprocator runs use the original code's one-step grudge: on the IPD the "
            "original's matrix agent (exact VoI, width-2 networks), on gridworlds the learned "
            "VoI; NL = the same PPO with reciprocal weight 0 (also the self-centered "
            "adversary). Details and the reasons for the iteration budgets: "
            "docs/results/reciprocators.md."
        ],
    )
    grudge = sorted(
        (r for r in runs if r.learner == LEARNER and not variant(r)),
        key=lambda r: condition_key(r.condition),
    )
    panels = [
        (env, [(r, r.condition, table.colors[r.condition]) for r in grudge if r.env == env])
        for env in envs
        if any(r.env == env for r in grudge)
    ]
    if panels:
        seeds = seeds_text(grudge)
        path, figure = ctx.figure(
            "fig7_reciprocators.png", f"Fig. 7: Reciprocators, clean vs ADMO ({seeds})"
        )
        title = f"C7: Reciprocators (mean over {seeds}, 95 % CI band)"
        if plots.curve_panels(panels, "eval/success", "success", path, 3, (-0.05, 1.05), title):
            out.figures.append(figure)
    path, figure = ctx.figure("fig7b_ipd_fidelity.png", "Fig. 7b: 2-player IPD fidelity")
    if fig_fidelity(runs, path):
        out.figures.append(figure)
    by = {(r["env"], r["learner"], r["condition"]): r for r in rows}
    parts, ok, clean_ok, admo_ok, targets = [], True, 0, 0, 0
    for env in [e for e in C7_ENVS if e in envs]:
        clean = by.get((env, LEARNER, CLEAN))
        admo = by.get((env, LEARNER, ATTACKED))
        if clean is None or admo is None:
            ok = False
            parts.append(f"{env}: not run")
            continue
        base, attacked = clean["success"].mean, admo["success"].mean
        ok &= base >= 0.8
        clean_ok += base >= 0.8
        if env in C7_TARGETS:
            ok &= attacked < C7_TARGETS[env]
            admo_ok += attacked < C7_TARGETS[env]
            targets += 1
        parts.append(f"{env}: {base:.2f} → {attacked:.2f}")
    judged = [e for e in C7_ENVS if e in envs]
    out.claims.append(
        Claim(
            "C7",
            C7_TEXT,
            "clean Reciprocator final success ≥ 0.8 in every env, and ADMO (disrupt) final "
            "success < 0.1 in ER(4,3), IPD(2,3,4), Stag Hunt(2,3,4) and < 0.3 in ER(4,2)",
            "clean → ADMO: " + "; ".join(parts),
            verdict(ok),
            f"clean ≥ 0.8 in {clean_ok}/{len(judged)} envs; ADMO below its bound in "
            f"{admo_ok}/{targets}",
        )
    )
    out.tables.append(results_table(rows))
    voi = voi_table(runs)
    if voi is not None:
        out.tables.append(voi)
    return out


def voi_table(runs: list[RunRecord]) -> Table | None:
    """Final VoI by role per Reciprocator run: ER's lever pullers and door agents (the
    action taken on the step), and the adversary against the others when attacked."""
    rows = []
    for run in sorted(runs, key=lambda r: (natural_key(r.env), condition_key(r.condition))):
        if run.learner != LEARNER:
            continue
        n, a = run.num_agents, run.adversary
        others = [j for j in range(n) if j != a]
        given = [run.per_seed(f"train/voi/agent_{a}_to_agent_{j}") for j in others]
        received = [run.per_seed(f"train/voi/agent_{j}_to_agent_{a}") for j in others]
        if any(v.size == 0 for v in given + received):
            continue  # a run stored before the pair metrics were logged
        row = [run.env, learner_label(run), run.condition, voi_kind(run)]
        row += [estimate(sum(given) / len(given)), estimate(sum(received) / len(received))]
        for metric in VOI_ROLES.values():
            values = run.per_seed(metric)
            row.append(estimate(values) if values.size and run.env.startswith("ER") else None)
        rows.append(row + [run.setting])
    if not rows:
        return None
    header = ["env", "learner", "condition", "VoI"]
    header += ["adversary (clean: agent 0) → others", "others → adversary"]
    header += [f"{label} (ER)" for label in VOI_ROLES] + ["run"]
    return Table(header, rows, name="reciprocator_voi")


def results_rows(runs: list[RunRecord]) -> list[dict]:
    """One row per run: final success and adversary margin with CIs, and the attack effect;
    Stag Hunt rows whose run directory holds replayed stag captures show them too."""
    clean = {(r.env_key, r.learner, variant(r)): r for r in runs if r.condition == CLEAN}
    rows = []
    for run in runs:
        success = run.per_seed("eval/success")
        margin = run.per_seed("eval/adversary_margin_env")
        row = {
            "env": run.env,
            "learner": learner_label(run),
            "condition": run.condition,
            "seeds": success.size,
            "iterations": run.iterations,
            "success": estimate(success),
            "margin": estimate(margin),
            "effect_success": None,
            "stag_captures": None,
            "run": run.setting,
        }
        if (run.path / CAPTURES_FILE).exists():
            row["stag_captures"] = estimate(store.read_json(run.path / CAPTURES_FILE)["per_seed"])
        base = clean.get((run.env_key, run.learner, variant(run)))
        if run.condition != CLEAN and base is not None:
            row["effect_success"] = difference(success, base.per_seed("eval/success"))
        rows.append(row)
    order = {e: k for k, e in enumerate(C7_ENVS)}
    rows.sort(
        key=lambda r: (
            r["learner"],
            order.get(r["env"], len(order)),
            natural_key(r["env"]),
            condition_key(r["condition"]),
        )
    )
    return rows


def results_table(rows: list[dict]) -> Table:
    header = ["env", "learner", "condition", "seeds", "iterations", "final success [95 % CI]"]
    header += ["attacked − clean success [95 % CI]", "adversary margin (env) [95 % CI]"]
    header += ["stag captures / episode [95 % CI]", "run"]
    keys = ["env", "learner", "condition", "seeds", "iterations", "success", "effect_success"]
    keys += ["margin", "stag_captures", "run"]
    return Table(header, [[r[k] for k in keys] for r in rows], name="reciprocators")


def fig_fidelity(runs: list[RunRecord], path) -> bool:
    """2-player IPD: cooperation and per-agent return, R vs R, NL vs NL, R vs NL (agent 0 NL)."""
    cases = []
    for run in runs:
        if run.env != "IPD(2)":
            continue
        if run.learner == LEARNER and run.condition == CLEAN:
            cases.append((run, "R vs R"))
        elif run.learner == "nl" and run.condition == CLEAN:
            cases.append((run, "NL vs NL"))
        elif run.learner == LEARNER and run.condition == "self_centered":
            cases.append((run, "NL (agent 0) vs R"))
    if not cases:
        return False
    fig, axes = plots.plt.subplots(1, len(cases), figsize=(4.2 * len(cases), 3.2), squeeze=False)
    for ax, (run, label) in zip(axes.flat, cases, strict=True):
        plots.band(ax, run.path, "eval/success", "mutual cooperation", "black")
        steps = float(run.identity["env_params"].get("max_steps", 5))
        for agent, color in ((0, "tab:green"), (1, "tab:blue")):
            iterations, values = load_curve(run.path, f"eval/return_env/agent_{agent}")
            # Per-step return, −3 … 0, drawn on the rate axis as (return/step + 3)/3.
            mean = ((values / steps + 3.0) / 3.0).mean(axis=0)
            ax.plot(iterations, mean, color=color, lw=1, ls="--", label=f"agent {agent} return")
        title = label + (f" [{variant(run)}]" if variant(run) else "")
        ax.set_title(title)
        ax.set_ylim(-0.05, 1.05)
        ax.set_xlabel("iteration")
        ax.set_ylabel("rate; (return/step + 3)/3")
        ax.legend(fontsize=7)
    fig.suptitle(f"2-player IPD fidelity (mean over {seeds_text(r for r, _ in cases)})")
    plots.save(fig, path)
    return True
