"""Frozen run configurations and their validation.

A `RunConfig` is what `pimbot train` runs: one env × one learner × S seeds.
`resolve` turns it into the concrete env object and learner config, failing
with `InvalidParameter` (naming the field and the allowed values) before
anything is written.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Iterator
from typing import Any

from pimbot import attacks, defenses, envs, learners
from pimbot.contracts.attack import NO_ATTACK
from pimbot.contracts.params import check_fields
from pimbot.errors import InvalidParameter, check_int


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """One training run: an environment, a learner, and S independent seeds."""

    env_id: str
    """Registered environment id (see `pimbot envs`)."""
    env_params: tuple[tuple[str, Any], ...] = ()
    """Environment parameters as sorted (name, value) pairs."""
    learner: str = learners.DEFAULT_LEARNER
    """Learner name (see `pimbot learners`)."""
    hparams: tuple[tuple[str, Any], ...] = ()
    """Overrides of the learner's per-environment default hyperparameters."""
    seeds: int = 10
    """Number of independent seeds S (a vmap axis)."""
    first_seed: int = 0
    """Seeds are first_seed, …, first_seed + S − 1."""
    iterations: int = 50_000
    """Training iterations per seed (one LIO iteration = two episodes)."""
    eval_period: int | None = None
    """Iterations between evaluations; None = the environment's (`EnvSpec.eval_period`: ER
    100, else 1000; a shorter run is evaluated once, at its end)."""
    eval_episodes: int | None = None
    """Evaluation episodes per evaluation point; None = the environment's (10)."""
    attack: str | None = None
    """Manipulation of one agent (see `pimbot attacks`); None = clean."""
    attack_params: tuple[tuple[str, Any], ...] = ()
    """Attack parameters as sorted (name, value) pairs (adversary index included)."""
    defenses: tuple[tuple[str, tuple[tuple[str, Any], ...]], ...] = ()
    """Training-time defenses (see `pimbot defenses`) as (name, sorted (param, value) pairs)."""

    def resolved_eval(self) -> tuple[int, int]:
        entry = envs.spec(self.env_id)
        period, episodes = entry.eval_period, entry.eval_episodes
        # a run shorter than the default period is evaluated once, at its end
        return (
            self.eval_period if self.eval_period is not None else min(period, self.iterations),
            self.eval_episodes if self.eval_episodes is not None else episodes,
        )


@dataclasses.dataclass(frozen=True)
class ResolvedRun:
    """A validated run: the concrete env, learner definition and learner config."""

    run: RunConfig
    env: Any
    learner: learners.LearnerDef
    learner_config: Any
    eval_period: int
    eval_episodes: int
    attack: Any = NO_ATTACK
    defenses: Any = defenses.NO_DEFENSE

    @property
    def num_evals(self) -> int:
        return self.run.iterations // self.eval_period

    def identity(self) -> dict[str, Any]:
        """Everything that determines the results; a resumed run must match it exactly."""
        return {
            "env_id": self.run.env_id,
            "env_params": env_parameters(self.env),
            "learner": self.run.learner,
            "learner_config": dataclasses.asdict(self.learner_config),
            "seeds": self.run.seeds,
            "first_seed": self.run.first_seed,
            "iterations": self.run.iterations,
            "eval_period": self.eval_period,
            "eval_episodes": self.eval_episodes,
            "attack": self.run.attack,
            "attack_params": dataclasses.asdict(self.attack) if self.run.attack else {},
        } | self._defense_identity()

    def _defense_identity(self) -> dict[str, Any]:
        # Absent without defenses, so runs made before defenses existed keep their identity.
        if not self.defenses:
            return {}
        return {"defenses": {d.name: dataclasses.asdict(d) for d in self.defenses}}


def env_parameters(env: Any) -> dict[str, Any]:
    """The init parameters of an env object, defaults included."""
    return {f.name: getattr(env, f.name) for f in dataclasses.fields(env) if f.init}


def env_arguments(run: RunConfig, learner: learners.LearnerDef) -> dict[str, Any]:
    """The run's env parameters over those declared for its learner on its env
    (`LearnerDef.default_env_params`: NL takes the Reciprocator's)."""
    return learner.default_env_params(envs.spec(run.env_id)) | dict(run.env_params)


SEED_LIMIT = 2**32
"""JAX's PRNG seeds are 32-bit: a run's seeds first_seed … first_seed + seeds − 1 lie below
this (a larger seed would wrap onto a smaller one's stream and repeat its results)."""

ITERATION_LIMIT = 2**31 - 1
"""The compiled program counts iterations in int32."""


_MEMO: dict | None = None
"""The parts `resolve` has built inside `resolving()`; None outside it."""


@contextlib.contextmanager
def resolving() -> Iterator[None]:
    """Inside the block, `resolve` builds each distinct part of the runs it resolves once
    (an env of one id and parameters, a learner config, an attack, a defense stack, the
    registries' hooks) and shares it, immutable, between the runs that have it; so does
    `memoized`. A grid's planning is then linear in its jobs with a small constant (10^5
    jobs of a product grid are a few hundred distinct parts). Nested blocks share the
    outer one's parts; they are dropped when it ends (plugins loaded later start afresh)."""
    global _MEMO
    if _MEMO is not None:
        yield
        return
    _MEMO = {}
    try:
        yield
    finally:
        _MEMO = None


def in_resolving() -> bool:
    """Whether a `resolving()` block is open."""
    return _MEMO is not None


def memoized(kind: str, key: Any, make: Callable[[], Any]) -> Any:
    """`make()`, once per (`kind`, `key`) inside `resolving()`; every call outside it."""
    memo = _MEMO
    if memo is None:
        return make()
    try:
        hash(key)
    except TypeError:  # a list among the values
        key = repr(key)
    if (kind, key) not in memo:
        memo[kind, key] = make()
    return memo[kind, key]


def resolve(run: RunConfig) -> ResolvedRun:
    """Validates `run` and builds its env and learner config (each distinct part once
    inside `resolving()`, and each run once: a sweep checks its jobs, then plans them).

    Raises:
        InvalidParameter: naming the bad field and the allowed values.
    """
    return memoized("run", run, lambda: _resolve(run))


def _resolve(run: RunConfig) -> ResolvedRun:
    learner = learners.get(run.learner)
    env = memoized(
        "env",
        (run.learner, run.env_id, run.env_params),
        lambda: envs.make(run.env_id, **env_arguments(run, learner)),
    )
    check_int("seeds", run.seeds, 1, SEED_LIMIT)
    check_int("first_seed", run.first_seed, 0, SEED_LIMIT - run.seeds)
    check_int("iterations", run.iterations, 1, ITERATION_LIMIT)
    eval_period, eval_episodes = run.resolved_eval()
    check_int("eval_period", eval_period, 1)
    check_int("eval_episodes", eval_episodes, 1)
    if run.iterations % eval_period:
        raise InvalidParameter(
            f"iterations: must be a multiple of eval_period = {eval_period}, got {run.iterations}"
        )
    learner_config = memoized(
        "learner_config", (run.learner, run.env_id, run.hparams), lambda: _learner_config(run)
    )
    attack = NO_ATTACK
    if run.attack is not None:
        attack = memoized(
            "attack",
            (run.attack, env.num_agents, run.attack_params),
            lambda: attacks.make(run.attack, env.num_agents, **dict(run.attack_params)),
        )
        known = memoized("attack_hooks", None, _attack_hooks)
        check_hooks("attack", run.attack, attack.hooks, learner.attack_hooks, run.learner, known)
    run_defenses = memoized(
        "defenses",
        (run.defenses, env.num_agents),
        lambda: defenses.compose(run.defenses, env.num_agents),
    )
    known = memoized("defense_hooks", None, _defense_hooks)
    for defense in run_defenses:
        check_hooks(
            "defenses", defense.name, defense.hooks, learner.defense_hooks, run.learner, known
        )
    return ResolvedRun(
        run, env, learner, learner_config, eval_period, eval_episodes, attack, run_defenses
    )


def _learner_config(run: RunConfig) -> Any:
    """The learner config of `run`: its learner's defaults on its env, `run.hparams` over."""
    learner = learners.get(run.learner)
    defaults = learner.default_config(envs.spec(run.env_id))
    fields = {f.name: f for f in dataclasses.fields(defaults)}
    overrides = {}
    for name, value in run.hparams:
        if name not in fields:
            raise InvalidParameter(
                f"{name}: not a hyperparameter of {run.learner}; allowed: {', '.join(fields)}"
            )
        overrides[name] = coerce_like(name, value, getattr(defaults, name))
    learner_config = dataclasses.replace(defaults, **overrides)
    check_fields(learner_config)  # finite, and within the config class's RANGES
    return learner_config


def _attack_hooks() -> dict[str, Any]:
    return {n: attacks.attack_class(n).hooks for n in attacks.registered()}


def _defense_hooks() -> dict[str, Any]:
    return {n: defenses.defense_class(n).hooks for n in defenses.registered()}


def check_hooks(field: str, name: str, needed, consulted, learner: str, others) -> None:
    """Fails naming the hook points of attack/defense `name` that `learner` never consults.

    `others`: name -> hooks of every registered attack (or defense), for the hint.
    """
    missing = [hook for hook in needed if hook not in consulted]
    if missing:
        usable = [other for other, hooks in others.items() if set(hooks) <= set(consulted)]
        acts = f"{name} acts at the hook point(s) {', '.join(missing)}, which learner {learner}"
        raise IncompatibleHooks(
            f"{field}: {acts} does not have; usable with {learner}: {', '.join(usable) or 'none'}",
            reason=f"{'attack' if field == 'attack' else 'defense'} {acts} does not have",
        )


class IncompatibleHooks(InvalidParameter):
    """A run whose attack or defense acts at a hook point its learner does not have. A grid
    skips such a cell, listing `reason`, instead of refusing the whole grid."""

    def __init__(self, message: str, reason: str = ""):
        super().__init__(message)
        self.reason = reason or message
        """One line without the field's prefix and the hint: why the cell cannot run."""


def coerce_like(name: str, value: Any, default: Any) -> Any:
    """Converts a (possibly string) value to the type of `default`, or fails naming `name`."""
    try:
        if isinstance(default, bool):
            if isinstance(value, str):
                if value.lower() not in ("true", "false", "1", "0"):
                    raise ValueError
                return value.lower() in ("true", "1")
            return bool(value)
        if isinstance(default, int):
            if isinstance(value, str):
                return int(value)
            if isinstance(value, float) and not value.is_integer():
                raise ValueError
            return int(value)
        if isinstance(default, float):
            return float(value)
        if isinstance(default, tuple):
            items = value.split(",") if isinstance(value, str) else value
            return tuple(int(v) for v in items)
    except (TypeError, ValueError):
        kind = {bool: "true or false", int: "an integer", float: "a number"}.get(
            type(default), "a comma-separated list of integers"
        )
        raise InvalidParameter(f"{name}: must be {kind}, got {value!r}") from None
    return value


def parse_env_params(env_id: str, pairs: list[str]) -> tuple[tuple[str, Any], ...]:
    """Parses command-line `name=value` env parameters, typed like their defaults."""
    return _parse_pairs(pairs, envs.spec(env_id).parameters(), f"parameter of {env_id}")


def parse_attack_params(attack: str, pairs: list[str]) -> tuple[tuple[str, Any], ...]:
    """Parses command-line `name=value` attack parameters, typed like their defaults."""
    return _parse_pairs(pairs, attacks.parameters(attack), f"parameter of attack {attack}")


def parse_defenses(
    names: list[str], pairs: list[str]
) -> tuple[tuple[str, tuple[tuple[str, Any], ...]], ...]:
    """Parses `--defense NAME ...` and `--dp [NAME.]param=value ...` into `RunConfig.defenses`.

    A parameter may be prefixed by its defense's name; unprefixed, it goes to the one
    given defense that has it.
    """
    for name in names:
        defenses.defense_class(name)
    params: dict[str, list[str]] = {name: [] for name in names}
    for pair in pairs:
        head, sep, _ = pair.partition("=")
        owner, dot, param = head.strip().rpartition(".")
        if dot:
            if owner not in params:
                raise InvalidParameter(
                    f"defense_param: {owner!r} is not a given defense; given: "
                    f"{', '.join(names) or 'none'}"
                )
            params[owner].append(pair.strip()[len(owner) + 1 :])
            continue
        owners = [n for n in names if head.strip().replace("-", "_") in defenses.parameters(n)]
        if len(owners) != 1 or not sep:
            allowed = sorted({p for n in names for p in defenses.parameters(n)})
            raise InvalidParameter(
                f"defense_param: {head.strip()!r} is not a parameter of exactly one given "
                f"defense; allowed: {', '.join(allowed) or 'none'}"
            )
        params[owners[0]].append(pair)
    return tuple(
        (name, _parse_pairs(params[name], defenses.parameters(name), f"parameter of {name}"))
        for name in names
    )


def parse_hparams(learner: str, pairs: list[str]) -> tuple[tuple[str, str], ...]:
    """Splits `name=value` hyperparameter overrides (typed later against the defaults)."""
    names = {f.name: None for f in dataclasses.fields(learners.get(learner).config_cls)}
    return tuple(
        (name, value) for name, value in _split_pairs(pairs, names, f"hyperparameter of {learner}")
    )


def _split_pairs(pairs: list[str], allowed: dict[str, Any], what: str):
    for pair in pairs:
        name, sep, value = pair.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or not name:
            raise InvalidParameter(f"{pair}: expected name=value")
        if name not in allowed:
            raise InvalidParameter(f"{name}: not a {what}; allowed: {', '.join(allowed) or 'none'}")
        yield name, value.strip()


def _parse_pairs(pairs, defaults, what) -> tuple[tuple[str, Any], ...]:
    parsed = {
        name: coerce_like(name, value, defaults[name])
        for name, value in _split_pairs(pairs, defaults, what)
    }
    return tuple(sorted(parsed.items()))
