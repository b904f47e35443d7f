"""JaxMARL adapters, both ways (an extra: ``pip install 'pimbot[jaxmarl]'``).

1. `PimbotMultiAgentEnv` shows a pimbot env as a JaxMARL `MultiAgentEnv`: agents
   ``"agent_0"`` … ``"agent_{N-1}"``, observation and action dicts, `Box` / `Discrete`
   spaces, and JaxMARL's auto-reset inside `step`::

       >>> import jax
       >>> from pimbot.envs.jaxmarl import to_jaxmarl
       >>> env = to_jaxmarl("ipd-v0")
       >>> obs, state = env.reset(jax.random.key(0))
       >>> actions = {agent: 0 for agent in env.agents}
       >>> obs, state, rewards, dones, infos = env.step(jax.random.key(1), state, actions)
       >>> float(rewards["agent_0"]), bool(dones["__all__"])
       (-1.0, False)

2. `register_jaxmarl(name, **params)` registers a JaxMARL env whose spaces fit pimbot's
   protocol (every agent: the same `Discrete(n)` actions and the same `Box`
   observation, flattened to float32) as a pimbot env, so that pimbot's learners,
   attacks and checks run on it. Importing this module registers
   ``jaxmarl_coin_game-v0`` and ``jaxmarl_simple_spread-v0``::

       pimbot train jaxmarl_coin_game-v0 --plugin pimbot.envs.jaxmarl --seeds 2 \\
           --iterations 20 --eval-period 10 --out runs/coin

   What the spaces do not say (the episode length, what a success is, which action
   is idle) is data: a `Rules` per JaxMARL env in `RULES`. docs/jaxmarl.md lists which
   JaxMARL envs fit and why the others do not.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import io
import math
import re
import sys
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from pimbot.envs.core import Env, InvalidParameter, make, register


@contextlib.contextmanager
def _quiet_stdout():
    """Swallows what jaxmarl prints on import and restores sys.stdout/stderr after it:
    jaxmarl's mabrax module resets both to sys.__stdout__/__stderr__ (dropping any
    redirection, e.g. pytest's capture)."""
    saved = sys.stdout, sys.stderr, sys.__stdout__
    sys.stdout = sys.__stdout__ = io.StringIO()
    try:
        yield
    finally:
        sys.stdout, sys.stderr, sys.__stdout__ = saved


try:
    with _quiet_stdout():
        import jaxmarl
        from jaxmarl.environments import spaces
        from jaxmarl.environments.mpe.simple import SimpleMPE
        from jaxmarl.environments.multi_agent_env import MultiAgentEnv, State
except ImportError as error:  # an extra: the base install does not carry it
    raise ImportError("pimbot.envs.jaxmarl needs jaxmarl: pip install 'pimbot[jaxmarl]'") from error

# --- 1. pimbot envs as JaxMARL MultiAgentEnvs --------------------------------------------


@struct.dataclass
class PimbotState(State):
    """JaxMARL state of a wrapped pimbot env: JaxMARL's (done, step) plus the pimbot
    state and its last observation (so that `get_obs` works, as `step(reset_state=…)`
    needs)."""

    env_state: Any
    obs: jax.Array  # float32 [N, obs_dim]


class PimbotMultiAgentEnv(MultiAgentEnv):
    """A pimbot `Env` behind JaxMARL's API; `step` auto-resets on done, as JaxMARL's do.

    Agent i of the pimbot env is ``"agent_i"``. An env with `incentive_obs` keeps its
    incentive slots zero here (no incentive learner fills them). `infos` is the pimbot
    step's info dict (``"success"`` and any env-specific scalars).
    """

    def __init__(self, env: Env) -> None:
        super().__init__(num_agents=env.num_agents)
        self.env = env
        self.max_steps = env.max_steps
        low, high = env.obs_bounds()
        self.observation_spaces = {
            agent: spaces.Box(low, high, (env.obs_dim,), jnp.float32) for agent in self.agents
        }
        self.action_spaces = {agent: spaces.Discrete(env.num_actions) for agent in self.agents}

    @functools.partial(jax.jit, static_argnums=0)
    def reset(self, key: jax.Array) -> tuple[dict[str, jax.Array], PimbotState]:
        obs, env_state = self.env.reset(key)
        state = PimbotState(
            done=jnp.array(False), step=jnp.zeros((), jnp.int32), env_state=env_state, obs=obs
        )
        return self.get_obs(state), state

    def step_env(self, key: jax.Array, state: PimbotState, actions: Mapping[str, jax.Array]):
        """One pimbot step without reset: actions {agent: int []} -> (obs, state, rewards,
        dones incl. "__all__", infos), every value keyed by agent."""
        joint = jnp.stack([jnp.asarray(actions[agent]) for agent in self.agents])
        obs, env_state, rewards, done, info = self.env.step(
            key, state.env_state, joint.astype(jnp.int32)
        )
        state = PimbotState(done=done, step=state.step + 1, env_state=env_state, obs=obs)
        dones = dict.fromkeys(self.agents, done) | {"__all__": done}
        rewards = {agent: rewards[i] for i, agent in enumerate(self.agents)}
        return self.get_obs(state), state, rewards, dones, info

    def get_obs(self, state: PimbotState) -> dict[str, jax.Array]:
        return {agent: state.obs[i] for i, agent in enumerate(self.agents)}

    def get_avail_actions(self, state: PimbotState) -> dict[str, jax.Array]:
        del state  # every action is always available
        return {agent: jnp.ones(self.env.num_actions, bool) for agent in self.agents}

    @property
    def name(self) -> str:
        return f"pimbot:{type(self.env).__name__}"

    @property
    def agent_classes(self) -> dict[str, list[str]]:
        return {"agent": list(self.agents)}


def to_jaxmarl(env_id: str, **params: Any) -> PimbotMultiAgentEnv:
    """The JaxMARL `MultiAgentEnv` of `make(env_id, **params)`."""
    return PimbotMultiAgentEnv(make(env_id, **params))


# --- 2. JaxMARL envs as pimbot envs ------------------------------------------------------

StepSuccess = Callable[[Any, Any, Any, jax.Array, jax.Array], jax.Array]
"""(jaxmarl env, state before, state after, rewards float32 [N], done) -> bool []."""


def jaxmarl_horizon(env: MultiAgentEnv) -> int:
    """Steps of a JaxMARL episode: `max_steps`, except MPE's, which end one step later
    (their `step_env` tests the step count before incrementing it)."""
    return int(env.max_steps) + 1 if isinstance(env, SimpleMPE) else int(env.max_steps)


def rewards_all_positive(env, state, next_state, rewards: jax.Array, done) -> jax.Array:
    """Generic proxy: every agent's reward this step is positive."""
    del env, state, next_state, done
    return jnp.all(rewards > 0)


def coin_own_pickup(env, state, next_state, rewards, done) -> jax.Array:
    """Coin game: some coin was picked up by its owner and none by the other agent.

    Read off JaxMARL's own counters (red/blue_coop count own-coin pickups, red/blue_defect
    the other's coin; int8, so differences are taken before widening)."""
    del env, rewards, done

    def gained(name: str) -> jax.Array:
        return jnp.sum((getattr(next_state, name) - getattr(state, name)).astype(jnp.int32))

    own = gained("red_coop") + gained("blue_coop")
    taken = gained("red_defect") + gained("blue_defect")
    return (own > 0) & (taken == 0)


def landmarks_covered(env, state, next_state, rewards, done) -> jax.Array:
    """MPE spread: every landmark touches some agent (their discs overlap) after the step."""
    del state, rewards, done
    n = env.num_agents
    agents, landmarks = next_state.p_pos[:n], next_state.p_pos[n:]
    distance = jnp.linalg.norm(landmarks[:, None, :] - agents[None, :, :], axis=-1)  # [L, N]
    reach = env.rad[n:, None] + env.rad[None, :n]
    return jnp.all(jnp.any(distance < reach, axis=1))


@dataclasses.dataclass(frozen=True)
class Rules:
    """What the spaces of a JaxMARL env do not say, for pimbot's protocol."""

    step_success: StepSuccess
    """A step's ``info["success"]``; an episode's success is the fraction of successful steps."""
    success_meaning: str
    """One line: what success means (said in docs/jaxmarl.md and the registry description)."""
    horizon: Callable[[Any], int] = jaxmarl_horizon
    """The number of steps of every episode of the built JaxMARL env."""
    idle_action: int = 0
    """The action of an agent that does nothing (the bypass attack plays it)."""
    stochastic: bool = True
    """False only when reset and step ignore their key."""


DEFAULT_RULES = Rules(
    rewards_all_positive,
    "no natural success; proxy: the fraction of steps in which every agent's reward is > 0",
)
RULES: dict[str, Rules] = {
    "coin_game": Rules(
        coin_own_pickup,
        "the fraction of steps in which a coin is picked up by its owner and none by the "
        "other agent (a per-step form of the own-coin pickup rate)",
        horizon=lambda env: env.num_inner_steps * env.num_outer_steps,
        idle_action=4,  # stay
    ),
    "MPE_simple_spread_v3": Rules(
        landmarks_covered,
        "no natural success; proxy: the fraction of steps in which every landmark touches an agent",
        idle_action=0,  # no-op
    ),
    "overcooked": Rules(  # fits, not registered: 400-step episodes of 520-dim observations
        rewards_all_positive,
        "the fraction of steps in which a soup is delivered (the shared reward is positive)",
        idle_action=4,  # stay
    ),
}
"""Rules by JaxMARL id; ids not here get `DEFAULT_RULES`."""

RESERVED = (
    "num_actions",
    "obs_dim",
    "max_steps",
    "incentive_obs",
    "idle_action",
    "stochastic",
    "terminates_on_success",
    "jaxmarl_env",
)
"""Protocol attributes a JaxMARL parameter may not be named after (``num_agents`` may,
and is then the number of agents)."""


@functools.cache
def _build(jaxmarl_id: str, params: tuple[tuple[str, Any], ...]) -> MultiAgentEnv:
    try:
        with _quiet_stdout():
            return jaxmarl.make(jaxmarl_id, **dict(params))
    except (TypeError, ValueError, AssertionError) as error:
        raise InvalidParameter(f"{jaxmarl_id}: JaxMARL rejects {dict(params)}: {error}") from None


@functools.cache
def space_fit(env: MultiAgentEnv) -> tuple[int, int, float, float]:
    """How a JaxMARL env's spaces map onto pimbot's protocol.

    Returns:
        (num_actions, obs_dim, obs low, obs high).
    Raises:
        InvalidParameter: the spaces do not fit, saying why.
    """
    name = env.name
    actions = [env.action_space(agent) for agent in env.agents]
    observations = [env.observation_space(agent) for agent in env.agents]
    if not all(isinstance(s, spaces.Discrete) for s in actions):
        kinds = sorted({type(s).__name__ for s in actions})
        raise InvalidParameter(f"{name}: actions must be Discrete for every agent, got {kinds}")
    if len({s.n for s in actions}) != 1:
        raise InvalidParameter(f"{name}: agents have different action counts")
    if not all(isinstance(s, spaces.Box) for s in observations):
        kinds = sorted({type(s).__name__ for s in observations})
        raise InvalidParameter(f"{name}: observations must be a Box for every agent, got {kinds}")
    shapes = sorted({tuple(np.atleast_1d(s.shape).tolist()) for s in observations})
    if len(shapes) != 1:
        raise InvalidParameter(f"{name}: agents observe different shapes {shapes}")
    low = min(float(np.min(s.low)) for s in observations)
    high = max(float(np.max(s.high)) for s in observations)
    return actions[0].n, math.prod(shapes[0]), low, high


@dataclasses.dataclass(frozen=True)
class JaxMARLEnv:
    """Base of the pimbot envs `register_jaxmarl` makes: each subclass names a JaxMARL id
    and its `Rules`, and has the JaxMARL constructor's parameters as its fields.

    `reset` and `step` are JaxMARL's `reset` and `step_env` (no auto-reset: pimbot's
    rollout resets); observations are flattened to float32 [N, obs_dim] in the order of
    the JaxMARL env's `agents`, rewards stacked to float32 [N], `done` is
    ``dones["__all__"]``; `info` holds JaxMARL's scalar infos and ``"success"``.
    """

    jaxmarl_id: ClassVar[str]
    rules: ClassVar[Rules]

    incentive_obs: bool = dataclasses.field(default=False, init=False, repr=False)
    terminates_on_success: bool = dataclasses.field(default=False, init=False, repr=False)

    def __post_init__(self) -> None:
        env = self.jaxmarl_env
        space_fit(env)
        try:
            horizon = self.rules.horizon(env)
        except (AttributeError, TypeError):
            horizon = None
        if not isinstance(horizon, int) or horizon < 1:
            raise InvalidParameter(
                f"{env.name}: no episode length (max_steps); register it with "
                "rules=Rules(..., horizon=...)"
            )
        if getattr(self, "num_agents", env.num_agents) != env.num_agents:
            raise InvalidParameter(f"num_agents: {env.name} has {env.num_agents} agents")

    def params(self) -> tuple[tuple[str, Any], ...]:
        return tuple((f.name, getattr(self, f.name)) for f in dataclasses.fields(self) if f.init)

    @property
    def jaxmarl_env(self) -> MultiAgentEnv:
        """The JaxMARL env these parameters build (one per equal parameters)."""
        return _build(self.jaxmarl_id, self.params())

    @property
    def num_agents(self) -> int:
        return self.jaxmarl_env.num_agents

    @property
    def num_actions(self) -> int:
        return space_fit(self.jaxmarl_env)[0]

    @property
    def obs_dim(self) -> int:
        return space_fit(self.jaxmarl_env)[1]

    @property
    def max_steps(self) -> int:
        return self.rules.horizon(self.jaxmarl_env)

    @property
    def idle_action(self) -> int:
        return self.rules.idle_action

    @property
    def stochastic(self) -> bool:
        return self.rules.stochastic

    def obs_bounds(self) -> tuple[float, float]:
        return space_fit(self.jaxmarl_env)[2:]

    def _stack_obs(self, obs: Mapping[str, jax.Array]) -> jax.Array:
        rows = [jnp.ravel(obs[agent]) for agent in self.jaxmarl_env.agents]
        return jnp.stack(rows).astype(jnp.float32)

    def reset(self, key: jax.Array) -> tuple[jax.Array, Any]:
        obs, state = self.jaxmarl_env.reset(key)
        return self._stack_obs(obs), state

    def step(self, key: jax.Array, state: Any, actions: jax.Array):
        env = self.jaxmarl_env
        actions = actions.astype(jnp.int32)
        joint = {agent: actions[i] for i, agent in enumerate(env.agents)}
        obs, next_state, rewards, dones, infos = env.step_env(key, state, joint)
        rewards = jnp.stack([rewards[agent] for agent in env.agents]).astype(jnp.float32)
        done = jnp.asarray(dones["__all__"], jnp.bool_)
        success = jnp.asarray(self.rules.step_success(env, state, next_state, rewards, done))
        info = {  # the scalar entries: per-agent dicts would not stack into pimbot's metrics
            name: value
            for name, value in infos.items()
            if isinstance(value, jax.Array | np.ndarray | bool | int | float)
            and jnp.ndim(value) == 0
        }
        info["success"] = success.astype(jnp.bool_)
        return self._stack_obs(obs), next_state, rewards, done, info

    def episode_success(self, success_steps, num_steps, env_return) -> jax.Array:
        del env_return
        return (success_steps / jnp.maximum(num_steps, 1)).astype(jnp.float32)


@functools.cache
def adapter_class(name: str, rules: Rules, params: tuple[tuple[str, Any], ...]) -> type:
    """The `JaxMARLEnv` subclass for JaxMARL id `name` with these parameter defaults
    (one class per arguments, so that registering twice alike is a no-op)."""
    taken = [key for key, _ in params if key in RESERVED]
    if taken:
        raise InvalidParameter(f"{', '.join(taken)}: reserved by pimbot's env protocol")
    fields = [(key, type(value), dataclasses.field(default=value)) for key, value in params]
    words = re.split(r"[^0-9a-zA-Z]+", name)
    return dataclasses.make_dataclass(
        "JaxMARL" + "".join(w[:1].upper() + w[1:] for w in words),
        fields,
        bases=(JaxMARLEnv,),
        frozen=True,
        namespace={
            "jaxmarl_id": name,
            "rules": rules,
            "__doc__": f"JaxMARL's {name} under pimbot's protocol. Success: "
            f"{rules.success_meaning}.",
            "__module__": __name__,
        },
    )


def register_jaxmarl(
    name: str,
    /,
    *,
    env_id: str | None = None,
    description: str | None = None,
    rules: Rules | None = None,
    learner_defaults: Mapping[str, Mapping[str, Any]] | None = None,
    **params: Any,
) -> str:
    """Registers the JaxMARL env `name` as a pimbot env and returns its id.

    Args:
        name: a JaxMARL id (`jaxmarl.registered_envs`), e.g. ``"coin_game"``.
        env_id: the pimbot id; default ``"jaxmarl_{name lowercased}-v0"``.
        description: the registry's one line; default from the rules' success meaning.
        rules: default ``RULES.get(name, DEFAULT_RULES)``.
        learner_defaults: as in `pimbot.envs.register`.
        **params: the JaxMARL constructor's parameters, with their defaults; they become
            the pimbot env's parameters (``pimbot train ID name=value``).

    Raises:
        InvalidParameter: not a JaxMARL id, a reserved parameter name, parameters
            JaxMARL rejects, or spaces that do not fit (checked here, with the defaults).
    """
    if name not in jaxmarl.registered_envs:
        raise InvalidParameter(
            f"name: {name!r} is not a JaxMARL env; JaxMARL has {', '.join(jaxmarl.registered_envs)}"
        )
    rules = RULES.get(name, DEFAULT_RULES) if rules is None else rules
    env_id = f"jaxmarl_{name.lower()}-v0" if env_id is None else env_id
    cls = adapter_class(name, rules, tuple(params.items()))
    cls()  # fails now, not at first use, when the spaces do not fit
    description = description or f"JaxMARL {name}; success: {rules.success_meaning}."
    register(env_id, cls, description, learner_defaults)
    return env_id


COIN_GAME = register_jaxmarl(
    "coin_game",
    # one inner game per episode (JaxMARL's default is 10 inner games of 10 steps)
    num_inner_steps=10,
    num_outer_steps=1,
    egocentric=False,
    shared_rewards=False,
)
SIMPLE_SPREAD = register_jaxmarl(
    "MPE_simple_spread_v3",
    env_id="jaxmarl_simple_spread-v0",
    num_agents=3,
    num_landmarks=3,
    local_ratio=0.5,
)
