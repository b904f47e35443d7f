"""Does a run fit in memory? A lower bound, known before anything is compiled or written.

The learner state of every seed (parameters, optimizer moments, attack and defense
state) is resident for the whole run, and `jax.eval_shape` gives its size from the
shapes alone. The rollouts and gradients need more on top, so a run whose state
alone exceeds the memory available cannot fit, and is refused with the estimate.
"""

from __future__ import annotations

import math

import jax
import psutil

from pimbot.envs.core import InvalidParameter
from pimbot.training import config, programs
from pimbot.training.config import ResolvedRun, memoized


def state_bytes(resolved: ResolvedRun) -> int:
    """Bytes of the learner state of all the run's seeds (shapes only, nothing computed);
    inside `config.resolving()`, traced once per `programs.state_structure` (a sweep's
    plan: a few distinct structures among many jobs)."""
    env, learner, cfg = resolved.env, resolved.learner, resolved.learner_config

    def per_seed() -> int:
        def init(key):
            return learner.init(key, env, cfg, resolved.attack, resolved.defenses)

        shapes = jax.eval_shape(init, jax.random.PRNGKey(0))
        return sum(math.prod(x.shape) * x.dtype.itemsize for x in jax.tree.leaves(shapes))

    if not config.in_resolving():
        return per_seed() * resolved.run.seeds
    # per ResolvedRun (kept, so its id stays its own), then per structure
    known = memoized(
        "state_bytes_of",
        id(resolved),
        lambda: (
            resolved,
            memoized("state_bytes", programs.state_structure(resolved), per_seed),
        ),
    )
    return known[1] * resolved.run.seeds


def evaluation_bytes(resolved: ResolvedRun) -> int:
    """A lower bound on an evaluation's memory: its episodes run at once, one observation
    (float32) per agent and step for every episode of every seed."""
    env = resolved.env
    steps = getattr(env, "max_steps", 1)
    per_step = env.num_agents * env.obs_dim * 4
    return resolved.run.seeds * resolved.eval_episodes * steps * per_step


def available_bytes() -> int:
    """Memory the run can use: the first device's free memory where the backend reports
    it (GPU), else the host's available memory."""
    stats = jax.devices()[0].memory_stats() if jax.default_backend() != "cpu" else None
    if stats and "bytes_limit" in stats:
        return int(stats["bytes_limit"] - stats.get("bytes_in_use", 0))
    return int(psutil.virtual_memory().available)


def check_fits(resolved: ResolvedRun, available: int | None = None) -> None:
    """Raises InvalidParameter when the evaluation's observations or the learner state alone
    need more than `available` bytes."""
    available = (
        memoized("available_bytes", None, available_bytes) if available is None else available
    )
    needed = state_bytes(resolved)
    if needed > available:
        params = ", ".join(f"{k}={v}" for k, v in resolved.run.env_params) or "defaults"
        raise InvalidParameter(
            f"size: {resolved.run.env_id} ({params}) × {resolved.run.seeds} seeds needs at "
            f"least {needed / 2**30:.1f} GiB for the learner state alone, more than the "
            f"{available / 2**30:.1f} GiB available; use fewer agents, seeds or smaller "
            "networks"
        )
    evaluation = evaluation_bytes(resolved)
    if evaluation > available:
        raise InvalidParameter(
            f"eval_episodes: {resolved.eval_episodes} evaluation episodes × "
            f"{resolved.run.seeds} seeds need at least {evaluation / 2**30:.1f} GiB for their "
            f"observations alone, more than the {available / 2**30:.1f} GiB available; "
            "use fewer seeds or evaluation episodes"
        )
