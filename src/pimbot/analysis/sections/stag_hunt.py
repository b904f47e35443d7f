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


def section(table: RunTable, ctx: Context) -> Section | None:
    runs = table.group(GROUP)
    if not runs:
        return None
    ctx.claim(runs)
    envs = sorted({r.env for r in runs}, key=natural_key)
    path, figure = ctx.figure(
        "fig6_stag_hunt.png",
        f"Fig. 6: Stag Hunt N = {', '.join(str(n) for n in sorted({r.num_agents for r in runs}))} "
        f"(mean over {seeds_text(runs)}, 95 % bootstrap band)",
    )
    panels = plots.condition_panels(runs, envs, table.colors)
    written = plots.curve_panels(panels, "eval/success", "success", path)
    rows, parts, ok, rising, low = [], [], True, 0, 0
    for env in envs:
        clean = next((r for r in runs if r.env == env and r.condition == CLEAN), None)
        admo = next((r for r in runs if r.env == env and r.condition == ATTACKED), None)
        if clean is None or admo is None:
            ok = False
            parts.append(f"{env}: not run")
            continue
        gain = rise(clean)
        final = estimate(admo.per_seed("eval/success"))
        ok &= gain.lo > 0 and final.mean <= 0.1
        rising += gain.lo > 0
        low += final.mean <= 0.1
        parts.append(f"{env}: clean rise {gain}, ADMO final {final}")
        for run in (clean, admo):
            success = run.per_seed("eval/success")
            rows.append([env, run.condition, success.size, estimate(success), rise(run)])
    claim = Claim(
        "C6",
        "Stag Hunt N = 2, 3, 4: LIO baseline success rises; ADMO drives it toward 0",
        "95 % CI of the clean runs' rise (final − first evaluation, per seed) > 0, and ADMO "
        "(disrupt) final success ≤ 0.1, for every N",
        "; ".join(parts),
        verdict(ok),
        f"clean rise CI > 0 in {rising}/{len(envs)}; ADMO final ≤ 0.1 in {low}/{len(envs)}",
    )
    header = ["env", "condition", "seeds", "final success [CI]", "rise [CI]"]
    return Section(
        "Stag Hunt: LIO vs ADMO (C6)",
        text=["Success = episode env reward / 5 (environments spec)."],
        tables=[Table(header, rows, name="stag_hunt")],
        figures=[figure] if written else [],
        claims=[claim],
    )


def rise(run: RunRecord) -> Estimate:
    """Mean over seeds of final − first-evaluation success, with a 95 % bootstrap CI."""
    rows = store.read_metrics(run.path)
    seeds = sorted({int(r["seed"]) for r in rows})
    first = []
    for seed in seeds:
        mine = [r for r in rows if int(r["seed"]) == seed]
        first.append(float(min(mine, key=lambda r: int(r["iteration"]))["eval/success"]))
    return estimate(run.per_seed("eval/success") - np.array(first), signed=True)
