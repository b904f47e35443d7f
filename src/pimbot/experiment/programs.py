"""Compiled programs of a suite: which jobs share one, and the attack that lets them.

A training job's compiled chunk is determined by everything the runner closes
over (the env, the learner and its config, the evaluation schedule, the
chunk length) and by the *structure* of the attack and defenses it is given
(their classes and static fields); their numeric parameters are traced.
`program_key` is that determinant, so two jobs with equal keys run on one
compiled program.

Attacks of different classes are different structures. The strategy attacks
(every attack without an `adversary_step`) are cheap elementwise hooks, so
`Strategies` folds several of them into one structure: it computes every
member's hook and keeps the chosen member's output with `jnp.where` on a
traced index, so a job of any member class runs on the same program and gets
exactly its own member's values. `shared_attack` builds it; `share_key` is the
key after that folding (the planner's grouping key).

An attack's `program_form` is what the program is compiled for: a static field
that only selects a number becomes a traced leaf there (ADMO's mode, a ±1
sign), so jobs that differ only in it share one program too.

An env's `traced_fields` (optional) name the numbers its compiled code uses only
as values, never in a shape or in Python control flow (Escape Room's M): the
program takes them, and the env's known optimal team return, as traced
arguments (`env_numbers`) and runs on `envs.core.with_traced(env, numbers)`, so ER(4, 2)
and ER(4, 3) share one program.
"""

from __future__ import annotations

import dataclasses
import hashlib
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from pimbot.contracts.attack import Attack
from pimbot.envs.core import traced_fields, traced_values, with_traced
from pimbot.experiment.config import ResolvedRun


def _structure(tree: Any) -> tuple:
    """Class/static structure and leaf avals of a pytree (not its numbers)."""
    leaves, treedef = jax.tree.flatten(tree)
    avals = tuple((jnp.shape(x), jnp.result_type(x).name, _weak(x)) for x in leaves)
    return (str(treedef), avals)


def _weak(x: Any) -> bool:
    return isinstance(x, (bool, int, float, complex)) or bool(getattr(x, "weak_type", False))


def env_numbers(env: Any) -> dict[str, Any]:
    """The traced numbers of `env`'s program: its traced fields (`envs.core.traced_values`)
    and, where the env knows its optimal team return, that return's reciprocal and the
    optimal-rate threshold 0.9 × it."""
    numbers: dict[str, Any] = traced_values(env)
    optimum = getattr(env, "optimal_team_return", None)
    if optimum:
        # XLA turns a division by a constant into a product with its float32 reciprocal;
        # the ratio is that product, so it stays bitwise what it was with the optimum
        # compiled in
        numbers["optimal_team_return_reciprocal"] = np.float32(1.0) / np.float32(optimum)
        numbers["optimal_threshold"] = np.float32(0.9 * optimum)
    return numbers


def _env_structure(env: Any) -> str:
    """`env`'s repr with its traced fields left out (their values are arguments)."""
    return repr(with_traced(env, {name: "<traced>" for name in traced_fields(env)}))


def _closed_over(resolved: ResolvedRun, periods: int, seeds: int, devices: int) -> tuple:
    """What the chunk closes over, besides the attack, the defenses and the env's
    traced numbers (their structure is part of the key)."""
    return (
        type(resolved.env).__module__,
        type(resolved.env).__qualname__,
        _env_structure(resolved.env),
        _structure(env_numbers(resolved.env)),
        resolved.run.learner,
        repr(resolved.learner_config),
        resolved.eval_period,
        resolved.eval_episodes,
        periods,
        seeds,
        devices,
    )


def program_key(resolved: ResolvedRun, periods: int, seeds: int, devices: int = 1) -> str:
    """A digest of what determines the compiled chunk of `periods` evaluation periods for
    `seeds` (padded) seeds on `devices` devices: jobs with equal keys share one program."""
    parts = (
        _closed_over(resolved, periods, seeds, devices),
        _structure(resolved.attack.program_form()),
        _structure(resolved.defenses),
    )
    return hashlib.sha256(repr(parts).encode()).hexdigest()[:16]


def shareable(attack: Attack) -> bool:
    """Whether `attack` may be folded into `Strategies`: no learning step and no per-seed
    state of its own (the members' states must share one structure; a stateful plugin
    attack, e.g. one growing its incentive in `observe`, gets its own program)."""
    stateless = type(attack).init_state is Attack.init_state and "observe" not in attack.hooks
    return "adversary_step" not in attack.hooks and stateless


def share_key(resolved: ResolvedRun, periods: int, seeds: int, devices: int = 1) -> str:
    """`program_key` after folding the strategy attacks: the planner's grouping key."""
    attack = resolved.attack
    attack_part = (
        ("strategies", attack.adversary) if shareable(attack) else _structure(attack.program_form())
    )
    parts = (
        _closed_over(resolved, periods, seeds, devices),
        attack_part,
        _structure(resolved.defenses),
    )
    return hashlib.sha256(repr(parts).encode()).hexdigest()[:16]


@struct.dataclass
class Strategies(Attack):
    """One of several strategy attacks, chosen by a traced index (`which`).

    Every member's hook is computed and the chosen member's output kept with
    `jnp.where`, so the values are exactly those of the chosen attack run alone.
    The members share the adversary; their per-seed states must have one
    structure (the strategies' states are empty), and the state is the chosen
    member's.
    """

    members: tuple = ()
    which: Any = 0

    name: ClassVar[str] = "strategies"
    lever: ClassVar[str] = "any"
    hooks: ClassVar[tuple[str, ...]] = ("act", "emit", "learning_rewards", "policy_sign", "observe")

    def _pick(self, outputs):
        chosen = outputs[0]
        for k, out in enumerate(outputs[1:], start=1):
            chosen = jax.tree.map(lambda a, b, k=k: jnp.where(self.which == k, a, b), out, chosen)
        return chosen

    def is_adversary(self, num_agents: int) -> jax.Array:
        active = jnp.asarray([m.active for m in self.members])[self.which]
        return (jnp.arange(num_agents) == self.adversary) & active

    def init_state(self, key, num_agents, adversary):
        states = [m.init_state(key, num_agents, adversary) for m in self.members]
        return self._pick(states)

    def act(self, state, key, actions, at):
        return self._pick([m.act(state, key, actions, at) for m in self.members])

    def emit(self, state, key, given_so_far):
        return self._pick([m.emit(state, key, given_so_far) for m in self.members])

    def learning_rewards(self, state, env_rewards, received):
        return self._pick([m.learning_rewards(state, env_rewards, received) for m in self.members])

    def policy_sign(self, state, num_agents):
        return self._pick([m.policy_sign(state, num_agents) for m in self.members])

    def observe(self, state, key, outcome):
        return self._pick([m.observe(state, key, outcome) for m in self.members])


def member_kind(attack: Attack) -> str:
    """The structure of a strategy attack (its class and static fields)."""
    return _structure(jax.tree.map(lambda _: 0, attack))[0]


def shared_attack(attack: Attack, templates: dict[str, Attack]) -> Strategies:
    """`attack` as the member of `Strategies` over the kinds in `templates` (kind ->
    an attack of that kind; sorted by kind so every job of a group builds one structure).
    The other members are placeholders: their values are computed and discarded."""
    kinds = sorted(templates)
    mine = member_kind(attack)
    members = tuple(attack if kind == mine else templates[kind] for kind in kinds)
    return Strategies(
        adversary=attack.adversary, members=members, which=jnp.int32(kinds.index(mine))
    )


def with_attack(resolved: ResolvedRun, attack: Attack) -> ResolvedRun:
    return dataclasses.replace(resolved, attack=attack)
