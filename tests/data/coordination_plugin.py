"""A test plugin: a two-player coordination game registered as `my_env-v0`.

The matrix games' rules with another payoff table (no copied class body).
"""

import dataclasses

import numpy as np

from pimbot import envs
from pimbot.envs.matrix_games import MatrixGame


@dataclasses.dataclass(frozen=True)
class Coordination(MatrixGame):
    """Both playing 0 pay 2 each, both playing 1 pay 1 each, a mismatch pays 0."""

    game: str = dataclasses.field(default="stag_hunt", init=False)

    @property
    def payoffs(self) -> np.ndarray:
        table = np.zeros((2, self.n_players))
        table[0, self.n_players - 1] = 2.0
        table[1, 0] = 1.0
        return table


envs.register("my_env-v0", Coordination, "Coordination game (test plugin)")
