"""The export's own check: onnxruntime against pimbot's agents, before anything is written.

Every model runs in onnxruntime on random observations within the env's bounds and on
every step of episodes the trained agents play (incentive slots filled, the run's attack
acting as in training). Policies are compared with the exported JAX functions, incentives
with the actor's own `give`, and the actions the actor samples with those drawn from the
ONNX logits with the same keys.
"""

from __future__ import annotations

from importlib import metadata
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from pimbot.contracts.rollout import rollout
from pimbot.errors import InvalidParameter
from pimbot.robot.exportable import (
    ACTIONS,
    INCENTIVES,
    LOGITS,
    OBSERVATION,
    PROBABILITIES,
    Agent,
    incentive_file,
    policy_file,
)
from pimbot.training import runs

TOLERANCE = 1e-5
"""Largest absolute difference allowed between onnxruntime's outputs and pimbot's (float32)."""
CHECK_OBSERVATIONS = 512
"""Random observations within the bounds each agent's models are checked on at export."""
CHECK_EPISODES = 16
"""Episodes of the trained agents whose observations the models are checked on as well."""
UNBOUNDED_SPAN = 10.0
"""Half-width of the range random observations take in an unbounded direction."""
RELATIVE_LOGITS = "logits_relative"
CHECKED = (RELATIVE_LOGITS, PROBABILITIES, INCENTIVES)
"""The differences held to `TOLERANCE` (absolute logits are reported, not held to it)."""


def sampling_range(low: float, high: float) -> tuple[float, float]:
    """The range random observations are drawn from: the bounds, 2·UNBOUNDED_SPAN wide on
    an unbounded side."""
    if np.isfinite(low) and np.isfinite(high):
        return low, high
    if np.isfinite(low):
        return low, low + 2 * UNBOUNDED_SPAN
    if np.isfinite(high):
        return high - 2 * UNBOUNDED_SPAN, high
    return -UNBOUNDED_SPAN, UNBOUNDED_SPAN


def random_inputs(env, key: jax.Array, count: int) -> tuple[np.ndarray, np.ndarray]:
    """`count` joint observations [count, N, obs_dim] uniform within the env's bounds and
    joint actions [count, N]."""
    low, high = sampling_range(*env.obs_bounds())
    obs_key, action_key = jax.random.split(key)
    shape = (count, env.num_agents, env.obs_dim)
    obs = jax.random.uniform(obs_key, shape, jnp.float32, low, high)
    actions = jax.random.randint(action_key, shape[:2], 0, env.num_actions, jnp.int32)
    return np.asarray(obs), np.asarray(actions)


def episode_inputs(
    loaded: runs.LoadedRun, seed_index: int, key: jax.Array, episodes: int
) -> tuple[np.ndarray, np.ndarray]:
    """The joint observations [K, N, obs_dim] (incentive slots filled) and joint actions
    [K, N] of every step of `episodes` episodes the seed's trained agents play (ε = 0,
    the run's attack acting as in training)."""
    r = loaded.resolved
    state = loaded.seed_state(seed_index)
    actor = loaded.actor(state)

    def play(k):
        return rollout(
            r.env, k, actor.act, actor.give, r.attack, state.env_steps, state.attack_state
        )

    trajs = jax.jit(jax.vmap(play))(jax.random.split(key, episodes))
    valid = np.asarray(trajs.valid).reshape(-1)
    obs = np.asarray(trajs.obs).reshape(-1, r.env.num_agents, r.env.obs_dim)[valid]
    return obs, np.asarray(trajs.actions).reshape(-1, r.env.num_agents)[valid]


def onnx_outputs(model, feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
    """What onnxruntime computes for `model` on `feeds` (the CPU provider)."""
    import onnxruntime

    session = onnxruntime.InferenceSession(
        model.SerializeToString(), providers=["CPUExecutionProvider"]
    )
    return session.run(None, feeds)


def largest_differences(
    loaded: runs.LoadedRun,
    seed_index: int,
    agents: list[Agent],
    models: dict[str, Any],
    inputs: tuple[np.ndarray, np.ndarray],
) -> tuple[dict[str, float], np.ndarray]:
    """Largest |onnxruntime − pimbot| per output over the joint `inputs` (obs [K, N, D],
    actions [K, N]) — logits and probabilities against the exported functions in JAX,
    incentives against the actor's own `give` — and the ONNX logits [K, N, A]. Logits are
    also compared relative to max(1, |logit|) (`CHECKED`: an absolute difference of
    float32 logits grows with their size)."""
    obs, actions = inputs
    actor = loaded.actor(loaded.seed_state(seed_index))
    given = np.asarray(jax.vmap(actor.give)(obs, actions)) if actor.give else None
    worst: dict[str, float] = {}

    def note(name: str, difference: np.ndarray) -> None:
        worst[name] = max(worst.get(name, 0.0), float(np.max(difference)))

    logits = []
    for agent in agents:
        got = onnx_outputs(models[policy_file(agent.index)], {OBSERVATION: obs[:, agent.index]})
        ours = [np.asarray(x) for x in agent.policy(obs[:, agent.index])]
        note(LOGITS, np.abs(ours[0] - got[0]))
        note(RELATIVE_LOGITS, np.abs(ours[0] - got[0]) / np.maximum(1.0, np.abs(ours[0])))
        note(PROBABILITIES, np.abs(ours[1] - got[1]))
        logits.append(got[0])
        if agent.give is not None:
            feeds = {OBSERVATION: obs[:, agent.index], ACTIONS: actions}
            (theirs,) = onnx_outputs(models[incentive_file(agent.index)], feeds)
            note(INCENTIVES, np.abs(given[:, agent.index] - theirs))
    return worst, np.stack(logits, axis=1)


def sampled_agreement(
    loaded: runs.LoadedRun, seed_index: int, obs: np.ndarray, onnx_logits: np.ndarray, key
) -> float:
    """Fraction of joint observations on which the actor's sampled actions equal those drawn
    with the same key from the ONNX models' logits (`jax.random.categorical`, as `acting`)."""
    actor = loaded.actor(loaded.seed_state(seed_index))
    keys = jax.random.split(key, len(obs))
    ours = jax.vmap(actor.act)(keys, jnp.asarray(obs))
    theirs = jax.vmap(jax.random.categorical)(keys, jnp.asarray(onnx_logits))
    return float(np.mean(np.all(np.asarray(ours) == np.asarray(theirs), axis=-1)))


class ExportMismatch(InvalidParameter):
    """The ONNX models compute something else than pimbot's agents (nothing is written)."""


def check_parity(loaded: runs.LoadedRun, seed_index: int, agents, models) -> dict[str, Any]:
    """onnxruntime against pimbot on random observations within the bounds and on the
    observations of real episodes; ExportMismatch (one line) beyond `TOLERANCE`."""
    key = jax.random.fold_in(jax.random.PRNGKey(loaded.seeds[seed_index]), 0x0E)
    random_key, episode_key, sample_key = jax.random.split(key, 3)
    env = loaded.resolved.env
    played = episode_inputs(loaded, seed_index, episode_key, CHECK_EPISODES)
    drawn = random_inputs(env, random_key, CHECK_OBSERVATIONS)
    inputs = tuple(np.concatenate(pair) for pair in zip(drawn, played, strict=True))
    worst, onnx_logits = largest_differences(loaded, seed_index, agents, models, inputs)
    for name in CHECKED:
        difference = worst.get(name, 0.0)
        if not difference <= TOLERANCE:
            raise ExportMismatch(
                f"export: the ONNX {name} differ from pimbot's by up to {difference:.3g} "
                f"(> {TOLERANCE:g}) on {len(inputs[0])} observations; nothing written"
            )
    low, high = sampling_range(*env.obs_bounds())
    return {
        "observations_per_agent": int(len(inputs[0])),
        "random_observations": CHECK_OBSERVATIONS,
        "random_range": [low, high],
        "episode_observations": int(len(played[0])),
        "episodes": CHECK_EPISODES,
        "max_abs_difference": worst,
        "tolerance": TOLERANCE,
        "sampled_actions_equal": sampled_agreement(
            loaded, seed_index, inputs[0], onnx_logits, sample_key
        ),
        "runtime": f"onnxruntime {metadata.version('onnxruntime')} (CPU)",
    }
