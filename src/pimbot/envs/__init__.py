"""Environments: pure functional social dilemmas behind a versioned registry.

>>> import jax
>>> from pimbot import envs
>>> env = envs.make("escape_room-v0", n_agents=4, min_at_lever=2)
>>> obs, state = env.reset(jax.random.key(0))
>>> envs.check_env(env)
"""

from pimbot.envs.checks import check_env
from pimbot.envs.core import (
    Env,
    EnvSpec,
    InvalidParameter,
    ids_of,
    make,
    register,
    registered,
    spec,
)
from pimbot.envs.escape_room import EscapeRoom, EscapeRoomWithTransfer
from pimbot.envs.matrix_games import IteratedPrisonersDilemma, MatrixGame, StagHuntMatrix
from pimbot.envs.stag_hunt import StagHunt

# Which learner hyperparameters suit each env is declared in the learners' registry entries
# (pimbot.learners), registered after the envs: this module holds only the envs' own facts.
# Escape Room runs are evaluated every 100 iterations, as the original LIO code's ER
# configs; the other envs take the registry's fallback (every 1000, 10 episodes).
register(
    "escape_room-v0",
    EscapeRoom,
    "Escape Room ER(N,M): M agents must pull the lever so that the others can exit by the door.",
    eval_period=100,
    eval_episodes=10,
    action_names=("lever", "start", "door"),
)
register(
    "escape_room_transfer-v0",
    EscapeRoomWithTransfer,
    "COUNTERFACTUAL Escape Room (not LIO's): each move may also give `transfer` of the "
    "step's positive reward to the others (a pay-back channel).",
)
register(
    "ipd-v0",
    IteratedPrisonersDilemma,
    "Iterated prisoner's dilemma, N players: the mean of the pairwise payoffs (LIO's for N=2).",
    action_names=("C", "D"),
)
register(
    "stag_hunt-v0",
    StagHunt,
    "Stag Hunt gridworld: all N hunters on the stag pay +5 each, a hare pays +1 to its hunter.",
)
register(
    "stag_hunt_matrix-v0",
    StagHuntMatrix,
    "Repeated N-player matrix Stag Hunt: stag pays 5 if all choose stag, else 0; hare pays 1.",
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
    "ids_of",
    "make",
    "register",
    "registered",
    "spec",
]
