"""Policies trained in the abstract Escape Room, evaluated in physics next to the abstract env.

`load_run` restores a run directory's final checkpoint through
`experiment.runs.load_run` (any learner: the policy comes from its `acting`).
`TrainedPolicy` plays one seed's policy in physics through the same
joint-decision function training uses (`rollout.decide`: the observation with
the incentives given so far, the attack's `act` hook — bypass idles the
adversary — and its incentive emission), with ε = 0 and sampled actions, as
the learners' own evaluation. `evaluate_run` reports, per seed, the success
rate over K physics episodes and over K abstract episodes of the same
checkpoint.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from pimbot import envs
from pimbot.contracts.rollout import decide
from pimbot.errors import InvalidParameter, check_int
from pimbot.robot.episode import EpisodeResult, PhysicsConfig, run_episode
from pimbot.training import runs, store
from pimbot.training.config import ResolvedRun, coerce_like
from pimbot.training.runs import LoadedRun


def load_run(run_dir: str | Path) -> LoadedRun:
    """Restores an Escape Room run for the robots; fails naming what is unsupported."""
    loaded = runs.load_run(run_dir)
    room_ids = envs.ids_of(envs.EscapeRoom)  # the rules the robots play
    if loaded.resolved.run.env_id not in room_ids:
        raise InvalidParameter(
            f"run_dir: {run_dir} trained on {loaded.resolved.run.env_id}; the robot case study "
            f"plays {', '.join(room_ids)} runs only"
        )
    return loaded


def decision_function(loaded: LoadedRun):
    """Jitted decision(state, key, obs [N, D], given [N, N], t) -> (actions [N], given)."""
    env, attack = loaded.resolved.env, loaded.resolved.attack

    def decision(state, key, obs, given, t):
        actor = loaded.actor(state)
        _, actions, incentives, _, _ = decide(
            env,
            key,
            obs,
            given,
            actor.act,
            actor.give,
            attack,
            state.env_steps + t,
            state.attack_state,
        )
        return actions, given + incentives

    return jax.jit(decision)


class TrainedPolicy:
    """One seed's trained agents choosing zones in physics (see `episode.Policy`)."""

    def __init__(self, decision, state, key: jax.Array, num_agents: int):
        self.decision, self.state, self.key, self.n = decision, state, key, num_agents
        self.given = jnp.zeros((num_agents, num_agents), jnp.float32)

    def start_episode(self) -> None:
        self.given = jnp.zeros((self.n, self.n), jnp.float32)

    def __call__(self, obs: np.ndarray, t: int) -> np.ndarray:
        self.key, key = jax.random.split(self.key)
        actions, self.given = self.decision(self.state, key, jnp.asarray(obs), self.given, t)
        return np.asarray(actions)


def physics_config(resolved: ResolvedRun, **overrides) -> PhysicsConfig:
    """The physics episode settings matching the run's ER(N, M)."""
    env = resolved.env
    return PhysicsConfig(
        n_robots=env.n_agents,
        min_at_lever=env.min_at_lever,
        max_steps=env.max_steps,
        **overrides,
    )


FROM_RUN = ("n_robots", "min_at_lever", "max_steps", "controller")


def parse_physics_overrides(pairs: list[str]) -> dict[str, Any]:
    """`name=value` settings of `PhysicsConfig` (noise, time limits, layout), typed like
    their defaults; N, M and the horizon come from the run."""
    defaults = {
        f.name: getattr(PhysicsConfig(), f.name)
        for f in dataclasses.fields(PhysicsConfig)
        if f.name not in FROM_RUN
    }
    out = {}
    for pair in pairs:
        name, sep, value = pair.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or name not in defaults:
            raise InvalidParameter(
                f"physics: {pair!r} is not name=value with a name in {', '.join(defaults)}"
            )
        out[name] = coerce_like(name, value.strip(), defaults[name])
    PhysicsConfig(**out)  # range checks, naming the field
    return out


def episode_rng(seed: int, episode: int) -> np.random.Generator:
    """The physics randomness (layout, poses, noise) of one seed's episode."""
    return np.random.default_rng([20260, seed, episode])


def physics_episodes(
    loaded: LoadedRun,
    seed_index: int,
    episodes: int,
    cfg: PhysicsConfig,
    record_first: bool = False,
    decision=None,
) -> list[EpisodeResult]:
    """`episodes` physics episodes of one seed's policy (the first recorded if asked)."""
    decision = decision or decision_function(loaded)
    seed = loaded.seeds[seed_index]
    policy = TrainedPolicy(
        decision,
        loaded.seed_state(seed_index),
        jax.random.fold_in(jax.random.PRNGKey(seed), 7),
        loaded.resolved.env.num_agents,
    )
    return [
        run_episode(policy, cfg, episode_rng(seed, k), record=record_first and k == 0)
        for k in range(episodes)
    ]


def abstract_success(loaded: LoadedRun, episodes: int) -> np.ndarray:
    """Per-seed success rate [S] over `episodes` abstract episodes of the same checkpoint."""
    resolved = loaded.resolved
    env, learner, cfg = resolved.env, resolved.learner, resolved.learner_config

    def one(state, seed):
        key = jax.random.fold_in(jax.random.PRNGKey(seed), 11)
        return learner.evaluate(key, state, env, cfg, episodes, resolved.attack)["success"].mean()

    count = len(loaded.seeds)
    states = jax.tree.map(lambda x: x[:count], loaded.states)
    return np.asarray(jax.jit(jax.vmap(one))(states, jnp.asarray(loaded.seeds)))


@dataclasses.dataclass
class RunEvaluation:
    """Physics next to abstract success of one run, per seed."""

    run_dir: Path
    label: str
    seeds: tuple[int, ...]
    episodes: int
    physics: np.ndarray  # [S] success rate in physics
    abstract: np.ndarray  # [S] success rate in the abstract env
    arrived: float  # fraction of driving robot-decisions that reached their slot in time
    decision_steps: float  # mean decision steps per physics episode
    physics_steps: int
    wall_s: float
    recorded: EpisodeResult | None = None

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "run_dir": str(self.run_dir),
            "label": self.label,
            "episodes_per_seed": self.episodes,
            "seeds": list(self.seeds),
        }
        for name in ("physics", "abstract"):
            values = getattr(self, name)  # intervals: pimbot.statistics, from per_seed
            out[name] = {"mean": float(values.mean()), "per_seed": values.tolist()}
        trained = self.run_dir / store.SUMMARY
        if trained.exists():  # the training's own final evaluation window, for reference
            final = store.read_json(trained).get("final", {}).get("eval/success")
            out["abstract_training_final"] = final
        out.update(
            arrived=self.arrived,
            decision_steps=self.decision_steps,
            physics_steps=self.physics_steps,
            wall_s=self.wall_s,
            physics_steps_per_s=self.physics_steps / self.wall_s if self.wall_s else None,
        )
        return out


def run_label(resolved: ResolvedRun) -> str:
    env = resolved.env
    attack = resolved.run.attack or "clean"
    mode = getattr(resolved.attack, "mode", None)
    if resolved.run.attack and isinstance(mode, str):
        attack = f"{attack}_{mode}"  # ADMO's stealthy / disrupt objectives
    return f"{resolved.run.learner} ER({env.n_agents},{env.min_at_lever}) {attack}"


def evaluate_run(
    run_dir: str | Path,
    episodes: int,
    cfg_overrides: dict[str, Any] | None = None,
    record_first: bool = False,
    on_seed=None,
) -> RunEvaluation:
    """Physics and abstract success of every seed of `run_dir` over `episodes` episodes each.

    Args:
        cfg_overrides: `PhysicsConfig` fields to change (noise, layout randomization, …).
        record_first: keep the bus log of the first seed's first episode (for a rosbag).
        on_seed: called with (seed, physics success, abstract success) after each seed.
    """
    check_int("episodes", episodes, 1)
    loaded = load_run(run_dir)
    cfg = physics_config(loaded.resolved, **(cfg_overrides or {}))
    start = time.perf_counter()
    abstract = abstract_success(loaded, episodes)
    decision = decision_function(loaded)
    physics, arrived, steps, physics_steps = [], [], [], 0
    recorded = None
    for s, seed in enumerate(loaded.seeds):
        results = physics_episodes(
            loaded, s, episodes, cfg, record_first=record_first and s == 0, decision=decision
        )
        if record_first and s == 0:
            recorded = results[0]
        physics.append(np.mean([r.success for r in results]))
        driving = np.concatenate([(r.actions != r.positions[:-1]).ravel() for r in results])
        reached = np.concatenate([r.arrived.ravel() for r in results])
        arrived.append(reached[driving])
        steps += [r.steps for r in results]
        physics_steps += sum(r.physics_steps for r in results)
        if on_seed is not None:
            on_seed(seed, physics[-1], float(abstract[s]))
    all_arrived = np.concatenate(arrived)
    return RunEvaluation(
        run_dir=Path(run_dir),
        label=run_label(loaded.resolved),
        seeds=loaded.seeds,
        episodes=episodes,
        physics=np.array(physics),
        abstract=abstract,
        arrived=float(all_arrived.mean()) if all_arrived.size else 1.0,
        decision_steps=float(np.mean(steps)),
        physics_steps=physics_steps,
        wall_s=time.perf_counter() - start,
        recorded=recorded,
    )
