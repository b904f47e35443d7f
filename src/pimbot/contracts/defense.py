"""The defense contract: training-time safeguards folded over at named hook points.

A run's defenses are a tuple of frozen pytree configs (numeric parameters are
traced leaves). At each hook point a learner folds over the tuple, in the
order given, passing one context object; a defense overrides only the hooks it
lists in `hooks`, and a learner that lacks one of them refuses it by name:

* `acting_epsilon`      — ε of every agent's acting policy and policy step;
* `learning_incentives` — the incentives the recipients learn from;
* `after_policy_step`   — a look at the policy step just taken (may replace it).

Only honest agents run defenses: against an attack, the adversary's own code is
the attacker's; in a clean run every agent is honest.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
from flax import struct

from pimbot.contracts import conformance
from pimbot.contracts.registry import Registry

HOOKS = ("acting_epsilon", "learning_incentives", "after_policy_step")


@dataclasses.dataclass(frozen=True)
class EpsilonContext:
    epsilon: jax.Array
    """[] the schedule's ε, or [N] per agent after an earlier defense."""
    honest: jax.Array
    """bool [N], the agents that run defenses."""


@dataclasses.dataclass(frozen=True)
class IncentiveContext:
    accepted: jax.Array
    """[T, N giver, N recipient] what recipients learn from so far (the incentives sent,
    masked to valid steps, after earlier defenses)."""
    sent: jax.Array
    """[T, N, N] as sent."""
    valid: jax.Array
    """bool [T]."""
    incentive_max: float
    """R_max of honest incentives."""
    honest: jax.Array


@dataclasses.dataclass(frozen=True)
class PolicyStepContext:
    policy: Any
    """The stacked policy after the step [N, ...] (after earlier defenses)."""
    iteration: jax.Array
    sent: jax.Array
    """[T, N, N] incentives as sent on the episode learnt from (zeros without a channel)."""
    valid: jax.Array
    env_rewards: jax.Array
    """[T, N]."""
    gradients: Callable[[jax.Array], jax.Array]
    """rewards [K, T, N] -> flat score-function policy gradients [K, N, P] on that episode."""
    incentive_max: float
    honest: jax.Array


@struct.dataclass
class Defense:
    """The base of every defense: every hook is the identity."""

    name: ClassVar[str] = "defense"
    hooks: ClassVar[tuple[str, ...]] = ()

    def validate(self, num_agents: int) -> None:
        """Raises InvalidParameter naming the bad field."""
        del num_agents

    def init_state(self, num_agents: int, policy) -> Any:
        del num_agents, policy
        return {}

    def acting_epsilon(self, state, ctx: EpsilonContext) -> jax.Array:
        del state
        return ctx.epsilon

    def learning_incentives(self, state, ctx: IncentiveContext):
        """(accepted [T, N, N], state, metrics)."""
        return ctx.accepted, state, {}

    def after_policy_step(self, state, ctx: PolicyStepContext):
        """(policy, state, metrics)."""
        return ctx.policy, state, {}


Defenses = tuple[Defense, ...]
NO_DEFENSE: Defenses = ()

DEFENSES: Registry[type[Defense]] = Registry("defense", "defenses")


def register(cls: type[Defense], *, replace: bool = False) -> type[Defense]:
    """Registers a defense class under `cls.name` (usable as a class decorator).

    Its code is checked against what it declares (`conformance.check_hooked_class`), and
    the hooks it overrides are replaced by checked ones (`conformance.install_checks`: each
    output checked against the contract below while a program is traced; an exception
    inside the defense's code is one line at its file and line).

    Raises:
        ContractError: one line naming the class's file and line.
    """
    registered = DEFENSES.register_hooked_class(cls, Defense, HOOKS, replace=replace)
    conformance.install_checks(cls, Defense, OUTPUT_CHECKS)
    return registered


def honest_agents(attack, num_agents: int) -> jax.Array:
    """bool [N]: the agents that run defenses — all but the adversary (all when clean)."""
    if not attack.active:
        return jnp.ones((num_agents,), bool)
    return ~attack.is_adversary(num_agents)


def init_states(defenses: Defenses, num_agents: int, policy) -> tuple:
    """Each defense's own state, in order (kept in the learner state)."""
    return tuple(d.init_state(num_agents, policy) for d in defenses)


def acting_epsilon(defenses: Defenses, states: tuple, ctx: EpsilonContext) -> jax.Array:
    epsilon = ctx.epsilon
    for defense, state in zip(defenses, states, strict=True):
        epsilon = defense.acting_epsilon(state, dataclasses.replace(ctx, epsilon=epsilon))
    return epsilon


def learning_incentives(defenses: Defenses, states: tuple, ctx: IncentiveContext):
    """(accepted, new states, metrics) folded over the defenses in order."""
    accepted, new_states, metrics = ctx.accepted, [], {}
    for defense, state in zip(defenses, states, strict=True):
        step_ctx = dataclasses.replace(ctx, accepted=accepted)
        accepted, state, step_metrics = defense.learning_incentives(state, step_ctx)
        new_states.append(state)
        metrics.update(step_metrics)
    return accepted, tuple(new_states), metrics


def after_policy_step(defenses: Defenses, states: tuple, ctx: PolicyStepContext):
    """(policy, new states, metrics) folded over the defenses in order."""
    policy, new_states, metrics = ctx.policy, [], {}
    for defense, state in zip(defenses, states, strict=True):
        policy, state, step_metrics = defense.after_policy_step(
            state, dataclasses.replace(ctx, policy=policy)
        )
        new_states.append(state)
        metrics.update(step_metrics)
    return policy, tuple(new_states), metrics


# --- each hook's output, as the learners take it (checked at trace time) ------------------


def _acting_epsilon_problem(defense: Defense, out, args) -> str | None:
    n = jnp.shape(args["ctx"].honest)[0]
    return conformance.array_problem(out, [(), (n,)])


def _folded_problem(out, args, first: str, expected, shape_words: str) -> str | None:
    """Why `out` is not (`first` like `expected`, the state as it came in, metrics)."""
    if not (isinstance(out, tuple | list) and len(out) == 3):
        return f"a {type(out).__name__}; expected ({first}, state, metrics)"
    value, state, metrics = out
    problem = conformance.like_problem(value, expected, first)
    if problem:
        return f"{problem} ({shape_words})"
    n = jnp.shape(args["ctx"].honest)[0]
    return conformance.like_problem(state, args["state"], "a state") or (
        conformance.metrics_problem(metrics, n)
    )


def _learning_incentives_problem(defense: Defense, out, args) -> str | None:
    accepted = args["ctx"].accepted
    return _folded_problem(out, args, "accepted", accepted, "[T, N giver, N recipient]")


def _after_policy_step_problem(defense: Defense, out, args) -> str | None:
    policy = args["ctx"].policy
    return _folded_problem(out, args, "policy", policy, "the stacked policy, as ctx.policy")


OUTPUT_CHECKS: dict[str, conformance.OutputCheck | None] = {
    "acting_epsilon": _acting_epsilon_problem,
    "learning_incentives": _learning_incentives_problem,
    "after_policy_step": _after_policy_step_problem,
    "init_state": None,  # any pytree: an exception inside it is still one line
    "validate": None,
}
"""Every hook's output check (`conformance.install_checks`), by the contract above."""
