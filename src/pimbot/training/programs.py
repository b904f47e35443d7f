"""Compiled programs of a suite: which jobs share one, and the attack that lets them.

A training job's compiled chunk is determined by everything the runner closes
over (the env, the learner and its config, the evaluation schedule, the
chunk length) and by the *structure* of the attack and defenses it is given
(their classes and static fields); their numeric parameters are traced.
`program_key` is that determinant, so two jobs with equal keys run on one
compiled program.

Attacks of different classes are different structures; the strategy attacks fold into
one (`pimbot.attacks.strategy_union.Strategies`), and `share_key` is the key after
that folding (the planner's grouping key).

An attack's `program_form` is what the program is compiled for: a static field
that only selects a number becomes a traced leaf there (ADMO's mode, a ±1
sign), so jobs that differ only in it share one program too.

Envs follow the same rule: an env whose class is an `envs.core.TracedFields` is a pytree
whose leaves are its `traced_fields`, the numbers its compiled code uses only as values,
never in a shape or in Python control flow (Escape Room's M), and whose treedef is its
class and every other field. The program takes the env itself as an argument
(`envs.core.program_env`), and the reciprocal of its known optimal team return and the
optimal-rate threshold beside it (`optimum_numbers`), so ER(4, 2) and ER(4, 3) share one
program. An env that is no `TracedFields` has no traced numbers: the program closes over it.

Learner configs follow it too (`contracts.learner.program_config`): a config whose class is
a `TracedFields` enters as an argument, its `traced_fields` traced, so runs that differ only
in those hyperparameters (the Reciprocator's balance and weight, for example: `nl` is its
weight 0) share one program. The learner enters by its code (`learner_code`), not its name.
"""

from __future__ import annotations

import dataclasses
import hashlib
from typing import Any

import numpy as np

from pimbot.attacks import strategy_union
from pimbot.attacks.strategy_union import structure
from pimbot.contracts.attack import Attack
from pimbot.contracts.learner import program_config
from pimbot.envs.core import program_env
from pimbot.training.config import ResolvedRun, memoized


def optimum_numbers(env: Any) -> dict[str, np.float32]:
    """Where `env` knows its optimal team return (from its numbers, on the host): that
    return's reciprocal and the optimal-rate threshold 0.9 × it, traced arguments of the
    program beside the env; else none."""
    optimum = getattr(env, "optimal_team_return", None)
    if not optimum:
        return {}
    # XLA turns a division by a constant into a product with its float32 reciprocal; the
    # ratio is that product, so it stays bitwise what it was with the optimum compiled in
    return {
        "optimal_team_return_reciprocal": np.float32(1.0) / np.float32(optimum),
        "optimal_threshold": np.float32(0.9 * optimum),
    }


def _env_structure(env: Any) -> tuple:
    """What of `env` the program is compiled for: the structure of the env it takes as an
    argument (its class and static fields), or all of an env it closes over (its repr)."""
    argument = program_env(env)
    closed_over = repr(env) if argument is None else None
    return closed_over, structure(argument), structure(optimum_numbers(env))


def learner_code(learner: Any) -> tuple[str, ...]:
    """The code a learner's program runs: its config class and its four functions, by
    module and name. Two registered learners that share them (the Reciprocator and `nl`, its
    weight-0 variant) compile one program; their names are no part of it."""
    parts = (learner.config_cls, learner.init, learner.update, learner.evaluate, learner.acting)
    names = tuple(
        f"{getattr(part, '__module__', '?')}.{getattr(part, '__qualname__', repr(part))}"
        for part in parts
    )
    if any("<" in name or "?" in name for name in names):  # a lambda, a local, a partial:
        names += (learner.name,)  # its name may not tell it apart, so the learner's does
    return names


def _config_structure(cfg: Any) -> tuple:
    """What of a learner config the program is compiled for: the structure of the config it
    takes as an argument (`program_config`), or all of a config it closes over (its repr)."""
    argument = program_config(cfg)
    return (repr(cfg),) if argument is None else structure(argument)


def _closed_over(resolved: ResolvedRun, periods: int, seeds: int, devices: int) -> tuple:
    """What the chunk closes over, besides the attack, the defenses and the env's traced
    numbers (their structure is part of the key)."""
    return (
        type(resolved.env).__module__,
        type(resolved.env).__qualname__,
        _env_structure(resolved.env),
        learner_code(resolved.learner),
        _config_structure(resolved.learner_config),
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
        structure(resolved.attack.program_form()),
        structure(resolved.defenses),
    )
    return hashlib.sha256(repr(parts).encode()).hexdigest()[:16]


def share_key(resolved: ResolvedRun, periods: int, seeds: int, devices: int = 1) -> str:
    """`program_key` after folding the strategy attacks: the planner's grouping key (a
    group that mixes strategy kinds across learner entries is then split by entry:
    `pimbot.suites.jobs.train_partition`)."""
    attack = resolved.attack
    attack_part = (
        ("strategies", attack.adversary)
        if strategy_union.shareable(attack)
        else structure(attack.program_form())
    )
    parts = (
        _closed_over(resolved, periods, seeds, devices),
        attack_part,
        structure(resolved.defenses),
    )
    return hashlib.sha256(repr(parts).encode()).hexdigest()[:16]


def with_attack(resolved: ResolvedRun, attack: Attack) -> ResolvedRun:
    return dataclasses.replace(resolved, attack=attack)


def _of(kind: str, obj: Any, make) -> Any:
    """`make(obj)`, once per object inside `config.resolving()` (whose runs share their
    parts); the object is kept with it, so its id is not reused meanwhile."""
    return memoized(kind, id(obj), lambda: (obj, make(obj)))[1]


def state_structure(resolved: ResolvedRun) -> tuple:
    """What the shapes of a run's learner state depend on: the structure its program is
    compiled for (`program_key` without the schedule: numbers that are traced never set a
    shape). Runs with one `state_structure` have states of one size per seed."""
    return (
        type(resolved.env).__module__,
        type(resolved.env).__qualname__,
        _of("env_structure", resolved.env, _env_structure),
        _of("learner_code", resolved.learner, learner_code),
        _of("config_structure", resolved.learner_config, _config_structure),
        _of("attack_structure", resolved.attack, lambda a: structure(a.program_form())),
        _of("defense_structure", resolved.defenses, structure),
    )
