"""Repeated symmetric N-player matrix games — `ipd-v0` and `stag_hunt_matrix-v0`.

One class, `MatrixGame`; the rules are data. Both games have two actions where
action 0 is the cooperative one (cooperate / stag) and action 1 the safe one
(defect / hare). Because the games are symmetric, an agent's reward depends
only on its own action and on how many of the other N-1 agents chose action 0,
so each game is a payoff table ``[2, N]`` indexed ``[own action, number of
other agents playing 0]``, built by a module-level function named by `game`.

Observation (identical for all agents): everyone's previous action, one-hot
per agent in id order, plus a "first step" bit (the one-hots are zero at the
first step). The two-player IPD instead uses LIO/LOLA's memory-1 observation:
a 5-way one-hot, index 4 at the first step, else ``2 * a0 + a1``.

A step succeeds when every agent plays action 0; episodes last exactly
`max_steps` steps.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from pimbot.envs.core import ObsPart, check_int
from pimbot.errors import check_choice

COOPERATE, DEFECT = 0, 1
STAG, HARE = 0, 1
NUM_ACTIONS = 2

IPD_PAYOFF = np.array([[-1.0, -3.0], [0.0, -2.0]])
"""Two-player IPD payoff of the row agent, indexed [own action, other's action] (LIO/LOLA)."""
STAG_PAYOFF = 5.0
"""Paid to every agent when all agents choose stag."""
HARE_PAYOFF = 1.0
"""Paid to a hare-chooser, whatever the others do."""


def ipd_payoffs(n_players: int) -> np.ndarray:
    """N-player IPD: the mean over the other N-1 agents of the two-player payoff against each.

    Returns:
        float [2, N]: entry [a, k] is the reward for playing a while k others cooperate.
    """
    others = n_players - 1
    k = np.arange(n_players)
    return (k * IPD_PAYOFF[:, [COOPERATE]] + (others - k) * IPD_PAYOFF[:, [DEFECT]]) / others


def stag_hunt_payoffs(n_players: int) -> np.ndarray:
    """N-player Stag Hunt: stag pays STAG_PAYOFF iff all choose stag, else 0; hare pays HARE_PAYOFF.

    Returns:
        float [2, N]: entry [a, k] is the reward for playing a while k others choose stag.
    """
    table = np.zeros((NUM_ACTIONS, n_players))
    table[STAG, n_players - 1] = STAG_PAYOFF
    table[HARE, :] = HARE_PAYOFF
    return table


PAYOFFS: dict[str, Callable[[int], np.ndarray]] = {
    "ipd": ipd_payoffs,
    "stag_hunt": stag_hunt_payoffs,
}


@struct.dataclass
class MatrixGameState:
    prev_actions: jax.Array  # int32 [N]
    step_count: jax.Array  # int32 []


@dataclasses.dataclass(frozen=True)
class MatrixGame:
    """A repeated symmetric N-player two-action game whose payoff table is `PAYOFFS[game]`."""

    game: str
    """Name of the payoff rule, a key of `PAYOFFS`."""
    n_players: int = 2
    """Number of agents N (≥ 2)."""
    max_steps: int = 5
    """Episode length; every episode lasts exactly this many steps."""

    num_actions: int = dataclasses.field(default=NUM_ACTIONS, init=False)
    incentive_obs: bool = dataclasses.field(default=False, init=False)
    idle_action: int = dataclasses.field(default=DEFECT, init=False)
    stochastic: bool = dataclasses.field(default=False, init=False)
    terminates_on_success: bool = dataclasses.field(default=False, init=False)

    def __post_init__(self) -> None:
        check_choice("game", self.game, PAYOFFS)
        check_int("n_players", self.n_players, 2)
        check_int("max_steps", self.max_steps, 1)

    @property
    def num_agents(self) -> int:
        return self.n_players

    @property
    def obs_dim(self) -> int:
        return NUM_ACTIONS * self.n_players + 1

    @property
    def joint_obs(self) -> bool:
        """True for the two-player IPD, which observes LIO/LOLA's 5-way joint-action one-hot."""
        return self.game == "ipd" and self.n_players == 2

    @property
    def payoffs(self) -> np.ndarray:
        """float [2, N]: reward for [own action, number of other agents playing action 0]."""
        return PAYOFFS[self.game](self.n_players)

    def obs_bounds(self) -> tuple[float, float]:
        return 0.0, 1.0

    def obs_parts(self) -> tuple[ObsPart, ...]:
        """The previous joint action, the same for every agent (action 0 = cooperate)."""
        if self.joint_obs:
            meaning = (
                "the previous joint action as one one-hot: index 2·a0 + a1 for (a0, a1) in "
                "(C, C), (C, D), (D, C), (D, D), and index 4 at the first step"
            )
            return (ObsPart("previous_joint_action", 5, meaning, "one-hot", 0.0, 1.0),)
        previous = ObsPart(
            "previous_actions",
            NUM_ACTIONS * self.n_players,
            "every player's previous action in player-id order, each a one-hot over the "
            "two actions (0: cooperate, the stag; 1: defect, the hare); zeros at the first "
            "step",
            "one-hot",
            0.0,
            1.0,
        )
        first = ObsPart("first_step", 1, "1 at the episode's first step, else 0", "flag", 0.0, 1.0)
        return previous, first

    def _observe(self, prev_actions: jax.Array, first: jax.Array) -> jax.Array:
        if self.joint_obs:
            index = jnp.where(first, 4, 2 * prev_actions[0] + prev_actions[1])
            row = jax.nn.one_hot(index, 5, dtype=jnp.float32)
        else:
            one_hot = jax.nn.one_hot(prev_actions, NUM_ACTIONS, dtype=jnp.float32)
            one_hot = jnp.where(first, 0.0, one_hot.reshape(-1))
            row = jnp.concatenate([one_hot, first[None].astype(jnp.float32)])
        return jnp.broadcast_to(row, (self.n_players, self.obs_dim))

    def reset(self, key: jax.Array) -> tuple[jax.Array, MatrixGameState]:
        del key  # deterministic
        state = MatrixGameState(jnp.zeros((self.n_players,), jnp.int32), jnp.zeros((), jnp.int32))
        return self._observe(state.prev_actions, jnp.array(True)), state

    def step(self, key: jax.Array, state: MatrixGameState, actions: jax.Array):
        del key  # deterministic
        actions = actions.astype(jnp.int32)
        plays_zero = actions == 0
        others_playing_zero = jnp.sum(plays_zero) - plays_zero
        payoffs = jnp.asarray(self.payoffs, jnp.float32)
        rewards = payoffs[actions, others_playing_zero]
        step_count = state.step_count + 1
        done = step_count >= self.max_steps
        info = {"success": jnp.all(plays_zero)}
        new_state = MatrixGameState(actions, step_count)
        return self._observe(actions, jnp.array(False)), new_state, rewards, done, info

    def episode_success(self, success_steps, num_steps, env_return):
        del env_return
        return (success_steps / jnp.maximum(num_steps, 1)).astype(jnp.float32)


@dataclasses.dataclass(frozen=True)
class IteratedPrisonersDilemma(MatrixGame):
    """`ipd-v0`: actions 0 = cooperate, 1 = defect; pairwise payoffs CC -1, CD -3, DC 0, DD -2."""

    game: str = dataclasses.field(default="ipd", init=False)


@dataclasses.dataclass(frozen=True)
class StagHuntMatrix(MatrixGame):
    """`stag_hunt_matrix-v0`: actions 0 = stag, 1 = hare; stag pays 5 iff all hunt it, hare 1."""

    game: str = dataclasses.field(default="stag_hunt", init=False)
    max_steps: int = 10
    """Episode length; every episode lasts exactly this many steps."""
