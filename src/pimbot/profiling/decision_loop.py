"""The on-device decision loop: batch-size-1 control with LIO heads, timed.

Per decision: the observation is ready on the host → it is put on the device,
every agent's policy and incentive heads run (one jitted function, batch 1
per agent) → the actions are back on the host (committed). The environment is
then stepped `action_repeat` times off the timed path. Every `update_every`
decisions one learner update (`lio.update`, with the ADMO attack on agent 0
for the adversarial controller) runs and is timed on its own. Compilation and
warm-up are timed separately and excluded from the steady-state samples.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from pimbot import attacks, envs, learners
from pimbot.contracts.attack import NO_ATTACK
from pimbot.rollout import decide

CONTROLLERS = ("benign", "admo")


@dataclasses.dataclass(frozen=True)
class ProfileConfig:
    """One profiling run."""

    env_id: str = "escape_room-v0"
    """Environment id."""
    env_params: tuple[tuple[str, Any], ...] = ()
    """Environment parameters as (name, value) pairs."""
    controller: str = "benign"
    """"benign" (plain LIO) or "admo" (ADMO attached to agent 0)."""
    duration_s: float = 20.0
    """Steady-state wall time of the loop."""
    hidden: tuple[int, ...] = (256, 128)
    """Hidden widths of both the policy and the incentive MLP."""
    action_repeat: int = 2
    """Environment steps per decision."""
    update_every: int = 100
    """Decisions between learner update steps."""
    warmup_decisions: int = 20
    """Decisions run (and discarded) after compilation, before steady state."""
    seed: int = 0
    """Root PRNG seed."""


@dataclasses.dataclass
class LoopResult:
    latencies_s: np.ndarray  # [decisions] steady-state decision latencies
    update_times_s: np.ndarray  # [updates] steady-state learner update times
    steady_wall_s: float  # wall time of the steady-state loop
    compile_s: dict[str, float]  # first call (compile + run) of each jitted function
    warmup_s: float  # the warm-up decisions and update after compilation
    env_steps: int


def make_attack(controller: str, num_agents: int):
    """The controller's attack: none (benign) or ADMO on agent 0."""
    if controller not in CONTROLLERS:
        raise envs.InvalidParameter(
            f"controller: unknown controller {controller!r}; allowed: {', '.join(CONTROLLERS)}"
        )
    if controller == "benign":
        return NO_ATTACK
    return attacks.make("admo", num_agents, adversary=0)


def decision_fn(env, learner, cfg, attack) -> Callable:
    """decide(state, key, obs [N, obs_dim], given [N, N], t) -> (actions, given).

    One joint decision: each agent's policy head on its own observation (batch 1)
    and each giver's incentive head (the learner's `acting`), with the attack's
    act/emit hooks as in training.
    """

    def decision(state, key, obs, given, t):
        actor = learner.acting(env, cfg, state)
        _, actions, incentives, _, _ = decide(
            env, key, obs, given, actor.act, actor.give, attack, t, state.attack_state
        )
        return actions, given + incentives

    return jax.jit(decision)


def _timed(fn, *args):
    start = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, time.perf_counter() - start


def run(config: ProfileConfig, on_phase: Callable[[str], None] | None = None) -> LoopResult:
    """Runs warm-up then `duration_s` of steady-state decisions; see the module docstring."""
    env = envs.make(config.env_id, **dict(config.env_params))
    learner = learners.get("lio")
    cfg = dataclasses.replace(
        learner.default_config(envs.spec(config.env_id)),
        policy_hidden=tuple(config.hidden),
        incentive_hidden=tuple(config.hidden),
    )
    attack = make_attack(config.controller, env.num_agents)
    key = jax.random.key(config.seed)
    init_key, env_key, act_key = jax.random.split(key, 3)
    state = learner.init(init_key, env, cfg, attack)
    decide = decision_fn(env, learner, cfg, attack)
    update = jax.jit(lambda s: learner.update(s, env, cfg, attack)[0])
    # The environment runs off the timed path (on the host CPU when there is one).
    cpu = jax.devices("cpu")[0]
    env_reset, env_step = jax.jit(env.reset), jax.jit(env.step)  # follow the committed key
    env_key = jax.device_put(env_key, cpu)

    compile_s: dict[str, float] = {}
    env_key, k = jax.random.split(env_key)
    (obs, env_state), compile_s["env_reset"] = _timed(env_reset, k)
    given = jnp.zeros((env.num_agents, env.num_agents), jnp.float32)
    t = jnp.int32(0)
    zeros = jnp.zeros(env.num_agents, jnp.int32)
    _, compile_s["env_step"] = _timed(env_step, k, env_state, zeros)
    _, compile_s["decision"] = _timed(
        decide, state, act_key, jnp.asarray(np.asarray(obs)), given, t
    )
    state, compile_s["update"] = _timed(update, state)

    def one_decision(obs, env_state, given, env_key, act_key, steps):
        act_key, k = jax.random.split(act_key)
        start = time.perf_counter()
        actions, given = decide(state, k, jax.device_put(np.asarray(obs)), given, steps)
        actions = np.asarray(actions)  # committed: on the host
        latency = time.perf_counter() - start
        done = False
        for _ in range(config.action_repeat):
            env_key, k = jax.random.split(env_key)
            obs, env_state, _, done, _ = env_step(k, env_state, actions)
            steps += 1
            if bool(done):
                break
        if bool(done):
            env_key, k = jax.random.split(env_key)
            obs, env_state = env_reset(k)
            given = jnp.zeros_like(given)
        return obs, env_state, given, env_key, act_key, steps, latency

    if on_phase is not None:
        on_phase("warmup")
    warm_start = time.perf_counter()
    steps = 0
    carry = (obs, env_state, given, env_key, act_key)
    for _ in range(config.warmup_decisions):
        *carry, steps, _ = one_decision(*carry, steps)
    state, _ = _timed(update, state)
    warmup_s = time.perf_counter() - warm_start

    if on_phase is not None:
        on_phase("steady")
    latencies, update_times = [], []
    start = time.perf_counter()
    decisions = 0
    while time.perf_counter() - start < config.duration_s:
        *carry, steps, latency = one_decision(*carry, steps)
        latencies.append(latency)
        decisions += 1
        if decisions % config.update_every == 0:
            state, update_time = _timed(update, state)
            update_times.append(update_time)
    steady_wall = time.perf_counter() - start
    return LoopResult(
        latencies_s=np.asarray(latencies),
        update_times_s=np.asarray(update_times),
        steady_wall_s=steady_wall,
        compile_s=compile_s,
        warmup_s=warmup_s,
        env_steps=steps,
    )
