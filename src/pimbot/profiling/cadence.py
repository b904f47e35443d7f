"""LIO's training cadence: how many decisions its training takes per update.

One LIO update is one iteration, and an iteration plays its own episodes (τ with
θ, then τ̂ with θ̂: docs/lio.md). Each episode is up to `env.max_steps` joint
decisions, one per environment step (training repeats no action), and the
training's rollout computes all of them (a scan over the horizon, the steps
after the end masked). So the training cadence is

    decisions per update = episodes per update × env.max_steps

(10 for ER(2,1): 2 × 5). The episodes are counted, not assumed: each episode
starts with one `env.reset`, and the resets in a trace of the learner's update
(`jax.eval_shape`: nothing is compiled or run) are its episodes. Fewer decisions
are *played* once episodes end early: a converged ER(2,1) policy leaves in one
step, 2 decisions per update, which the profile measures as another cadence.
"""

from __future__ import annotations

import copy

import jax


def episodes_per_update(env, learner, cfg, state, attack) -> int:
    """Episodes one `learner.update` plays: the env.reset calls in a trace of it (`state`
    may be abstract: shapes and dtypes only).

    Counts episodes only for learners that reset once per episode played (LIO's
    rollout does; a learner that vmaps a rollout over a batch would be counted
    once per batch)."""
    resets = []
    reset = env.reset

    def counted(key):
        resets.append(1)
        return reset(key)

    counting = copy.copy(env)
    object.__setattr__(counting, "reset", counted)
    jax.eval_shape(lambda s: learner.update(s, counting, cfg, attack), state)
    return len(resets)


def training_cadence(env, learner, cfg, state, attack) -> dict[str, int]:
    """{"episodes_per_update", "max_steps", "decisions_per_update"} of the training."""
    episodes = episodes_per_update(env, learner, cfg, state, attack)
    return {
        "episodes_per_update": episodes,
        "max_steps": int(env.max_steps),
        "decisions_per_update": episodes * int(env.max_steps),
    }


def of_profile(config) -> dict[str, int]:
    """The training cadence of the learner and environment a `ProfileConfig` profiles
    (benign: an attack plays no episodes of its own)."""
    from pimbot.profiling.decision_loop import NO_ATTACK, build

    env, learner, cfg = build(config)
    state = jax.eval_shape(
        lambda key: learner.init(key, env, cfg, NO_ATTACK), jax.random.key(config.seed)
    )
    return training_cadence(env, learner, cfg, state, NO_ATTACK)
