"""Stag Hunt: LIO's baseline vs both ADMOs, claim C6 and Fig. 6 (group `stag_hunt`).

C6 is judged on the quantity the PIMbot code logs and plots as Stag Hunt "success": the
adversary's (its agent 1's, our agent 0's) summed episode env reward / 5, unclipped
(`lio/alg/train_lio_staghunt_admo.py` of UCR-Intelligent-Robotics-Lab/greedy_agent,
evaluated by `evaluate.test_staghunt`). Two ADMOs are judged: the paper's (`admo`,
disrupt) and the code's Stag Hunt one (`negated_env_reward`, docs/attacks.md). Team
success and stag captures stand beside it; the captures are compared with a uniformly
random team's, computed here from the environment (`random_team_captures`).
"""

from __future__ import annotations

import jax
import numpy as np

from pimbot import envs
from pimbot.analysis import judging, plots, verdicts
from pimbot.analysis.claims import Claim, Comparison, deciding_part, summarized
from pimbot.analysis.document import Context, Section, seeds_text
from pimbot.analysis.runs import CLEAN, RunRecord, RunTable, natural_key
from pimbot.analysis.tables import INTERVAL, Estimate, Table, difference, estimate
from pimbot.attacks import NegatedEnvReward
from pimbot.statistics import interval_text

GROUP = "stag_hunt"
PAPER_ADMO = "admo_disrupt"
CODE_ADMO = NegatedEnvReward.name
ATTACKED = (PAPER_ADMO, CODE_ADMO)
"""The ADMOs C6 judges, by condition label: the paper's (Alg. 1) and the code's."""
SUCCESS = "eval/success"
CAPTURES = "eval/stag_captures"
RANDOM_EPISODES = 20_000
"""Episodes of the random team per environment (the N = 2 rate's standard error ≈ 0.002)."""
RANDOM_SEED = 0


def code_metric(agent: int) -> str:
    """The code's Stag Hunt "success" of `agent`: its episode env return / 5 (the env's
    per-step metric `return_over_stag_payoff`, summed over the episode)."""
    return f"eval/return_over_stag_payoff/agent_{agent}"


def random_team_captures(env_id: str, env_params: dict, episodes: int, seed: int) -> Estimate:
    """Stag captures per episode of a team acting uniformly at random, from the env itself.

    `episodes` independent episodes of `env.max_steps` steps, every hunter drawing each
    action uniformly; the key is `jax.random.key(seed)`, so the figure is deterministic.
    Returns the mean with a normal 95 % interval (1.96 standard errors, cut at 0).
    """
    env = envs.make(env_id, **env_params)

    def episode(key):
        reset_key, steps_key = jax.random.split(key)
        _, state = env.reset(reset_key)

        def one(state, key):
            act_key, step_key = jax.random.split(key)
            actions = jax.random.randint(act_key, (env.num_agents,), 0, env.num_actions)
            _, state, _, _, info = env.step(step_key, state, actions)
            return state, info["stag_captures"]

        _, captures = jax.lax.scan(one, state, jax.random.split(steps_key, env.max_steps))
        return captures.sum()

    keys = jax.random.split(jax.random.key(seed), episodes)
    counts = np.asarray(jax.jit(jax.vmap(episode))(keys), dtype=float)
    half = 1.96 * counts.std(ddof=1) / np.sqrt(episodes) if episodes > 1 else 0.0
    mean = float(counts.mean())
    return Estimate(mean, max(mean - half, 0.0), mean + half, digits=4)


def section(table: RunTable, ctx: Context) -> Section | None:
    runs = table.group(GROUP)
    if not runs:
        return None
    ctx.claim(runs)
    envs_seen = sorted({r.env for r in runs}, key=natural_key)
    rows, parts, lines, numbers, headlines = [], {}, [], [], {}
    for env in envs_seen:
        of_env = {r.condition: r for r in runs if r.env == env}
        clean = of_env.get(CLEAN)
        attacked = {c: of_env[c] for c in ATTACKED if c in of_env}
        if clean is None:
            parts[env] = verdicts.not_run(f"{env}: no clean run")
            continue
        random_rate = random_team_captures(
            clean.identity["env_id"], clean.identity["env_params"], RANDOM_EPISODES, RANDOM_SEED
        )
        judged, line = judge_env(env, clean, attacked, random_rate)
        parts.update(judged)
        headlines.update(part_numbers(env, clean, attacked, random_rate))
        lines.append(line)
        numbers += comparisons(env, clean, attacked, random_rate)
        rows += [table_row(env, run, clean, random_rate) for run in (clean, *attacked.values())]
    return Section(
        "Stag Hunt: LIO vs ADMO (C6)",
        text=[
            "The code's success = the adversary's own episode env reward / 5, unclipped: "
            "the quantity the PIMbot code logs and plots as Stag Hunt success (its agent 1, "
            "our agent 0, the default adversary; docs/experiments.md). Team success = the "
            "hunters' mean episode env reward / 5, clipped at 1 (docs/environments.md). A "
            "hare pays +1 whatever the others do, so both rise without any stag hunting: "
            "the stag captures per episode are shown beside them with a uniformly random "
            f"team's, computed from the environment ({RANDOM_EPISODES:,} episodes, "
            "95 % normal interval). Two ADMOs: the paper's (admo, disrupt) and the code's "
            "Stag Hunt one (negated_env_reward: the adversary learns on its env reward "
            f"negated; docs/attacks.md). {interval_text(r.seeds for r in runs)}."
        ],
        tables=[Table(HEADER, rows, name="stag_hunt")],
        figures=figures(runs, envs_seen, table.colors, ctx),
        claims=[c6(parts, lines, numbers, headlines)],
    )


HEADER = [
    "env",
    "condition",
    "seeds",
    f"code's success: adversary return / 5 {INTERVAL}",
    f"Δ code's success vs clean {INTERVAL}",
    f"team success {INTERVAL}",
    f"stag captures / episode {INTERVAL}",
    "random team's captures [95 % CI]",
]


def table_row(env: str, run: RunRecord, clean: RunRecord, random_rate: Estimate) -> list:
    """One run's row of the Stag Hunt table (the code's metric of the run's adversary)."""
    column = code_metric(run.adversary)
    delta = None if run is clean else difference(run.per_seed(column), clean.per_seed(column))
    return [
        env,
        run.condition,
        run.per_seed(SUCCESS).size,
        estimate(run.per_seed(column)),
        delta,
        estimate(run.per_seed(SUCCESS)),
        estimate(run.per_seed(CAPTURES)),
        random_rate,
    ]


def figures(runs: list[RunRecord], envs_seen: list[str], colors: dict, ctx: Context) -> list:
    """Fig. 6 (the code's success), 6b (stag captures) and 6c (team success) per N."""
    counts = ", ".join(str(n) for n in sorted({r.num_agents for r in runs}))
    panels = plots.condition_panels(runs, envs_seen, colors)
    out = []
    for name, number, column, label in (
        ("fig6_stag_hunt.png", "6", code_metric(0), "code's success (agent 0 return / 5)"),
        ("fig6b_stag_captures.png", "6b", CAPTURES, "stag captures / episode"),
        ("fig6c_team_success.png", "6c", SUCCESS, "team success"),
    ):
        path, figure = ctx.figure(name)
        if bands := plots.curve_panels(panels, column, label, path):
            figure.caption = (
                f"Fig. {number}: Stag Hunt N = {counts}, {label} (mean over "
                f"{seeds_text(runs)}, {bands})"
            )
            out.append(figure)
    return out


def comparisons(
    env: str, clean: RunRecord, attacked: dict[str, RunRecord], random_rate: Estimate
) -> list[Comparison]:
    """C6's paper | original code | pimbot rows of one N (no original-code log covers it)."""
    horizon = f"{clean.iterations:,} it"
    rows = [
        Comparison(f"{env} clean code's-success rise", horizon, "rises", None, str(rise(clean, 0))),
        Comparison(
            f"{env} clean stag captures / episode",
            horizon,
            "(not stated)",
            None,
            f"{estimate(clean.per_seed(CAPTURES))} (random team {random_rate})",
        ),
    ]
    for condition, run in attacked.items():
        final = estimate(run.per_seed(code_metric(run.adversary)))
        rows.append(
            Comparison(f"{env} {condition} final code's success", horizon, "→ 0", None, str(final))
        )
    return rows


def part_numbers(
    env: str, clean: RunRecord, attacked: dict[str, RunRecord], random_rate: Estimate
) -> dict[str, str]:
    """The number of each C6 part of one N (by part name), for the report's summary."""
    captures = estimate(clean.per_seed(CAPTURES), digits=4)
    out = {
        f"{env} code's success rises": f"{env} clean rise of the code's success {rise(clean, 0)}",
        f"{env} stag captures above a random team's": (
            f"{env} clean stag captures {captures} vs a random team's {random_rate}"
        ),
    }
    for condition, run in attacked.items():
        out[f"{env} {condition} → 0"] = f"{env} {condition} Δ code's success {fall(clean, run)}"
    return out


WHY_REFUTED = {
    verdicts.PAPER_METRIC: "the code's success rises on hares: the clean team captures no "
    "more stags than a random team, so the paper's success is no stag hunt",
    verdicts.PAPER_CODE: "the paper's ADMO (Alg. 1) does not lower the code's success; the "
    "code's own Stag Hunt ADMO (the adversary's reward negated) does",
}
"""The summary's clause of why for a C6 part refuted with each cause."""


def c6(
    parts: dict[str, verdicts.Verdict],
    lines: list[str],
    numbers: list,
    headlines: dict[str, str] | None = None,
) -> Claim:
    counts = {k: sum(v.kind == k for v in parts.values()) for k in verdicts.KINDS}
    verdict = verdicts.combine(parts)
    found = deciding_part(verdict)
    why = WHY_REFUTED.get(found[1].causes[0], "") if found and found[1].causes else ""
    return Claim(
        "C6",
        "Stag Hunt N = 2, 3, 4: LIO baseline success rises; ADMO drives it toward 0",
        "per N, on the code's success (the adversary's own episode env reward / 5): the "
        "interval of the clean runs' rise (final − first evaluation, per seed) > 0; for each "
        "ADMO (the paper's admo disrupt, the code's negated_env_reward) the interval of its "
        "final minus the clean final < 0 (the paper gives the direction, no number). Stag "
        "captures: the clean final's interval above a random team's (computed from the "
        "env); at or below it, the paper's rising success is hares, a property of its metric",
        "; ".join(lines) or "no runs",
        verdict,
        ", ".join(f"{n} {verdicts.LABELS[k].split(' (')[0]}" for k, n in counts.items() if n)
        + f" of {len(parts)} parts",
        numbers,
        **summarized(
            verdict,
            headlines or {},
            agreed="in every N the clean team's success rises, its stag captures beat a "
            "random team's, and both ADMOs drive the success down",
            why=why,
        ),
    )


def judge_env(
    env: str, clean: RunRecord, attacked: dict[str, RunRecord], random_rate: Estimate
) -> tuple[dict, str]:
    """C6's parts for one N: the clean rise of the code's success, the clean stag captures
    against a random team's, and each ADMO's fall of the code's success."""
    parts = {}
    gain = rise(clean, 0)
    parts[f"{env} code's success rises"] = judging.above(
        gain, 0.0, "clean rise"
    ) or judging.disagreement(f"clean rise of the code's success {gain} not above 0", None)
    captures = estimate(clean.per_seed(CAPTURES), digits=4)
    parts[f"{env} stag captures above a random team's"] = captures_verdict(
        captures, random_rate, parts[f"{env} code's success rises"]
    )
    falls = {c: fall(clean, run) for c, run in attacked.items()}
    for condition in ATTACKED:
        name = f"{env} {condition} → 0"
        if condition not in attacked:
            parts[name] = verdicts.not_run(f"{env}: no {condition} run")
            continue
        parts[name] = fall_verdict(condition, falls)
    fell = ", ".join(
        f"{c} final {estimate(run.per_seed(code_metric(run.adversary)))}, Δ {falls[c]}"
        for c, run in attacked.items()
    )
    line = (
        f"{env}: clean rise of the code's success {gain}; clean captures {captures} vs a "
        f"random team's {random_rate}; " + (fell or "no ADMO run")
    )
    return parts, line


def captures_verdict(
    captures: Estimate | None, random_rate: Estimate, metric_rises: verdicts.Verdict
) -> verdicts.Verdict:
    """Clean stag captures above a random team's; at or below it while the code's success
    rises, the paper's metric counts hares: "the paper (contradicts its own metric)"."""
    if captures is None:
        return verdicts.inconclusive("stag captures not logged by these runs")
    above = judging.above(captures, random_rate.hi, "clean captures")
    if above is not None:
        return above
    reason = (
        f"clean captures {captures} not above a random team's {random_rate} (computed from the env)"
    )
    if metric_rises.kind != verdicts.REPRODUCED:
        return verdicts.inconclusive(f"{reason}, and the code's success does not rise either")
    return verdicts.refuted(
        verdicts.PAPER_METRIC,
        f"{reason}, while the code's success rises: a hare pays +1 whatever the others do, "
        "so the paper's success measures hares, not the stag hunt it describes",
    )


def fall(clean: RunRecord, run: RunRecord) -> Estimate | None:
    """The attacked run's final code's success minus the clean run's, of its adversary."""
    column = code_metric(run.adversary)
    return difference(run.per_seed(column), clean.per_seed(column))


def fall_verdict(condition: str, falls: dict[str, Estimate | None]) -> verdicts.Verdict:
    """ "ADMO drives it toward 0" for one ADMO: its Δ interval below 0 reproduces it. The
    paper's admo failing where the code's negated_env_reward reproduces it is the paper
    contradicting its own code (its Stag Hunt ADMO negates the adversary's reward)."""
    delta = falls[condition]
    if delta is None:
        return verdicts.inconclusive(f"{condition}: the code's success not logged")
    if delta.hi < 0:
        return verdicts.reproduced(f"{condition} Δ {delta}")
    if delta.mean < 0:
        return verdicts.inconclusive(f"{condition} Δ {delta}: the interval includes 0")
    reason = f"{condition} Δ {delta} not below 0"
    code_fall = falls.get(CODE_ADMO)
    if condition == PAPER_ADMO and code_fall is not None and code_fall.hi < 0:
        return verdicts.refuted(
            verdicts.PAPER_CODE,
            f"{reason}, while the code's Stag Hunt ADMO (the adversary's env reward negated, "
            f"lio/alg/train_lio_staghunt_admo.py) gives Δ {code_fall}: the paper's falling "
            "curve is its code's attack, not its Alg. 1",
        )
    return judging.disagreement(reason, None)


def rise(run: RunRecord, agent: int | None = None) -> Estimate | None:
    """Mean over seeds of final − first evaluation of the code's success of `agent` (team
    success when None), with its interval (None when the run did not log it)."""
    column = SUCCESS if agent is None else code_metric(agent)
    final = run.per_seed(column)
    if final.size == 0:
        return None
    return estimate(final - run.curves.first(column), signed=True)
