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

The copy carries a traced flag `canary_on`: 1 passes the hook's own output on, 0 the
no-op output. Both settings are one compiled program (the flag is a number, not
structure), so a paired run with and without a plugin costs one compilation, and its two
halves differ only in what the plugin's hooks return.

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

    def recorder(self, label: str, hook: str) -> Callable[[Any, Any], None]:
        """The host callback of one hook: (flag, changed) -> counted under (label, hook)."""

        def record(on, changed) -> None:
            key = (label, hook, bool(np.asarray(on) > 0.5))
            self.calls[key] += 1
            self.changed[key] += int(np.any(np.asarray(changed)))

        return record

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


def _base_of(obj: Any) -> type:
    return Attack if isinstance(obj, Attack) else Defense


def _counted(hook: str, method: Callable, base: type, record: Callable) -> Callable:
    signature = inspect.signature(getattr(base, hook))

    def counted(self, *args, **kwargs):
        out = method(self, *args, **kwargs)
        noop = NOOPS[hook](self, out, signature.bind(self, *args, **kwargs).arguments)
        jax.debug.callback(record, self.canary_on, differs(hook, out, noop))
        return select(self.canary_on, out, noop)

    counted.__name__ = counted.__qualname__ = hook
    return counted


def instrument(obj: Any, hooks: tuple[str, ...], tally: Tally, label: str, on: bool) -> Any:
    """A copy of attack or defense `obj` whose `hooks` are counted in `tally` under `label`
    and answer with their own output (`on`) or the no-op output (not `on`).

    The copy is an instance of a subclass made here (a `flax.struct` dataclass with one more
    traced field, `canary_on`); its name, hook lists and fields are `obj`'s.
    """
    cls, base = type(obj), _base_of(obj)
    namespace: dict[str, Any] = {
        "__annotations__": {"canary_on": "float"},
        "canary_on": 1.0,
        "__module__": cls.__module__,
        "__qualname__": cls.__qualname__,
    }
    for hook in hooks:
        namespace[hook] = _counted(hook, getattr(cls, hook), base, tally.recorder(label, hook))
    counted_cls = struct.dataclass(type(cls.__name__, (cls,), namespace))
    values = {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj) if f.init}
    return counted_cls(**values, canary_on=jnp.float32(1.0 if on else 0.0))


def _still_adversary(self, state, key, view):
    """No step: the adversary keeps its parameters (the probe's `adversary_step`)."""
    del key
    row = agent_row(view.policy, self.adversary)
    incentive = None if view.incentive is None else agent_row(view.incentive, self.adversary)
    return AgentParams(row, incentive if incentive is not None else {}), state, {}


def probe_attack(hooks: tuple[str, ...]) -> Attack:
    """An attack on agent 0 that does nothing at `hooks` (instrument it to count them)."""
    namespace: dict[str, Any] = {
        "__annotations__": {k: ClassVar for k in ("name", "lever", "hooks")},
        "name": "canary_probe",
        "lever": "none",
        "hooks": tuple(hooks),
        "adversary_step": _still_adversary,
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
