"""Manipulations of one agent (docs/attacks.md): strategy attacks, ADMO and the
published code's ADMO (`admo_code`) and its Stag Hunt ADMO (`negated_env_reward`),
by name.

`make(name, num_agents, **params)` builds a validated attack config;
`register(cls)` adds a user's attack (the built-ins register the same way);
`registered()` lists names; `parameters(name)` gives each parameter's default.
"""

from __future__ import annotations

from typing import Any

from pimbot.attacks.admo import ADMO
from pimbot.attacks.admo import MODES as ADMO_MODES
from pimbot.attacks.admo_code import ADMOCode
from pimbot.attacks.negated_env_reward import NegatedEnvReward
from pimbot.attacks.strategies import Bypass, FakeIncentive, Reverse, SelfCentered
from pimbot.contracts import attack as contract
from pimbot.contracts.attack import NO_ATTACK, Attack, register
from pimbot.envs.core import InvalidParameter

for _cls in (SelfCentered, FakeIncentive, Bypass, Reverse, ADMO, ADMOCode, NegatedEnvReward):
    register(_cls, replace=True)


def registered() -> list[str]:
    return contract.ATTACKS.names()


def attack_class(name: str) -> type[Attack]:
    return contract.ATTACKS.get(name)


def parameters(name: str) -> dict[str, Any]:
    """The attack's parameters and their defaults."""
    return contract.parameters(attack_class(name))


def conditions(name: str) -> tuple[str, ...]:
    """Attack `name`'s run conditions as reports label them (`analysis.runs.
    condition_label`): its name, or, for an attack with a text `mode` parameter, one per
    mode of the paper's ADMO (`admo.MODES`: stealthy, then disrupt), ``<name>_<mode>``."""
    if isinstance(parameters(name).get("mode"), str):
        return tuple(f"{name}_{mode}" for mode in ADMO_MODES)
    return (name,)


CONDITION_ORDER = ("clean", *(c for name in registered() for c in conditions(name)))
"""The paper's display order of run conditions (attack labels): clean, then the built-in
attacks in their order of registration above (`conditions`). For sorting only:
conditions not in it (a plugin's, or one with numeric parameters set) sort after it, by
name."""


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
    "NegatedEnvReward",
    "Reverse",
    "SelfCentered",
    "make",
    "register",
]
