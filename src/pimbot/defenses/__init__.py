"""Defenses against manipulation of incentive-based MARL (docs/defenses.md), by name.

Training-time defenses, folded over at the hook points of
`pimbot.contracts.defense` in the order given: `incentive_guard`,
`exploration_floor`, `health_monitor`. `make(name, **params)` builds a
validated config, `compose([(name, params), ...])` a run's tuple of them;
`register(cls)` adds a user's defense; `registered()` lists names;
`parameters(name)` gives defaults. Deployment-layer defenses: `channel`
(authenticated incentive messages) and `audit` (keyed, tamper-evident log).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from pimbot.contracts import defense as contract
from pimbot.contracts.defense import NO_DEFENSE, Defense, Defenses, register
from pimbot.defenses.exploration import ExplorationFloor
from pimbot.defenses.guard import IncentiveGuard
from pimbot.defenses.monitor import HealthMonitor
from pimbot.envs.core import InvalidParameter

for _cls in (IncentiveGuard, ExplorationFloor, HealthMonitor):
    register(_cls, replace=True)


def registered() -> list[str]:
    return contract.DEFENSES.names()


def defense_class(name: str) -> type[Defense]:
    return contract.DEFENSES.get(name)


def parameters(name: str) -> dict[str, Any]:
    """The defense's parameters and their defaults."""
    import dataclasses

    return {f.name: f.default for f in dataclasses.fields(defense_class(name)) if f.init}


def make(name: str, num_agents: int, **params: Any) -> Defense:
    """A validated defense config.

    Raises:
        InvalidParameter: unknown defense or parameter, or a bad value (named).
    """
    cls = defense_class(name)
    allowed = parameters(name)
    for key in params:
        if key not in allowed:
            raise InvalidParameter(
                f"{key}: not a parameter of defense {name}; allowed: {', '.join(allowed)}"
            )
    defense = cls(**params)
    defense.validate(num_agents)
    return defense


def compose(specs: Iterable[tuple[str, dict[str, Any]]], num_agents: int) -> Defenses:
    """A run's defenses from (name, params) pairs, in the order given; each at most once."""
    made: list[Defense] = []
    for name, params in specs:
        if any(d.name == name for d in made):
            raise InvalidParameter(f"defenses: {name} given twice; give each defense once")
        made.append(make(name, num_agents, **dict(params)))
    return tuple(made)


__all__ = [
    "NO_DEFENSE",
    "Defense",
    "Defenses",
    "ExplorationFloor",
    "HealthMonitor",
    "IncentiveGuard",
    "compose",
    "make",
    "parameters",
    "register",
    "registered",
]
