"""Several strategy attacks as one compiled program (`Strategies`), chosen by a traced index.

Attacks of different classes are different program structures. The strategy attacks
(every attack without an `adversary_step` and without per-seed state) are cheap
elementwise hooks, so `Strategies` folds several of them into one structure: it computes
every member's hook and keeps the chosen member's output with `jnp.where` on a traced
index, so a job of any member class runs on the same program and gets exactly its own
member's values. `shared_attack` builds it; `pimbot.training.programs.share_key` groups
jobs by the key after this folding.
"""

from __future__ import annotations

import inspect
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
from flax import struct

from pimbot.contracts.attack import Attack


def structure(tree: Any) -> tuple:
    """Class/static structure and leaf avals of a pytree (not its numbers)."""
    leaves, treedef = jax.tree.flatten(tree)
    avals = tuple((jnp.shape(x), jnp.result_type(x).name, _weak(x)) for x in leaves)
    return (str(treedef), avals)


def _weak(x: Any) -> bool:
    return isinstance(x, (bool, int, float, complex)) or bool(getattr(x, "weak_type", False))


def shareable(attack: Attack) -> bool:
    """Whether `attack` may be folded into `Strategies`: no learning step and no per-seed
    state of its own (the members' states must share one structure; a stateful plugin
    attack, e.g. one growing its incentive in `observe`, gets its own program), and no
    metrics of its own (`Attack.metrics`: the members' would differ in their names)."""
    stateless = type(attack).init_state is Attack.init_state and "observe" not in attack.hooks
    silent = inspect.unwrap(type(attack).metrics) is Attack.metrics
    return "adversary_step" not in attack.hooks and stateless and silent


@struct.dataclass
class Strategies(Attack):
    """One of several strategy attacks, chosen by a traced index (`which`).

    Every member's hook is computed and the chosen member's output kept with
    `jnp.where`, so the values are exactly those of the chosen attack run alone.
    The members share the adversary; their per-seed states must have one
    structure (the strategies' states are empty), and the state is the chosen
    member's.
    """

    members: tuple = ()
    which: Any = 0

    name: ClassVar[str] = "strategies"
    lever: ClassVar[str] = "any"
    hooks: ClassVar[tuple[str, ...]] = ("act", "emit", "learning_rewards", "policy_sign", "observe")

    def _pick(self, outputs):
        chosen = outputs[0]
        for k, out in enumerate(outputs[1:], start=1):
            chosen = jax.tree.map(lambda a, b, k=k: jnp.where(self.which == k, a, b), out, chosen)
        return chosen

    def is_adversary(self, num_agents: int) -> jax.Array:
        active = jnp.asarray([m.active for m in self.members])[self.which]
        return (jnp.arange(num_agents) == self.adversary) & active

    def init_state(self, key, num_agents, adversary):
        states = [m.init_state(key, num_agents, adversary) for m in self.members]
        return self._pick(states)

    def act(self, state, key, actions, at):
        return self._pick([m.act(state, key, actions, at) for m in self.members])

    def emit(self, state, key, given_so_far):
        return self._pick([m.emit(state, key, given_so_far) for m in self.members])

    def learning_rewards(self, state, env_rewards, received):
        return self._pick([m.learning_rewards(state, env_rewards, received) for m in self.members])

    def policy_sign(self, state, num_agents):
        return self._pick([m.policy_sign(state, num_agents) for m in self.members])

    def observe(self, state, key, outcome):
        return self._pick([m.observe(state, key, outcome) for m in self.members])


def member_kind(attack: Attack) -> str:
    """The structure of a strategy attack (its class and static fields)."""
    return structure(jax.tree.map(lambda _: 0, attack))[0]


def shared_attack(attack: Attack, templates: dict[str, Attack]) -> Strategies:
    """`attack` as the member of `Strategies` over the kinds in `templates` (kind ->
    an attack of that kind; sorted by kind so every job of a group builds one structure).
    The other members are placeholders: their values are computed and discarded."""
    kinds = sorted(templates)
    mine = member_kind(attack)
    members = tuple(attack if kind == mine else templates[kind] for kind in kinds)
    return Strategies(
        adversary=attack.adversary, members=members, which=jnp.int32(kinds.index(mine))
    )
