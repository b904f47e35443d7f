"""Escape Room ER(N, M) — `escape_room-v0`, with the semantics of LIO's original environment.

Positions and actions: 0 = lever, 1 = start, 2 = door; an action sets the
position directly. The door is open in a step iff at least M agents chose the
lever in that step. Reward per agent and step: +10 if the door is open and the
agent chose the door; else 0 if it stayed where it was; else -1. The episode
ends with success when the door is open and some agent is at the door after the
step, otherwise it is truncated at `max_steps`.

Per-step metric (`step_metrics`): "exit_success" [N], 1 for every agent that
stands at the open door in the step (summed over an episode: whether agent i
itself exited; the episode's success only says that some agent did).

`escape_room_transfer-v0` (`EscapeRoomWithTransfer`) is a COUNTERFACTUAL variant, not
LIO's environment: it adds a reward-transfer choice, to test whether a pay-back channel
is what Reciprocators need in Escape Room (in `escape_room-v0` a door-goer's action
cannot change a lever-puller's reward). Every action is a move plus a choice to give:
actions 0-2 are the moves above, keeping everything; actions 3-5 are the same moves
(action − 3) while giving the fraction `transfer` of the agent's positive reward of that
step, split equally among the other agents (a zero-sum transfer: team returns, success
and the optimal team return are those of ER(N, M)). Its per-step metric "transferred"
[N] is what each agent gave. `escape_room-v0` itself is unchanged.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp
from flax import struct

from pimbot.envs.core import InvalidParameter, ObsPart, TracedFields, check_int

LEVER, START, DOOR = 0, 1, 2
NUM_POSITIONS = 3
OPTIMAL_TEAM_RETURN = {(2, 1): 9.0, (3, 2): 8.0, (4, 2): 18.0, (4, 3): 7.0}


@struct.dataclass
class EscapeRoomState:
    positions: jax.Array  # int32 [N]
    step_count: jax.Array  # int32 []


@dataclasses.dataclass(frozen=True)
class EscapeRoom(TracedFields):
    """ER(N, M): N agents, the door opens while at least M of them pull the lever."""

    n_agents: int = 2
    """Number of agents N (≥ 2)."""
    min_at_lever: int = 1
    """Agents needed at the lever to open the door, M (1 ≤ M < N)."""
    max_steps: int = 5
    """Episode horizon."""
    randomize_start: bool = False
    """Start every agent at a uniformly random position instead of the start."""

    num_actions: int = dataclasses.field(default=3, init=False)
    incentive_obs: bool = dataclasses.field(default=True, init=False)
    idle_action: int = dataclasses.field(default=START, init=False)
    terminates_on_success: bool = dataclasses.field(default=True, init=False)
    step_metrics: tuple[str, ...] = dataclasses.field(default=("exit_success",), init=False)
    traced_fields: ClassVar[tuple[str, ...]] = ("min_at_lever",)
    """M is a value in `step` only: the env is a pytree whose one leaf is M (`TracedFields`),
    so ER(N, M) for every M runs on one compiled program."""

    def __post_init__(self) -> None:
        check_int("n_agents", self.n_agents, 2)
        if isinstance(self.min_at_lever, bool) or not isinstance(self.min_at_lever, int):
            raise InvalidParameter(
                f"min_at_lever: must be an integer in [1, {self.n_agents - 1}], "
                f"got {self.min_at_lever!r}"
            )
        if not 1 <= self.min_at_lever < self.n_agents:
            raise InvalidParameter(
                f"min_at_lever: must satisfy 1 ≤ M < N = {self.n_agents}, "
                f"i.e. be in [1, {self.n_agents - 1}], got {self.min_at_lever}"
            )
        check_int("max_steps", self.max_steps, 1)
        if not isinstance(self.randomize_start, bool):
            raise InvalidParameter(
                f"randomize_start: must be true or false, got {self.randomize_start!r}"
            )

    @property
    def num_agents(self) -> int:
        return self.n_agents

    @property
    def stochastic(self) -> bool:
        return self.randomize_start

    @property
    def obs_dim(self) -> int:
        n = self.n_agents
        return NUM_POSITIONS * n + (n - 1)

    @property
    def optimal_team_return(self) -> float | None:
        """The best possible team env return, where known (else None)."""
        return OPTIMAL_TEAM_RETURN.get((self.n_agents, self.min_at_lever))

    def obs_bounds(self) -> tuple[float, float]:
        # The incentive slots hold cumulative incentives filled by a learner.
        return 0.0, float("inf")

    def obs_parts(self) -> tuple[ObsPart, ...]:
        """Own position, each other agent's (agent-id order skipping this one), each a
        one-hot over (lever, start, door); then the incentives given so far."""
        where = "one-hot over (lever, start, door) at index 0, 1, 2"
        own = ObsPart(
            "own_position", NUM_POSITIONS, f"this agent's position, {where}", "one-hot", 0.0, 1.0
        )
        others = [
            ObsPart(
                f"other_position_{k}",
                NUM_POSITIONS,
                f"the position of the {k}. other agent in agent-id order skipping this "
                f"one, {where}",
                "one-hot",
                0.0,
                1.0,
            )
            for k in range(1, self.n_agents)
        ]
        given = ObsPart(
            "incentives_given",
            self.n_agents - 1,
            "the incentives this agent has given each other agent so far this episode, in "
            "agent-id order skipping itself (zeros where no agent gives incentives)",
            "reward units, summed over the episode's steps",
            0.0,
            None,
        )
        return (own, *others, given)

    def _observe(self, positions: jax.Array) -> jax.Array:
        n = self.n_agents
        one_hot = jax.nn.one_hot(positions, NUM_POSITIONS, dtype=jnp.float32)  # [N, 3]
        # Row i: own position, then the others in id order skipping i.
        order = jnp.array([[i] + [j for j in range(n) if j != i] for i in range(n)])
        positions_part = one_hot[order].reshape(n, n * NUM_POSITIONS)
        return jnp.concatenate([positions_part, jnp.zeros((n, n - 1), jnp.float32)], axis=1)

    def reset(self, key: jax.Array) -> tuple[jax.Array, EscapeRoomState]:
        if self.randomize_start:
            positions = jax.random.randint(key, (self.n_agents,), 0, NUM_POSITIONS)
        else:
            positions = jnp.full((self.n_agents,), START, jnp.int32)
        state = EscapeRoomState(positions.astype(jnp.int32), jnp.zeros((), jnp.int32))
        return self._observe(state.positions), state

    def step(self, key: jax.Array, state: EscapeRoomState, actions: jax.Array):
        del key  # deterministic transitions
        actions = actions.astype(jnp.int32)
        door_open = jnp.sum(actions == LEVER) >= self.min_at_lever
        stayed = actions == state.positions
        rewards = jnp.where(
            door_open & (actions == DOOR), 10.0, jnp.where(stayed, 0.0, -1.0)
        ).astype(jnp.float32)
        step_count = state.step_count + 1
        success = door_open & jnp.any(actions == DOOR)
        done = success | (step_count >= self.max_steps)
        new_state = EscapeRoomState(actions, step_count)
        # Agent i exits when it is at the door while it is open (only on the last step).
        exit_success = door_open & (actions == DOOR)
        info = {"success": success, "door_open": door_open, "exit_success": exit_success}
        return self._observe(actions), new_state, rewards, done, info

    def episode_success(self, success_steps, num_steps, env_return):
        del num_steps, env_return
        return (success_steps > 0).astype(jnp.float32)


@dataclasses.dataclass(frozen=True)
class EscapeRoomWithTransfer(EscapeRoom):
    """Counterfactual ER(N, M) with a pay-back action: actions 3-5 move as 0-2 and give away
    the fraction `transfer` of the step's positive reward, split among the others."""

    transfer: float = 0.5
    """Fraction of its positive step reward an agent gives with actions 3-5, in (0, 1]."""

    num_actions: int = dataclasses.field(default=2 * NUM_POSITIONS, init=False)
    step_metrics: tuple[str, ...] = dataclasses.field(
        default=("exit_success", "transferred"), init=False
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        value = self.transfer
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value <= 1:
            raise InvalidParameter(f"transfer: must be a number in (0, 1], got {value!r}")

    def step(self, key: jax.Array, state: EscapeRoomState, actions: jax.Array):
        actions = actions.astype(jnp.int32)
        moves = actions % NUM_POSITIONS
        obs, new_state, rewards, done, info = super().step(key, state, moves)
        n = self.n_agents
        given = jnp.where(actions >= NUM_POSITIONS, self.transfer * jnp.maximum(rewards, 0.0), 0.0)
        rewards = rewards - given + (given.sum() - given) / (n - 1)
        return obs, new_state, rewards.astype(jnp.float32), done, info | {"transferred": given}
