"""What the claim rules measure on runs: convergence at equal horizons, interval tests,
direction tests over seeds where the paper gives a direction and no number (a fall to ≈ 0,
above 0, earlier: permutation and Mann–Whitney tests, `pimbot.statistics`), what an
environment's rules make impossible, and the cause of a disagreement.

Pure functions of measured values (a run's `analysis.curves.Curves`, estimates over seeds)
and of the registered environments; the sections turn their results into `Claim`s.
"""

from __future__ import annotations

import itertools

import numpy as np

from pimbot.analysis import verdicts
from pimbot.analysis.tables import Estimate, estimate
from pimbot.analysis.verdicts import Verdict
from pimbot.statistics import (
    MIN_SEEDS_FOR_CI,
    difference_p_value,
    rank_p_value,
    sign_p_value,
)

PAPER_ATTACK_BUDGET = 25_000
"""PIMbot ran its ER attacks for 20–25k iterations (docs/experiments.md)."""


# --- convergence ------------------------------------------------------------------------


def median_iteration(values: list) -> float | None:
    """The median of per-seed iterations, a seed that never got there counted as +∞; None
    where the median is +∞."""
    if not values:
        return None
    median = float(np.median([np.inf if v is None else v for v in values]))
    return median if np.isfinite(median) else None


def iteration_text(value: float | None) -> str:
    return "never" if value is None or np.isinf(value) else f"{value / 1000:.1f}k"


# --- interval tests ---------------------------------------------------------------------


def above(est: Estimate | None, bound: float, what: str) -> Verdict | None:
    """`what` > bound: reproduced if the whole interval is above; refuted-evidence (None
    returned for the caller to classify) if the interval lies at or below, or a ≥ 5-seed CI
    straddles with its mean at or below; inconclusive if it straddles with the mean above."""
    if est is None:
        return verdicts.inconclusive(f"{what} not logged by these runs")
    if est.lo > bound:
        return verdicts.reproduced(f"{what} {est}")
    if est.hi <= bound or est.mean <= bound:
        return None
    return verdicts.inconclusive(f"{what} {est}: the interval includes {bound:g}")


def below(est: Estimate, bound: float, what: str) -> Verdict | None:
    """`what` < bound, the mirror of `above`: reproduced if the whole interval is below;
    None (evidence against, for the caller to classify) if the interval lies at or above,
    or straddles with its mean at or above; inconclusive if it straddles with the mean
    below."""
    if est.hi < bound:
        return verdicts.reproduced(f"{what} {est} < {bound:g}")
    if est.lo >= bound or est.mean >= bound:
        return None
    return verdicts.inconclusive(f"{what} {est}: the interval includes {bound:g}")


def falls_to_zero(
    early: np.ndarray, final: np.ndarray, resolution: float, what: str = "success"
) -> Verdict | None:
    """`what` falls to ≈ 0, in the paper's words only: per seed (the same seeds, paired)
    the final value is below the early one (a sign-flip permutation test of final − early,
    one-sided p < DIFFERS_P), and the interval of the final mean reaches down to
    `resolution` (the smallest nonzero value the metric can take: it cannot be told from
    0). None (evidence against, for the caller to classify) where the final's interval
    lies above `resolution` or the final is significantly above the early value;
    inconclusive where the seeds cannot tell."""
    early, final = np.asarray(early, dtype=float), np.asarray(final, dtype=float)
    if not early.size or not final.size:
        return verdicts.inconclusive(f"{what} not logged by these runs")
    est = estimate(final)
    change = final - early
    down, up = sign_p_value(change, "less"), sign_p_value(change, "greater")
    text = (
        f"final {what} {est} after {estimate(early)} early (final − early "
        f"{estimate(change, signed=True)}, sign-flip permutation p = {down:.3f} for a fall)"
    )
    if est.lo > resolution or up < DIFFERS_P:
        return None
    if down < DIFFERS_P:
        return verdicts.reproduced(text)
    return verdicts.inconclusive(f"{text}: the seeds cannot tell a fall (p ≥ {DIFFERS_P:g})")


def falls_text(early: np.ndarray, final: np.ndarray, resolution: float) -> str:
    """Why `falls_to_zero` found evidence against: the numbers it was judged on."""
    est = estimate(np.asarray(final, dtype=float))
    if est.lo > resolution:
        return f"final {est} lies above the metric's resolution {resolution:g}"
    return f"final {est} rose from {estimate(np.asarray(early, dtype=float))} early"


def above_zero(values: np.ndarray, what: str) -> Verdict | None:
    """`what` > 0 by a sign-flip permutation test of the per-seed values (one-sided,
    p < DIFFERS_P): reproduced; None (evidence against) where it is significantly below 0;
    inconclusive where the seeds cannot tell."""
    values = np.asarray(values, dtype=float)
    if not values.size:
        return verdicts.inconclusive(f"{what} not logged by these runs")
    est = estimate(values, 2, signed=True)
    up, down = sign_p_value(values, "greater"), sign_p_value(values, "less")
    text = f"{what} {est} (sign-flip permutation p = {up:.3f} for > 0, {down:.3f} for < 0)"
    if up < DIFFERS_P:
        return verdicts.reproduced(text)
    if down < DIFFERS_P:
        return None
    return verdicts.inconclusive(f"{text}: the seeds cannot tell it from 0")


def earlier(ours: list, theirs: list) -> tuple[float, float]:
    """(p that `ours` are earlier, p that they are later) than `theirs`: one-sided
    Mann–Whitney U tests of per-seed iterations, a seed that never got there at +∞."""
    a = [np.inf if v is None else v for v in ours]
    b = [np.inf if v is None else v for v in theirs]
    if not a or not b:
        return 1.0, 1.0
    return rank_p_value(a, b, "less"), rank_p_value(a, b, "greater")


def enough_seeds(*counts: int) -> bool:
    return min(counts) >= MIN_SEEDS_FOR_CI


# --- the environment's rules ------------------------------------------------------------


def success_reachable_with_idle(env_id: str, env_params: dict, idle_agent: int) -> bool:
    """Whether any play of the other agents can make an episode succeed while `idle_agent`
    always takes the env's idle action: every joint action of the others is stepped from
    reset and again from every state that reached (two steps; in Escape Room an action sets
    the position, so every reachable state is among those after one step)."""
    import jax
    import jax.numpy as jnp

    from pimbot import envs

    env = envs.make(env_id, **env_params)
    others = [a for a in range(env.num_agents) if a != idle_agent]
    joint = []
    for choice in itertools.product(range(env.num_actions), repeat=len(others)):
        actions = [env.idle_action] * env.num_agents
        for agent, action in zip(others, choice, strict=True):
            actions[agent] = action
        joint.append(actions)
    joint = jnp.array(joint, jnp.int32)  # [J, N]

    @jax.jit  # one program, not one per eager op
    def reachable(key, joint):
        _, state = env.reset(key)

        def one(state, actions):
            _, next_state, _, _, info = env.step(key, state, actions)
            return next_state, info["success"]

        first_states, first_success = jax.vmap(one, in_axes=(None, 0))(state, joint)
        second = jax.vmap(lambda s: jax.vmap(one, in_axes=(None, 0))(s, joint)[1])(first_states)
        return first_success.any() | second.any()

    return bool(reachable(jax.random.PRNGKey(0), joint))


def structure_text(env_params: dict, idle_agent: int, reachable: bool) -> str:
    n, m = env_params.get("n_agents"), env_params.get("min_at_lever")
    sizes = f"ER({n},{m}) needs {m} on the lever and one at the door; " if n else ""
    others = f"the other {n - 1}" if n else "the others"
    can = "can" if reachable else "cannot"
    return f"{sizes}with agent {idle_agent} idle {others} {can} succeed (env rules enumerated)"


# --- causes -----------------------------------------------------------------------------


DIFFERS_P = 0.05
"""Below this permutation p-value pimbot's seeds and the original code's logs differ."""

NO_LOG = "no original-code log at these settings: no cause can be named"
"""What an unexplained disagreement lacks where the original code left no log."""


def distribution_text(values: np.ndarray, iterations: bool = False) -> str:
    """ "n = 10, mean 0.227, median 0.005": one side of a two-sample test, named."""
    values = np.asarray(values, dtype=float)
    median = float(np.median(values))
    never = int(np.isinf(values).sum())
    if never or iterations:  # a mean over "never" has no value
        return f"n = {values.size}, {never} never, median {iteration_text(median)}"
    return f"n = {values.size}, mean {values.mean():.3f}, median {median:.3f}"


def disagreement(
    reason: str,
    original_agrees_with_paper: bool | None,
    ours: np.ndarray | None = None,
    original: np.ndarray | None = None,
    rank: bool = False,
) -> Verdict:
    """A refutation on learning evidence, its cause named only from evidence.

    - No original-code log (`original_agrees_with_paper` None): inconclusive, saying so;
      an unexplained difference is nobody's defect by default.
    - The logs agree with pimbot (False): the paper contradicts its own code.
    - The logs reproduce the paper (True): "our implementation" only where pimbot's
      per-seed values (`ours`) and the logs' (`original`, one per log, at the same
      horizon) differ by a permutation test of their means, p < DIFFERS_P; the verdict
      names both distributions and p (`rank`: a Mann–Whitney U test instead, for
      iterations where +∞ is "never"). Without per-seed values to test, or where the test
      cannot tell them apart (what a few seeds of a bimodal outcome give), inconclusive."""
    if original_agrees_with_paper is None:
        return verdicts.inconclusive(f"{reason}; {NO_LOG}")
    if not original_agrees_with_paper:
        return verdicts.refuted(
            verdicts.PAPER_CODE, f"{reason}; the original code's logs agree with pimbot"
        )
    reproduce = f"{reason}; the original code's logs reproduce the paper"
    if ours is None or original is None or not len(ours) or not len(original):
        return verdicts.inconclusive(
            f"{reproduce}, but there are no per-seed values to test against ours: no cause "
            "can be named"
        )
    p = rank_p_value(ours, original) if rank else difference_p_value(ours, original)
    test = "Mann–Whitney U test" if rank else "permutation test of the means"
    sides = f"ours {distribution_text(ours, rank)}; the logs' {distribution_text(original, rank)}"
    if p >= DIFFERS_P:
        return verdicts.inconclusive(
            f"{reproduce}, but theirs and ours do not differ ({sides}; {test}, "
            f"p = {p:.2f}): too few seeds to name a cause"
        )
    return verdicts.refuted(
        verdicts.IMPLEMENTATION,
        f"{reproduce}, and ours differ from them at the same horizon ({sides}; {test}, "
        f"p = {p:.3f} < {DIFFERS_P:g})",
    )
