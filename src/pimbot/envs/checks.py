"""Conformance checks for functional environments, shipped as library code.

`check_env(env)` is what the test suite runs over every registered id, so a
new environment is tested by being registered (cf. Gymnasium's `check_env` and
PettingZoo's `pettingzoo.test`). It compiles two functions per environment: a
rollout of random actions (reset, then steps under `lax.scan` with a reset
after every `done`) and its `vmap` over a batch of keys.
"""

from __future__ import annotations

import functools
import warnings
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from pimbot.envs.core import Env, TracedFields, program_env, step_metric_names, traced_fields
from pimbot.moved import PimbotDeprecationWarning

_PROTOCOL_FLAGS = ("incentive_obs", "stochastic", "terminates_on_success")


def check_env(
    env: Env, *, num_steps: int | None = None, batch_size: int = 4, seed: int = 0
) -> None:
    """Asserts that `env` follows the functional environment protocol (`pimbot.envs.core.Env`).

    Checks the attributes; the shapes and dtypes of `reset` and `step` (obs
    float32 [N, obs_dim], rewards float32 [N], done bool [], info["success"]
    bool []) with int32 actions; observations within `obs_bounds` (and zero
    incentive slots); episodes that end by `max_steps`; `episode_success` in
    [0, 1]; same key ⇒ identical trajectory; vmap over a batch of keys (hence
    of states) agrees with the unbatched rollouts; different keys give
    different trajectories iff `env.stochastic`.

    Args:
        env: the environment to check.
        num_steps: length of the random-action rollout (default 2 * max_steps,
            so that at least one reset after `done` is exercised).
        batch_size: number of keys in the vmapped rollout (≥ 2).
        seed: seed of the keys and the random actions.

    Raises:
        AssertionError: naming the first property that does not hold.
    """
    _check_attributes(env)
    num_steps = 2 * env.max_steps if num_steps is None else num_steps
    assert batch_size >= 2, f"batch_size must be at least 2, got {batch_size}"
    keys = jax.random.split(jax.random.key(seed), batch_size)
    actions = np.random.default_rng(seed).integers(0, env.num_actions, (num_steps, env.num_agents))
    actions = jnp.asarray(actions, jnp.int32)
    _check_signatures(env, keys[0], actions[0])

    rollout = jax.jit(functools.partial(_rollout, env))
    trajectories = [_to_numpy(rollout(keys[b], actions)) for b in range(batch_size)]
    for trajectory in trajectories:
        _check_trajectory(env, trajectory)
    _assert_trees_equal(
        _to_numpy(rollout(keys[0], actions)), trajectories[0], "two rollouts with the same key"
    )

    vmapped = jax.jit(jax.vmap(functools.partial(_rollout, env), in_axes=(0, None)))
    batched = _to_numpy(vmapped(keys, actions))
    rows = [jax.tree.map(lambda x, b=b: x[b], batched) for b in range(batch_size)]
    for b, (row, trajectory) in enumerate(zip(rows, trajectories, strict=True)):
        _assert_trees_close(
            row, trajectory, f"row {b} of the vmapped rollout and the rollout of its key"
        )
    _check_traced_fields(env, keys[0], actions, trajectories[0])
    differ = [not _trees_equal(other, trajectories[0]) for other in trajectories[1:]]
    if env.stochastic:
        assert any(differ), (
            f"{env}: stochastic is True but {batch_size} different keys gave identical trajectories"
        )
    else:
        assert not any(differ), (
            f"{env}: stochastic is False but different keys gave different trajectories"
        )


def _rollout(env: Env, key: jax.Array, actions: jax.Array) -> dict[str, Any]:
    """Resets, then steps through `actions` [T, N], resetting after every `done`."""
    reset_key, key = jax.random.split(key)
    obs, state = env.reset(reset_key)

    def body(carry, action):
        obs, state, key, t = carry
        key, step_key, reset_key = jax.random.split(key, 3)
        next_obs, next_state, rewards, done, info = env.step(step_key, state, action)
        t = t + 1
        fresh = env.reset(reset_key)
        carry_obs, carry_state = jax.tree.map(
            lambda new, cont: jnp.where(done, new, cont), fresh, (next_obs, next_state)
        )
        out = {
            "obs": obs,
            "next_obs": next_obs,
            "rewards": rewards,
            "done": done,
            "info": info,
            "t": t,
        }
        return (carry_obs, carry_state, key, jnp.where(done, 0, t)), out

    _, trajectory = jax.lax.scan(body, (obs, state, key, jnp.zeros((), jnp.int32)), actions)
    return trajectory


def _check_traced_fields(env: Env, key: jax.Array, actions: jax.Array, expected) -> None:
    """The env passed as an argument (as a training program takes it: its traced fields
    traced) gives the rollout it gives with them compiled in."""
    fields = traced_fields(env)
    if not fields:
        return
    if not isinstance(env, TracedFields):  # written for 0.1: compiled in, as it was then
        warnings.warn(
            f"{type(env).__name__} declares traced_fields {fields} without subclassing "
            "pimbot.envs.core.TracedFields: its numbers are compiled in (one program per "
            "value); subclass TracedFields to share one program (refused from 0.3.0)",
            PimbotDeprecationWarning,
            stacklevel=2,
        )
        return
    argument = program_env(env)
    assert argument is not None and jax.tree.leaves(argument) == [
        getattr(env, name) for name in fields
    ], f"{env}: traced_fields {fields} but it is no pytree of them (see envs.core.TracedFields)"
    try:
        got = jax.jit(_rollout)(argument, key, actions)
    except Exception as error:  # a tracer where a concrete value was needed
        raise AssertionError(
            f"{env}: traced_fields {fields}: reset or step uses one as a static value "
            f"(a shape or Python control flow): {type(error).__name__}"
        ) from None
    _assert_trees_equal(_to_numpy(got), expected, "the rollout with traced_fields traced")


def _check_attributes(env: Env) -> None:
    for name in ("num_agents", "num_actions", "obs_dim", "max_steps"):
        value = getattr(env, name, None)
        assert isinstance(value, int) and value >= 1, (
            f"{env}: {name} must be a positive int, got {value!r}"
        )
    idle = getattr(env, "idle_action", None)
    assert isinstance(idle, int) and 0 <= idle < env.num_actions, (
        f"{env}: idle_action must be an int in [0, {env.num_actions}), got {idle!r}"
    )
    for name in _PROTOCOL_FLAGS:
        value = getattr(env, name, None)
        assert isinstance(value, bool), f"{env}: {name} must be a bool, got {value!r}"
    try:
        hash(env)
    except TypeError as error:
        raise AssertionError(f"{env}: must be hashable (a jit static argument)") from error
    low, high = env.obs_bounds()
    assert low < high, f"{env}: obs_bounds must satisfy low < high, got {(low, high)}"


def _assert_array(what: str, value: Any, shape: tuple[int, ...], dtype: Any) -> None:
    assert hasattr(value, "shape") and hasattr(value, "dtype"), (
        f"{what} must be an array, got {type(value).__name__}"
    )
    assert value.shape == shape, f"{what} must have shape {shape}, got {value.shape}"
    assert value.dtype == dtype, f"{what} must have dtype {jnp.dtype(dtype)}, got {value.dtype}"


def _check_signatures(env: Env, key: jax.Array, actions: jax.Array) -> None:
    """Shapes and dtypes of reset and step, traced abstractly (no compilation)."""
    n, d = env.num_agents, env.obs_dim
    obs, state = jax.eval_shape(env.reset, key)
    _assert_array("reset obs", obs, (n, d), jnp.float32)
    result = jax.eval_shape(env.step, key, state, actions)
    assert isinstance(result, tuple) and len(result) == 5, (
        "step must return (obs, state, rewards, done, info)"
    )
    obs, next_state, rewards, done, info = result
    _assert_array("step obs", obs, (n, d), jnp.float32)
    _assert_array("rewards", rewards, (n,), jnp.float32)
    _assert_array("done", done, (), jnp.bool_)
    assert isinstance(info, dict) and "success" in info, 'info must be a dict with "success"'
    _assert_array('info["success"]', info["success"], (), jnp.bool_)
    for name in step_metric_names(env):
        assert name in info, f"step_metrics names {name!r}, which info does not hold"
        assert info[name].shape in ((), (n,)), (
            f'info["{name}"] (a step metric) must have shape () or ({n},), got {info[name].shape}'
        )
    assert jax.tree.structure(state) == jax.tree.structure(next_state) and all(
        (x.shape, x.dtype) == (y.shape, y.dtype)
        for x, y in zip(jax.tree.leaves(state), jax.tree.leaves(next_state), strict=True)
    ), f"step changed the state's structure: {state} -> {next_state}"


def _check_trajectory(env: Env, trajectory: dict[str, Any]) -> None:
    obs = np.asarray(trajectory["obs"])
    next_obs = np.asarray(trajectory["next_obs"])
    rewards = np.asarray(trajectory["rewards"])
    done = np.asarray(trajectory["done"])
    success = np.asarray(trajectory["info"]["success"])
    t = np.asarray(trajectory["t"])
    low, high = env.obs_bounds()
    for what, o in (("reset/previous obs", obs), ("step obs", next_obs)):
        assert not np.isnan(o).any(), f"{env}: {what} contains NaN"
        assert (o >= low).all() and (o <= high).all(), (
            f"{env}: {what} outside obs_bounds {(low, high)}: range [{o.min()}, {o.max()}]"
        )
        if env.incentive_obs:
            slots = o[..., env.obs_dim - (env.num_agents - 1) :]
            assert (slots == 0).all(), f"{env}: {what} has nonzero incentive slots"
    assert np.isfinite(rewards).all(), f"{env}: rewards must be finite"

    horizon = t == env.max_steps
    assert (t <= env.max_steps).all(), f"{env}: an episode ran past max_steps={env.max_steps}"
    assert done[horizon].all(), f"{env}: done must be true at step max_steps={env.max_steps}"
    early = done & ~horizon
    if env.terminates_on_success:
        assert success[early].all(), f"{env}: episode ended before max_steps without success"
    else:
        assert not early.any(), (
            f"{env}: terminates_on_success is False but an episode ended before max_steps"
        )

    if done.any():
        end = int(np.argmax(done)) + 1
        score = env.episode_success(
            jnp.sum(success[:end], dtype=jnp.int32),
            jnp.int32(end),
            jnp.sum(rewards[:end], axis=0),
        )
        assert jnp.shape(score) == () and 0.0 <= float(score) <= 1.0, (
            f"{env}: episode_success must be a scalar in [0, 1], got {score}"
        )


def _to_numpy(tree: Any) -> Any:
    return jax.tree.map(np.asarray, tree)


def _leaves(tree: Any) -> list[np.ndarray]:
    return [np.asarray(x) for x in jax.tree.leaves(tree)]


def _trees_equal(a: Any, b: Any) -> bool:
    return jax.tree.structure(a) == jax.tree.structure(b) and all(
        np.array_equal(x, y) for x, y in zip(_leaves(a), _leaves(b), strict=True)
    )


def _assert_trees_equal(a: Any, b: Any, what: str) -> None:
    assert _trees_equal(a, b), f"{what} differ"


def _assert_trees_close(a: Any, b: Any, what: str) -> None:
    assert jax.tree.structure(a) == jax.tree.structure(b), f"{what} differ in structure"
    for x, y in zip(_leaves(a), _leaves(b), strict=True):
        assert x.shape == y.shape and x.dtype == y.dtype, f"{what} differ in shape or dtype"
        if np.issubdtype(x.dtype, np.floating):
            assert np.allclose(x, y, rtol=1e-6, atol=1e-6), f"{what} differ"
        else:
            assert np.array_equal(x, y), f"{what} differ"
