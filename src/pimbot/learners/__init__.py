"""Learners: one module each, with pure `init` / `update` / `evaluate` / `acting` and a
frozen config, registered through `pimbot.contracts.learner.register` (as a user's
plugin learner is). `get(name)` returns a learner's definition; `registered()` lists names.

Each built-in learner's entry declares its hyperparameters on the built-in envs by env id
(`LearnerDef.env_defaults`) and the env parameters its runs need there (`env_params`);
a plugin adds its own for any env with `set_env_defaults` / `set_env_params`.
"""

from __future__ import annotations

from pimbot import envs
from pimbot.contracts import attack as attack_contract
from pimbot.contracts import defense as defense_contract
from pimbot.contracts import learner as contract
from pimbot.contracts.learner import LearnerDef, register, set_env_defaults, set_env_params
from pimbot.learners import lio, pg, reciprocator

DEFAULT_LEARNER = "lio"
"""The learner a run uses where it names none: the paper's, LIO."""

_ALL_ATTACK_HOOKS = attack_contract.HOOKS
_NO_CHANNEL_HOOKS = tuple(h for h in attack_contract.HOOKS if h != "emit")  # no incentives

# The original codes' hyperparameter columns: LIO's and PG's Escape Room column is their
# base config (also the Stag Hunt gridworld's: the original config_staghunt_lio is LIO's ER
# column); the IPD column (no incentive cost: reg_coeff 0) serves the matrix games. PG on
# the gridworld takes the same policy settings as LIO there (PG's own base is its ER column).
_LIO_IPD_COLUMN = {
    "policy_hidden": (16, 8),
    "incentive_hidden": (16, 8),
    "lr_policy": 1e-3,
    "lr_incentive": 1e-3,
    "lr_cost": 0.0,
    "incentive_max": 3.0,
    "entropy_coef": 0.1,
    "epsilon_start": 1.0,
    "epsilon_end": 0.01,
    "epsilon_decay_iters": 5000,
}
_PG_IPD_COLUMN = {
    "policy_hidden": (16, 8),
    "lr_policy": 1e-3,
    "entropy_coef": 0.1,
    "epsilon_start": 1.0,
    "epsilon_end": 0.01,
    "epsilon_decay_iters": 5000,
}
# The Reciprocator's base is its IPD config (w = 5); elsewhere w = 1.
_RECIPROCATOR_W1 = {"reciprocal_weight": 1.0}
# The Reciprocator on Escape Room (every room): the Reciprocator as its authors publish it,
# the credit − debit balance (johnlyzhou/reciprocator `configs/coins.yaml`,
# `reciprocal_reward_type: "petty_payoff"`), at the learner settings of the PIMbot code's
# Escape Room script (greedy_agent `reciprocators/run_er.py`: PPO lr 1e-4, γ 0.99, K 10,
# clip 0.1, entropy 0.01, 64 hidden, w 5, VoI lr 1e-3) and 128 episodes per update. The
# script's own balance, 'linear' → the credit-only `petty_rr`, learns to stay at the start
# (ER(2,1) 0.025 at 10 seeds × 300 updates, where credit − debit reaches 1.00), so it is the
# named row `--hp grudge=petty` (docs/reciprocators.md#escape-room); the script's one
# episode per update collapses (`num_envs=1` keeps it; docs/deviations.md#reciprocators).
# NL takes the same with weight 0.
_RECIPROCATOR_ESCAPE_ROOM = {
    "lr": 1e-4,
    "gamma": 0.99,
    "ppo_epochs": 10,
    "clip": 0.1,
    "entropy_coef": 0.01,
    "policy_hidden": (64, 64),
    "reciprocal_weight": 5.0,
    "grudge": "accumulated",
    "voi_lr": 1e-3,
    "num_envs": 128,
}
# The Reciprocator on matrix games: the original's IPD agent (exact VoI against the others'
# action frequencies of the last batch, refreshed every 3 updates; one-step grudge; width-2
# policy and value networks; 2048 parallel games per update). w stays 5 on the IPD.
_RECIPROCATOR_MATRIX = {
    "voi": "exact",
    "grudge": "one_step",
    "policy_hidden": (2, 2),
    "num_envs": 2048,
    "voi_refit_period": 3,
    "voi_history": 1,
}

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
        env_defaults={
            "ipd-v0": _PG_IPD_COLUMN,
            "stag_hunt-v0": {"lr_policy": 1e-4, "epsilon_start": 0.5},
            "stag_hunt_matrix-v0": _PG_IPD_COLUMN,
        },
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
        env_defaults={"ipd-v0": _LIO_IPD_COLUMN, "stag_hunt_matrix-v0": _LIO_IPD_COLUMN},
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
        env_defaults={
            "escape_room-v0": _RECIPROCATOR_ESCAPE_ROOM,
            "escape_room_transfer-v0": _RECIPROCATOR_ESCAPE_ROOM,
            "ipd-v0": _RECIPROCATOR_MATRIX,
            "stag_hunt-v0": _RECIPROCATOR_W1,
            "stag_hunt_matrix-v0": _RECIPROCATOR_MATRIX | _RECIPROCATOR_W1,
        },
        # The original IPD trainer plays 32-step episodes; with 5 the Reciprocator's
        # cooperation stalled well short of it in earlier runs (docs/reciprocators.md).
        # NL shares it.
        env_params={"ipd-v0": {"max_steps": 32}},
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


def default_env_params(name: str, env_id: str) -> dict:
    """The env parameters learner `name`'s runs on `env_id` use where the run gives none."""
    return get(name).default_env_params(envs.spec(env_id))


def declared_env_params(env_id: str) -> dict[str, dict]:
    """learner name -> the env parameters declared for its runs on `env_id`, by the learners
    that declare some (a learner taking another's, as NL the Reciprocator's, is not named)."""
    entry = envs.spec(env_id)
    declared = {name: dict(params) for name, params in entry.learner_env_defaults.items()}
    for name in contract.LEARNERS:
        own = get(name).env_params.get(env_id, {})
        if own:
            declared[name] = declared.get(name, {}) | dict(own)
    return declared


__all__ = [
    "DEFAULT_LEARNER",
    "LearnerDef",
    "declared_env_params",
    "default_config",
    "default_env_params",
    "get",
    "register",
    "registered",
    "set_env_defaults",
    "set_env_params",
]
