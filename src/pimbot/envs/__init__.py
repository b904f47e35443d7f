"""Environments: pure functional social dilemmas behind a versioned registry.

>>> import jax
>>> from pimbot import envs
>>> env = envs.make("escape_room-v0", n_agents=4, min_at_lever=2)
>>> obs, state = env.reset(jax.random.key(0))
>>> envs.check_env(env)
"""

from pimbot.envs.checks import check_env
from pimbot.envs.core import Env, EnvSpec, InvalidParameter, make, register, registered, spec
from pimbot.envs.escape_room import EscapeRoom, EscapeRoomWithTransfer
from pimbot.envs.matrix_games import IteratedPrisonersDilemma, MatrixGame, StagHuntMatrix
from pimbot.envs.stag_hunt import StagHunt

# The original codes' hyperparameter columns: LIO's and PG's Escape Room column is their
# base config; the IPD column (no incentive cost: reg_coeff 0) serves the other games.
# The Reciprocator's base is its IPD config (w = 5); elsewhere w = 1.
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
_RECIPROCATOR_W1 = {"reciprocal_weight": 1.0}
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
_OTHER_GAMES = {"lio": _LIO_IPD_COLUMN, "pg": _PG_IPD_COLUMN, "reciprocator": _RECIPROCATOR_W1}
# Stag Hunt gridworld: the original config_staghunt_lio is LIO's Escape Room column (LIO's
# base config); PG takes the same policy settings (PG's own base is its ER column).
_STAG_HUNT_LIO_PG = {"lio": {}, "pg": {"lr_policy": 1e-4, "epsilon_start": 0.5}}

register(
    "escape_room-v0",
    EscapeRoom,
    "Escape Room ER(N,M): M agents must pull the lever so that the others can exit by the door.",
    learner_defaults={"reciprocator": _RECIPROCATOR_W1},
)
register(
    "escape_room_transfer-v0",
    EscapeRoomWithTransfer,
    "COUNTERFACTUAL Escape Room (not LIO's): each move may also give `transfer` of the "
    "step's positive reward to the others (a pay-back channel).",
    learner_defaults={"reciprocator": _RECIPROCATOR_W1},
)
register(
    "ipd-v0",
    IteratedPrisonersDilemma,
    "Iterated prisoner's dilemma, N players: the mean of the pairwise payoffs (LIO's for N=2).",
    learner_defaults={
        "lio": _LIO_IPD_COLUMN,
        "pg": _PG_IPD_COLUMN,
        "reciprocator": _RECIPROCATOR_MATRIX,
    },
    # The original IPD trainer plays 32-step episodes; with 5 the Reciprocator's
    # cooperation stalls at 0.5-0.7 (docs/results/reciprocators.md). NL shares its defaults.
    learner_env_defaults={"reciprocator": {"max_steps": 32}},
)
register(
    "stag_hunt-v0",
    StagHunt,
    "Stag Hunt gridworld: all N hunters on the stag pay +5 each, a hare pays +1 to its hunter.",
    learner_defaults=_OTHER_GAMES | _STAG_HUNT_LIO_PG,
)
register(
    "stag_hunt_matrix-v0",
    StagHuntMatrix,
    "Repeated N-player matrix Stag Hunt: stag pays 5 if all choose stag, else 0; hare pays 1.",
    learner_defaults=_OTHER_GAMES | {"reciprocator": _RECIPROCATOR_MATRIX | _RECIPROCATOR_W1},
)

__all__ = [
    "Env",
    "EnvSpec",
    "EscapeRoom",
    "EscapeRoomWithTransfer",
    "InvalidParameter",
    "IteratedPrisonersDilemma",
    "MatrixGame",
    "StagHunt",
    "StagHuntMatrix",
    "check_env",
    "make",
    "register",
    "registered",
    "spec",
]
