"""The on-device decision loop: batch-size-1 control with LIO heads, timed.

Per decision: the observation is ready on the host → it is put on the device,
every agent's policy and incentive heads run (one jitted function, batch 1
per agent) → the actions are back on the host (committed). The environment is
then stepped `action_repeat` times off the timed path. Every `cadence`
decisions one learner update (`lio.update`, with the controller's attack on agent
0: `CONTROLLERS`) runs and is timed on its own. Compilation and warm-up are timed
separately and excluded from the steady-state samples.

One profile measures several cadences (decisions per update) and, paired, every
controller in one process: the steady state is cut into segments, one per
(round, cadence, controller), run interleaved (the controllers' order alternating)
so that a change in the machine's load falls on all controllers alike. A segment
ends on an update, so it holds whole cycles of `cadence` decisions and one update.
Each decision and update is timed by the wall clock and by the process's CPU time
(all its threads); the process's CPU is also read in windows of `cpu_window_s`
inside each segment (the last one up to 1.5 windows long).
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
from pimbot.contracts.rollout import decide
from pimbot.errors import check_int
from pimbot.profiling import process_cpu

CONTROLLERS = ("benign", "admo", "admo_code")
"""Plain LIO; the paper's ADMO on agent 0; the published code's ADMO (`admo_code`, a
scheduler of extra ordinary steps) on agent 0. A paired profile runs them all."""
DEFAULT_CADENCES = (2, 10, 100)
"""Decisions per learner update profiled by default: LIO's ER(2,1) training takes 10
(two episodes of a 5-step horizon, `cadence.training_cadence`), a converged policy plays
2 of them (one step per episode), and 100 was pimbot's earlier single cadence."""


@dataclasses.dataclass(frozen=True)
class ProfileConfig:
    """One profiling run."""

    env_id: str = "escape_room-v0"
    """Environment id."""
    env_params: tuple[tuple[str, Any], ...] = ()
    """Environment parameters as (name, value) pairs."""
    controller: str = "benign"
    """"benign" (plain LIO), "admo" (the paper's ADMO on agent 0) or "admo_code" (the
    published code's ADMO on agent 0); a paired profile runs all three."""
    duration_s: float = 20.0
    """Steady-state wall time per controller, split evenly over the cadences and rounds."""
    hidden: tuple[int, ...] = (256, 128)
    """Hidden widths of both the policy and the incentive MLP."""
    action_repeat: int = 2
    """Environment steps per decision."""
    cadences: tuple[int, ...] = DEFAULT_CADENCES
    """Decisions between learner update steps; each is profiled in this one run."""
    rounds: int = 6
    """Interleaved rounds: each runs one segment per cadence and controller."""
    cpu_window_s: float = 0.25
    """Wall time of one window of the process's CPU time."""
    warmup_decisions: int = 20
    """Decisions run (and discarded) after compilation, before steady state."""
    seed: int = 0
    """Root PRNG seed."""

    def __post_init__(self):
        if not self.cadences or any(
            isinstance(c, bool) or not isinstance(c, int) or c < 1 for c in self.cadences
        ):
            raise envs.InvalidParameter(
                f"cadences: must be one or more integers ≥ 1, got {self.cadences!r}"
            )
        check_int("rounds", self.rounds, 1)
        if not self.cpu_window_s > 0:
            raise envs.InvalidParameter(f"cpu_window_s: must be > 0, got {self.cpu_window_s!r}")

    def segment_s(self) -> float:
        """Steady-state wall time of one segment (one cadence, one controller, one round)."""
        return self.duration_s / (self.rounds * len(self.cadences))


@dataclasses.dataclass
class Segment:
    """One stretch of steady state at one cadence: whole cycles of decisions + update."""

    round: int
    cadence: int
    latencies_s: np.ndarray  # [decisions]
    update_times_s: np.ndarray  # [updates]
    decision_cpu_s: np.ndarray  # [decisions] the process's CPU time over each decision
    update_cpu_s: np.ndarray  # [updates] the process's CPU time over each update
    wall_s: float  # the segment's wall time, environment steps included
    cpu_s: float  # the process's CPU time over the segment (all threads)
    cpu_windows: np.ndarray  # [windows, 2]: (wall s, process CPU s) of each window


@dataclasses.dataclass
class LoopResult:
    segments: list[Segment]
    compile_s: dict[str, float]  # first call (compile + run) of each jitted function
    warmup_s: float  # the warm-up decisions and update after compilation
    env_steps: int  # environment steps of the decision loop (off the timed path)
    played_per_update: float  # env steps the learner's own updates played, per update

    def cadence(self, cadence: int) -> list[Segment]:
        return [s for s in self.segments if s.cadence == cadence]

    @property
    def latencies_s(self) -> np.ndarray:
        return np.concatenate([s.latencies_s for s in self.segments] or [np.zeros(0)])

    @property
    def update_times_s(self) -> np.ndarray:
        return np.concatenate([s.update_times_s for s in self.segments] or [np.zeros(0)])

    @property
    def steady_wall_s(self) -> float:
        return float(sum(s.wall_s for s in self.segments))


def make_attack(controller: str, num_agents: int):
    """The controller's attack: none (benign), or `admo` / `admo_code` on agent 0."""
    if controller not in CONTROLLERS:
        raise envs.InvalidParameter(
            f"controller: unknown controller {controller!r}; allowed: {', '.join(CONTROLLERS)}"
        )
    if controller == "benign":
        return NO_ATTACK
    return attacks.make(controller, num_agents, adversary=0)


def build(config: ProfileConfig):
    """(env, learner, learner config) of a profile: LIO with the profile's head widths."""
    env = envs.make(config.env_id, **dict(config.env_params))
    learner = learners.get("lio")
    cfg = dataclasses.replace(
        learner.default_config(envs.spec(config.env_id)),
        policy_hidden=tuple(config.hidden),
        incentive_hidden=tuple(config.hidden),
    )
    return env, learner, cfg


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


def _timed_cpu(fn, *args):
    """(output, wall s, the process's CPU s) of one call, finished on the device."""
    cpu = process_cpu.seconds()
    out, wall = _timed(fn, *args)
    return out, wall, process_cpu.seconds() - cpu


class Controller:
    """One controller's compiled decision and update functions and its running loop
    (learner state, environment state, keys); `segment` advances it."""

    def __init__(self, config: ProfileConfig, controller: str):
        self.config = config
        env, learner, cfg = build(config)
        self.env = env
        attack = make_attack(controller, env.num_agents)
        init_key, env_key, self.act_key = jax.random.split(jax.random.key(config.seed), 3)
        self.state = learner.init(init_key, env, cfg, attack)
        self._decide = decision_fn(env, learner, cfg, attack)
        self._update = jax.jit(lambda s: learner.update(s, env, cfg, attack)[0])
        # The environment runs off the timed path (on the host CPU when there is one).
        self._env_reset, self._env_step = jax.jit(env.reset), jax.jit(env.step)
        self.env_key = jax.device_put(env_key, jax.devices("cpu")[0])

        self.compile_s: dict[str, float] = {}
        self.env_key, k = jax.random.split(self.env_key)
        (self.obs, self.env_state), self.compile_s["env_reset"] = _timed(self._env_reset, k)
        self.given = jnp.zeros((env.num_agents, env.num_agents), jnp.float32)
        zeros = jnp.zeros(env.num_agents, jnp.int32)
        _, self.compile_s["env_step"] = _timed(self._env_step, k, self.env_state, zeros)
        _, self.compile_s["decision"] = _timed(
            self._decide,
            self.state,
            self.act_key,
            jnp.asarray(np.asarray(self.obs)),
            self.given,
            jnp.int32(0),
        )
        self.state, self.compile_s["update"] = _timed(self._update, self.state)
        self.steps = 0

        warm_start = time.perf_counter()
        for _ in range(config.warmup_decisions):
            self.decision()
        self.state, _ = _timed(self._update, self.state)
        self.warmup_s = time.perf_counter() - warm_start

    def decision(self) -> tuple[float, float]:
        """One timed decision, then the environment off the timed path; its latency and
        the process's CPU time over it (s)."""
        self.act_key, k = jax.random.split(self.act_key)
        cpu = process_cpu.seconds()
        start = time.perf_counter()
        actions, self.given = self._decide(
            self.state, k, jax.device_put(np.asarray(self.obs)), self.given, self.steps
        )
        actions = np.asarray(actions)  # committed: on the host
        latency = time.perf_counter() - start
        cpu = process_cpu.seconds() - cpu
        done = False
        for _ in range(self.config.action_repeat):
            self.env_key, k = jax.random.split(self.env_key)
            self.obs, self.env_state, _, done, _ = self._env_step(k, self.env_state, actions)
            self.steps += 1
            if bool(done):
                break
        if bool(done):
            self.env_key, k = jax.random.split(self.env_key)
            self.obs, self.env_state = self._env_reset(k)
            self.given = jnp.zeros_like(self.given)
        return latency, cpu

    def segment(self, round_index: int, cadence: int) -> Segment:
        """Cycles of `cadence` decisions and one update until the segment's time is up."""
        duration, window_s = self.config.segment_s(), self.config.cpu_window_s
        latencies, updates, windows = [], [], []  # (wall s, CPU s) each
        start = time.perf_counter()
        cpu_start = process_cpu.seconds()
        window_wall, window_cpu = start, cpu_start
        decisions = 0
        while decisions == 0 or decisions % cadence or time.perf_counter() - start < duration:
            latencies.append(self.decision())
            decisions += 1
            if decisions % cadence == 0:
                self.state, *update = _timed_cpu(self._update, self.state)
                updates.append(update)
            now = time.perf_counter()
            if now - window_wall >= window_s:
                cpu = process_cpu.seconds()
                windows.append((now - window_wall, cpu - window_cpu))
                window_wall, window_cpu = now, cpu
        end, cpu = time.perf_counter(), process_cpu.seconds()
        if end > window_wall:  # the last, partial window; a short one joins the one before
            if windows and end - window_wall < window_s / 2:
                last_wall, last_cpu = windows.pop()
                window_wall, window_cpu = window_wall - last_wall, window_cpu - last_cpu
            windows.append((end - window_wall, cpu - window_cpu))
        wall = end - start
        return Segment(
            round=round_index,
            cadence=cadence,
            latencies_s=np.asarray(latencies).reshape(-1, 2)[:, 0],
            update_times_s=np.asarray(updates).reshape(-1, 2)[:, 0],
            decision_cpu_s=np.asarray(latencies).reshape(-1, 2)[:, 1],
            update_cpu_s=np.asarray(updates).reshape(-1, 2)[:, 1],
            wall_s=wall,
            cpu_s=cpu - cpu_start,
            cpu_windows=np.asarray(windows, dtype=float).reshape(-1, 2),
        )

    def played_per_update(self) -> float:
        """Environment steps the learner's own updates played (its `env_steps` counter),
        per update so far."""
        return float(self.state.env_steps) / max(int(self.state.iteration), 1)


def run(
    config: ProfileConfig,
    controllers: tuple[str, ...] | None = None,
    on_segment: Callable[[dict[str, Any]], None] | None = None,
) -> dict[str, LoopResult]:
    """Warms up each controller, then runs the interleaved segments; see the module
    docstring. `controllers`: default `(config.controller,)`. `on_segment(tags)` is
    told the phase, controller and cadence before each part runs."""
    controllers = (config.controller,) if controllers is None else tuple(controllers)
    tell = on_segment or (lambda tags: None)
    loops = {}
    for name in controllers:
        tell({"phase": "warmup", "controller": name, "cadence": None})
        loops[name] = Controller(config, name)
    segments: dict[str, list[Segment]] = {name: [] for name in controllers}
    for r in range(config.rounds):
        for i, cadence in enumerate(config.cadences):
            order = controllers if (r + i) % 2 == 0 else controllers[::-1]
            for name in order:
                tell({"phase": "steady", "controller": name, "cadence": cadence})
                segments[name].append(loops[name].segment(r, cadence))
    tell({"phase": "done", "controller": None, "cadence": None})
    return {
        name: LoopResult(
            segments=segments[name],
            compile_s=loop.compile_s,
            warmup_s=loop.warmup_s,
            env_steps=loop.steps,
            played_per_update=loop.played_per_update(),
        )
        for name, loop in loops.items()
    }
