"""Reciprocators vs ADMO (claim C7, Fig. 7) and the 2-player IPD fidelity runs (Fig. 7b)."""

from __future__ import annotations

import dataclasses

from pimbot import envs, learners
from pimbot.analysis import judging, plots, verdicts
from pimbot.analysis.claims import CLAIM_TEXT, Claim, Comparison, summarized
from pimbot.analysis.document import Context, Section, seeds_text
from pimbot.analysis.runs import (
    CLEAN,
    RunRecord,
    RunTable,
    condition_key,
    natural_key,
    settings_difference,
)
from pimbot.analysis.tables import INTERVAL, Table, difference, estimate
from pimbot.statistics import MIN_SEEDS_FOR_CI, difference_p_value, interval_text

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
CAPTURES = "eval/stag_captures"
"""Stag captures per evaluation episode (the Stag Hunt's step metric; its success counts
hares too), final per seed as every other column."""
BASELINE = 0.8
"""The published baseline "80–90 %": its lower end."""


BALANCE_NAMES = {
    "accumulated": "credit − debit balance",
    "petty": "PIMbot code's ER script's balance, 'linear' → petty_rr",
    "one_step": "one-step grudge",
}
"""How a run's balance (`grudge`) is named where it is not its env's default."""


def default_balance(env_id: str) -> str:
    """The Reciprocator's default balance on `env_id` (its registry entry's env defaults):
    the one-step grudge on the matrix games, credit − debit on the gridworlds; an env
    pimbot does not know: the one-step grudge of the C7 runs."""
    if env_id not in envs.registered():
        return "one_step"
    return learners.default_config(LEARNER, env_id).grudge


def variant(run: RunRecord) -> str:
    """The balance, where it is neither the env's default nor the one-step grudge of the
    suite's Stag Hunt runs: the credit − debit balance (on the matrix games) or the PIMbot
    code's ER script's credit-only petty balance (`BALANCE_NAMES`). Runs stored before the
    option was named `grudge` carry `original_one_step_grudge` instead."""
    if run.learner != LEARNER:
        return ""  # NL: weight 0, no balance
    config = run.identity["learner_config"]
    legacy = "one_step" if config.get("original_one_step_grudge") else "accumulated"
    grudge = config.get("grudge", legacy)
    if grudge in ("one_step", default_balance(run.identity["env_id"])):
        return ""
    return BALANCE_NAMES.get(grudge, str(grudge))


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
            "On the IPD the Reciprocator is the original's matrix agent (exact VoI, "
            "one-step grudge, width-2 networks, 2 048 games per update); on Escape Room the "
            "credit − debit balance the Reciprocator's authors publish, at the PIMbot code's "
            "Escape Room script's learner settings (lr 1e-4, γ 0.99, entropy 0.01, w 5, VoI "
            "lr 1e-3) and 128 episodes per update, with rows of that script's own balance "
            "('linear' → the credit-only petty_rr), also at its own batch of one episode per "
            "update; on the Stag "
            "Hunt gridworld the learned VoI with the one-step grudge. NL = the same PPO with "
            "reciprocal weight 0 (also the self-centered adversary). Details and the reasons "
            "for the iteration budgets: docs/reciprocators.md. "
            f"{interval_text(r.seeds for r in runs)}."
        ],
    )
    grudge = sorted(
        (r for r in runs if r.learner == LEARNER and not variant(r)),
        key=lambda r: condition_key(r.condition),
    )

    def line_label(run: RunRecord) -> str:
        # two runs of one env and condition (e.g. the IPD at 32 and 2048 games per update)
        # are told apart by the hyperparameters they override
        twins = sum(1 for r in grudge if r.env == run.env and r.condition == run.condition)
        return f"{run.condition} [{run.hparams}]" if twins > 1 and run.hparams else run.condition

    panels = [
        (env, [(r, line_label(r), table.colors[r.condition]) for r in grudge if r.env == env])
        for env in envs
        if any(r.env == env for r in grudge)
    ]
    if panels:
        seeds = seeds_text(grudge)
        path, figure = ctx.figure("fig7_reciprocators.png")
        title = f"C7: Reciprocators (mean over {seeds})"
        bands = plots.curve_panels(panels, "eval/success", "success", path, 3, (-0.05, 1.05), title)
        if bands:
            figure.caption = f"Fig. 7: Reciprocators, clean vs ADMO (mean over {seeds}, {bands})"
            out.figures.append(figure)
    path, figure = ctx.figure("fig7b_ipd_fidelity.png")
    if bands := fig_fidelity(runs, path):
        figure.caption = (
            f"Fig. 7b: 2-player IPD fidelity (mean over seeds, {bands}; dashed: each agent's "
            "env return per step, rescaled to the rate axis)"
        )
        out.figures.append(figure)
    out.claims.append(c7(runs, table.original))
    settings = settings_table(runs)
    if settings is not None:
        out.tables.append(settings)
    out.tables.append(results_table(rows))
    voi = voi_table(runs)
    if voi is not None:
        out.tables.append(voi)
    return out


# --- C7 ---------------------------------------------------------------------------------


def is_counterfactual(run: RunRecord) -> bool:
    """A run of the clearly labelled ER variant with a reward-transfer action
    (escape_room_transfer-v0, or an env parameter naming "transfer", set): not the paper's
    environment."""
    params = run.identity["env_params"]
    return "transfer" in run.identity["env_id"] or any(
        "transfer" in k and bool(v) for k, v in params.items()
    )


def size(run: RunRecord) -> tuple:
    """The env's size parameters, matching a counterfactual run to the paper env's."""
    params = run.identity["env_params"]
    return tuple(params.get(k) for k in ("n_agents", "n_players", "min_at_lever"))


CODE_SETTINGS = {
    "lr": 1e-4,
    "gamma": 0.99,
    "reciprocal_weight": 5.0,
    "num_envs": 1,
    "grudge": "petty",
}
"""The original code's Reciprocator Escape Room script as it runs (greedy_agent
`reciprocators/run_er.py`; docs/reciprocators.md): its learner settings, which are pimbot's
Escape Room defaults, with its own credit-only balance and batch of one episode per
update."""
CODE_LOGS = "the original scripts (greedy_agent reciprocators/run_*.py) log no success"
"""What a C7 disagreement lacks: the original code's Reciprocator scripts, clean and ADMO,
print the reciprocal reward only."""


def is_code_setting(run: RunRecord) -> bool:
    """A run at the original code's Reciprocator Escape Room settings and batch of one
    episode per update, read from its learner config."""
    config = run.identity.get("learner_config", {})
    return all(config.get(k) == v for k, v in CODE_SETTINGS.items())


def setting_label(run: RunRecord) -> str:
    """The learner settings a run overrode and the env parameters beyond the size."""
    given = dict(run.config["run_config"].get("env_params", ()))
    extra = {k: v for k, v in given.items() if k not in ("n_agents", "n_players", "min_at_lever")}
    label = learner_label(run) + (f" [{run.hparams}]" if run.hparams else "")
    if extra:
        label += " env: " + ", ".join(f"{k}={v}" for k, v in sorted(extra.items()))
    return label


def primary(runs: list[RunRecord], env: str, condition: str) -> RunRecord | None:
    """Our setting of `env`: the Reciprocator run (not the counterfactual, not the original
    code's batch of one, not another balance) that overrides the fewest of the learner's
    defaults (the suite's own C7 job)."""
    mine = [
        r
        for r in runs
        if r.env == env
        and r.learner == LEARNER
        and r.condition == condition
        and not is_counterfactual(r)
        and not is_code_setting(r)
        and not variant(r)
    ]
    return min(
        mine, key=lambda r: (len(r.config["run_config"].get("hparams", ())), r.name), default=None
    )


def c7(runs: list[RunRecord], originals: tuple[RunRecord, ...] = ()) -> Claim:
    """C7 as stated: clean ≥ BASELINE everywhere, ADMO below its published bound. Each
    setting's baseline is its own part (pimbot's defaults, and the original code's batch of
    one episode per update where it ran), never the best of several runs. A shortfall at the
    defaults is the paper's environment where the transfer counterfactual solves the room;
    otherwise its cause comes from the original code's run at the same settings
    (`originals`, `against_original`), and without one it is inconclusive."""
    parts, lines, numbers, headlines = {}, [], [], {}
    for env in C7_ENVS:
        clean, admo = primary(runs, env, CLEAN), primary(runs, env, ATTACKED)
        if clean is not None and admo is not None:
            base = estimate(clean.per_seed("eval/success"))
            attacked = estimate(admo.per_seed("eval/success"))
            lines.append(f"{env}: {base.mean:.2f} → {attacked.mean:.2f}")
            numbers.append(
                Comparison(
                    f"{env} clean → ADMO success",
                    f"{clean.iterations:,} updates",
                    f"≥ {BASELINE:g}" + (f" → < {C7_TARGETS[env]:g}" if env in C7_TARGETS else ""),
                    None,
                    f"{base.mean:.2f} → {attacked.mean:.2f}",
                )
            )
            reached = judging.above(base, BASELINE, "clean")
            if reached is not None:
                reached = with_original(reached, originals, clean)
            parts[f"{env} baseline"] = reached or baseline_shortfall(runs, clean, base, originals)
            headlines[f"{env} baseline"] = f"{env} clean {base}"
            if env in C7_TARGETS:
                parts[f"{env} ADMO"] = admo_part(base, reached is None, attacked, C7_TARGETS[env])
                headlines[f"{env} ADMO"] = f"{env} clean {base} → ADMO {attacked}"
        for run in code_batch_runs(runs, env):
            name = f"{env} baseline, {CODE_BATCH}"
            name = name if name not in parts else f"{name} ({run.setting})"
            parts[name] = code_batch_part(run, originals)
            headlines[name] = f"{env} clean {estimate(run.per_seed('eval/success'))}, batch of one"
    counts = {k: sum(v.kind == k for v in parts.values()) for k in verdicts.KINDS}
    verdict = verdicts.combine(parts)
    return Claim(
        "C7",
        CLAIM_TEXT["C7"],
        f"our setting (the suite's C7 runs): the interval of the clean Reciprocator's final "
        f"success above {BASELINE:g} (the paper's 80–90 %) in every env, and ADMO's (disrupt) "
        "below 0.3 in ER(4,2) and 0.1 in IPD(2,3,4) (the paper's < 30 %, < 10 %) and in "
        "ER(4,3) and Stag Hunt(2,3,4) (the paper's 'near 0': 0.1 is ours); an interval that "
        "includes the bound is inconclusive where its mean is on the paper's side; each "
        f"setting judged on its own runs (pimbot's defaults; ER also at {CODE_BATCH}); an ER "
        "shortfall at the defaults is classified by the transfer counterfactual",
        "; ".join((["clean → ADMO: " + "; ".join(lines)] if lines else []) + [_parts_text(parts)]),
        verdict,
        ", ".join(f"{n} {verdicts.LABELS[k].split(' (')[0]}" for k, n in counts.items() if n)
        + f" of {len(parts)} parts",
        numbers,
        **summarized(
            verdict,
            headlines,
            agreed="every setting's clean baseline reaches 0.8 and ADMO stays below its bound",
        ),
    )


CODE_BATCH = "the original code's batch of one episode per update"


def admo_part(base, base_short: bool, attacked, bound: float) -> verdicts.Verdict:
    """ADMO (disrupt) success below the published bound (`judging.below`: by its interval)
    where the clean baseline `base` is not short of BASELINE (`base_short`: its
    `judging.above` found evidence against); below it with the baseline short,
    inconclusive (no effect of the attack to see); above it, inconclusive: the original
    scripts left no log to test against (`judging.disagreement`)."""
    judged = judging.below(attacked, bound, "ADMO success")
    if judged is None:
        return judging.disagreement(f"ADMO success {attacked} not < {bound:g}; {CODE_LOGS}", None)
    if judged.kind == verdicts.REPRODUCED and base_short:
        return verdicts.inconclusive(
            f"ADMO success {attacked} < {bound:g}, but clean {base} does not reach "
            f"{BASELINE:g} either: no effect of the attack to judge"
        )
    return judged


def code_batch_runs(runs: list[RunRecord], env: str) -> list[RunRecord]:
    """The clean Reciprocator runs of `env` at the original code's Escape Room settings and
    batch of one episode per update, each a setting of its own."""
    return sorted(
        (
            r
            for r in runs
            if r.env == env
            and r.learner == LEARNER
            and r.condition == CLEAN
            and is_code_setting(r)
            and not is_counterfactual(r)
            and r.per_seed("eval/success").size
        ),
        key=lambda r: r.name,
    )


def code_batch_part(run: RunRecord, originals: tuple[RunRecord, ...] = ()) -> verdicts.Verdict:
    """The baseline at the original code's batch of one: reproduced where its interval lies
    above BASELINE (`judging.above`); below, its cause from the original code's run at the
    same settings (`against_original`)."""
    est = estimate(run.per_seed("eval/success"))
    at = f"after {run.iterations:,} updates of one episode ({run.setting})"
    reached = judging.above(est, BASELINE, "clean")
    if reached is not None:
        return with_original(
            dataclasses.replace(reached, reason=f"{reached.reason} {at}"), originals, run
        )
    return against_original(f"clean {est} {at}", originals, run)


def original_code(originals, run: RunRecord) -> tuple[RunRecord | None, str]:
    """The original code's run at `run`'s exact settings (None: there is none) and a clause
    naming every original-code run of `run`'s env, learner and attack with its final
    success, and for one at other settings what differs (`RunTable.originals_for` and
    `originals_elsewhere`, `settings_difference`), with what was seen of its learning
    (`finding`)."""
    table = RunTable((), tuple(originals))
    same = table.originals_for(run)
    near = [o for o in table.originals_elsewhere(run) if o.per_seed("eval/success").size]
    texts = [
        f"the original code ({o.name}, {o.seeds} seeds"
        + (f"; {settings_difference(o, run)}" if o in near else ", the same settings")
        + f"): {estimate(o.per_seed('eval/success'))}"
        + (f" — {finding(o)}" if finding(o) else "")
        for o in same + near
    ]
    return (same[0] if same else None), "; ".join(texts)


def finding(original: RunRecord) -> str | None:
    """What was seen of an original-code run's learning when it was run here (config.json
    `original.finding`, written by benchmarks/original/import_runs.py), else None."""
    return (original.config.get("original") or {}).get("finding")


def with_original(verdict: verdicts.Verdict, originals, run: RunRecord) -> verdicts.Verdict:
    """`verdict` with the original code's runs of `run`'s setting named in its reason."""
    _, text = original_code(originals, run)
    return dataclasses.replace(verdict, reason=f"{verdict.reason}; {text}") if text else verdict


def against_original(reason: str, originals, run: RunRecord) -> verdicts.Verdict:
    """A clean shortfall of `run` below BASELINE, its cause from the original code's run at
    the same settings (`judging.disagreement`): above BASELINE by its interval, the original
    reproduces the paper (pimbot's seeds tested against its seeds); at or below it, the
    paper contradicts its own code, saying whether ours differ from the original's;
    undecided, or no such run, inconclusive naming what there is."""
    same, text = original_code(originals, run)
    if same is None:
        return judging.disagreement(f"{reason}; {text or CODE_LOGS}", None)
    theirs = same.per_seed("eval/success")
    if not judging.enough_seeds(len(theirs)):
        return verdicts.inconclusive(
            f"{reason}; {text}: {len(theirs)} original seeds are too few to name a cause "
            f"(at least {MIN_SEEDS_FOR_CI})"
        )
    reached = judging.above(estimate(theirs), BASELINE, "the original code's clean success")
    if reached is not None and reached.kind == verdicts.INCONCLUSIVE:
        return verdicts.inconclusive(f"{reason}; {text}: its interval includes {BASELINE:g}")
    ours = run.per_seed("eval/success")
    if reached is None:  # the original code falls short of the paper too
        p = difference_p_value(ours, theirs)
        relation = (
            f"ours differ from it (permutation test of the means, p = {p:.3f})"
            if p < judging.DIFFERS_P
            else f"ours do not differ from it (p = {p:.2f})"
        )
        return verdicts.refuted(
            verdicts.PAPER_CODE,
            f"{reason}; {text}: the original code does not reach {BASELINE:g} either; " + relation,
        )
    return judging.disagreement(f"{reason}; {text}", True, ours, theirs)


def baseline_shortfall(runs, clean, base, originals=()) -> verdicts.Verdict:
    """A clean shortfall at pimbot's defaults. Where another balance solves the same
    environment (≥ BASELINE, each run on its own) the environment is not the cause:
    inconclusive, naming that run. Otherwise the paper's environment where a transfer
    counterfactual of the same size solves the room; else inconclusive, naming what is
    missing."""
    same_size = [
        r
        for r in runs
        if size(r) == size(clean)
        and r.learner == LEARNER
        and r.condition == CLEAN
        and r.per_seed("eval/success").size
    ]
    for run in same_size:
        score = float(run.per_seed("eval/success").mean())
        if variant(run) and not is_counterfactual(run) and score >= BASELINE:
            return judging.disagreement(
                f"clean {base} at pimbot's defaults; with the {variant(run)} "
                f"({run.setting}) {score:.2f} in the same environment; {CODE_LOGS}",
                None,
            )
    transfer = [r for r in same_size if is_counterfactual(r)]
    for run in transfer:
        score = float(run.per_seed("eval/success").mean())
        if score >= BASELINE:
            return verdicts.refuted(
                verdicts.PAPER_ENVIRONMENT,
                f"clean {base}; with a reward-transfer action (counterfactual, {run.setting}) "
                f"{score:.2f}: the paper's env has no pay-back channel",
            )
    return against_original(
        f"clean {base} at pimbot's defaults; no transfer counterfactual that succeeds",
        originals,
        clean,
    )


def _parts_text(parts: dict) -> str:
    return "; ".join(f"{name}: {v.reason or v.label}" for name, v in parts.items())


def voi_roles(run: RunRecord) -> str | None:
    """Final VoI by role ("lever → door 0.12; …"), read from the train/voi_role/ columns."""
    curves = run.curves
    env_id = run.identity["env_id"]  # its registry entry names the actions, where it does
    names = envs.spec(env_id).action_names if env_id in envs.registered() else ()
    keys = sorted(k for k in curves.values[curves.seeds[0]] if k.startswith("train/voi_role/"))
    if not keys:
        return None
    parts = []
    for key in keys:
        x, y = key.removeprefix("train/voi_role/action_").split("_to_action_")

        def name(a):
            return names[int(a)] if names and int(a) < len(names) else f"a{a}"

        parts.append(f"{name(x)} → {name(y)} {curves.final(key).mean():.3f}")
    return "; ".join(parts)


def _setting_kind(run: RunRecord) -> str:
    if is_counterfactual(run):
        return " (counterfactual: reward-transfer action)"
    return f" ({CODE_BATCH})" if is_code_setting(run) else ""


def settings_table(runs: list[RunRecord]) -> Table | None:
    """Success and VoI by role per Reciprocator setting (ours, the original code's, the
    transfer counterfactual, 2048 games per update) where the runs logged VoI by role."""
    rows = []
    for run in sorted(runs, key=lambda r: (natural_key(r.env), r.name)):
        if run.learner != LEARNER:
            continue
        rows.append(
            [
                run.env,
                setting_label(run) + _setting_kind(run),
                run.condition,
                run.seeds,
                run.iterations,
                estimate(run.per_seed("eval/success")),
                voi_roles(run),
                run.setting,
            ]
        )
    if not any(row[6] for row in rows):
        return None
    header = ["env", "setting", "condition", "seeds", "updates", f"success {INTERVAL}"]
    header += ["final VoI by role (j's action → i's)", "run"]
    return Table(
        header, rows, "C7: success and VoI by role per setting", name="reciprocator_settings"
    )


def voi_table(runs: list[RunRecord]) -> Table | None:
    """Final VoI by role per Reciprocator run: ER's lever pullers and door agents (the
    action taken on the step), and the adversary against the others when attacked."""
    rows = []
    for run in sorted(runs, key=lambda r: (natural_key(r.env), condition_key(r.condition))):
        if run.learner != LEARNER:
            continue
        n, a = run.num_agents, run.adversary
        others = [j for j in range(n) if j != a]
        curves = run.curves  # train/ columns: summary.json has eval/ only
        given = [curves.final(f"train/voi/agent_{a}_to_agent_{j}") for j in others]
        received = [curves.final(f"train/voi/agent_{j}_to_agent_{a}") for j in others]
        if any(v.size == 0 for v in given + received):
            continue  # a run stored before the pair metrics were logged
        row = [run.env, learner_label(run), run.condition, voi_kind(run)]
        row += [estimate(sum(given) / len(given)), estimate(sum(received) / len(received))]
        for metric in VOI_ROLES.values():
            values = curves.final(metric)
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
    Stag Hunt rows show their stag captures per episode too."""
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
        if (captures := run.per_seed(CAPTURES)).size:
            row["stag_captures"] = estimate(captures)
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
    header = ["env", "learner", "condition", "seeds", "iterations", f"final success {INTERVAL}"]
    header += [f"attacked − clean success {INTERVAL}", f"adversary margin (env) {INTERVAL}"]
    header += [f"stag captures / episode {INTERVAL}", "run"]
    keys = ["env", "learner", "condition", "seeds", "iterations", "success", "effect_success"]
    keys += ["margin", "stag_captures", "run"]
    return Table(header, [[r[k] for k in keys] for r in rows], name="reciprocators")


def fig_fidelity(runs: list[RunRecord], path) -> str:
    """2-player IPD: cooperation and per-agent return, R vs R, NL vs NL, R vs NL (agent 0 NL).
    Returns what the bands are ("" where no such run: nothing written)."""
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
        return ""
    fig, axes = plots.plt.subplots(1, len(cases), figsize=(4.2 * len(cases), 3.2), squeeze=False)
    drawn = []
    for ax, (run, label) in zip(axes.flat, cases, strict=True):
        drawn.append(plots.band(ax, run.curves, "eval/success", "mutual cooperation", "black"))
        steps = float(run.identity["env_params"].get("max_steps", 5))
        for agent, color in ((0, "tab:green"), (1, "tab:blue")):
            iterations, values = run.curves.matrix(f"eval/return_env/agent_{agent}")
            # Per-step return, −3 … 0, drawn on the rate axis as (return/step + 3)/3.
            mean = ((values / steps + 3.0) / 3.0).mean(axis=0)
            ax.plot(iterations, mean, color=color, lw=1, ls="--", label=f"agent {agent} return")
        title = label + (f" [{variant(run)}]" if variant(run) else "")
        ax.set_title(title)
        ax.set_ylim(-0.05, 1.05)
        ax.set_xlabel("iteration")
        ax.set_ylabel("rate; (return/step + 3)/3")
    fig.suptitle(f"2-player IPD fidelity (mean over {seeds_text(r for r, _ in cases)})")
    bands = plots.band_text(drawn)
    plots.legend_below(fig, axes.flat, [plots.band_handle(bands)])
    plots.save(fig, path)
    return bands
