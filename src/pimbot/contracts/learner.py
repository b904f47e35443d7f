"""The learner contract: pure `init` / `update` / `evaluate` / `acting` over a frozen config.

    init(key, env, cfg, attack, defenses)             -> state (a pytree, one seed)
    update(state, env, cfg, attack, defenses)         -> (state, metrics of one iteration)
    evaluate(key, state, env, cfg, episodes, attack)  -> per-episode metrics [episodes, ...]
    acting(env, cfg, state)                           -> Actor: the policy at ε = 0

A learner lists the attack and defense hook points it consults; a run that
needs one it lacks is refused naming the hook. Per-environment defaults come
from the environment's registration (`EnvSpec.learner_defaults`), never from
sniffing env attributes.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from pimbot.contracts.registry import Registry
from pimbot.contracts.rollout import ActFn, GiveFn


@dataclasses.dataclass(frozen=True)
class Actor:
    """A trained policy as it acts: `act(key, obs [N, obs_dim]) -> actions [N]`, and the
    learned incentives `give(obs, actions) -> [N, N]` (None without a channel)."""

    act: ActFn
    give: GiveFn | None = None


@dataclasses.dataclass(frozen=True)
class LearnerDef:
    """What every command needs of a learner."""

    name: str
    description: str
    config_cls: type
    """Frozen dataclass of hyperparameters; its defaults are the learner's base config."""
    init: Callable
    update: Callable
    evaluate: Callable
    acting: Callable[[Any, Any, Any], Actor]
    attack_hooks: tuple[str, ...]
    """Attack hook points the learner consults (`pimbot.contracts.attack.HOOKS`)."""
    defense_hooks: tuple[str, ...] = ()
    """Defense hook points the learner consults (`pimbot.contracts.defense.HOOKS`)."""
    has_incentives: bool = False
    """Whether the learner has an incentive channel (agents pay each other rewards)."""
    base_overrides: tuple[tuple[str, Any], ...] = ()
    """Changes to `config_cls()` that make this learner (e.g. `nl`: reciprocal weight 0),
    applied after the environment's defaults."""
    env_defaults_of: str | None = None
    """Take the environment's declared defaults of this other learner (a variant of it)."""

    def default_config(self, env_spec) -> Any:
        """`config_cls()` with the environment's declared defaults for this learner."""
        declared = dict(env_spec.learner_defaults.get(self.env_defaults_of or self.name, {}))
        return dataclasses.replace(self.config_cls(), **(declared | dict(self.base_overrides)))


LEARNERS: Registry[LearnerDef] = Registry("learner", "learner")


def register(definition: LearnerDef, *, replace: bool = False) -> LearnerDef:
    """Registers a learner under `definition.name`."""
    if not isinstance(definition, LearnerDef):
        raise TypeError(f"learners register a LearnerDef, got {definition!r}")
    return LEARNERS.register(definition.name, definition, replace=replace)
