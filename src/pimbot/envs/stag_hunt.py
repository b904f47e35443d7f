"""Stag Hunt gridworld — `stag_hunt-v0`: N hunters, one stag and N hares on a square grid.

The rules of the N-player Stag Hunt in the PIMbot code (docs/environments.md).
Cells are (x, y) with 0 ≤ x, y < grid_size; all entities start at uniformly
random cells (overlaps allowed). Actions: 0 up (y - 1), 1 down (y + 1),
2 left (x - 1), 3 right (x + 1), 4 stay; moves are clipped at the walls.

One step:
1. every hunter moves;
2. with probability `stag_random_action_prob` the stag takes one of the five
   actions uniformly at random (stay included, so it moves with probability
   0.4 at the default 0.5); hares never move;
3. captures: if all N hunters stand on the stag's cell, each gets +5 and the
   stag respawns at a uniformly random cell (hares are then left alone);
   otherwise the hunters, in id order, each take every hare on their cell
   (+1 each) and a taken hare respawns at once at a uniformly random cell, so
   of two hunters on one hare the lower id gets it and the higher one only if
   the respawned hare lands on its cell (the original checks hunter by hunter
   against the hares' current cells).

`stag_moves_first=False` swaps steps 2 and 3 (captures are checked on the
hunters' new cells, then a stag that was not captured acts; a respawned stag
stays put that step): the stag can no longer step off a cell all hunters have
just reached, which makes it much easier to catch. pimbot used this order before
it followed the original; it is kept to measure how much the order matters.

Observation of hunter i: every entity's (x, y) divided by grid_size — own
position, the other hunters in id order, the stag, then the hares. (The original
gives every hunter the same vector in id order; with one network per hunter
this is a fixed permutation of its inputs.)

Info per step: "success" (bool) is true when the stag was captured this step.
Per-step metrics (`step_metrics`, summed over an episode and reported as
evaluation metrics): "stag_captures" (0 or 1), and
"return_over_stag_payoff" [N], each hunter's reward divided by the stag payoff
5: summed over an episode, agent 0's entry is the quantity the PIMbot code logs
and plots as Stag Hunt "success" (A1_reward_env / 5, unclipped). Episode
success is the mean hunter return divided by 5, clipped to [0, 1].
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

from pimbot.envs.core import InvalidParameter, ObsPart, check_int

UP, DOWN, LEFT, RIGHT, STAY = 0, 1, 2, 3, 4
MOVES = ((0, -1), (0, 1), (-1, 0), (1, 0), (0, 0))
"""(dx, dy) of each action."""
STAG_REWARD = 5.0
HARE_REWARD = 1.0


@struct.dataclass
class StagHuntState:
    hunters: jax.Array  # int32 [N, 2]
    stag: jax.Array  # int32 [2]
    hares: jax.Array  # int32 [H, 2]
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
    n_hares: int = 0
    """Number of hares; 0 (the default) means one per hunter, N, as the original."""
    stag_random_action_prob: float = 0.5
    """Probability that the stag takes a uniformly random one of the five actions in a
    step (stay included), in [0, 1]; otherwise it stays."""
    stag_moves_first: bool = True
    """The stag acts before the capture check (the original); False: after it."""

    num_actions: int = dataclasses.field(default=len(MOVES), init=False)
    incentive_obs: bool = dataclasses.field(default=False, init=False)
    idle_action: int = dataclasses.field(default=STAY, init=False)
    stochastic: bool = dataclasses.field(default=True, init=False)
    terminates_on_success: bool = dataclasses.field(default=False, init=False)
    step_metrics: tuple[str, ...] = dataclasses.field(
        default=("stag_captures", "return_over_stag_payoff"), init=False
    )

    def __post_init__(self) -> None:
        check_int("n_players", self.n_players, 2)
        check_int("grid_size", self.grid_size, 2)
        check_int("max_steps", self.max_steps, 1)
        check_int("n_hares", self.n_hares, 0)
        p = self.stag_random_action_prob
        if isinstance(p, bool) or not isinstance(p, int | float) or not 0.0 <= p <= 1.0:
            raise InvalidParameter(
                f"stag_random_action_prob: must be a number in [0, 1], got {p!r}"
            )
        if not isinstance(self.stag_moves_first, bool):
            raise InvalidParameter(
                f"stag_moves_first: must be true or false, got {self.stag_moves_first!r}"
            )

    @property
    def num_agents(self) -> int:
        return self.n_players

    @property
    def num_hares(self) -> int:
        """H, the number of hares: `n_hares`, or N when it is 0."""
        return self.n_hares or self.n_players

    @property
    def obs_dim(self) -> int:
        return 2 * (self.n_players + 1 + self.num_hares)

    def obs_bounds(self) -> tuple[float, float]:
        return 0.0, 1.0

    def _random_cells(self, key: jax.Array, shape: tuple[int, ...]) -> jax.Array:
        return jax.random.randint(key, (*shape, 2), 0, self.grid_size, jnp.int32)

    def _move(self, positions: jax.Array, actions: jax.Array) -> jax.Array:
        moved = positions + jnp.array(MOVES, jnp.int32)[actions]
        return jnp.clip(moved, 0, self.grid_size - 1)

    def obs_parts(self) -> tuple[ObsPart, ...]:
        """Cell (x, y) / grid size of this hunter, the other hunters (hunter-id order
        skipping this one), the stag and each hare."""
        units = f"grid cells / {self.grid_size} (the grid's size)"
        high = (self.grid_size - 1) / self.grid_size

        def cell(name: str, whose: str) -> ObsPart:
            return ObsPart(name, 2, f"the (x, y) cell of {whose}", units, 0.0, high)

        others = [
            cell(f"other_hunter_{k}", f"the {k}. other hunter in id order skipping this one")
            for k in range(1, self.n_players)
        ]
        hares = [cell(f"hare_{k}", f"hare {k}") for k in range(self.num_hares)]
        return (cell("own_cell", "this hunter"), *others, cell("stag", "the stag"), *hares)

    def _observe(self, state: StagHuntState) -> jax.Array:
        n = self.n_players
        entities = jnp.concatenate([state.hunters, state.stag[None], state.hares])
        animals = list(range(n, n + 1 + self.num_hares))
        # Row i: own position, then the other hunters in id order, then the animals.
        order = jnp.array([[i] + [j for j in range(n) if j != i] + animals for i in range(n)])
        return entities[order].reshape(n, self.obs_dim).astype(jnp.float32) / self.grid_size

    def reset(self, key: jax.Array) -> tuple[jax.Array, StagHuntState]:
        n = self.n_players
        cells = self._random_cells(key, (n + 1 + self.num_hares,))
        state = StagHuntState(cells[:n], cells[n], cells[n + 1 :], jnp.zeros((), jnp.int32))
        return self._observe(state), state

    def _stag_acts(self, key: jax.Array, stag: jax.Array) -> jax.Array:
        draw = jax.random.uniform(key, (2,))  # one call: random draws dominate a step's cost
        action = jnp.minimum((draw[1] * len(MOVES)).astype(jnp.int32), len(MOVES) - 1)
        return jnp.where(draw[0] < self.stag_random_action_prob, self._move(stag, action), stag)

    def _take_hares(self, fresh: jax.Array, hunters: jax.Array, hares: jax.Array, allowed):
        """Hunter by hunter in id order, each hare on the hunter's cell pays it +1 and
        respawns at once at fresh[i, j] (a later hunter sees the respawned cell)."""
        rewards = []
        for i in range(self.n_players):
            taken = allowed & jnp.all(hares == hunters[i], axis=-1)  # [H]
            rewards.append(HARE_REWARD * jnp.sum(taken))
            hares = jnp.where(taken[:, None], fresh[i], hares)
        return jnp.stack(rewards), hares

    def step(self, key: jax.Array, state: StagHuntState, actions: jax.Array):
        stag_key, cells_key = jax.random.split(key)
        n, h = self.n_players, self.num_hares
        fresh = self._random_cells(cells_key, (n * h + 1,))  # respawn cells: hares, stag
        hunters = self._move(state.hunters, actions.astype(jnp.int32))
        stag = self._stag_acts(stag_key, state.stag) if self.stag_moves_first else state.stag

        captured = jnp.all(hunters == stag)
        hare_rewards, hares = self._take_hares(
            fresh[1:].reshape(n, h, 2), hunters, state.hares, ~captured
        )
        rewards = jnp.where(captured, STAG_REWARD, hare_rewards).astype(jnp.float32)
        if not self.stag_moves_first:
            stag = self._stag_acts(stag_key, stag)
        stag = jnp.where(captured, fresh[0], stag)

        step_count = state.step_count + 1
        new_state = StagHuntState(hunters, stag, hares, step_count)
        done = step_count >= self.max_steps
        info = {
            "success": captured,
            "stag_captures": captured.astype(jnp.int32),
            "return_over_stag_payoff": rewards / STAG_REWARD,
        }
        return self._observe(new_state), new_state, rewards, done, info

    def episode_success(self, success_steps, num_steps, env_return):
        del success_steps, num_steps
        return jnp.clip(jnp.mean(env_return) / STAG_REWARD, 0.0, 1.0).astype(jnp.float32)
