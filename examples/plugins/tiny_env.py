"""`public_goods_game-v0`: a tiny repeated public goods game, with its learner defaults.

Each step every agent gives 0, ½ or all of an endowment of 1 (actions 0, 1, 2) to a
pot multiplied by r and shared equally: for 1 < r < N giving pays the team, not the
giver. A step succeeds when all give everything. Observation (the same for all):
everyone's previous action one-hot and a "first step" bit.

    pimbot envs --plugin examples/plugins/tiny_env.py
    pimbot train public_goods_game-v0 --plugin examples/plugins/tiny_env.py \
        --iterations 2000 --eval-period 100 --out runs/pgg
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from pimbot import envs
from pimbot.contracts.params import check_number
from pimbot.envs.core import check_int
from pimbot.envs.matrix_games import MatrixGameState  # (prev_actions, step_count)


@dataclasses.dataclass(frozen=True)
class PublicGoods:
    """N agents give to a pot that is multiplied by r and shared equally."""

    n_agents: int = 2
    """Number of agents N (≥ 2)."""
    multiplier: float = 1.5
    """r: the pot is multiplied by r and shared equally (a dilemma for 1 < r < N)."""
    max_steps: int = 5
    """Episode length."""

    num_actions: int = dataclasses.field(default=3, init=False)  # give 0, 1/2, 1
    incentive_obs: bool = dataclasses.field(default=False, init=False)
    idle_action: int = dataclasses.field(default=0, init=False)  # give nothing
    stochastic: bool = dataclasses.field(default=False, init=False)
    terminates_on_success: bool = dataclasses.field(default=False, init=False)

    def __post_init__(self) -> None:
        check_int("n_agents", self.n_agents, 2)
        check_int("max_steps", self.max_steps, 1)
        check_number("multiplier", self.multiplier, low=0.0, strict_low=True)

    @property
    def num_agents(self) -> int:
        return self.n_agents

    @property
    def obs_dim(self) -> int:
        return self.num_actions * self.num_agents + 1

    @property
    def optimal_team_return(self) -> float:
        return self.num_agents * self.multiplier * self.max_steps  # everyone gives everything

    def obs_bounds(self) -> tuple[float, float]:
        return 0.0, 1.0

    def _observe(self, prev_actions: jax.Array, first: bool) -> jax.Array:
        one_hot = jax.nn.one_hot(prev_actions, self.num_actions, dtype=jnp.float32).reshape(-1)
        row = jnp.concatenate([one_hot * (not first), jnp.array([float(first)])])
        return jnp.broadcast_to(row, (self.num_agents, self.obs_dim))

    def reset(self, key: jax.Array):
        del key  # deterministic
        state = MatrixGameState(jnp.zeros(self.num_agents, jnp.int32), jnp.zeros((), jnp.int32))
        return self._observe(state.prev_actions, True), state

    def step(self, key: jax.Array, state: MatrixGameState, actions: jax.Array):
        del key  # deterministic
        actions = actions.astype(jnp.int32)
        given = actions / (self.num_actions - 1)
        rewards = (1.0 - given + self.multiplier * given.mean()).astype(jnp.float32)
        new_state = MatrixGameState(actions, state.step_count + 1)
        done = new_state.step_count >= self.max_steps
        info = {"success": jnp.all(actions == self.num_actions - 1)}
        return self._observe(actions, False), new_state, rewards, done, info

    def episode_success(self, success_steps, num_steps, env_return):
        del env_return
        return (success_steps / jnp.maximum(num_steps, 1)).astype(jnp.float32)


SMALL = {"policy_hidden": (16,), "lr_policy": 1e-2, "entropy_coef": 0.05}
envs.register(
    "public_goods_game-v0",
    PublicGoods,
    "Repeated public goods game: give 0, 1/2 or 1 to a pot × multiplier shared by all.",
    learner_defaults={
        "lio": SMALL | {"incentive_hidden": (16,), "incentive_max": 1.0, "lr_cost": 0.0},
        "pg": SMALL | {"epsilon_start": 0.5, "epsilon_decay_iters": 500},
    },
)
