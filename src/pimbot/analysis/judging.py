"""What the claim rules measure on runs: convergence at equal horizons, interval tests,
what an environment's rules make impossible, and the cause of a disagreement.

Pure functions of measured values (a run's `analysis.curves.Curves`, estimates over seeds)
and of the registered environments; the sections turn their results into `Claim`s.
"""

from __future__ import annotations

import itertools

import numpy as np

from pimbot.analysis import verdicts
from pimbot.analysis.tables import Estimate
from pimbot.analysis.verdicts import Verdict
from pimbot.statistics import MIN_SEEDS_FOR_CI, difference_p_value

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
    return "never" if value is None else f"{value / 1000:.1f}k"


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


def distribution_text(values: np.ndarray) -> str:
    """ "n = 10, mean 0.227, median 0.005": one side of a two-sample test, named."""
    values = np.asarray(values, dtype=float)
    return f"n = {values.size}, mean {values.mean():.3f}, median {float(np.median(values)):.3f}"


def disagreement(
    reason: str,
    original_agrees_with_paper: bool | None,
    ours: np.ndarray | None = None,
    original: np.ndarray | None = None,
) -> Verdict:
    """A refutation on learning evidence, its cause named only from evidence.

    - No original-code log (`original_agrees_with_paper` None): inconclusive, saying so;
      an unexplained difference is nobody's defect by default.
    - The logs agree with pimbot (False): the paper contradicts its own code.
    - The logs reproduce the paper (True): "our implementation" only where pimbot's
      per-seed values (`ours`) and the logs' (`original`, one per log, at the same
      horizon) differ by a permutation test of their means, p < DIFFERS_P; the verdict
      names both distributions and p. Without per-seed values to test, or where the test
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
    p = difference_p_value(ours, original)
    sides = f"ours {distribution_text(ours)}; the logs' {distribution_text(original)}"
    if p >= DIFFERS_P:
        return verdicts.inconclusive(
            f"{reproduce}, but theirs and ours do not differ ({sides}; permutation test of "
            f"the means, p = {p:.2f}): too few seeds to name a cause"
        )
    return verdicts.refuted(
        verdicts.IMPLEMENTATION,
        f"{reproduce}, and ours differ from them at the same horizon ({sides}; permutation "
        f"test of the means, p = {p:.3f} < {DIFFERS_P:g})",
    )
