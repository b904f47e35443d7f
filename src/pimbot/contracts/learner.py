"""The learner contract: pure `init` / `update` / `evaluate` / `acting` over a frozen config.

    init(key, env, cfg, attack, defenses)             -> state (a pytree, one seed)
    update(state, env, cfg, attack, defenses)         -> (state, metrics of one iteration)
    evaluate(key, state, env, cfg, episodes, attack)  -> per-episode metrics [episodes, ...]
    acting(env, cfg, state)                           -> Actor: the policy at ε = 0

A learner is registered with `register(LearnerDef(...))`, by pimbot's own (`pimbot.learners`)
and by a plugin alike (docs/extending.md, "(e) A learner": the worked example
`examples/plugins/actor_critic.py`). The runner (`pimbot.training.runner`) vmaps `init`
over seeds, scans `update` for an evaluation period, then calls `evaluate`, all inside one
compiled program; `attack`, `defenses` and `env` are pytrees whose numbers are traced, and
so is `cfg` where its class is a `pimbot.envs.core.TracedFields` (`program_config`: the
fields it names in `traced_fields` are traced, so runs that differ only in those numbers
share one program; a `program_form()` method may map a choice of formula to a traced
index); any other config is static (a frozen dataclass the program closes over).

**The state** (one seed's; a `flax.struct.dataclass` of arrays, checkpointed with
`flax.serialization` and resumed from) holds everything the learner learns (parameters,
optimizer states), its PRNG key (all randomness comes from the state: a resumed run goes
on identically), and the fields the runner reads by name:

* `iteration`: int32 [], +1 per `update` (the evaluation key and metrics.csv's column);
* `attack_state`: what `attack.init_state(attack_key(key), N, AgentParams(adversary's
  row, its incentive row or {}))` returned in `init`, replaced only by the attack's
  `observe` and `adversary_step` (read for the attack's `metrics`; its non-finite values
  are no divergence);
* `defense_state`: the tuple `pimbot.contracts.defense.init_states(defenses, N, policy)`,
  replaced by what the defense hooks return;
* by convention `env_steps`: int32 [], environment steps taken in training (the
  `env_step0` of `rollout`, `Outcome.env_steps`).

**The hook points it calls itself.** Nothing calls a hook for the learner; `attack_hooks`
and `defense_hooks` list exactly those its `update` / `evaluate` consult (`pimbot
learners` shows them; a run whose attack or defense acts elsewhere is refused naming the
hook). Attack hooks (`pimbot.contracts.attack`), each with the attack's per-seed state and
a key from `attack_key` (derived, never consumed):

* `act` (and `emit` where the learner has an incentive channel): consulted at every step
  by `pimbot.contracts.rollout.rollout(env, key, act, give, attack, env_steps,
  attack_state)`: play every training and evaluation episode through it;
* `learning_rewards(state, env_rewards, received)`: the reward of every agent's policy
  step (`received`: zeros without a channel);
* `policy_sign(state, N)`: multiplies every agent's policy step (−1 reverses it, 0
  freezes it: scale the optimizer's step, not the gradient, where momentum would move a
  frozen agent);
* `adversary_step(state, key, view)`, where "adversary_step" is in `attack.hooks`: the
  adversary's new ω replaces its row (a learning attack, ADMO), given an `AdversaryView`;
* `observe(state, key, Outcome(success, iteration, env_steps))`, once per iteration;
* `update_schedule`, for a multi-epoch learner only (the Reciprocator's PPO epochs).

Defense hooks (`pimbot.contracts.defense`), folded over the run's defenses, with
`honest_agents(attack, N)` (the adversary runs none): `acting_epsilon` (the ε every agent
acts and learns with), `learning_incentives` (what recipients accept) and
`after_policy_step`.

**ADMO** (`admo`, `pimbot.attacks.admo`) needs `policy_sign` (it freezes the adversary's
ordinary step) and `adversary_step`, and of the `AdversaryView` the learner builds: the
stacked `policy` [N, ...] (the adversary's row is θ_a, as `init_state` was given it),
`log_probs(θ_a) -> [B..., T]` differentiable in θ_a on the batch just played, its
`env_rewards` [B..., T, N], `valid`, `received` / `received_valid` (zeros without a
channel), `success`, `gamma`, `iteration`. Without an incentive channel `incentive`,
`emitted` and `meta_pullback` are None and `emission_scales` is (): ADMO then trains θ_a
alone. With one, all three are set: `incentive` is the stacked η, `emitted(η_a)` the
batch's incentives recomputed from η_a, and `meta_pullback` the gradient through the
recipients' updates (LIO's, `pimbot.learners.lio`); a view that sets `incentive` without
the other two is refused in one line when the attack's step is traced, before any
iteration (`pimbot.contracts.attack.incentive_channel`: ADMO, admo_code and the Stag
Hunt's negated reward read them). ADMO's budget acts at `emit` where the learner has it.

**Incentive channel** (`LearnerDef.has_incentives`): a learner whose rollouts pass a
`give` function declares it, and must then list `emit` among its `attack_hooks` (refused
at registration otherwise). `give` gets no PRNG key: incentives must be a deterministic
function of (obs, actions) given the learner's parameters, because a learning attack and
LIO's meta-gradient recompute them on the batch as played; a stochastic incentive draws
its noise from the learner's key before the rollout and closes `give` over it
(`pimbot.contracts.rollout.GiveFn`).

**Evaluation**: `evaluate` plays `episodes` episodes at ε = 0 through `rollout`, the
attack acting as in training, and returns `episode_metrics` of each ([episodes] or
[episodes, N]: `success`, `team_return`, `return_env`, `return_total`, ... which the
runner averages into the `eval/` columns and the adversary's margins). `update`'s metrics
are float32 [] or [N] named `train/...` (and the attack's own, e.g. `admo/...`): the
runner writes their mean over each evaluation period.

**Per-environment defaults** are declared by env id, never sniffed from env attributes:
in the learner's registry entry (`LearnerDef.env_defaults`, `env_params`; `set_env_defaults`
and `set_env_params` add them later, for any env id, built-in or a plugin's, from any
plugin, without registering the learner again), or, for a plugin env registered after the
learner, in the env's registration (`EnvSpec.learner_defaults`, `learner_env_defaults`);
the learner's entry wins, `base_overrides` over both, `--hp` over everything. Each is
checked where it is declared: a name that is no hyperparameter, or a value of another type,
is one line naming the file and line.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

from pimbot.contracts import conformance
from pimbot.contracts.registry import Registry
from pimbot.contracts.rollout import ActFn, GiveFn
from pimbot.envs.core import TracedFields, check_traced_numbers


@dataclasses.dataclass(frozen=True)
class Actor:
    """A trained policy as it acts: `act(key, obs [N, obs_dim]) -> actions [N]`, and the
    learned incentives `give(obs, actions) -> [N, N]` (None without a channel)."""

    act: ActFn
    give: GiveFn | None = None


@dataclasses.dataclass(frozen=True)
class LearnerDef:
    """What every command needs of a learner (the module docstring says what each function
    and the state must do; `examples/plugins/actor_critic.py` is a complete one)."""

    name: str
    """`--learner NAME`; unique among the registered learners."""
    description: str
    """One line for `pimbot learners`."""
    config_cls: type
    """Frozen dataclass of hyperparameters; its defaults are the learner's base config. Each
    field's docstring is its `--hp` help; `RANGES: ClassVar[dict]` (name -> (low, high))
    bounds numbers, the others must be ≥ 0 (`pimbot.contracts.params.check_fields`)."""
    init: Callable
    """init(key, env, cfg, attack, defenses) -> state of one seed (module docstring)."""
    update: Callable
    """update(state, env, cfg, attack, defenses) -> (state, metrics): one iteration."""
    evaluate: Callable
    """evaluate(key, state, env, cfg, episodes, attack) -> per-episode metrics."""
    acting: Callable[[Any, Any, Any], Actor]
    """acting(env, cfg, state) -> Actor: the trained policy at ε = 0 (robot, profiling)."""
    attack_hooks: tuple[str, ...]
    """Attack hook points the learner consults (`pimbot.contracts.attack.HOOKS`): exactly
    those its code calls (a name that is no hook point is refused at registration). A run
    whose attack lists a hook point not here is refused, one line naming it and the attacks
    usable with this learner."""
    defense_hooks: tuple[str, ...] = ()
    """Defense hook points the learner consults (`pimbot.contracts.defense.HOOKS`); a run
    with a defense acting elsewhere is refused naming the hook."""
    has_incentives: bool = False
    """Whether the learner has an incentive channel (agents pay each other rewards, passed
    to `rollout` as `give`). It must then list `emit` in `attack_hooks` (checked at
    registration); `pimbot learners` shows it."""
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


def program_config(cfg: Any) -> Any | None:
    """What a compiled program takes for the learner config `cfg`: where its class is a
    `TracedFields`, the config in its program form (`cfg.program_form()` where it has one,
    else `cfg`), whose `traced_fields` are the program's traced arguments; else None (the
    program closes over `cfg`, and every field of it is structure)."""
    if not isinstance(cfg, TracedFields):
        return None
    form = getattr(cfg, "program_form", None)
    cfg = form() if callable(form) else cfg
    check_traced_numbers(cfg)
    return cfg


def register(definition: LearnerDef, *, replace: bool = False) -> LearnerDef:
    """Registers a learner under `definition.name`, a built-in's or a plugin's alike; the
    defaults it declares (per env id, and `base_overrides`) must name its hyperparameters
    with values of their types. Registering a name again fails unless `replace`: to declare
    defaults for another env later (built-in or a plugin's), call `set_env_defaults` /
    `set_env_params` instead.

    Raises:
        InvalidParameter: a default that is no hyperparameter, or of the wrong type.
    """
    if not isinstance(definition, LearnerDef):
        raise TypeError(f"learners register a LearnerDef, got {definition!r}")
    where = f"at {conformance.caller_location()}"
    _check_hook_names(definition, where)
    if definition.has_incentives and "emit" not in definition.attack_hooks:
        raise conformance.ContractError(
            f"attack_hooks: learner {definition.name} declares has_incentives, so its rollouts "
            f"consult `emit`: list it (declared {where})"
        )
    check_hparams(definition, dict(definition.base_overrides), "base_overrides", where)
    for env_id, values in definition.env_defaults.items():
        check_hparams(definition, values, f"{definition.name}'s default on {env_id}", where)
    return LEARNERS.register(definition.name, definition, replace=replace)


def _check_hook_names(definition: LearnerDef, where: str) -> None:
    """Each of `attack_hooks` / `defense_hooks` names a hook point of its contract: a
    misspelt one would otherwise only show as every attack at it being refused.

    Raises:
        ContractError: ``FIELD: NAME is no attack|defense hook point; allowed: ...``.
    """
    from pimbot.contracts import attack, defense  # JAX-side; registering a learner is too

    for field, kind, known in (
        ("attack_hooks", "attack", attack.HOOKS),
        ("defense_hooks", "defense", defense.HOOKS),
    ):
        hooks = getattr(definition, field)
        if not isinstance(hooks, (tuple, list)):
            raise conformance.ContractError(
                f"{field}: {definition.name}'s must be a tuple of hook points, got {hooks!r} "
                f"(declared {where})"
            )
        for hook in hooks:
            if hook not in known:
                raise conformance.ContractError(
                    f"{field}: {hook!r} is no {kind} hook point"
                    f"{conformance.did_you_mean(hook, known)}; allowed: {', '.join(known)} "
                    f"(learner {definition.name}, declared {where})"
                )


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
