"""The attack contract: what a manipulation of one agent (the adversary) may change.

An attack is a frozen pytree config: its numeric parameters are leaves (traced
data, so runs that differ only in numbers share one compiled program), its
structural ones (`adversary`, modes) static fields. A learner consults it at
named hook points; an attack overrides only those of its lever and lists them
in `hooks`, so a learner that does not consult a hook refuses it by name:

* `act`              — the joint action actually played (bypass, ε-random);
* `emit`             — the incentives actually emitted, as a scale [N giver,
                       N recipient] of the learned incentives plus an offset;
* `learning_rewards` — the reward of every agent's actual policy step;
* `policy_sign`      — +1 ascends, −1 descends, 0 freezes an agent's policy step;
* `adversary_step`   — replaces the adversary's update (a learning attack),
                       given an `AdversaryView` the learner builds;
* `observe`          — updates the attack's per-seed state once per iteration;
* `update_schedule`  — every agent's number of update epochs and the scale of its
                       shaped-reward weight, before a multi-epoch update (the
                       Reciprocator's PPO), given an `AdversaryView` of the batch.

Besides the hooks, an attack may report numbers of its per-seed state with `metrics`
(read at every evaluation by the training runner from the learner state's `attack_state`,
and written to metrics.csv as `attack/<name>/<metric>`: `state_metrics`). It is no hook
point: a learner need not consult it, and an attack without a learning step logs through it
too.

Every hook gets the attack's per-seed state (`init_state`, kept in the learner
state) and, where randomness may be needed, its own PRNG key, derived from the
learner's keys without consuming them (clean streams stay bit-identical).
Everything the other agents *model* of the adversary stays the ordinary
learner: only the adversary's actual behaviour changes.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from pimbot.contracts import conformance
from pimbot.contracts.registry import Registry
from pimbot.errors import InvalidParameter

HOOKS = (
    "act",
    "emit",
    "learning_rewards",
    "policy_sign",
    "adversary_step",
    "observe",
    "update_schedule",
)
"""Every attack hook point (the first six in the order a learner's iteration meets them;
`update_schedule` comes before the Reciprocator's `learning_rewards`)."""

ATTACK_STREAM = 0x5A7
"""`fold_in` data of the attack's keys: derived from a learner key without splitting it."""


def attack_key(key: jax.Array) -> jax.Array:
    """The attack's key beside a learner key (`key` itself is left to its own use)."""
    return jax.random.fold_in(key, ATTACK_STREAM)


@struct.dataclass
class AgentParams:
    """One agent's parameters ω: its policy θ and its incentive function η ({} if none)."""

    policy: Any
    incentive: Any


def agent_row(stacked, agent: int):
    """Agent `agent`'s parameters from stacked ones (leaves [N, ...] -> [...])."""
    return jax.tree.map(lambda x: x[agent], stacked)


def with_agent_row(stacked, agent: int, own):
    """`stacked` with agent `agent`'s parameters replaced by `own`."""
    return jax.tree.map(lambda x, o: x.at[agent].set(o), stacked, own)


@dataclasses.dataclass(frozen=True)
class AdversaryView:
    """What a learner shows a learning attack's `adversary_step`, once per iteration.

    Arrays have leading batch axes B (LIO: none, one episode; Reciprocator: [E]
    episodes) before time T. The adversary's row of `policy` (and `incentive`) is
    its current ω: the learner has not moved it (its policy sign is 0). For
    `update_schedule` the view is taken before the update, on the batch it learns from.
    """

    policy: Any
    """Stacked policy parameters of every agent, leaves [N, ...]."""
    incentive: Any
    """Stacked incentive parameters [N, ...]; None without an incentive channel. Where it is
    set, `emitted` and `meta_pullback` must be too: an attack that trains the adversary's
    incentives reads all three (`incentive_channel`)."""
    log_probs: Callable[[Any], jax.Array]
    """θ_a -> [B..., T] log-probability of the adversary's actions on the judged batch,
    as it played them, zero on invalid steps."""
    env_rewards: jax.Array
    """[B..., T, N] env rewards of the judged batch (zero on invalid steps)."""
    valid: jax.Array
    """bool [B..., T]."""
    emitted: Callable[[Any], jax.Array] | None
    """η_a (the adversary's own incentive parameters) -> [B..., T, N, N] incentives emitted
    on the judged batch, as emitted: the adversary's row recomputed from η_a
    (differentiable), the other givers' as they gave them; None exactly when `incentive`
    is."""
    meta_pullback: Callable[[jax.Array], Any] | None
    """Cotangents [K, T, N] on the recipients' log-probabilities on the judged batch ->
    [K, ...] their gradients w.r.t. η_a through the recipients' updates from the incentives
    the adversary gave (LIO's second-order path). Batched over K: call it once, not under
    vmap (the learner may pull its own givers' cotangents back in the same pass); None
    exactly when `incentive` is."""
    received: jax.Array
    """[B'..., T] the signal the adversary received per step (incentives, or the
    influence others exert on it), on the batch it learnt from."""
    received_valid: jax.Array
    """bool [B'..., T] of `received`."""
    emission_scales: tuple[tuple[jax.Array, jax.Array], ...]
    """(scale [T, N, N], valid [T]) of every episode played this iteration (with an
    incentive channel), for budget accounting."""
    success: jax.Array
    """[] team success of the iteration."""
    gamma: float
    iteration: jax.Array


def incentive_channel(view: AdversaryView, attack: str) -> bool:
    """Whether the learner showed `attack` an incentive channel (`view.incentive` set),
    checked at trace time, before any iteration runs: with one, `emitted` and
    `meta_pullback` must be set too, since the attack trains the adversary's incentives
    through the recipients' updates.

    Raises:
        InvalidParameter: naming the missing fields of the learner's view.
    """
    if view.incentive is None:
        return False
    missing = [name for name in ("emitted", "meta_pullback") if getattr(view, name) is None]
    if missing:
        raise InvalidParameter(
            f"attack: {attack} trains the adversary's incentives through the recipients' "
            f"updates, but the learner's AdversaryView sets `incentive` without "
            f"{' and '.join(f'`{m}`' for m in missing)} (pimbot.contracts.attack.AdversaryView; "
            "docs/extending.md)"
        )
    return True


@dataclasses.dataclass(frozen=True)
class Decision:
    """Where `act` is consulted: what it may need of the env and of training."""

    idle_action: int
    """The env's "do nothing" action."""
    num_actions: int
    """Size of every agent's action set."""
    env_step: jax.Array
    """int32 [] environment steps taken in training before this decision."""


@dataclasses.dataclass(frozen=True)
class UpdateSchedule:
    """What `update_schedule` returns: how every agent's next multi-epoch update runs."""

    epochs: jax.Array
    """int32 [N] full-batch epochs of every agent's update (1 ≤ epochs ≤ `most_epochs`)."""
    reward_weight_scale: jax.Array
    """[N] factor on every agent's shaped-reward weight (Reciprocator: the reciprocal
    weight w)."""
    most_epochs: int
    """Static bound of `epochs`: the learner runs this many epochs and keeps each agent's
    first `epochs[i]`."""
    metrics: dict[str, jax.Array]
    """`attack/`-style float32 scalars of the iteration."""


@dataclasses.dataclass(frozen=True)
class Outcome:
    """What `observe` sees after each iteration."""

    success: jax.Array
    """[] team success of the episodes just played."""
    iteration: jax.Array
    """int32 [] the iteration just trained."""
    env_steps: jax.Array
    """int32 [] environment steps taken in training so far."""


@struct.dataclass
class Attack:
    """No manipulation; the base of every attack (every hook is the identity)."""

    adversary: int = struct.field(pytree_node=False, default=0)
    """Index of the manipulated agent."""

    name: ClassVar[str] = "none"
    lever: ClassVar[str] = "none"
    hooks: ClassVar[tuple[str, ...]] = ()
    """The hook points this attack changes; a learner must consult all of them."""
    optional_hooks: ClassVar[tuple[str, ...]] = ()
    """Hook points it overrides that a learner may lack: consulted where the learner has
    them, no reason to refuse one that has not (ADMO's budget on `emit`, which only a
    learner with an incentive channel has). Every overridden hook is in one of the two."""

    def validate(self, num_agents: int) -> None:
        """Raises InvalidParameter naming the bad field (override and call super)."""
        if isinstance(self.adversary, bool) or not isinstance(self.adversary, int):
            raise InvalidParameter(f"adversary: must be an integer, got {self.adversary!r}")
        if not 0 <= self.adversary < num_agents:
            raise InvalidParameter(
                f"adversary: must be an agent index in [0, {num_agents - 1}], got {self.adversary}"
            )

    @property
    def active(self) -> bool:
        """False for the clean (no-attack) config."""
        return self.name != "none"

    def program_form(self) -> Attack:
        """The attack as a compiled program takes it: equivalent, with any static field
        that only selects a number (a mode that is a sign) made a traced leaf, so runs
        that differ only in that choice share one program. The default: the attack
        itself. Its hooks must give exactly the values the attack's own give.

        Programs take attacks, defenses and envs alike, as pytree arguments whose data
        fields are the numbers (traced) and whose class and meta fields are the structure
        (static): a form declares its number as a data field, as an env declares its
        numbers in `traced_fields` (`pimbot.envs.core.TracedFields`), and is built by its
        constructor (`pimbot.attacks.signed_modes.with_traced_sign`)."""
        return self

    def is_adversary(self, num_agents: int) -> jax.Array:
        """bool [N], True at the adversary."""
        return jnp.arange(num_agents) == self.adversary

    def init_state(self, key: jax.Array, num_agents: int, adversary: AgentParams) -> Any:
        """The attack's per-seed state; `adversary` is ω at initialisation."""
        del key, num_agents, adversary
        return {}

    def act(self, state: Any, key: jax.Array, actions: jax.Array, at: Decision) -> jax.Array:
        """The joint action int32 [N] played instead of the learners' `actions`."""
        del state, key, at
        return actions

    def emit(
        self, state: Any, key: jax.Array, given_so_far: jax.Array
    ) -> tuple[jax.Array, jax.Array]:
        """(scale [N, N], offset [N, N]): emitted[i, j] = scale[i, j] · learned[i, j] + offset
        (each may be [N, 1] instead: giver i's value for every recipient).

        Args:
            given_so_far: [N, N] incentives emitted earlier in this episode.
        """
        del state, key
        n = given_so_far.shape[0]
        return jnp.ones((n, n)), jnp.zeros((n, n))

    def learning_rewards(self, state: Any, env_rewards: jax.Array, received: jax.Array):
        """[..., T, N] rewards of every agent's actual policy step (env + received)."""
        del state
        return env_rewards + received

    def policy_sign(self, state: Any, num_agents: int) -> jax.Array:
        """[N] sign of every agent's actual policy step."""
        del state
        return jnp.ones((num_agents,))

    def adversary_step(
        self, state: Any, key: jax.Array, view: AdversaryView
    ) -> tuple[AgentParams, Any, dict[str, jax.Array]]:
        """The adversary's new ω, the new state and `attack/`-style metrics.

        Only called for attacks listing "adversary_step" in `hooks`.
        """
        raise NotImplementedError(f"attack {self.name} has no adversary step")

    def observe(self, state: Any, key: jax.Array, outcome: Outcome) -> Any:
        """The state after an iteration (identity by default)."""
        del key, outcome
        return state

    def metrics(self, state: Any) -> dict[str, jax.Array]:
        """Numbers of the attack's per-seed `state` to log at every evaluation: name ->
        a number [] (or [N], one per agent). Default: none.

        Read by the training runner after each evaluation period (`state_metrics`, from
        the learner state's `attack_state`) and written to metrics.csv as
        `attack/<attack name>/<name>` (`/agent_<i>` added per agent); `pimbot table
        --metric`, `pimbot plot --metric` and the report's sweep section show them. A
        value may be non-finite (a "not yet" NaN): like the attack's state, it is not
        taken for divergence. Keep names and shapes fixed: they are metrics.csv's columns.
        """
        del state
        return {}

    def update_schedule(
        self, state: Any, key: jax.Array, view: AdversaryView, ordinary_epochs: int
    ) -> UpdateSchedule:
        """Every agent's epochs and reward-weight scale of the coming update (default: the
        learner's own `ordinary_epochs` and scale 1 for everyone).

        `view` shows the batch the update learns from, before the update (the adversary's
        row is its current ω). Only consulted for attacks listing "update_schedule" in
        `hooks`: a learner runs its ordinary update program otherwise.
        """
        del state, key
        n = view.env_rewards.shape[-1]
        return UpdateSchedule(
            epochs=jnp.full((n,), ordinary_epochs, jnp.int32),
            reward_weight_scale=jnp.ones((n,)),
            most_epochs=ordinary_epochs,
            metrics={},
        )


NO_ATTACK = Attack()

ATTACKS: Registry[type[Attack]] = Registry("attack", "attack")


def register(cls: type[Attack], *, replace: bool = False) -> type[Attack]:
    """Registers an attack class under `cls.name` (usable as a class decorator).

    Its code is checked against what it declares (`conformance.check_hooked_class`), and
    the hooks it overrides are replaced by checked ones (`conformance.install_checks`:
    while a program is traced, each output is checked against the contract below, and an
    exception inside the attack's code is one line at its file and line).

    Raises:
        ContractError: one line naming the class's file and line.
    """
    registered = ATTACKS.register_hooked_class(cls, Attack, HOOKS, replace=replace)
    conformance.install_checks(cls, Attack, OUTPUT_CHECKS)
    return registered


STATE_METRICS = "attack/"
"""Namespace of the metrics.csv columns an attack's `metrics` writes: `attack/<name>/…`."""


def state_metrics(attack: Attack, learner_state: Any, num_agents: int) -> dict[str, jax.Array]:
    """The attack's `metrics` of the state a learner keeps for it (the learner state's
    `attack_state` field, as every built-in learner keeps it), each float32 [] or [N];
    none where the learner keeps no attack state.

    Raises:
        ContractError: `metrics` returned something else than a dict of numbers [] or [N],
            one line at the attack's file and line.
    """
    state = getattr(learner_state, "attack_state", None)
    if state is None:
        return {}
    out = attack.metrics(state)
    problem = conformance.metrics_problem(out, num_agents)
    if problem:
        raise conformance.hook_error(attack, type(attack).metrics, "metrics", problem)
    return {str(name): jnp.asarray(value, jnp.float32) for name, value in out.items()}


def state_metric_prefix(attack_name: str) -> str:
    """The metrics.csv prefix of the state metrics of attack `attack_name`."""
    return f"{STATE_METRICS}{attack_name}/"


def parameters(cls: type[Attack]) -> dict[str, Any]:
    """The attack's parameters and their defaults."""
    return {f.name: f.default for f in dataclasses.fields(cls) if f.init}


# --- each hook's output, as the rollout and the learners take it (checked at trace time) ---


def _act_problem(attack: Attack, out, args) -> str | None:
    actions = args["actions"]
    return conformance.array_problem(out, [jnp.shape(actions)], dtype=conformance.aval(actions)[1])


def _emit_problem(attack: Attack, out, args) -> str | None:
    n = jnp.shape(args["given_so_far"])[0]
    if not (isinstance(out, tuple | list) and len(out) == 2):
        return f"a {type(out).__name__}; expected (scale [{n}, {n}], offset [{n}, {n}])"
    for part, value in zip(("scale", "offset"), out, strict=True):
        problem = conformance.array_problem(value, [(n, n), (n, 1)])
        if problem:
            return f"{part} {problem} (givers × recipients)"
    return None


def _learning_rewards_problem(attack: Attack, out, args) -> str | None:
    shape = np.broadcast_shapes(jnp.shape(args["env_rewards"]), jnp.shape(args["received"]))
    return conformance.array_problem(out, [shape])


def _policy_sign_problem(attack: Attack, out, args) -> str | None:
    return conformance.array_problem(out, [(args["num_agents"],)], kinds="fi")


def _observe_problem(attack: Attack, out, args) -> str | None:
    return conformance.like_problem(out, args["state"], "a state")


def _row(stacked):
    """The shapes of one agent's row of stacked parameters (no array is made)."""
    return jax.tree.map(lambda x: jax.ShapeDtypeStruct(jnp.shape(x)[1:], x.dtype), stacked)


def _adversary_step_problem(attack: Attack, out, args) -> str | None:
    if not (isinstance(out, tuple | list) and len(out) == 3):
        return f"a {type(out).__name__}; expected (AgentParams, state, metrics)"
    own, state, metrics = out
    if not isinstance(own, AgentParams):
        return f"{type(own).__name__} first; expected AgentParams(policy, incentive)"
    view = args["view"]
    n = jnp.shape(view.env_rewards)[-1]
    return (
        conformance.like_problem(own.policy, _row(view.policy), "policy")
        or (
            conformance.like_problem(own.incentive, _row(view.incentive), "incentive")
            if view.incentive is not None
            else None
        )
        or conformance.like_problem(state, args["state"], "a state")
        or conformance.metrics_problem(metrics, n)
    )


def _update_schedule_problem(attack: Attack, out, args) -> str | None:
    if not isinstance(out, UpdateSchedule):
        return f"a {type(out).__name__}; expected an UpdateSchedule"
    n = jnp.shape(args["view"].env_rewards)[-1]
    if isinstance(out.most_epochs, bool) or not isinstance(out.most_epochs, int):
        return f"most_epochs {out.most_epochs!r}; expected a Python int (a static bound)"
    problem = conformance.array_problem(out.epochs, [(n,)], kinds="iu")
    if problem:
        return f"epochs {problem}"
    problem = conformance.array_problem(out.reward_weight_scale, [(n,)])
    if problem:
        return f"reward_weight_scale {problem}"
    return conformance.metrics_problem(out.metrics, n)


OUTPUT_CHECKS: dict[str, conformance.OutputCheck | None] = {
    "act": _act_problem,
    "emit": _emit_problem,
    "learning_rewards": _learning_rewards_problem,
    "policy_sign": _policy_sign_problem,
    "adversary_step": _adversary_step_problem,
    "observe": _observe_problem,
    "update_schedule": _update_schedule_problem,
    "metrics": None,  # checked where it is read, knowing N (`state_metrics`)
    "init_state": None,  # any pytree: an exception inside it is still one line
    "validate": None,
}
"""Every hook's output check (`conformance.install_checks`), by the contract above."""
