"""Environments: pure functional social dilemmas behind a versioned registry.

>>> import jax
>>> from pimbot import envs
>>> env = envs.make("escape_room-v0", n_agents=4, min_at_lever=2)
>>> obs, state = env.reset(jax.random.key(0))
>>> envs.check_env(env)
"""

from pimbot.envs.checks import check_env
from pimbot.envs.core import Env, EnvSpec, InvalidParameter, make, register, registered, spec
from pimbot.envs.escape_room import EscapeRoom
from pimbot.envs.matrix_games import IteratedPrisonersDilemma, MatrixGame, StagHuntMatrix
from pimbot.envs.stag_hunt import StagHunt

register(
    "escape_room-v0",
    EscapeRoom,
    "Escape Room ER(N,M): M agents must pull the lever so that the others can exit by the door.",
)
register(
    "ipd-v0",
    IteratedPrisonersDilemma,
    "Iterated prisoner's dilemma, N players: the mean of the pairwise payoffs (LIO's for N=2).",
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
