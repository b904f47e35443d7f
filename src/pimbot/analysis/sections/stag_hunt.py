"""Stag Hunt: LIO's baseline vs ADMO (disrupt), claim C6 and Fig. 6 (group `stag_hunt`)."""

from __future__ import annotations

from pimbot.analysis import judging, plots, verdicts
from pimbot.analysis.claims import Claim, Comparison
from pimbot.analysis.document import Context, Section, seeds_text
from pimbot.analysis.runs import CLEAN, RunRecord, RunTable, natural_key
from pimbot.analysis.tables import INTERVAL, Estimate, Table, difference, estimate
from pimbot.statistics import interval_text

GROUP = "stag_hunt"
ATTACKED = "admo_disrupt"
SUCCESS = "eval/success"
CAPTURES = "eval/stag_captures"
TOWARD_ZERO = 0.1
"""ADMO "drives success toward 0": mean final success at most this."""
CODE_SUCCESS = "eval/return_over_stag_payoff/agent_0"
"""The quantity the PIMbot code logs and plots as Stag Hunt "success": agent 0's (its A1)
episode env return / 5, unclipped."""


def section(table: RunTable, ctx: Context) -> Section | None:
    runs = table.group(GROUP)
    if not runs:
        return None
    ctx.claim(runs)
    envs = sorted({r.env for r in runs}, key=natural_key)
    rows, parts, lines, numbers = [], {}, [], []
    for env in envs:
        clean = next((r for r in runs if r.env == env and r.condition == CLEAN), None)
        admo = next((r for r in runs if r.env == env and r.condition == ATTACKED), None)
        if clean is None or admo is None:
            parts[env] = verdicts.not_run(f"{env}: no clean or ADMO run")
            continue
        judged, line = judge_env(env, clean, admo)
        parts.update(judged)
        lines.append(line)
        numbers += comparisons(env, clean, admo)
        rows += [table_row(env, run) for run in (clean, admo)]
    header = [
        "env",
        "condition",
        "seeds",
        f"final success {INTERVAL}",
        f"rise {INTERVAL}",
        f"stag captures / episode {INTERVAL}",
        f"captures rise {INTERVAL}",
        "random team's captures",
        f"code's success: agent 0 return / 5 {INTERVAL}",
    ]
    return Section(
        "Stag Hunt: LIO vs ADMO (C6)",
        text=[
            "Success = the hunters' mean episode env reward / 5, clipped at 1 "
            "(docs/environments.md); hares alone can make it high, so the stag captures per "
            "episode are shown beside it with a uniformly random team's (docs/environments.md, "
            "simulated under "
            "the original rules). The last column is the quantity the PIMbot code logs and "
            "plots as Stag Hunt success: its agent 1's (our agent 0's) episode env reward / "
            "5, unclipped; that agent is also the default ADMO adversary, whose reward the "
            "code's ADMO script negates. Runs made before these metrics existed show –. "
            f"{interval_text(r.seeds for r in runs)}."
        ],
        tables=[Table(header, rows, name="stag_hunt")],
        figures=figures(runs, envs, table.colors, ctx),
        claims=[c6(parts, lines, numbers)],
    )


def figures(runs: list[RunRecord], envs: list[str], colors: dict, ctx: Context) -> list:
    """Fig. 6 (success) and 6b (stag captures) per N, clean and ADMO; those with data."""
    counts = ", ".join(str(n) for n in sorted({r.num_agents for r in runs}))
    panels = plots.condition_panels(runs, envs, colors)
    out = []
    for name, number, column, label in (
        ("fig6_stag_hunt.png", "6", SUCCESS, "success"),
        ("fig6b_stag_captures.png", "6b", CAPTURES, "stag captures / episode"),
    ):
        path, figure = ctx.figure(name)
        if bands := plots.curve_panels(panels, column, label, path):
            figure.caption = (
                f"Fig. {number}: Stag Hunt N = {counts}, {label} (mean over "
                f"{seeds_text(runs)}, {bands})"
            )
            out.append(figure)
    return out


def comparisons(env: str, clean: RunRecord, admo: RunRecord) -> list[Comparison]:
    """C6's paper | original code | pimbot rows of one N (no original-code log covers it)."""
    return [
        Comparison(
            f"{env} clean success rise", f"{clean.iterations:,} it", "rises", None, str(rise(clean))
        ),
        Comparison(
            f"{env} ADMO final success",
            f"{admo.iterations:,} it",
            "→ 0",
            None,
            str(estimate(admo.per_seed(SUCCESS))),
        ),
    ]


def table_row(env: str, run: RunRecord) -> list:
    """One run's row of the Stag Hunt table."""
    return [
        env,
        run.condition,
        run.per_seed(SUCCESS).size,
        estimate(run.per_seed(SUCCESS)),
        rise(run),
        estimate(run.per_seed(CAPTURES)),
        rise(run, CAPTURES),
        plots.RANDOM_POLICY.get(env, {}).get(CAPTURES),
        estimate(run.per_seed(CODE_SUCCESS)),
    ]


def c6(parts: dict[str, verdicts.Verdict], lines: list[str], numbers: list) -> Claim:
    counts = {k: sum(v.kind == k for v in parts.values()) for k in verdicts.KINDS}
    return Claim(
        "C6",
        "Stag Hunt N = 2, 3, 4: LIO baseline success rises; ADMO drives it toward 0",
        "per N: the interval of the clean runs' rise of success (final − first evaluation, "
        "per seed) > 0, and of their rise of stag captures > 0; ADMO (disrupt) mean final "
        f"success ≤ {TOWARD_ZERO:g}. Where ours is not, but the code's metric (agent 0's own "
        "return / 5) is, the paper's curve measures the adversary's reward",
        "; ".join(lines) or "no runs",
        verdicts.combine(parts),
        ", ".join(f"{n} {verdicts.LABELS[k].split(' (')[0]}" for k, n in counts.items() if n)
        + f" of {len(parts)} parts",
        numbers,
    )


def judge_env(env: str, clean: RunRecord, admo: RunRecord) -> tuple[dict, str]:
    """C6's parts for one N: the clean rise of success and of stag captures, and ADMO's
    final success (with the code's metric as the cause where ours disagrees)."""
    parts = {}
    gain = rise(clean)
    parts[f"{env} success rises"] = judging.above(gain, 0.0, "rise") or judging.disagreement(
        f"clean rise {gain} not above 0", None
    )
    captures_gain = rise(clean, CAPTURES)
    parts[f"{env} stag captures rise"] = judging.above(
        captures_gain, 0.0, "captures rise"
    ) or judging.disagreement(f"clean captures rise {captures_gain} not above 0", None)
    final = estimate(admo.per_seed(SUCCESS))
    code = estimate(admo.per_seed(CODE_SUCCESS))
    if final.mean <= TOWARD_ZERO:
        parts[f"{env} ADMO → 0"] = verdicts.reproduced(f"ADMO final {final}")
    elif code is not None and code.mean <= TOWARD_ZERO:
        parts[f"{env} ADMO → 0"] = verdicts.refuted(
            verdicts.PAPER_METRIC,
            f"team success under ADMO {final}, but the code's 'success' (the adversary's own "
            f"return / 5) {code}",
        )
    else:
        parts[f"{env} ADMO → 0"] = judging.disagreement(
            f"ADMO final {final}" + (f", code's metric {code}" if code is not None else ""), None
        )
    d_success = difference(admo.per_seed(SUCCESS), clean.per_seed(SUCCESS))
    d_captures = difference(admo.per_seed(CAPTURES), clean.per_seed(CAPTURES))
    line = (
        f"{env}: clean rise {gain}, captures rise {captures_gain}; ADMO final {final}, "
        f"Δ success {d_success}, Δ captures {d_captures}, code's metric under ADMO {code}"
    )
    return parts, line


def rise(run: RunRecord, column: str = SUCCESS) -> Estimate | None:
    """Mean over seeds of final − first evaluation of `column`, with its interval (None
    when the run did not log it)."""
    final = run.per_seed(column)
    if final.size == 0:
        return None
    return estimate(final - run.curves.first(column), signed=True)
