"""Manipulations of one agent (spec/attacks.md): strategy attacks, ADMO and the
published code's ADMO (`admo_code`), by name.

`make(name, num_agents, **params)` builds a validated attack config;
`register(cls)` adds a user's attack (the built-ins register the same way);
`registered()` lists names; `parameters(name)` gives each parameter's default.
"""

from __future__ import annotations

from typing import Any

from pimbot.attacks.admo import ADMO
from pimbot.attacks.admo_code import ADMOCode
from pimbot.attacks.strategies import Bypass, FakeIncentive, Reverse, SelfCentered
from pimbot.contracts import attack as contract
from pimbot.contracts.attack import NO_ATTACK, Attack, register
from pimbot.envs.core import InvalidParameter

for _cls in (SelfCentered, FakeIncentive, Bypass, Reverse, ADMO, ADMOCode):
    register(_cls, replace=True)

CONDITION_ORDER = (
    "clean",
    "self_centered",
    "fake_incentive",
    "bypass",
    "reverse",
    "admo_stealthy",
    "admo_disrupt",
    "admo_code_stealthy",
    "admo_code_disrupt",
)
"""The paper's display order of run conditions (attack labels); for sorting only —
conditions not in it (a plugin's) sort after it, by name."""


def registered() -> list[str]:
    return contract.ATTACKS.names()


def attack_class(name: str) -> type[Attack]:
    return contract.ATTACKS.get(name)


def parameters(name: str) -> dict[str, Any]:
    """The attack's parameters and their defaults."""
    return contract.parameters(attack_class(name))


def make(name: str, num_agents: int, **params: Any) -> Attack:
    """A validated attack config for a team of `num_agents`.

    Raises:
        InvalidParameter: unknown attack or parameter, or a bad value (named).
    """
    cls = attack_class(name)
    allowed = parameters(name)
    for key in params:
        if key not in allowed:
            raise InvalidParameter(
                f"{key}: not a parameter of attack {name}; allowed: {', '.join(allowed)}"
            )
    attack = cls(**params)
    attack.validate(num_agents)
    return attack


__all__ = [
    "ADMO",
    "NO_ATTACK",
    "ADMOCode",
    "Attack",
    "Bypass",
    "FakeIncentive",
    "Reverse",
    "SelfCentered",
    "make",
    "register",
]
