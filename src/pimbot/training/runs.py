"""A run directory back as a policy: its resolved config, per-seed states and actors.

`load_run(run_dir)` is the one way from a checkpoint to an acting policy; the
robot case study, profiling and the analyses use it rather than reading
learner internals. The policy comes from the learner contract's `acting`.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import flax.serialization
import jax

from pimbot.contracts.learner import Actor
from pimbot.envs.core import InvalidParameter
from pimbot.training import store
from pimbot.training.config import ResolvedRun, RunConfig, resolve


@dataclasses.dataclass(frozen=True)
class LoadedRun:
    """A finished (or checkpointed) run: its resolved config and per-seed learner states."""

    run_dir: Path
    resolved: ResolvedRun
    states: Any  # learner state, leaves [S_padded, ...]
    seeds: tuple[int, ...]
    iteration: int

    def seed_state(self, index: int):
        return jax.tree.map(lambda x: x[index], self.states)

    def actor(self, state) -> Actor:
        """The acting policy (ε = 0) of one seed's `state` (traceable: use inside jit)."""
        r = self.resolved
        return r.learner.acting(r.env, r.learner_config, state)


def saved_run_config(run_dir: Path) -> RunConfig:
    """The `RunConfig` a run directory was trained with (from its config.json)."""
    if not (run_dir / store.CONFIG).exists():
        raise InvalidParameter(f"run_dir: {run_dir} has no {store.CONFIG}; not a pimbot run")
    saved = dict(store.read_json(run_dir / store.CONFIG)["run_config"])
    for name in ("env_params", "hparams", "attack_params"):
        saved[name] = _pairs(saved.get(name) or [])
    saved["defenses"] = tuple((n, _pairs(p)) for n, p in saved.get("defenses") or [])
    return RunConfig(**saved)


def _pairs(value) -> tuple[tuple[str, Any], ...]:
    return tuple((str(k), tuple(v) if isinstance(v, list) else v) for k, v in value)


def _merge(template: Any, saved: Any) -> Any:
    if isinstance(template, dict) and isinstance(saved, dict):
        return {k: _merge(v, saved[k]) if k in saved else v for k, v in template.items()}
    return saved


def check_config(run_dir: Path, resolved: ResolvedRun) -> None:
    """DamagedRunDir (one line) where config.json's `run_config`, from which `resolved` was
    made, no longer describes the run its `identity` records (one of them was edited:
    `n_agents` in the env parameters, `policy_hidden` in the hyperparameters)."""
    from pimbot.training.runner import run_description, with_later_fields

    path = run_dir / store.CONFIG
    config = store.read_json(path)
    wanted = json.loads(json.dumps(run_description(resolved)["identity"], default=str))
    saved = config.get("identity")
    if isinstance(saved, dict):
        saved = with_later_fields(saved, wanted, resolved)
    if saved != wanted:
        keys = sorted(set(saved or {}) | set(wanted))
        diff = [k for k in keys if (saved or {}).get(k) != wanted.get(k)]
        raise store.DamagedRunDir(
            f"{path}: does not match the run it holds (its run_config and identity differ in "
            f"{', '.join(diff)}: the file was edited); {store.RESTART_HINT}"
        )


def _check_shapes(run_dir: Path, template: Any, saved: Any, where: str = "") -> None:
    """DamagedRunDir (one line) at the first leaf of the checkpoint's `saved` state whose
    shape is not the shape config.json's run gives it (`template`)."""
    if isinstance(template, dict) and isinstance(saved, dict):
        for key in template.keys() & saved.keys():
            _check_shapes(run_dir, template[key], saved[key], f"{where}/{key}")
        return
    have, want = getattr(saved, "shape", None), getattr(template, "shape", None)
    # leaves carry the seeds first: the checkpoint's every seed, the template's one
    if have is not None and want is not None and tuple(have)[1:] != tuple(want)[1:]:
        raise store.DamagedRunDir(
            f"{run_dir / store.CONFIG}: does not match the checkpoint (the state's {where} is "
            f"{tuple(have)[1:]} per seed, the config makes it {tuple(want)[1:]}: config.json "
            f"was edited); {store.RESTART_HINT}"
        )


def load_run(run_dir: str | Path) -> LoadedRun:
    """Restores the checkpoint of `run_dir`; fails naming what is missing, or, in one line,
    a config.json that no longer matches its identity or its checkpoint."""
    run_dir = Path(run_dir)
    resolved = resolve(saved_run_config(run_dir))
    check_config(run_dir, resolved)
    checkpoint = store.load_checkpoint(run_dir)
    if checkpoint is None:
        raise InvalidParameter(f"run_dir: {run_dir} has no checkpoint/ to load")
    state_bytes, iteration = checkpoint
    env, learner, cfg = resolved.env, resolved.learner, resolved.learner_config
    template = learner.init(jax.random.PRNGKey(0), env, cfg, resolved.attack, resolved.defenses)
    # Leaves are restored with their saved leading (seed) axis; state fields added to the
    # learner after the run was trained keep the template's (unbatched, unused) values.
    target = jax.tree.map(lambda x: x[None], template)
    try:
        saved_dict = flax.serialization.msgpack_restore(state_bytes)
    except Exception as error:  # not a msgpack state: damaged
        raise store.DamagedRunDir(
            f"{run_dir / store.CHECKPOINT_DIR}: damaged (the state does not load: "
            f"{type(error).__name__}); {store.RESTART_HINT}"
        ) from None
    _check_shapes(run_dir, flax.serialization.to_state_dict(target), saved_dict)
    merged = _merge(flax.serialization.to_state_dict(target), saved_dict)
    states = flax.serialization.from_state_dict(target, merged)
    seeds = tuple(range(resolved.run.first_seed, resolved.run.first_seed + resolved.run.seeds))
    return LoadedRun(run_dir, resolved, states, seeds, iteration)
