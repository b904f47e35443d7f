"""The PettingZoo ParallelEnv adapter: the official API and seed tests, plus episode endings."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from pimbot import envs
from pimbot.envs.pettingzoo import parallel_env


@pytest.mark.parametrize("env_id", envs.registered())
def test_parallel_api(env_id):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the API test reports problems as warnings
        parallel_api_test(parallel_env(env_id), num_cycles=200)


@pytest.mark.parametrize("env_id", envs.registered())
def test_parallel_seed(env_id):
    parallel_seed_test(lambda: parallel_env(env_id))


@pytest.mark.parametrize("env_id", envs.registered())
def test_spaces_metadata_and_observations(env_id):
    env = parallel_env(env_id)
    functional = envs.make(env_id)
    assert env.metadata["name"] == env_id and env.metadata["is_parallelizable"]
    assert env.render_mode is None
    assert env.possible_agents == [f"agent_{i}" for i in range(functional.num_agents)]
    observations, infos = env.reset(seed=3)
    assert set(observations) == set(infos) == set(env.agents)
    for agent, obs in observations.items():
        space = env.observation_space(agent)
        assert space.dtype == np.float32 and space.shape == (functional.obs_dim,)
        assert isinstance(obs, np.ndarray) and obs.dtype == np.float32
        assert space.contains(obs)
        assert env.action_space(agent).n == functional.num_actions


def test_success_terminates_and_empties_agents():
    env = parallel_env("escape_room-v0")
    env.reset(seed=0)
    _, rewards, terminations, truncations, infos = env.step({"agent_0": 0, "agent_1": 2})
    assert rewards == {"agent_0": -1.0, "agent_1": 10.0}
    assert all(terminations.values()) and not any(truncations.values())
    assert infos["agent_1"]["success"] and infos["agent_1"]["door_open"]
    assert env.agents == []
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})


def test_escape_room_without_success_truncates_at_max_steps():
    env = parallel_env("escape_room-v0")
    env.reset(seed=0)
    for _ in range(4):
        _, _, terminations, truncations, _ = env.step({"agent_0": 1, "agent_1": 1})
        assert not any(terminations.values()) and not any(truncations.values())
    _, _, terminations, truncations, _ = env.step({"agent_0": 1, "agent_1": 1})
    assert all(truncations.values()) and not any(terminations.values())
    assert env.agents == []


def test_matrix_game_truncates_at_max_steps_even_when_cooperating():
    env = parallel_env("ipd-v0", max_steps=3)
    env.reset(seed=0)
    for t in range(3):
        _, rewards, terminations, truncations, infos = env.step({"agent_0": 0, "agent_1": 0})
        assert rewards == {"agent_0": -1.0, "agent_1": -1.0} and infos["agent_0"]["success"]
        assert not any(terminations.values())
        assert all(truncations.values()) == (t == 2)


def test_missing_action_is_a_clear_error():
    env = parallel_env("escape_room-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="agent_1"):
        env.step({"agent_0": 0})


def test_seeds_replay_and_differ():
    env = parallel_env("stag_hunt-v0")
    first, _ = env.reset(seed=7)
    again, _ = env.reset(seed=7)
    other, _ = env.reset(seed=8)
    unseeded, _ = env.reset()  # continues the key stream of seed 8
    assert all(np.array_equal(first[a], again[a]) for a in env.agents)
    assert not all(np.array_equal(first[a], other[a]) for a in env.agents)
    assert not all(np.array_equal(other[a], unseeded[a]) for a in env.agents)
