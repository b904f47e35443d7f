"""The functional environment protocol and the versioned registry.

An environment is a frozen dataclass (hashable, so it can be a static argument
of `jax.jit`) whose fields are its parameters. It is pure: `reset(key)` and
`step(key, state, actions)` never touch global state and are jit- and
vmap-able. Variants are parameters, never copied classes.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Mapping
from typing import Any, ClassVar, Protocol

import jax
import numpy as np

from pimbot.errors import InvalidParameter, check_int  # noqa: F401 (public here too)


class Env(Protocol):
    """What every registered environment provides.

    Attributes:
        num_agents: number of agents N.
        num_actions: size of each agent's discrete action set.
        obs_dim: length of each agent's observation vector.
        max_steps: episode horizon (episodes may terminate earlier).
        incentive_obs: True when the last N-1 entries of an observation are the
            cumulative incentives the agent has given to each other agent this
            episode; the env leaves them zero and an incentive learner fills them.
        idle_action: the action an agent takes when it "does nothing"
            (used by the bypass manipulation).
        stochastic: False when `reset` and `step` ignore their key (the
            conformance check then asserts that the key changes nothing).
        terminates_on_success: True when a successful step ends the episode
            (a genuine terminal state); otherwise `done` only marks the horizon
            `max_steps`, which the PettingZoo adapter reports as truncation.

    Optional: ``step_metrics``, a tuple of `info` keys whose per-step values (scalar
    or [N], numbers or bools) are summed over each episode's steps and reported by
    every learner as evaluation metrics of those names (``eval/<name>``, per agent
    ``eval/<name>/agent_<i>``); see `step_metric_names`. Optional: ``traced_fields``
    (a class attribute of a `TracedFields` env), numeric fields used only as values in
    `reset` and `step` (never in a shape or Python control flow): the env is a pytree whose
    leaves are those fields, a training program takes it as an argument, and runs that
    differ only in them share one compiled program. Optional: ``obs_parts()``, the
    observation's parts in order (`ObsPart`: name, size, meaning, units, bounds), which an
    export writes into policy.json (`observation_parts`).
    """

    num_agents: int
    num_actions: int
    obs_dim: int
    max_steps: int
    incentive_obs: bool
    idle_action: int
    stochastic: bool
    terminates_on_success: bool

    def reset(self, key: jax.Array) -> tuple[jax.Array, Any]:
        """Returns (obs float32 [N, obs_dim], state)."""
        ...

    def step(
        self, key: jax.Array, state: Any, actions: jax.Array
    ) -> tuple[jax.Array, Any, jax.Array, jax.Array, dict[str, jax.Array]]:
        """Returns (obs [N, obs_dim], state, rewards float32 [N], done bool [], info).

        `info["success"]` is a bool scalar for this step (env-specific meaning).
        """
        ...

    def obs_bounds(self) -> tuple[float, float]:
        """Lower and upper bound of every observation entry (inf where unbounded)."""
        ...

    def episode_success(
        self, success_steps: jax.Array, num_steps: jax.Array, env_return: jax.Array
    ) -> jax.Array:
        """Success score of one episode in [0, 1] from its per-step flags.

        Args:
            success_steps: number of steps whose `info["success"]` was true.
            num_steps: number of steps the episode lasted.
            env_return: float32 [N] environment return of each agent.
        """
        ...


class TracedFields:
    """Base of an env (or a learner config) whose numbers are a compiled program's
    arguments: a pytree whose leaves
    are the fields its class names in `traced_fields` and whose static part (the treedef)
    is its class and every other field. This is the data/meta split of
    `jax.tree_util.register_dataclass` and of the attacks' `flax.struct` (numbers are data,
    structure is meta), and gymnax's `EnvParams`: passed into `jax.jit`, the numbers are
    traced and the structure is static, so envs that differ only in them share a program.
    A learner config does the same (`pimbot.contracts.learner.program_config`).

    Unflattening does not call `__init__`: the leaves are then tracers (or the placeholders
    JAX passes while it transforms), and the env's validation (`__post_init__`) ran once,
    when the env was made. The new instance gets its fields as `pickle` restores an
    instance, following the custom-pytree guidance of JAX
    (https://docs.jax.dev/en/latest/custom_pytrees.html, "initialization with unexpected
    values"); no existing env is changed. Subclasses are registered when they are defined.
    """

    traced_fields: ClassVar[tuple[str, ...]] = ()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        jax.tree_util.register_pytree_with_keys(
            cls, _flatten_with_keys, functools.partial(_unflatten, cls), _flatten
        )


def _split(env: TracedFields) -> tuple[tuple[str, ...], tuple[tuple[str, Any], ...]]:
    """(the traced field names, every other field's (name, value)): the treedef's part."""
    names = tuple(type(env).traced_fields)
    static = tuple(
        (f.name, getattr(env, f.name)) for f in dataclasses.fields(env) if f.name not in names
    )
    return names, static


def _flatten(env: TracedFields):
    names, static = _split(env)
    return tuple(getattr(env, name) for name in names), (names, static)


def _flatten_with_keys(env: TracedFields):
    names, static = _split(env)
    keyed = tuple((jax.tree_util.GetAttrKey(name), getattr(env, name)) for name in names)
    return keyed, (names, static)


def _unflatten(cls: type, aux, leaves) -> Any:
    """A new `cls` with these fields, `__init__` not called (see `TracedFields`)."""
    names, static = aux
    env = object.__new__(cls)
    vars(env).update(static)
    vars(env).update(zip(names, leaves, strict=True))
    return env


def traced_fields(env: Env) -> tuple[str, ...]:
    """The fields `env` declares traced (`Env.traced_fields`; none by default)."""
    return tuple(getattr(env, "traced_fields", ()))


def check_traced_numbers(obj: Any) -> None:
    """Refuses by name a traced field of `obj` (an env or a learner config) that is no bool,
    int or float (it would trace as some other pytree, or not at all)."""
    for name in traced_fields(obj):
        value = getattr(obj, name, None)
        if not isinstance(value, (bool, int, float)):
            raise InvalidParameter(
                f"{type(obj).__name__}.traced_fields: {name} must be a bool, int or float "
                f"field, got {value!r}"
            )


def program_env(env: Env) -> Env | None:
    """What a compiled program takes for `env`: the env itself where it is a `TracedFields`
    pytree (its traced fields become the program's traced arguments), else None: an env
    without traced numbers is all structure, and the program closes over it."""
    if not isinstance(env, TracedFields):
        return None
    check_traced_numbers(env)
    return env


def step_metric_names(env: Env) -> tuple[str, ...]:
    """The `info` keys `env` declares as per-step metrics (``step_metrics``; none if absent)."""
    return tuple(getattr(env, "step_metrics", ()))


FALLBACK_EVAL_PERIOD = 1000
"""Training iterations between evaluations on an env that declares none."""
FALLBACK_EVAL_EPISODES = 10
"""Episodes per evaluation point on an env that declares none."""


@dataclasses.dataclass(frozen=True)
class ObsPart:
    """One part of an agent's observation, as a robot must build it."""

    name: str
    size: int
    meaning: str
    units: str
    low: float
    high: float | None
    """None: unbounded (the env cannot know the bound: an incentive sum, say)."""


def observation_parts(env: Env) -> tuple[ObsPart, ...]:
    """The parts of `env`'s observation (`obs_parts()` where it declares them), checked to
    add up to `obs_dim`; one part, "observation", with `obs_bounds()`, where it does not.

    Raises:
        InvalidParameter: declared parts whose sizes do not add up to `obs_dim`.
    """
    declare = getattr(env, "obs_parts", None)
    if declare is None:
        low, high = env.obs_bounds()
        meaning = "the env's observation of this agent (its docs say what each entry is)"
        return (ObsPart("observation", env.obs_dim, meaning, "", low, _finite(high)),)
    parts = tuple(declare())
    if sum(p.size for p in parts) != env.obs_dim:
        raise InvalidParameter(
            f"{type(env).__name__}.obs_parts: sizes {[p.size for p in parts]} add up to "
            f"{sum(p.size for p in parts)}, not obs_dim = {env.obs_dim}"
        )
    return parts


def _finite(bound: float) -> float | None:
    return bound if np.isfinite(bound) else None


@dataclasses.dataclass(frozen=True)
class EnvSpec:
    """A registry entry: the id, the constructor, a one-line description, and the facts of
    the environment that are no parameter of it (how it is evaluated, its action names).

    Which learner hyperparameters suit an env is declared by whichever of the two is
    registered later, as it knows the other: the built-in learners declare theirs for the
    built-in envs in their registry entries (`pimbot.contracts.learner.LearnerDef.
    env_defaults`, `env_params`); a plugin env declares the learners' defaults on it here
    (`learner_defaults`, `learner_env_defaults`); a learner's entry wins where both name a
    field. Its best team return, where known, depends on the parameters: the env object's
    optional ``optimal_team_return`` (e.g. `EscapeRoom`).
    """

    env_id: str
    constructor: Callable[..., Env]
    description: str
    learner_defaults: Mapping[str, Mapping[str, Any]] = dataclasses.field(default_factory=dict)
    """learner name -> hyperparameter overrides of its base config on this environment,
    as the env's author declares them (a plugin env; see the class docstring)."""
    learner_env_defaults: Mapping[str, Mapping[str, Any]] = dataclasses.field(default_factory=dict)
    """learner name -> env parameters a run of that learner uses where the user gave none,
    as the env's author declares them."""
    eval_period: int = FALLBACK_EVAL_PERIOD
    """Training iterations between evaluations where a run names none (a shorter run is
    evaluated once, at its end)."""
    eval_episodes: int = FALLBACK_EVAL_EPISODES
    """Episodes per evaluation point where a run names none."""
    action_names: tuple[str, ...] = ()
    """Each action's name by index, for reports (none: reports write ``a<index>``)."""

    def parameters(self) -> dict[str, Any]:
        """The constructor's parameters with their defaults."""
        return {
            f.name: f.default
            for f in dataclasses.fields(self.constructor)  # type: ignore[arg-type]
            if f.init
        }


_REGISTRY: dict[str, EnvSpec] = {}


def register(
    env_id: str,
    constructor: Callable[..., Env],
    description: str,
    learner_defaults: Mapping[str, Mapping[str, Any]] | None = None,
    learner_env_defaults: Mapping[str, Mapping[str, Any]] | None = None,
    *,
    eval_period: int = FALLBACK_EVAL_PERIOD,
    eval_episodes: int = FALLBACK_EVAL_EPISODES,
    action_names: tuple[str, ...] = (),
) -> None:
    """Adds an environment constructor under a versioned id (e.g. ``"my_env-v0"``).

    Args:
        learner_defaults: per learner name, the hyperparameters it should use here
            (e.g. ``{"lio": {"lr_policy": 1e-3}}``); learners not named keep their base
            config (or what their registry entries declare for this id).
        learner_env_defaults: per learner name, env parameters its runs default to
            (e.g. ``{"reciprocator": {"max_steps": 32}}``); a parameter the run gives wins.
        eval_period, eval_episodes: how runs on this env are evaluated where they name
            no other (`EnvSpec`).
        action_names: each action's name by index (`EnvSpec.action_names`).
    """
    check_int("eval_period", eval_period, 1)
    check_int("eval_episodes", eval_episodes, 1)
    entry = EnvSpec(
        env_id,
        constructor,
        description,
        dict(learner_defaults or {}),
        {name: dict(params) for name, params in (learner_env_defaults or {}).items()},
        eval_period,
        eval_episodes,
        tuple(action_names),
    )
    if env_id in _REGISTRY and _REGISTRY[env_id] != entry:
        raise ValueError(f"env id {env_id!r} is already registered")
    _REGISTRY[env_id] = entry


def registered() -> list[str]:
    """The registered environment ids, sorted."""
    return sorted(_REGISTRY)


def spec(env_id: str) -> EnvSpec:
    """The registry entry of `env_id`; unknown ids fail listing the valid ones."""
    if env_id not in _REGISTRY:
        raise InvalidParameter(
            f"env_id: unknown environment {env_id!r}; registered: {', '.join(registered())}"
        )
    return _REGISTRY[env_id]


def ids_of(constructor: Callable[..., Env]) -> list[str]:
    """The ids `constructor` is registered under, sorted (code written for one env class,
    such as the robot case study's Escape Room, finds its id here rather than naming it)."""
    return sorted(i for i, entry in _REGISTRY.items() if entry.constructor is constructor)


def make(env_id: str, **params: Any) -> Env:
    """Builds the environment `env_id` with the given parameters.

    Raises:
        InvalidParameter: unknown id, unknown parameter name, or a bad value;
            the message names the field and the allowed values.
    """
    entry = spec(env_id)
    allowed = entry.parameters()
    for name in params:
        if name not in allowed:
            raise InvalidParameter(
                f"{name}: not a parameter of {env_id}; allowed: {', '.join(allowed) or 'none'}"
            )
    return entry.constructor(**params)
