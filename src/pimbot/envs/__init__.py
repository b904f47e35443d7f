"""Environments: pure functional social dilemmas behind a versioned registry.

    >>> from pimbot import envs
    >>> env = envs.make("escape_room-v0", n_agents=4, min_at_lever=2)
    >>> obs, state = env.reset(jax.random.key(0))
"""

from pimbot.envs.core import Env, EnvSpec, InvalidParameter, make, register, registered, spec
from pimbot.envs.escape_room import EscapeRoom

register(
    "escape_room-v0",
    EscapeRoom,
    "Escape Room ER(N,M): M agents must pull the lever so that the others can exit by the door.",
)

__all__ = [
    "Env",
    "EnvSpec",
    "EscapeRoom",
    "InvalidParameter",
    "make",
    "register",
    "registered",
    "spec",
]
