"""Counted hooks for `pimbot check`: each call of a hook, and whether it did anything.

`instrument(obj, hooks, tally, label, on)` returns a copy of an attack or defense whose
hooks (the ones named) run the original hook, then the same hook's *no-op* output for the
same inputs (what the base class `Attack` or `Defense` would do: play the actions given,
emit the learned incentives, keep the state, accept what was sent, ...; `NOOPS`), and
report through `jax.debug.callback` that the hook ran and whether the two outputs differ.
A callback runs when the compiled program executes the hook, not when it is traced: a
hook behind a branch the program never takes is never counted. (Under a vmap, a hook whose
inputs are not batched runs, and is counted, once for the whole batch: `pimbot check` runs
its seeds one at a time.)

The copy carries three traced numbers, so every setting below is one compiled program
(numbers, not structure) and a check of a part costs one compilation:

* `canary_on` [hooks]: per hook, 1 passes the hook's own output on, 0 the no-op output.
  A paired run with and without a plugin differs only in what its hooks return; a run
  with one hook on and the others off shows what that hook alone changes.
* `canary_nudge`: the index of one hook whose output is then perturbed (`PERTURB`: a
  different action for the adversary, its reward column reversed, its policy sign
  flipped, its parameters moved by 0.01, ...; -1: none). A learner that consults a hook
  point and ignores what it returns keeps the same state under the perturbation: that is
  how `pimbot check` proves that a hook's output is used, not only that it was asked.
* `canary_count`: 1 counts the calls in the tally, 0 leaves the tally as it is (the runs
  that only compare states).

`probe_attack` and `probe_defense` make an attack or defense that does nothing at the
given hook points (an adversary's own step leaves it where it was), to count where a
learner consults them.
"""

from __future__ import annotations

import collections
import dataclasses
import inspect
from collections.abc import Callable
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from pimbot.contracts.attack import AgentParams, Attack, UpdateSchedule, agent_row
from pimbot.contracts.defense import Defense


@dataclasses.dataclass
class Tally:
    """Calls and changed outputs per (part, hook, flag): what the callbacks record while a
    compiled program runs. One tally per check; nothing else holds it."""

    calls: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    changed: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    classes: dict = dataclasses.field(default_factory=dict)
    """(class, hooks, label) -> its counted subclass (`counted_class`)."""

    def recorder(self, label: str, hook: str) -> Callable[[Any, Any, Any], None]:
        """The host callback of one hook: (flag, counting, changed) -> counted under (label,
        hook) where `counting` is set."""

        def record(on, counting, changed) -> None:
            if not np.asarray(counting) > 0.5:
                return
            key = (label, hook, bool(np.asarray(on) > 0.5))
            self.calls[key] += 1
            self.changed[key] += int(np.any(np.asarray(changed)))

        return record

    def counted_class(self, cls: type, hooks: tuple[str, ...], label: str) -> type:
        """The subclass of attack or defense class `cls` whose `hooks` record here under
        `label` (`instrument`): made once, so that every setting of it is one pytree
        structure, and one compiled program."""
        key = (cls, hooks, label)
        if key not in self.classes:
            self.classes[key] = _counted_class(cls, hooks, self, label)
        return self.classes[key]

    def of(self, label: str, hook: str, on: bool = True) -> tuple[int, int]:
        """(calls, calls whose output differed from the no-op) of a hook in one setting."""
        key = (label, hook, on)
        return self.calls[key], self.changed[key]


# --- the no-op output of each hook, shaped like what the hook returned --------------------


def _zeros_like(tree):
    return jax.tree.map(jnp.zeros_like, tree)


def _noop_adversary_step(obj, out, args):
    view, own = args["view"], out[0]
    incentive = own.incentive
    if view.incentive is not None:
        incentive = agent_row(view.incentive, obj.adversary)
    still = AgentParams(agent_row(view.policy, obj.adversary), incentive)
    return still, args["state"], _zeros_like(out[2])


def _noop_update_schedule(obj, out, args):
    n = out.epochs.shape[0]
    epochs = jnp.minimum(args["ordinary_epochs"], out.most_epochs)
    return UpdateSchedule(
        epochs=jnp.full((n,), epochs, jnp.int32),
        reward_weight_scale=jnp.ones((n,)),
        most_epochs=out.most_epochs,
        metrics=_zeros_like(out.metrics),
    )


NoOp = Callable[[Any, Any, dict[str, Any]], Any]

NOOPS: dict[str, NoOp] = {
    # attack hooks (pimbot.contracts.attack.Attack's own behaviour)
    "act": lambda obj, out, args: args["actions"],
    "emit": lambda obj, out, args: (jnp.ones_like(out[0]), jnp.zeros_like(out[1])),
    "learning_rewards": lambda obj, out, args: args["env_rewards"] + args["received"],
    "policy_sign": lambda obj, out, args: jnp.ones_like(out),
    "adversary_step": _noop_adversary_step,
    "observe": lambda obj, out, args: args["state"],
    "update_schedule": _noop_update_schedule,
    # defense hooks (pimbot.contracts.defense.Defense's own behaviour)
    "acting_epsilon": lambda obj, out, args: args["ctx"].epsilon,
    "learning_incentives": lambda obj, out, args: (
        args["ctx"].accepted,
        args["state"],
        _zeros_like(out[2]),
    ),
    "after_policy_step": lambda obj, out, args: (
        args["ctx"].policy,
        args["state"],
        _zeros_like(out[2]),
    ),
}
"""hook -> (the attack or defense, what its hook returned, the hook's arguments by name)
-> what the base class would have returned, in the same structure."""

# --- a perturbed output of each hook, to prove that the learner uses it ---------------------


def _moved(tree, by: float = 0.01):
    """Every float leaf of `tree` plus `by` (the other leaves as they are)."""

    def move(x):
        x = jnp.asarray(x)
        return x + by if jnp.issubdtype(x.dtype, jnp.floating) else x

    return jax.tree.map(move, tree)


def _other_action(obj, out, args):
    """The adversary plays 1 where it was to play 0, else 0 (every env has 2 actions)."""
    del args
    mine = out[obj.adversary]
    return out.at[obj.adversary].set(jnp.where(mine == 0, 1, 0).astype(out.dtype))


def _reversed_rewards(obj, out, args):
    """The adversary's reward column [..., T] reversed in sign, plus 1 + 0.1·t: no
    normalisation of returns (by mean or scale) can hide the change."""
    del args
    column = out[..., obj.adversary]
    ramp = 1.0 + 0.1 * jnp.arange(column.shape[-1], dtype=out.dtype)
    return out.at[..., obj.adversary].set(-column + ramp)


def _shifted_schedule(obj, out, args):
    del obj, args
    fewer = jnp.where(out.epochs > 1, out.epochs - 1, jnp.minimum(out.epochs + 1, out.most_epochs))
    return dataclasses.replace(
        out,
        epochs=fewer.astype(out.epochs.dtype),
        reward_weight_scale=out.reward_weight_scale * 0.5,
    )


def _moved_first(obj, out, args):
    """(what the learner acts on, moved by 0.01; the rest as it is)."""
    del obj, args
    return (_moved(out[0]), *out[1:])


PERTURB: dict[str, NoOp] = {
    # attack hooks: only the adversary's share, as an attack's would be
    "act": _other_action,
    "emit": lambda obj, out, args: (out[0] * 0.5, out[1] + 0.1),
    "learning_rewards": _reversed_rewards,
    "policy_sign": lambda obj, out, args: out.at[obj.adversary].multiply(-1),
    "adversary_step": _moved_first,
    "observe": lambda obj, out, args: _moved(out),
    "update_schedule": _shifted_schedule,
    # defense hooks
    "acting_epsilon": lambda obj, out, args: jnp.where(out < 0.5, out + 0.5, out - 0.5),
    "learning_incentives": lambda obj, out, args: (out[0] + 0.1, *out[1:]),
    "after_policy_step": _moved_first,
}
"""hook -> (the attack or defense, the output the learner would get, the hook's arguments)
-> a different output of the same structure, with valid values."""

PERTURBED_AS = {
    "act": "the adversary's action swapped",
    "emit": "emitted scale halved, offset +0.1",
    "learning_rewards": "the adversary's rewards reversed, +1 + 0.1·t",
    "policy_sign": "the adversary's sign flipped",
    "adversary_step": "the adversary's parameters +0.01",
    "observe": "the attack state +0.01",
    "update_schedule": "epochs ±1, reward weight halved",
    "acting_epsilon": "ε ± 0.5",
    "learning_incentives": "accepted incentives +0.1",
    "after_policy_step": "the policy parameters +0.01",
}
"""hook -> how `PERTURB` changes its output, in the words of `pimbot check`'s table."""

METRICS_AT = {"adversary_step": 2, "learning_incentives": 2, "after_policy_step": 2}
"""Hooks whose output holds metrics at this position: a change in metrics alone is no
change of what the learner does."""


def _acted_on(hook: str, out):
    """The part of a hook's output the learner acts on (metrics left out)."""
    if hook in METRICS_AT:
        return tuple(v for i, v in enumerate(out) if i != METRICS_AT[hook])
    if isinstance(out, UpdateSchedule):
        return out.epochs, out.reward_weight_scale
    return out


def differs(hook: str, out, noop) -> jax.Array:
    """bool []: whether what the learner acts on in `out` differs anywhere from `noop`."""
    pairs = zip(
        jax.tree.leaves(_acted_on(hook, out)), jax.tree.leaves(_acted_on(hook, noop)), strict=True
    )
    found = [jnp.any(jnp.asarray(a) != jnp.asarray(b)) for a, b in pairs]
    return jnp.any(jnp.stack(found)) if found else jnp.zeros((), bool)


def select(on, out, noop):
    """`out` where the flag is on, else `noop` (cast to `out`'s shapes and dtypes)."""

    def pick(a, b):
        a = jnp.asarray(a)
        b = jnp.broadcast_to(jnp.asarray(b), a.shape).astype(a.dtype)
        return jnp.where(on > 0.5, a, b)

    if isinstance(out, UpdateSchedule):  # most_epochs is static: the same in both
        return dataclasses.replace(
            out,
            epochs=pick(out.epochs, noop.epochs),
            reward_weight_scale=pick(out.reward_weight_scale, noop.reward_weight_scale),
            metrics=jax.tree.map(pick, out.metrics, noop.metrics),
        )
    return jax.tree.map(pick, out, noop)


# --- counted copies -----------------------------------------------------------------------


def _counted(hook: str, index: int, method: Callable, base: type, record: Callable) -> Callable:
    signature = inspect.signature(getattr(base, hook))

    def counted(self, *args, **kwargs):
        out = method(self, *args, **kwargs)
        arguments = signature.bind(self, *args, **kwargs).arguments
        noop = NOOPS[hook](self, out, arguments)
        on = self.canary_on[index]
        jax.debug.callback(record, on, self.canary_count, differs(hook, out, noop))
        given = select(on, out, noop)
        nudged = (self.canary_nudge == index).astype(jnp.float32)
        return select(nudged, PERTURB[hook](self, given, arguments), given)

    counted.__name__ = counted.__qualname__ = hook
    return counted


@dataclasses.dataclass(frozen=True)
class Setting:
    """What an instrumented copy's hooks answer (`instrument`): own outputs or the no-op's,
    one perturbed, counted or not."""

    on: bool | tuple[bool, ...] = True
    """Own output (True) or the no-op's, for every hook or per hook."""
    nudge: str | None = None
    """The hook whose output is perturbed (`PERTURB`); None: none."""
    count: bool = True
    """Whether the calls are counted in the tally."""


def _counted_class(cls: type, hooks: tuple[str, ...], tally: Tally, label: str) -> type:
    """A `flax.struct` subclass of `cls` with three more traced fields (`canary_on`,
    `canary_nudge`, `canary_count`) whose `hooks` are counted in `tally` under `label`."""
    base = Attack if issubclass(cls, Attack) else Defense
    namespace: dict[str, Any] = {
        "__annotations__": {"canary_on": Any, "canary_nudge": Any, "canary_count": Any},
        "canary_on": None,
        "canary_nudge": -1,
        "canary_count": 1.0,
        "__module__": cls.__module__,
        "__qualname__": cls.__qualname__,
    }
    for index, hook in enumerate(hooks):
        method = getattr(cls, hook)
        namespace[hook] = _counted(hook, index, method, base, tally.recorder(label, hook))
    return struct.dataclass(type(cls.__name__, (cls,), namespace))


def instrument(
    obj: Any, hooks: tuple[str, ...], tally: Tally, label: str, setting: Setting | bool
) -> Any:
    """A copy of attack or defense `obj` whose `hooks` are counted in `tally` under `label`
    and answer as `setting` says (a bool: every hook's own output, or every no-op's).

    The copy is an instance of a subclass made here (a `flax.struct` dataclass with three
    more traced fields, `canary_on`, `canary_nudge`, `canary_count`); its name, hook lists
    and fields are `obj`'s. Copies of one `obj` and `hooks` in any setting share one
    compiled program.
    """
    if isinstance(setting, bool):
        setting = Setting(on=setting)
    counted_cls = tally.counted_class(type(obj), hooks, label)
    values = {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj) if f.init}
    on = setting.on if isinstance(setting.on, tuple) else (setting.on,) * len(hooks)
    return counted_cls(
        **values,
        canary_on=jnp.asarray(on, jnp.float32).reshape(len(hooks)),
        canary_nudge=jnp.int32(hooks.index(setting.nudge) if setting.nudge in hooks else -1),
        canary_count=jnp.float32(setting.count),
    )


def _still_adversary(self, state, key, view):
    """No step: the adversary keeps its parameters (the probe's `adversary_step`)."""
    del key
    row = agent_row(view.policy, self.adversary)
    incentive = None if view.incentive is None else agent_row(view.incentive, self.adversary)
    return AgentParams(row, incentive if incentive is not None else {}), state, {}


def _probe_state(self, key, num_agents, adversary):
    """A per-seed state with one number, so that a perturbed `observe` has something to
    change and a learner that keeps what `observe` returns shows it."""
    del self, key, num_agents, adversary
    return {"canary_probe": jnp.zeros((), jnp.float32)}


def probe_attack(hooks: tuple[str, ...]) -> Attack:
    """An attack on agent 0 that does nothing at `hooks` (instrument it to count them)."""
    namespace: dict[str, Any] = {
        "__annotations__": {k: ClassVar for k in ("name", "lever", "hooks")},
        "name": "canary_probe",
        "lever": "none",
        "hooks": tuple(hooks),
        "adversary_step": _still_adversary,
        "init_state": _probe_state,
    }
    return struct.dataclass(type("CanaryProbe", (Attack,), namespace))()


def probe_defense(hooks: tuple[str, ...]) -> Defense:
    """A defense that does nothing at `hooks` (instrument it to count them)."""
    namespace = {
        "__annotations__": {k: ClassVar for k in ("name", "hooks")},
        "name": "canary_probe",
        "hooks": tuple(hooks),
    }
    return struct.dataclass(type("CanaryProbeDefense", (Defense,), namespace))()
