"""Stag Hunt: LIO's baseline vs ADMO (disrupt), claim C6 and Fig. 6 (group `stag_hunt`)."""

from __future__ import annotations

import numpy as np

from pimbot.analysis import plots
from pimbot.analysis.document import Claim, Context, Section, seeds_text, verdict
from pimbot.analysis.runs import CLEAN, RunRecord, RunTable, natural_key
from pimbot.analysis.tables import Estimate, Table, estimate
from pimbot.experiment import store

GROUP = "stag_hunt"
ATTACKED = "admo_disrupt"
SUCCESS = "eval/success"
CAPTURES = "eval/stag_captures"
CODE_SUCCESS = "eval/return_over_stag_payoff/agent_0"
"""The quantity the PIMbot code logs and plots as Stag Hunt "success": agent 0's (its A1)
episode env return / 5, unclipped."""


def section(table: RunTable, ctx: Context) -> Section | None:
    runs = table.group(GROUP)
    if not runs:
        return None
    ctx.claim(runs)
    envs = sorted({r.env for r in runs}, key=natural_key)
    counts = ", ".join(str(n) for n in sorted({r.num_agents for r in runs}))
    band = f"mean over {seeds_text(runs)}, 95 % bootstrap band"
    panels = plots.condition_panels(runs, envs, table.colors)
    figures = []
    for name, number, column, label in (
        ("fig6_stag_hunt.png", "6", SUCCESS, "success"),
        ("fig6b_stag_captures.png", "6b", CAPTURES, "stag captures / episode"),
    ):
        caption = f"Fig. {number}: Stag Hunt N = {counts}, {label} ({band})"
        path, figure = ctx.figure(name, caption)
        if plots.curve_panels(panels, column, label, path):
            figures.append(figure)
    rows, parts, ok, rising, low = [], [], True, 0, 0
    for env in envs:
        clean = next((r for r in runs if r.env == env and r.condition == CLEAN), None)
        admo = next((r for r in runs if r.env == env and r.condition == ATTACKED), None)
        if clean is None or admo is None:
            ok = False
            parts.append(f"{env}: not run")
            continue
        gain = rise(clean)
        final = estimate(admo.per_seed(SUCCESS))
        ok &= gain.lo > 0 and final.mean <= 0.1
        rising += gain.lo > 0
        low += final.mean <= 0.1
        part = f"{env}: clean rise {gain}, ADMO final {final}"
        captures = estimate(clean.per_seed(CAPTURES))
        if captures is not None:
            part += (
                f"; stag captures/episode clean {captures} (rise {rise(clean, CAPTURES)}), "
                f"ADMO {estimate(admo.per_seed(CAPTURES))}"
            )
        parts.append(part)
        for run in (clean, admo):
            rows.append(
                [
                    env,
                    run.condition,
                    run.per_seed(SUCCESS).size,
                    estimate(run.per_seed(SUCCESS)),
                    rise(run),
                    estimate(run.per_seed(CAPTURES)),
                    rise(run, CAPTURES),
                    estimate(run.per_seed(CODE_SUCCESS)),
                ]
            )
    claim = Claim(
        "C6",
        "Stag Hunt N = 2, 3, 4: LIO baseline success rises; ADMO drives it toward 0",
        "95 % CI of the clean runs' rise (final − first evaluation, per seed) > 0, and ADMO "
        "(disrupt) final success ≤ 0.1, for every N",
        "; ".join(parts),
        verdict(ok),
        f"clean rise CI > 0 in {rising}/{len(envs)}; ADMO final ≤ 0.1 in {low}/{len(envs)}",
    )
    header = [
        "env",
        "condition",
        "seeds",
        "final success [CI]",
        "rise [CI]",
        "stag captures / episode [CI]",
        "captures rise [CI]",
        "code's success: agent 0 return / 5 [CI]",
    ]
    return Section(
        "Stag Hunt: LIO vs ADMO (C6)",
        text=[
            "Success = the hunters' mean episode env reward / 5, clipped at 1 (environments "
            "spec); hares alone can make it high, so the stag captures per episode are shown "
            "beside it (a uniformly random team: ~0.067 for N = 2, ~0.003 for N = 3, ~1e-4 "
            "for N = 4). The last column is the quantity the PIMbot code logs and plots as "
            "Stag Hunt success: agent 0's (its A1's) episode env reward / 5, unclipped; "
            "agent 0 is also the default ADMO adversary. Runs made before these metrics "
            "existed show –."
        ],
        tables=[Table(header, rows, name="stag_hunt")],
        figures=figures,
        claims=[claim],
    )


def rise(run: RunRecord, column: str = SUCCESS) -> Estimate | None:
    """Mean over seeds of final − first evaluation of `column`, with a 95 % bootstrap CI
    (None when the run did not log it)."""
    final = run.per_seed(column)
    if final.size == 0:
        return None
    rows = store.read_metrics(run.path)
    seeds = sorted({int(r["seed"]) for r in rows})
    first = []
    for seed in seeds:
        mine = [r for r in rows if int(r["seed"]) == seed]
        first.append(float(min(mine, key=lambda r: int(r["iteration"]))[column]))
    return estimate(final - np.array(first), signed=True)
