"""Stag Hunt gridworld — `stag_hunt-v0`: N hunters, one stag and two hares on a square grid.

Cells are (x, y) with 0 ≤ x, y < grid_size; all entities start at uniformly
random cells (overlaps allowed). Actions: 0 up (y - 1), 1 down (y + 1),
2 left (x - 1), 3 right (x + 1), 4 stay; moves are clipped at the walls.

Order within a step (our decision; the spec fixes only the rules):
1. every hunter moves;
2. captures are checked on the new hunter positions: if all N hunters stand
   on the stag's cell, each gets +5 and the stag respawns at a uniformly
   random cell (hares are then left alone); otherwise every hunter gets +1
   for each hare on its cell (several hunters on one hare all get +1), and
   every such hare respawns at a uniformly random cell;
3. a stag that was not captured takes a random step (one of the four moves,
   clipped) with probability `stag_move_prob`; a respawned stag stays put
   this step. Hares never move.

Observation of hunter i: every entity's (x, y) divided by grid_size — own
position, the other hunters in id order, the stag, then the two hares.

Info per step: "success" (bool) is true when the stag was captured this step;
"stag_captures" (int32, 0 or 1) is the same count, to be summed over an
episode for the raw number of captures. Episode success is the mean hunter
return divided by the stag payoff 5, clipped to [0, 1].
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

from pimbot.envs.core import InvalidParameter, check_int

UP, DOWN, LEFT, RIGHT, STAY = 0, 1, 2, 3, 4
MOVES = ((0, -1), (0, 1), (-1, 0), (1, 0), (0, 0))
"""(dx, dy) of each action."""
NUM_HARES = 2
STAG_REWARD = 5.0
HARE_REWARD = 1.0


@struct.dataclass
class StagHuntState:
    hunters: jax.Array  # int32 [N, 2]
    stag: jax.Array  # int32 [2]
    hares: jax.Array  # int32 [NUM_HARES, 2]
    step_count: jax.Array  # int32 []


@dataclasses.dataclass(frozen=True)
class StagHunt:
    """N hunters on a grid: the stag pays +5 each only when all N stand on it; a hare pays +1."""

    n_players: int = 2
    """Number of hunters N (≥ 2)."""
    grid_size: int = 5
    """Side length of the square grid (≥ 2)."""
    max_steps: int = 50
    """Episode length; every episode lasts exactly this many steps."""
    stag_move_prob: float = 0.5
    """Probability that the stag takes a random step each step, in [0, 1]."""

    num_actions: int = dataclasses.field(default=len(MOVES), init=False)
    incentive_obs: bool = dataclasses.field(default=False, init=False)
    idle_action: int = dataclasses.field(default=STAY, init=False)
    stochastic: bool = dataclasses.field(default=True, init=False)
    terminates_on_success: bool = dataclasses.field(default=False, init=False)

    def __post_init__(self) -> None:
        check_int("n_players", self.n_players, 2)
        check_int("grid_size", self.grid_size, 2)
        check_int("max_steps", self.max_steps, 1)
        p = self.stag_move_prob
        if isinstance(p, bool) or not isinstance(p, int | float) or not 0.0 <= p <= 1.0:
            raise InvalidParameter(f"stag_move_prob: must be a number in [0, 1], got {p!r}")

    @property
    def num_agents(self) -> int:
        return self.n_players

    @property
    def obs_dim(self) -> int:
        return 2 * (self.n_players + 1 + NUM_HARES)

    def obs_bounds(self) -> tuple[float, float]:
        return 0.0, 1.0

    def _random_cells(self, key: jax.Array, count: int) -> jax.Array:
        return jax.random.randint(key, (count, 2), 0, self.grid_size, jnp.int32)

    def _move(self, positions: jax.Array, actions: jax.Array) -> jax.Array:
        moved = positions + jnp.array(MOVES, jnp.int32)[actions]
        return jnp.clip(moved, 0, self.grid_size - 1)

    def _observe(self, state: StagHuntState) -> jax.Array:
        n = self.n_players
        entities = jnp.concatenate([state.hunters, state.stag[None], state.hares])
        animals = list(range(n, n + 1 + NUM_HARES))
        # Row i: own position, then the other hunters in id order, then the animals.
        order = jnp.array([[i] + [j for j in range(n) if j != i] + animals for i in range(n)])
        return entities[order].reshape(n, self.obs_dim).astype(jnp.float32) / self.grid_size

    def reset(self, key: jax.Array) -> tuple[jax.Array, StagHuntState]:
        cells = self._random_cells(key, self.n_players + 1 + NUM_HARES)
        n = self.n_players
        state = StagHuntState(cells[:n], cells[n], cells[n + 1 :], jnp.zeros((), jnp.int32))
        return self._observe(state), state

    def step(self, key: jax.Array, state: StagHuntState, actions: jax.Array):
        respawn_key, wander_key, direction_key = jax.random.split(key, 3)
        hunters = self._move(state.hunters, actions.astype(jnp.int32))

        captured = jnp.all(hunters == state.stag)
        on_hare = jnp.all(hunters[:, None, :] == state.hares[None, :, :], axis=-1)  # [N, H]
        rewards = jnp.where(captured, STAG_REWARD, HARE_REWARD * jnp.sum(on_hare, axis=1))
        hare_caught = jnp.any(on_hare, axis=0) & ~captured  # [H]
        # One draw of a fresh cell per animal, used only where the animal was caught.
        respawn = self._random_cells(respawn_key, 1 + NUM_HARES)
        hares = jnp.where(hare_caught[:, None], respawn[1:], state.hares)

        wanders = jax.random.bernoulli(wander_key, self.stag_move_prob)
        direction = jax.random.randint(direction_key, (), 0, 4)
        wandered = jnp.where(wanders, self._move(state.stag, direction), state.stag)
        stag = jnp.where(captured, respawn[0], wandered)

        step_count = state.step_count + 1
        new_state = StagHuntState(hunters, stag, hares, step_count)
        done = step_count >= self.max_steps
        info = {"success": captured, "stag_captures": captured.astype(jnp.int32)}
        return self._observe(new_state), new_state, rewards.astype(jnp.float32), done, info

    def episode_success(self, success_steps, num_steps, env_return):
        del success_steps, num_steps
        return jnp.clip(jnp.mean(env_return) / STAG_REWARD, 0.0, 1.0).astype(jnp.float32)
