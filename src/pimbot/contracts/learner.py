"""The learner contract: pure `init` / `update` / `evaluate` / `acting` over a frozen config.

    init(key, env, cfg, attack, defenses)             -> state (a pytree, one seed)
    update(state, env, cfg, attack, defenses)         -> (state, metrics of one iteration)
    evaluate(key, state, env, cfg, episodes, attack)  -> per-episode metrics [episodes, ...]
    acting(env, cfg, state)                           -> Actor: the policy at ε = 0

A learner lists the attack and defense hook points it consults; a run that
needs one it lacks is refused naming the hook. Per-environment defaults are
declared by env id, never sniffed from env attributes: in the learner's registry
entry (`LearnerDef.env_defaults`, `env_params`; `set_env_defaults` and
`set_env_params` add them later, for any env id, built-in or a plugin's), or, for
a plugin env registered after the learner, in the env's registration
(`EnvSpec.learner_defaults`, `learner_env_defaults`); the learner's entry wins.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

from pimbot.contracts import conformance
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
    applied after the per-env defaults."""
    env_defaults_of: str | None = None
    """Take the per-env defaults of this other learner (a variant of it), under its own."""
    env_defaults: Mapping[str, Mapping[str, Any]] = dataclasses.field(
        default_factory=dict, hash=False
    )
    """env id -> hyperparameter overrides of `config_cls()` on that env (a built-in env or
    a plugin's; `set_env_defaults` adds some to a registered learner)."""
    env_params: Mapping[str, Mapping[str, Any]] = dataclasses.field(
        default_factory=dict, hash=False
    )
    """env id -> env parameters this learner's runs use where the run gives none. They are
    the learner's: its training protocol, not the game, needs them (the Reciprocator's
    32-step IPD episodes, as its original trainer plays), so they live in its entry."""

    def _declared(self, env_spec, entry_field: str, env_field: str) -> dict[str, Any]:
        """What the env's registration declares for this learner (or the one it takes its
        defaults of), under what the entries declare for the env id: that learner's, then
        this one's."""
        owner = self.env_defaults_of or self.name
        declared = dict(getattr(env_spec, env_field).get(owner, {}))
        entries = [LEARNERS.get(self.env_defaults_of)] if self.env_defaults_of else []
        for entry in [*entries, self]:
            declared |= dict(getattr(entry, entry_field).get(env_spec.env_id, {}))
        return declared

    def default_config(self, env_spec) -> Any:
        """`config_cls()` with the defaults declared for this learner on `env_spec`'s env,
        then `base_overrides`."""
        declared = self._declared(env_spec, "env_defaults", "learner_defaults")
        # what a plugin env declared is checked here, where the learner is known
        where = f"by env {env_spec.env_id}, {conformance.location(env_spec.constructor)}"
        check_hparams(self, declared, f"{self.name}'s default on {env_spec.env_id}", where)
        return dataclasses.replace(self.config_cls(), **(declared | dict(self.base_overrides)))

    def default_env_params(self, env_spec) -> dict[str, Any]:
        """The env parameters declared for this learner's runs on `env_spec`'s env."""
        return self._declared(env_spec, "env_params", "learner_env_defaults")


LEARNERS: Registry[LearnerDef] = Registry("learner", "learner")


def register(definition: LearnerDef, *, replace: bool = False) -> LearnerDef:
    """Registers a learner under `definition.name`; the defaults it declares (per env id,
    and `base_overrides`) must name its hyperparameters with values of their types.

    Raises:
        InvalidParameter: a default that is no hyperparameter, or of the wrong type.
    """
    if not isinstance(definition, LearnerDef):
        raise TypeError(f"learners register a LearnerDef, got {definition!r}")
    where = f"at {conformance.caller_location()}"
    check_hparams(definition, dict(definition.base_overrides), "base_overrides", where)
    for env_id, values in definition.env_defaults.items():
        check_hparams(definition, values, f"{definition.name}'s default on {env_id}", where)
    return LEARNERS.register(definition.name, definition, replace=replace)


def check_hparams(definition: LearnerDef, values: Mapping[str, Any], what: str, where: str):
    """Each of `values` names a hyperparameter of `definition` and is of its type (that of
    its default: `conformance.value_problem`); declared `where` ("at FILE:LINE").

    Raises:
        ContractError: ``NAME: not a hyperparameter of LEARNER; ...`` or ``NAME: WHAT must be
        TYPE, got VALUE``, ending with where it was declared (an `InvalidParameter`).
    """
    fields = {f.name: f for f in dataclasses.fields(definition.config_cls)}
    at = f" (declared {where})" if where.strip() not in ("", "at") else ""
    for key, value in values.items():
        if key not in fields:
            raise conformance.ContractError(
                f"{key}: not a hyperparameter of {definition.name}; allowed: "
                f"{', '.join(fields)}{at}"
            )
        default = _field_default(fields[key])
        expected = conformance.value_problem(default, value)
        if expected is not None:
            raise conformance.ContractError(
                f"{key}: {what} must be {expected}, got {value!r} ({type(value).__name__}){at}"
            )


def _field_default(field: dataclasses.Field) -> Any:
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return None


def set_env_defaults(name: str, env_id: str, **hparams: Any) -> LearnerDef:
    """Declares learner `name`'s hyperparameter defaults on env `env_id` (any id, registered
    yet or not: a plugin tunes a built-in learner on a built-in env without registering
    either again); merged over what the entry declared for that id.

    Raises:
        InvalidParameter: unknown learner, a name that is not one of its hyperparameters, or
            a value of another type than the hyperparameter's (`check_hparams`).
    """
    definition = LEARNERS.get(name)
    where = f"at {conformance.caller_location()}"
    check_hparams(definition, hparams, f"{name}'s default on {env_id}", where)
    return _with_declared(definition, "env_defaults", env_id, hparams)


def set_env_params(name: str, env_id: str, **params: Any) -> LearnerDef:
    """Declares the env parameters learner `name`'s runs on `env_id` use where the run gives
    none, merged over what the entry declared for that id (checked when the env is made).

    Raises:
        InvalidParameter: unknown learner.
    """
    return _with_declared(LEARNERS.get(name), "env_params", env_id, params)


def _with_declared(definition: LearnerDef, field: str, env_id: str, values) -> LearnerDef:
    """Replaces the registered entry by one whose `field` has `values` merged in for
    `env_id` (entries stay frozen: the registry holds the new one)."""
    declared = {k: dict(v) for k, v in getattr(definition, field).items()}
    declared[env_id] = declared.get(env_id, {}) | dict(values)
    return register(dataclasses.replace(definition, **{field: declared}), replace=True)
