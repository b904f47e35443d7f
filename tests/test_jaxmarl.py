"""The JaxMARL adapters, both ways (`pimbot.envs.jaxmarl`; jaxmarl comes with the test extra).

pimbot's ER and IPD as JaxMARL `MultiAgentEnv`s: jit + vmap rollouts agree step for step
with the raw env (JaxMARL's auto-reset included). JaxMARL envs under pimbot: every
registered id passes `check_env`, the coin game's rewards and success on hand-set states,
spaces that do not fit fail naming why, and the coin game trains (2 seeds × 20
iterations) with lio + bypass and pg through `runner.train`, then from the command line
with `--plugin pimbot.envs.jaxmarl` in a fresh process. The module is loaded by a
fixture (at run time, as `--plugin` loads it), so ids registered here do not leak into
the parametrizations of other test files.
"""

from __future__ import annotations

import csv
import functools
import json
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import jaxmarl  # noqa: F401  (required, not skipped: the test extra installs it)
import numpy as np
import pytest
from jaxmarl.environments import spaces
from jaxmarl.environments.multi_agent_env import MultiAgentEnv

from pimbot import envs, plugins
from pimbot.envs.core import InvalidParameter
from pimbot.training import runner, store
from pimbot.training.config import RunConfig

MODULE = "pimbot.envs.jaxmarl"
JAXMARL_IDS = ["jaxmarl_coin_game-v0", "jaxmarl_simple_spread-v0"]
COIN = "jaxmarl_coin_game-v0"
STAY, RIGHT = 4, 0  # coin game moves: 0 right = (0, +1), 4 stay


@pytest.fixture(scope="module")
def adapters():
    return plugins.load(MODULE)


# --- pimbot envs as JaxMARL MultiAgentEnvs -------------------------------------------------

PIMBOT_ENVS = [
    ("escape_room-v0", {"n_agents": 3, "min_at_lever": 1, "randomize_start": True}),
    ("ipd-v0", {}),
]


def _jaxmarl_rollout(wrapped, key, actions):
    """JaxMARL's loop: reset once, then `step` (which auto-resets) through actions [T, N]."""
    reset_key, key = jax.random.split(key)
    obs, state = wrapped.reset(reset_key)

    def body(carry, joint):
        state, key = carry
        key, step_key = jax.random.split(key)
        act = {agent: joint[i] for i, agent in enumerate(wrapped.agents)}
        obs, state, rewards, dones, infos = wrapped.step(step_key, state, act)
        out = {
            "obs": jnp.stack([obs[a] for a in wrapped.agents]),
            "rewards": jnp.stack([rewards[a] for a in wrapped.agents]),
            "done": dones["__all__"],
            "agent_done": jnp.stack([dones[a] for a in wrapped.agents]),
            "success": infos["success"],
        }
        return (state, key), out

    _, out = jax.lax.scan(body, (state, key), actions)
    return jnp.stack([obs[a] for a in wrapped.agents]), out


def _raw_rollout(env, key, actions):
    """The same loop on the raw pimbot env, unjitted, splitting keys as JaxMARL's `step` does."""
    reset_key, key = jax.random.split(key)
    obs, state = env.reset(reset_key)
    first, steps = np.asarray(obs), []
    for joint in actions:
        key, step_key = jax.random.split(key)
        env_key, auto_reset_key = jax.random.split(step_key)
        obs, state, rewards, done, info = env.step(env_key, state, jnp.asarray(joint))
        if done:
            obs, state = env.reset(auto_reset_key)
        steps.append((np.asarray(obs), np.asarray(rewards), bool(done), bool(info["success"])))
    return first, steps


@pytest.mark.parametrize(("env_id", "params"), PIMBOT_ENVS)
def test_pimbot_env_as_multi_agent_env_matches_raw_env_under_jit_and_vmap(adapters, env_id, params):
    raw = envs.make(env_id, **params)
    wrapped = adapters.to_jaxmarl(env_id, **params)
    assert isinstance(wrapped, MultiAgentEnv) and wrapped.env == raw
    assert wrapped.agents == [f"agent_{i}" for i in range(raw.num_agents)]
    low, high = raw.obs_bounds()
    for agent in wrapped.agents:
        box, discrete = wrapped.observation_space(agent), wrapped.action_space(agent)
        assert isinstance(box, spaces.Box) and box.shape == (raw.obs_dim,)
        assert (box.low, box.high) == (low, high)
        assert isinstance(discrete, spaces.Discrete) and discrete.n == raw.num_actions

    batch, steps = 3, 2 * raw.max_steps + 1
    keys = jax.random.split(jax.random.key(7), batch)
    actions = np.random.default_rng(0).integers(0, raw.num_actions, (batch, steps, raw.num_agents))
    rollout = jax.jit(jax.vmap(functools.partial(_jaxmarl_rollout, wrapped)))
    first_obs, out = jax.tree.map(np.asarray, rollout(keys, jnp.asarray(actions, jnp.int32)))

    ends = 0
    for b in range(batch):
        raw_first, raw_steps = _raw_rollout(raw, keys[b], actions[b])
        np.testing.assert_allclose(first_obs[b], raw_first)
        for t, (obs, rewards, done, success) in enumerate(raw_steps):
            np.testing.assert_allclose(out["obs"][b, t], obs, err_msg=f"obs, row {b} step {t}")
            np.testing.assert_allclose(out["rewards"][b, t], rewards, err_msg=f"step {t}")
            assert out["done"][b, t] == done and (out["agent_done"][b, t] == done).all()
            assert out["success"][b, t] == success
            ends += done
    assert ends >= batch, "every row crosses at least one episode end (the auto-reset)"


def test_multi_agent_env_state_carries_obs_and_avail_actions(adapters):
    wrapped = adapters.to_jaxmarl("escape_room-v0")
    obs, state = wrapped.reset(jax.random.key(0))
    assert {a: np.asarray(o).tolist() for a, o in wrapped.get_obs(state).items()} == {
        a: np.asarray(o).tolist() for a, o in obs.items()
    }
    assert int(state.step) == 0 and not bool(state.done)
    avail = wrapped.get_avail_actions(state)
    assert all(np.asarray(mask).all() and mask.shape == (3,) for mask in avail.values())
    # a fixed reset state for the auto-reset (JaxMARL's `reset_state`) is honoured
    _, fresh = wrapped.reset(jax.random.key(1))
    act = {"agent_0": 0, "agent_1": 2}  # lever + door: success, the episode ends
    obs, after, rewards, dones, _ = wrapped.step(jax.random.key(2), state, act, reset_state=fresh)
    assert bool(dones["__all__"]) and float(rewards["agent_1"]) == 10.0
    assert int(after.step) == 0


# --- JaxMARL envs under pimbot ---------------------------------------------------------------


def test_module_registers_exactly_the_documented_ids(adapters):
    assert [e for e in envs.registered() if e.startswith("jaxmarl_")] == JAXMARL_IDS
    assert tuple(JAXMARL_IDS) == (adapters.COIN_GAME, adapters.SIMPLE_SPREAD)
    assert envs.spec(COIN).parameters() == {
        "num_inner_steps": 10,
        "num_outer_steps": 1,
        "egocentric": False,
        "shared_rewards": False,
    }
    # registering alike again is a no-op; the id table is unchanged
    adapters.register_jaxmarl(
        "coin_game", num_inner_steps=10, num_outer_steps=1, egocentric=False, shared_rewards=False
    )
    assert [e for e in envs.registered() if e.startswith("jaxmarl_")] == JAXMARL_IDS


@pytest.mark.parametrize("env_id", JAXMARL_IDS)
def test_check_env_on_every_registered_jaxmarl_id(adapters, env_id):
    env = envs.make(env_id)
    envs.check_env(env)
    assert hash(env) == hash(envs.make(env_id)) and env.jaxmarl_env is envs.make(env_id).jaxmarl_env


def test_coin_game_attributes_and_parameters(adapters):
    env = envs.make(COIN, num_inner_steps=4, num_outer_steps=2)
    assert (env.num_agents, env.num_actions, env.obs_dim, env.max_steps) == (2, 5, 36, 8)
    assert (env.idle_action, env.stochastic, env.incentive_obs) == (STAY, True, False)
    assert not env.terminates_on_success and env.obs_bounds() == (0.0, 1.0)
    spread = envs.make("jaxmarl_simple_spread-v0")
    assert (spread.num_agents, spread.num_actions, spread.obs_dim) == (3, 5, 18)
    assert spread.max_steps == 26  # JaxMARL's MPE: max_steps = 25 ends after step 26
    assert spread.obs_bounds() == (-np.inf, np.inf)


def test_coin_game_rewards_and_success_on_hand_set_states(adapters):
    """Red at (0, 0) moves right onto (0, 1) or stays; blue stays at (2, 2). Three cases,
    one vmapped step: red takes its own coin, red takes blue's coin, nobody takes one."""
    env = envs.make(COIN)
    _, state = env.reset(jax.random.key(0))
    cases = {  # (red coin, blue coin, red's action)
        "own": ([0, 1], [1, 1], RIGHT),
        "other": ([1, 1], [0, 1], RIGHT),
        "nothing": ([1, 1], [1, 0], STAY),
    }
    states = [
        state.replace(
            red_pos=jnp.array([0, 0]),
            blue_pos=jnp.array([2, 2]),
            red_coin_pos=jnp.array(red_coin),
            blue_coin_pos=jnp.array(blue_coin),
        )
        for red_coin, blue_coin, _ in cases.values()
    ]
    states = jax.tree.map(lambda *xs: jnp.stack(xs), *states)
    actions = jnp.array([[red, STAY] for *_, red in cases.values()], jnp.int32)
    step = jax.jit(jax.vmap(env.step, in_axes=(None, 0, 0)))
    obs, _, rewards, done, info = step(jax.random.key(1), states, actions)
    assert rewards.tolist() == [[1.0, 0.0], [1.0, -2.0], [0.0, 0.0]]
    assert info["success"].tolist() == [True, False, False]
    assert not done.any() and not info["inner_episode_done"].any()
    assert obs.dtype == jnp.float32 and obs.shape == (3, 2, 36)
    # the score of an episode is the fraction of its successful steps
    score = env.episode_success(jnp.int32(3), jnp.int32(10), jnp.zeros(2))
    assert float(score) == pytest.approx(0.3)


@pytest.mark.parametrize(
    ("name", "reason"),
    [
        ("MPE_simple_tag_v3", "agents observe different shapes"),
        ("MPE_simple_facmac_v1", "actions must be Discrete for every agent, got \\['Box'\\]"),
        ("overcooked_v2", None),  # fits once flattened; tested only for the message below
        ("storm", "observations must be a Box for every agent, got \\['dict'\\]"),
        ("nope", "is not a JaxMARL env; JaxMARL has MPE_simple_v3"),
    ],
)
def test_spaces_that_do_not_fit_fail_saying_why(adapters, name, reason):
    if reason is None:
        cls = adapters.adapter_class(name, adapters.DEFAULT_RULES, ())
        assert cls().obs_dim == 4 * 5 * 30
        return
    before = envs.registered()
    with pytest.raises(InvalidParameter, match=reason):
        adapters.register_jaxmarl(name)
    assert envs.registered() == before


def test_reserved_and_rejected_parameters(adapters):
    with pytest.raises(InvalidParameter, match="max_steps: reserved"):
        adapters.register_jaxmarl("MPE_simple_spread_v3", env_id="x-v0", max_steps=10)
    with pytest.raises(InvalidParameter, match="JaxMARL rejects"):
        envs.make("jaxmarl_simple_spread-v0", local_ratio=2.0)


# --- training: runner and command line ------------------------------------------------------

TRAIN = {"seeds": 2, "iterations": 20, "eval_period": 10, "eval_episodes": 2}


def _check_run(run_dir, learner, attack):
    summary = store.read_json(run_dir / store.SUMMARY)
    assert summary["finished"] and summary["env_id"] == COIN and summary["learner"] == learner
    config = store.read_json(run_dir / store.CONFIG)
    assert json.dumps(config).count(COIN) >= 1 and (attack is None or attack in json.dumps(config))
    rows = store.read_metrics(run_dir)
    assert sorted((int(r["iteration"]), int(r["seed"])) for r in rows) == [
        (it, s) for it in (10, 20) for s in (0, 1)
    ]
    success = [float(r["eval/success"]) for r in rows]
    assert all(0.0 <= s <= 1.0 for s in success)
    returns = [float(v) for r in rows for k, v in r.items() if k.startswith("eval/return_env")]
    assert returns and np.isfinite(returns).all()
    return rows


@pytest.mark.parametrize(("learner", "attack"), [("lio", "bypass"), ("pg", None)])
def test_coin_game_trains_through_the_runner(adapters, tmp_path, learner, attack):
    run = RunConfig(COIN, learner=learner, attack=attack, **TRAIN)
    result = runner.train(run, tmp_path / "run", progress=False)
    assert not result.already_finished
    _check_run(tmp_path / "run", learner, attack)


def test_coin_game_trains_from_the_command_line_with_the_plugin(adapters, tmp_path):
    """A fresh process (so `--plugin` is what registers the id); the program is the pg run's
    above, so the session's persistent compilation cache serves it."""
    out = tmp_path / "cli"
    argv = [sys.executable, "-m", "pimbot.cli", "train", COIN, "--plugin", MODULE]
    argv += ["--learner", "pg", "--seeds", "2", "--iterations", "20", "--eval-period", "10"]
    argv += ["--eval-episodes", "2", "--quiet", "--out", str(out)]
    done = subprocess.run(argv, capture_output=True, text=True, env=dict(os.environ), timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "submoduled" not in done.stdout.lower()  # jaxmarl's import prints are swallowed
    rows = _check_run(out, "pg", None)
    with open(out / store.METRICS, newline="") as f:
        assert len(list(csv.DictReader(f))) == len(rows) == 4
