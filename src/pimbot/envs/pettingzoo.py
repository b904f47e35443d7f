"""A thin stateful PettingZoo `ParallelEnv` adapter over a functional environment.

    >>> from pimbot.envs.pettingzoo import parallel_env
    >>> env = parallel_env("escape_room-v0", n_agents=2, min_at_lever=1)
    >>> observations, infos = env.reset(seed=0)
    >>> observations, rewards, terminations, truncations, infos = env.step(
    ...     {"agent_0": 0, "agent_1": 2}
    ... )
    >>> terminations["agent_1"], env.agents
    (True, [])

The adapter holds a JAX key and the env state; `reset(seed=s)` restarts the key
stream from `jax.random.key(s)` (so equal seeds replay equally), `reset()`
without a seed continues it. An episode that ends by success (when the env
`terminates_on_success`) is a termination; one that reaches `max_steps`
otherwise is a truncation; either way `agents` becomes empty until the next
`reset`.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import numpy as np

try:
    import gymnasium
    from pettingzoo import ParallelEnv
except ImportError as error:  # an extra: the base install does not carry it
    raise ImportError(
        "pimbot.envs.pettingzoo needs pettingzoo and gymnasium: pip install 'pimbot[pettingzoo]'"
    ) from error

from pimbot.envs.core import Env, make


@functools.cache
def _compiled(env: Env) -> tuple[Any, Any]:
    """Jitted reset and step that also advance the key; shared by equal envs."""

    def reset(key):
        key, reset_key = jax.random.split(key)
        return (key, *env.reset(reset_key))

    def step(key, state, actions):
        key, step_key = jax.random.split(key)
        return (key, *env.step(step_key, state, actions))

    return jax.jit(reset), jax.jit(step)


class FunctionalParallelEnv(ParallelEnv):
    """PettingZoo view of a functional env; agents are "agent_0" … "agent_{N-1}"."""

    def __init__(self, env: Env, name: str) -> None:
        self.env = env
        self.metadata = {"name": name, "is_parallelizable": True, "render_modes": []}
        self.render_mode = None
        self.possible_agents = [f"agent_{i}" for i in range(env.num_agents)]
        self.agents: list[str] = []
        low, high = env.obs_bounds()
        self.observation_spaces = {
            agent: gymnasium.spaces.Box(low, high, (env.obs_dim,), np.float32)
            for agent in self.possible_agents
        }
        self.action_spaces = {
            agent: gymnasium.spaces.Discrete(env.num_actions) for agent in self.possible_agents
        }
        self._reset, self._step = _compiled(env)
        self._key: jax.Array | None = None
        self._state: Any = None
        self._num_steps = 0

    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> gymnasium.spaces.Discrete:
        return self.action_spaces[agent]

    def _per_agent(self, obs: jax.Array) -> dict[str, np.ndarray]:
        obs = np.array(obs, dtype=np.float32)
        return {agent: obs[i] for i, agent in enumerate(self.possible_agents)}

    def reset(
        self, seed: int | None = None, options: dict | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
        del options  # none are defined
        if seed is not None:
            self._key = jax.random.key(seed)
        elif self._key is None:
            self._key = jax.random.key(int(np.random.default_rng().integers(2**31)))
        self._key, obs, self._state = self._reset(self._key)
        self._num_steps = 0
        self.agents = list(self.possible_agents)
        return self._per_agent(obs), {agent: {} for agent in self.agents}

    def step(self, actions: dict[str, int]):
        if not self.agents:
            raise RuntimeError("step() called with no live agents; call reset() first")
        missing = [agent for agent in self.agents if agent not in actions]
        if missing:
            raise ValueError(f"actions: missing an action for {', '.join(missing)}")
        action_array = np.array([actions[agent] for agent in self.possible_agents], dtype=np.int32)
        self._key, obs, self._state, rewards, done, info = self._step(
            self._key, self._state, action_array
        )
        self._num_steps += 1
        info = {name: np.asarray(value).tolist() for name, value in info.items()}
        done = bool(done)
        terminated = done and (
            self._num_steps < self.env.max_steps
            or (self.env.terminates_on_success and info["success"])
        )
        truncated = done and not terminated
        rewards = np.asarray(rewards)
        agents = self.agents
        if done:
            self.agents = []
        return (
            self._per_agent(obs),
            {agent: float(rewards[i]) for i, agent in enumerate(agents)},
            dict.fromkeys(agents, terminated),
            dict.fromkeys(agents, truncated),
            {
                agent: _own_info(info, i, len(self.possible_agents))
                for i, agent in enumerate(agents)
            },
        )

    def render(self) -> None:
        return None

    def close(self) -> None:
        pass


def _own_info(info: dict[str, Any], agent: int, num_agents: int) -> dict[str, Any]:
    """An agent's info: its own entry of per-agent ([N]) values, scalars as they are."""
    return {
        name: value[agent] if isinstance(value, list) and len(value) == num_agents else value
        for name, value in info.items()
    }


def parallel_env(env_id: str, **params: Any) -> FunctionalParallelEnv:
    """The PettingZoo `ParallelEnv` of `make(env_id, **params)`."""
    return FunctionalParallelEnv(make(env_id, **params), env_id)
