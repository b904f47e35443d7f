"""The functional environment protocol and the versioned registry.

An environment is a frozen dataclass (hashable, so it can be a static argument
of `jax.jit`) whose fields are its parameters. It is pure: `reset(key)` and
`step(key, state, actions)` never touch global state and are jit- and
vmap-able. Variants are parameters, never copied classes.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable, Mapping
from typing import Any, Protocol

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
    (a class attribute), numeric fields used only as values in `reset` and `step` (never
    in a shape or Python control flow): training programs take them as traced arguments,
    so runs that differ only in them share one compiled program
    (`traced_values`, `with_traced`).
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


def traced_fields(env: Env) -> tuple[str, ...]:
    """The fields `env` declares traced (`Env.traced_fields`; none by default)."""
    return tuple(getattr(env, "traced_fields", ()))


def traced_values(env: Env) -> dict[str, np.ndarray]:
    """Each traced field's value as a 0-d bool, int32 or float32 array (a program's
    traced argument); a field that is no bool, int or float is refused by name."""
    values: dict[str, np.ndarray] = {}
    for name in traced_fields(env):
        value = getattr(env, name, None)
        if isinstance(value, bool):
            values[name] = np.bool_(value)
        elif isinstance(value, int):
            values[name] = np.int32(value)
        elif isinstance(value, float):
            values[name] = np.float32(value)
        else:
            raise InvalidParameter(
                f"{type(env).__name__}.traced_fields: {name} must be a bool, int or float "
                f"field, got {value!r}"
            )
    return values


def with_traced(env: Env, values: Mapping[str, Any]) -> Env:
    """`env` with its traced fields set to `values` (tracers inside a program; its
    validation is not rerun: the values were validated when it was made)."""
    fields = traced_fields(env)
    if not fields:
        return env
    traced = copy.copy(env)
    for name in fields:
        object.__setattr__(traced, name, values[name])
    return traced


def step_metric_names(env: Env) -> tuple[str, ...]:
    """The `info` keys `env` declares as per-step metrics (``step_metrics``; none if absent)."""
    return tuple(getattr(env, "step_metrics", ()))


@dataclasses.dataclass(frozen=True)
class EnvSpec:
    """A registry entry: the id, the constructor, a one-line description, and the
    hyperparameters each learner should default to on this environment."""

    env_id: str
    constructor: Callable[..., Env]
    description: str
    learner_defaults: Mapping[str, Mapping[str, Any]] = dataclasses.field(default_factory=dict)
    """learner name -> hyperparameter overrides of its base config on this environment."""
    learner_env_defaults: Mapping[str, Mapping[str, Any]] = dataclasses.field(default_factory=dict)
    """learner name -> env parameters a run of that learner uses where the user gave none
    (e.g. the Reciprocator's 32-step IPD episodes)."""

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
) -> None:
    """Adds an environment constructor under a versioned id (e.g. ``"my_env-v0"``).

    Args:
        learner_defaults: per learner name, the hyperparameters it should use here
            (e.g. ``{"lio": {"lr_policy": 1e-3}}``); learners not named keep their base
            config.
        learner_env_defaults: per learner name, env parameters its runs default to
            (e.g. ``{"reciprocator": {"max_steps": 32}}``); a parameter the run gives wins.
    """
    entry = EnvSpec(
        env_id,
        constructor,
        description,
        dict(learner_defaults or {}),
        {name: dict(params) for name, params in (learner_env_defaults or {}).items()},
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
