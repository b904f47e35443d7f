"""Learners: one module each, with pure `init` / `update` / `evaluate` / `acting` and a
frozen config, registered through `pimbot.contracts.learner.register` (as a user's
plugin learner is). `get(name)` returns a learner's definition; `registered()` lists names.
"""

from __future__ import annotations

from pimbot import envs
from pimbot.contracts import attack as attack_contract
from pimbot.contracts import defense as defense_contract
from pimbot.contracts import learner as contract
from pimbot.contracts.learner import LearnerDef, register
from pimbot.learners import lio, pg, reciprocator

_ALL_ATTACK_HOOKS = attack_contract.HOOKS
_NO_CHANNEL_HOOKS = tuple(h for h in attack_contract.HOOKS if h != "emit")  # no incentives

for _definition in (
    LearnerDef(
        "pg",
        "independent REINFORCE on environment reward (no incentives)",
        pg.PGConfig,
        pg.init,
        pg.update,
        pg.evaluate,
        pg.acting,
        attack_hooks=("act", "policy_sign", "adversary_step", "observe"),
        defense_hooks=("acting_epsilon",),
    ),
    LearnerDef(
        "lio",
        "LIO: learned incentives trained through the recipients' policy updates",
        lio.LIOConfig,
        lio.init,
        lio.update,
        lio.evaluate,
        lio.acting,
        attack_hooks=_ALL_ATTACK_HOOKS,
        defense_hooks=defense_contract.HOOKS,
        has_incentives=True,
    ),
    LearnerDef(
        "reciprocator",
        "Reciprocator: PPO on env reward + learned reciprocal reward (no incentives)",
        reciprocator.ReciprocatorConfig,
        reciprocator.init,
        reciprocator.update,
        reciprocator.evaluate,
        reciprocator.acting,
        attack_hooks=_NO_CHANNEL_HOOKS,
    ),
    LearnerDef(
        "nl",
        "naive learner: the Reciprocator's PPO with reciprocal weight 0",
        reciprocator.ReciprocatorConfig,
        reciprocator.init,
        reciprocator.update,
        reciprocator.evaluate,
        reciprocator.acting,
        attack_hooks=_NO_CHANNEL_HOOKS,
        base_overrides=(("reciprocal_weight", 0.0),),
        env_defaults_of="reciprocator",
    ),
):
    register(_definition, replace=True)


def registered() -> list[str]:
    return sorted(contract.LEARNERS.names())


def get(name: str) -> LearnerDef:
    return contract.LEARNERS.get(name)


def default_config(name: str, env_id: str):
    """Learner `name`'s config on environment `env_id` (its declared defaults applied)."""
    return get(name).default_config(envs.spec(env_id))


__all__ = ["LearnerDef", "default_config", "get", "register", "registered"]
