"""Manipulations of one agent (spec/attacks.md): strategy attacks and ADMO, by name.

`make(name, **params)` builds a validated attack config; `registered()` lists
names; `parameters(name)` gives each parameter's default and description.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from pimbot.attacks.admo import ADMO
from pimbot.attacks.strategies import Attack, Bypass, FakeIncentive, Reverse, SelfCentered
from pimbot.envs.core import InvalidParameter

ATTACKS: dict[str, type[Attack]] = {
    cls.name: cls for cls in (SelfCentered, FakeIncentive, Bypass, Reverse, ADMO)
}


def registered() -> list[str]:
    return list(ATTACKS)


def attack_class(name: str) -> type[Attack]:
    if name not in ATTACKS:
        raise InvalidParameter(f"attack: unknown attack {name!r}; allowed: {', '.join(ATTACKS)}")
    return ATTACKS[name]


def parameters(name: str) -> dict[str, Any]:
    """The attack's parameters and their defaults."""
    return {f.name: f.default for f in dataclasses.fields(attack_class(name)) if f.init}


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


__all__ = ["ADMO", "Attack", "Bypass", "FakeIncentive", "Reverse", "SelfCentered", "make"]
