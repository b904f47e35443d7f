"""`pimbot export`: trained policies as ONNX, checked against pimbot's own agents.

onnxruntime runs the exported models on 1000 random observations within the env's bounds
and on every step of 64 episodes the trained agents play; its probabilities are compared
with the learner's own log-probabilities, its incentives with the actor's `give`, and the
actions the actor samples with those drawn from the ONNX logits with the same keys.
"""

from __future__ import annotations

import dataclasses
import json
import types
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import onnx
import onnxruntime
import pytest

import pimbot
from pimbot import envs
from pimbot.cli import main
from pimbot.contracts.rollout import rollout
from pimbot.learners import lio
from pimbot.robot import export, export_check, exportable
from pimbot.training import runs
from pimbot.training.config import RunConfig
from pimbot.training.runner import train

TOLERANCE = 1e-5
"""Largest absolute difference allowed (float32 probabilities and incentives)."""
RANDOM_OBSERVATIONS = 1000
EPISODES = 64


@pytest.fixture(scope="module")
def lio_run(tmp_path_factory):
    """LIO on ER(2,1), two seeds, 20 iterations, and its export (seed 0)."""
    root = tmp_path_factory.mktemp("export")
    run_dir = root / "lio"
    config = RunConfig("escape_room-v0", seeds=2, iterations=20, eval_period=20, eval_episodes=2)
    train(config, run_dir, progress=False)
    assert main(["export", str(run_dir), "--out", str(root / "onnx")]) == 0
    return run_dir, root / "onnx"


def session(path: Path) -> onnxruntime.InferenceSession:
    return onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])


def inputs_to_check(loaded: runs.LoadedRun, seed_index: int, key) -> tuple[np.ndarray, ...]:
    """Joint observations [K, N, D] and actions [K, N]: random ones within the bounds (an
    unbounded side up to 20 away), then every step of `EPISODES` episodes played."""
    env = loaded.resolved.env
    low, high = env.obs_bounds()
    high = high if np.isfinite(high) else low + 20.0
    k_obs, k_act, k_play = jax.random.split(key, 3)
    shape = (RANDOM_OBSERVATIONS, env.num_agents, env.obs_dim)
    obs = np.asarray(jax.random.uniform(k_obs, shape, jnp.float32, low, high))
    acts = np.asarray(jax.random.randint(k_act, shape[:2], 0, env.num_actions, jnp.int32))
    state = loaded.seed_state(seed_index)
    actor = loaded.actor(state)
    r = loaded.resolved

    def play(k):
        return rollout(env, k, actor.act, actor.give, r.attack, state.env_steps, state.attack_state)

    trajs = jax.vmap(play)(jax.random.split(k_play, EPISODES))
    valid = np.asarray(trajs.valid).reshape(-1)
    played_obs = np.asarray(trajs.obs).reshape(-1, env.num_agents, env.obs_dim)[valid]
    played_acts = np.asarray(trajs.actions).reshape(-1, env.num_agents)[valid]
    assert len(played_obs) >= EPISODES
    return np.concatenate([obs, played_obs]), np.concatenate([acts, played_acts])


def lio_probabilities(loaded: runs.LoadedRun, seed_index: int, obs: np.ndarray) -> np.ndarray:
    """π(a | o) [K, N, A] from LIO's own `taken_log_probs`, one action at a time."""
    r = loaded.resolved
    policy = loaded.seed_state(seed_index).policy
    columns = []
    for a in range(r.env.num_actions):
        taken = types.SimpleNamespace(obs=jnp.asarray(obs), actions=jnp.full(obs.shape[:2], a))
        columns.append(lio.taken_log_probs(r.env, r.learner_config, policy, taken))
    return np.exp(np.stack(columns, axis=-1))


def test_onnx_outputs_match_pimbots_agents(lio_run):
    run_dir, out = lio_run
    loaded = runs.load_run(run_dir)
    obs, acts = inputs_to_check(loaded, 0, jax.random.PRNGKey(42))
    actor = loaded.actor(loaded.seed_state(0))
    expected_probs = lio_probabilities(loaded, 0, obs)
    expected_given = np.asarray(jax.vmap(actor.give)(jnp.asarray(obs), jnp.asarray(acts)))
    logits, worst = [], {"probabilities": 0.0, "incentives": 0.0}
    for i in range(loaded.resolved.env.num_agents):
        agent_logits, probs = session(out / f"agent_{i}_policy.onnx").run(
            ["logits", "probabilities"], {"observation": obs[:, i]}
        )
        worst["probabilities"] = max(
            worst["probabilities"], np.abs(probs - expected_probs[:, i]).max()
        )
        np.testing.assert_array_equal(probs.argmax(-1), expected_probs[:, i].argmax(-1))
        (given,) = session(out / f"agent_{i}_incentive.onnx").run(
            ["incentives"], {"observation": obs[:, i], "actions": acts}
        )
        worst["incentives"] = max(worst["incentives"], np.abs(given - expected_given[:, i]).max())
        logits.append(agent_logits)
    print(f"largest |onnxruntime − pimbot| over {len(obs)} observations per agent: {worst}")
    assert max(worst.values()) <= TOLERANCE, worst
    # The actions the actor samples are those drawn from the ONNX logits with the same keys.
    keys = jax.random.split(jax.random.PRNGKey(7), len(obs))
    sampled = np.asarray(jax.vmap(actor.act)(keys, jnp.asarray(obs)))
    drawn = np.asarray(jax.vmap(jax.random.categorical)(keys, jnp.stack(logits, axis=1)))
    np.testing.assert_array_equal(sampled, drawn)


def test_policy_json_describes_the_models_and_the_run(lio_run):
    run_dir, out = lio_run
    loaded = runs.load_run(run_dir)
    r = loaded.resolved
    sidecar = json.loads((out / "policy.json").read_text())
    assert sidecar["format"] == export.FORMAT and sidecar["pimbot_version"] == pimbot.__version__
    assert sidecar["seed"] == 0 and sidecar["iteration"] == loaded.iteration == 20
    assert sidecar["run_dir"] == str(run_dir.resolve())
    assert sidecar["env"]["id"] == r.run.env_id
    assert sidecar["env"]["params"] == {"n_agents": 2, "min_at_lever": 1, "max_steps": 5} | {
        "randomize_start": False
    }
    assert sidecar["learner"] == {
        "name": "lio",
        "config": json.loads(json.dumps(dataclasses.asdict(r.learner_config))),
    }
    assert sidecar["actions"]["names"] == list(envs.spec(r.run.env_id).action_names)
    observation = sidecar["observation"]
    assert observation["shape"] == [r.env.obs_dim] and observation["dtype"] == "float32"
    # every part with its slice, meaning, units and bounds; the incentives a LIO agent can
    # have given by the last step bound its incentive part
    most = r.learner_config.incentive_max * r.env.max_steps
    assert (observation["low"], observation["high"]) == (0.0, most)
    parts = observation["parts"]
    assert [p["name"] for p in parts] == ["own_position", "other_position_1", "incentives_given"]
    assert [(p["start"], p["stop"]) for p in parts] == [(0, 3), (3, 6), (6, 7)]
    assert [(p["units"], p["low"], p["high"]) for p in parts[:2]] == [("one-hot", 0.0, 1.0)] * 2
    assert parts[2]["high"] == most and "given" in parts[2]["meaning"] and parts[2]["units"]
    parity = sidecar["parity"]
    assert parity["observations_per_agent"] > export_check.CHECK_OBSERVATIONS
    assert max(parity["max_abs_difference"][k] for k in export_check.CHECKED) <= TOLERANCE
    files = sorted(p.name for p in out.iterdir())
    assert files == [
        "agent_0_incentive.onnx",
        "agent_0_policy.onnx",
        "agent_1_incentive.onnx",
        "agent_1_policy.onnx",
        "policy.json",
    ]
    for agent in sidecar["agents"]:
        for part in ("policy", "incentive"):
            entry = agent[part]
            model = onnx.load(out / entry["file"])
            onnx.checker.check_model(model, full_check=True)
            assert (model.ir_version, model.opset_import[0].version) == (8, 17)
            assert [v.name for v in model.graph.input] == [v["name"] for v in entry["inputs"]]
            assert [v.name for v in model.graph.output] == [v["name"] for v in entry["outputs"]]
        assert agent["policy"]["outputs"][1] == {
            "name": "probabilities",
            "shape": ["B", 3],
            "dtype": "float32",
        }
        assert agent["incentive"]["inputs"][1] == {
            "name": "actions",
            "shape": ["B", 2],
            "dtype": "int32",
        }


def test_seed_option_exports_another_seed_and_replaces_a_previous_export(lio_run, capsys):
    run_dir, out = lio_run
    other = out.parent / "onnx_seed1"
    assert main(["export", str(run_dir), "--out", str(other), "--seed", "1"]) == 0
    assert main(["export", str(run_dir), "--out", str(other), "--seed", "1"]) == 0  # replaced
    assert "largest difference" in capsys.readouterr().out
    assert json.loads((other / "policy.json").read_text())["seed"] == 1
    obs = np.eye(7, dtype=np.float32)
    seed0 = session(out / "agent_0_policy.onnx").run(["logits"], {"observation": obs})[0]
    seed1 = session(other / "agent_0_policy.onnx").run(["logits"], {"observation": obs})[0]
    assert not np.allclose(seed0, seed1)
    assert sorted(p.name for p in other.parent.iterdir() if p.name.startswith(".")) == []


NO_INCENTIVES = [("pg", "escape_room-v0", 10), ("reciprocator", "ipd-v0", 2)]


@pytest.mark.parametrize(("learner", "env_id", "iterations"), NO_INCENTIVES)
def test_a_learner_without_incentives_exports_its_policies_only(
    tmp_path, learner, env_id, iterations
):
    run_dir = tmp_path / learner
    config = RunConfig(
        env_id,
        learner=learner,
        seeds=1,
        iterations=iterations,
        eval_period=iterations,
        eval_episodes=2,
    )
    train(config, run_dir, progress=False)
    sidecar = export.export_run(run_dir, tmp_path / "onnx")
    assert sorted(p.name for p in (tmp_path / "onnx").iterdir()) == [
        "agent_0_policy.onnx",
        "agent_1_policy.onnx",
        "policy.json",
    ]
    assert [a["incentive"] for a in sidecar["agents"]] == [None, None]
    assert sidecar["learner"]["name"] == learner and sidecar["env"]["id"] == env_id
    loaded = runs.load_run(run_dir)
    obs, _ = inputs_to_check(loaded, 0, jax.random.PRNGKey(3))
    actor = loaded.actor(loaded.seed_state(0))
    logits = [
        session(tmp_path / "onnx" / f"agent_{i}_policy.onnx").run(
            ["logits"], {"observation": obs[:, i]}
        )[0]
        for i in range(2)
    ]
    keys = jax.random.split(jax.random.PRNGKey(8), len(obs))
    sampled = np.asarray(jax.vmap(actor.act)(keys, jnp.asarray(obs)))
    drawn = np.asarray(jax.vmap(jax.random.categorical)(keys, jnp.stack(logits, axis=1)))
    np.testing.assert_array_equal(sampled, drawn)


def test_a_policy_onnx_cannot_hold_is_refused_by_name(tmp_path, capsys):
    """The original IPD Reciprocator's encoded input shifts int32 bits, which ONNX lacks."""
    run_dir = tmp_path / "encoded"
    hparams = (("net_input", "previous_actions"), ("policy_head", "sigmoid"), ("num_envs", 8))
    config = RunConfig(
        "ipd-v0", learner="reciprocator", seeds=1, iterations=1, eval_period=1, hparams=hparams
    )
    train(config, run_dir, progress=False)
    out = tmp_path / "onnx"
    expected = "learner: reciprocator's agent_0_policy does not convert to ONNX"
    _one_line_exit_2(["export", str(run_dir), "--out", str(out)], capsys, expected)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["encoded"]


def _one_line_exit_2(argv, capsys, expected: str) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("pimbot: error: ") and len(err.strip().splitlines()) == 1, err
    assert expected in err, err


def test_bad_input_is_one_line_and_writes_nothing(lio_run, tmp_path, capsys, monkeypatch):
    run_dir, _ = lio_run
    out = tmp_path / "out"
    _one_line_exit_2(["export", str(tmp_path / "nowhere"), "--out", str(out)], capsys, "run_dir:")
    bare = tmp_path / "bare"
    bare.mkdir()
    (bare / "config.json").write_text((run_dir / "config.json").read_text())
    _one_line_exit_2(["export", str(bare), "--out", str(out)], capsys, "no checkpoint")
    _one_line_exit_2(["export", str(run_dir), "--out", str(out), "--seed", "5"], capsys, "seed: 5")
    monkeypatch.delitem(exportable.EXPORTS, lio.acting)
    _one_line_exit_2(
        ["export", str(run_dir), "--out", str(out)], capsys, "learner: lio's policy cannot"
    )
    monkeypatch.undo()
    assert not out.exists()
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "notes.txt").write_text("mine")
    _one_line_exit_2(["export", str(run_dir), "--out", str(busy)], capsys, "holds no pimbot export")
    assert sorted(p.name for p in busy.iterdir()) == ["notes.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bare", "busy"]
