"""Does a run fit in memory? A lower bound, known before anything is compiled or written.

The learner state of every seed (parameters, optimizer moments, attack and defense
state) is resident for the whole run, and `jax.eval_shape` gives its size from the
shapes alone. The rollouts and gradients need more on top, so a run whose state
alone exceeds the memory available cannot fit, and is refused with the estimate.

The abstract trace of `init` is made once per structure (learner, env, config, the
attack's and defenses' structure and leaf shapes): a sweep's jobs that differ in numbers
share it, and its per-seed size is recorded beside the compiled programs of this code
(`jax_setup.marker`, as the preflight's record), so a run whose structure this code
measured before (a rerun, a resume, the warm path) is not traced for it again before the
runner traces `init` to compile it.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import jax
import psutil

from pimbot import jax_setup, plugins
from pimbot.contracts import conformance
from pimbot.envs.core import InvalidParameter
from pimbot.training.config import ResolvedRun

_PER_SEED: dict[Any, int] = {}
"""Per-seed state bytes this process measured, by structure (`_structure`)."""


def state_bytes(resolved: ResolvedRun) -> int:
    """Bytes of the learner state of all the run's seeds (shapes only, nothing computed;
    measured once per structure, see the module docstring)."""
    key = _structure(resolved)
    per_seed = _PER_SEED.get(key) if key is not None else None
    record = _record(key, resolved) if per_seed is None else None
    if per_seed is None and record is not None:
        per_seed = _read(record)
    if per_seed is None:
        per_seed = _measure(resolved)
        _write(record, per_seed)
    if key is not None:
        _PER_SEED[key] = per_seed
    return per_seed * resolved.run.seeds


def _measure(resolved: ResolvedRun) -> int:
    env, learner, cfg = resolved.env, resolved.learner, resolved.learner_config

    def init(key):
        return learner.init(key, env, cfg, resolved.attack, resolved.defenses)

    shapes = jax.eval_shape(init, jax.random.PRNGKey(0))
    return sum(math.prod(x.shape) * x.dtype.itemsize for x in jax.tree.leaves(shapes))


def _structure(resolved: ResolvedRun) -> Any:
    """What the state's shapes depend on: the learner, env and config (hashable frozen
    dataclasses), the attack's and defenses' structure and leaf shapes; None where one
    of them cannot be hashed."""
    leaves, tree = jax.tree.flatten((resolved.attack, tuple(resolved.defenses)))
    key = (
        resolved.learner.name,
        resolved.env,
        resolved.learner_config,
        tree,
        tuple(map(conformance.aval, leaves)),
    )
    try:
        hash(key)
    except TypeError:
        return None
    return key


def _record(key: Any, resolved: ResolvedRun) -> Path | None:
    """The file recording the per-seed size of `key`'s structure for this code (pimbot's
    sources and the plugin files loaded: `jax_setup.marker`), covering the learner's
    `init` and the attack's and defenses' classes with their files' sha256; None where
    something could differ unseen (a key printed with an address, a part defined inside a
    function or without a readable file) or no cache is active."""
    if key is None:
        return None
    learner, env, config, *rest = key
    texts = [repr((learner, type(env), env, type(config), config, *rest))]
    parts = [resolved.learner.init, type(resolved.attack), *map(type, resolved.defenses)]
    for part in parts:
        qualname = getattr(part, "__qualname__", "<locals>")
        file = conformance.source_file(part)
        digest = plugins.file_sha256(file) if file else None
        if "<locals>" in qualname or digest is None:
            return None
        texts.append(f"{part.__module__}.{qualname} {digest}")
    if " at 0x" in texts[0]:
        return None
    return jax_setup.marker("state_bytes", "\n".join(texts))


def _read(path: Path) -> int | None:
    try:
        return int(path.read_text())
    except (OSError, ValueError):
        return None


def _write(path: Path | None, per_seed: int) -> None:
    if path is None:
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(str(per_seed))
    except OSError:  # a read-only cache: the next process measures again
        pass


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
    available = available_bytes() if available is None else available
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
