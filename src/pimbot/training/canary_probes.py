"""Counted hooks for `pimbot check`: each call of a hook, and whether it did anything.

`instrument(obj, hooks, tally, label, on)` returns a copy of an attack or defense whose
hooks (the ones named) run the original hook, then the same hook's *no-op* output for the
same inputs (what the base class `Attack` or `Defense` would do: play the actions given,
emit the learned incentives, keep the state, accept what was sent, ...; `NOOPS`), and
add one call, and one change where the two outputs differ, to the hook's row of a counter
(`Tally.counting`). The counter is an array the traced program carries and returns with
its results (a `jax.new_ref` the program makes, written by the primitive `count_p`): the
count is of the hook's executions by the compiled program, not of its traces, so a hook
behind a branch the program never takes is never counted, a hook in a `scan` counts once
per step, and under a vmap a hook whose inputs are batched counts once per element (one
whose inputs are not batched counts once for the whole batch: `pimbot check` runs its
seeds one at a time). These are the counts a host callback (`jax.debug.callback`) at the
hook would see, but the program has no callback, so the persistent compilation cache keeps
it (JAX never caches a program with host callbacks) and a second `pimbot check` of the
same file compiles nothing.

The copy carries a traced flag `canary_on`: 1 passes the hook's own output on, 0 the
no-op output. Both settings are one compiled program (the flag is a number, not
structure: `switched` makes the other setting of the same copy), so a paired run with
and without a plugin costs one compilation, and its two halves differ only in what the
plugin's hooks return.

`probe_attack` and `probe_defense` make an attack or defense that does nothing at the
given hook points (an adversary's own step leaves it where it was), to count where a
learner consults them.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import inspect
from collections.abc import Callable, Iterator
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax._src import core as jax_core
from jax._src.interpreters import ad, batching
from jax._src.interpreters import partial_eval as pe
from jax._src.state import discharge as state_discharge
from jax._src.state import types as state_types

from pimbot.contracts.attack import AgentParams, Attack, UpdateSchedule, agent_row
from pimbot.contracts.defense import Defense

# --- the counter: a row per counted hook, (calls, changed), carried by the program ---------

count_p = jax_core.Primitive("pimbot_canary_count")
"""count_p.bind(counter, value, row=r): counter[r] += value, where `counter` is a `Ref`
int32[rows, 2] made by the traced program and `value` int32[2] (1, changed). Under a vmap
it adds the sum over the mapped axis (a `jax.debug.callback` would run once per element);
a counter's own updates are the program's: discharged into its outputs when it is lowered
(`jax._src.state.discharge`), with no host callback."""
count_p.multiple_results = True


def _count_abstract(counter, value, *, row):
    del counter, value, row
    return [], {state_types.AccumEffect(0)}


count_p.def_effectful_abstract_eval(_count_abstract)


def _count_impl(counter, value, *, row):
    counter[row] += value
    return []


count_p.def_impl(_count_impl)


def _count_batched(axis_data, values, dims, *, row):
    """Under a vmap: the sum over the mapped axis, counted once (by the level outside)."""
    del axis_data
    (counter, value), (counter_dim, value_dim) = values, dims
    if counter_dim is not None:
        raise NotImplementedError("a canary counter made inside a vmap")
    if value_dim is not None:
        value = jnp.sum(value, axis=value_dim)
    return count_p.bind(counter, value, row=row), []


batching.fancy_primitive_batchers[count_p] = _count_batched


def _count_jvp(primals, tangents, *, row):
    """Differentiated: the primal computation counts, as a callback would."""
    del tangents
    count_p.bind(*primals, row=row)
    return [], []


ad.primitive_jvps[count_p] = _count_jvp
ad.primitive_transposes[count_p] = lambda cts, *args, row: [None] * len(args)


def _count_partial_eval_custom(saveable, unks_in, inst_in, eqn):
    """As `jax.debug.callback`'s rule: staged where an input is unknown; else kept in the
    known part, and in the staged part too unless the policy saves it."""
    if any(unks_in):
        residuals = [v for v, inst in zip(eqn.invars, inst_in, strict=True) if not inst]
        return None, eqn, [], [], residuals
    if saveable(count_p, *[v.aval for v in eqn.invars], **eqn.params):
        return (eqn, eqn, [], [], []) if all(inst_in) else (eqn, None, [], [], [])
    return eqn, eqn, [], [], []


pe.partial_eval_jaxpr_custom_rules[count_p] = _count_partial_eval_custom


@state_discharge.register_discharge_rule(count_p)
def _count_discharge(in_avals, out_avals, counter, value, *, row):
    del in_avals, out_avals
    return [counter.at[row].add(value), None], []


@dataclasses.dataclass
class Tally:
    """Calls and changed outputs per (part, hook, flag). A counted hook has a row
    (`row`); a program traced inside `counting` carries a counter of every row and returns
    it, and `add` sums what it returned under the half of the paired run it ran. One tally
    per check; nothing else holds it."""

    rows: dict[tuple[str, str], int] = dataclasses.field(default_factory=dict)
    calls: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    changed: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    _counter: Any = None
    """The counter of the program being traced (a `Ref`), else None."""

    def row(self, label: str, hook: str) -> int:
        """The counter row of hook `hook` under `label` (a new one the first time)."""
        return self.rows.setdefault((label, hook), len(self.rows))

    @contextlib.contextmanager
    def counting(self) -> Iterator[Callable[[], jax.Array]]:
        """Inside a traced function: the counted hooks traced within add to a new counter;
        yields the function that reads it (int32 [rows, 2]: calls, changed), for the
        program to return."""
        counter = jax.new_ref(jnp.zeros((len(self.rows), 2), jnp.int32))
        previous, self._counter = self._counter, counter
        try:
            yield lambda: counter[...]
        finally:
            self._counter = previous

    def count(self, row: int, changed: jax.Array, on: jax.Array) -> None:
        """One call of the hook of `row` with flag `on` (at trace time: counted where the
        program executes it), changed or not; nothing outside `counting` (an abstract
        trace). Under a vmap it counts once per element where `changed` or `on` is mapped."""
        if self._counter is None:
            return
        changed = jnp.asarray(changed, jnp.int32) + jnp.asarray(on * 0, jnp.int32)
        count_p.bind(self._counter, jnp.stack([changed * 0 + 1, changed]), row=row)

    def add(self, counts, on: bool) -> None:
        """Adds a program's counter (`counting`) to the half `on` of the paired run."""
        counts = np.asarray(counts)
        for (label, hook), row in self.rows.items():
            if row < counts.shape[0]:
                self.calls[(label, hook, on)] += int(counts[row, 0])
                self.changed[(label, hook, on)] += int(counts[row, 1])

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


def _counted(hook: str, method: Callable, base: type, tally: Tally, row: int) -> Callable:
    signature = inspect.signature(getattr(base, hook))

    def counted(self, *args, **kwargs):
        out = method(self, *args, **kwargs)
        noop = NOOPS[hook](self, out, signature.bind(self, *args, **kwargs).arguments)
        tally.count(row, differs(hook, out, noop), self.canary_on)
        return select(self.canary_on, out, noop)

    counted.__name__ = counted.__qualname__ = hook
    return counted


def instrument(obj: Any, hooks: tuple[str, ...], tally: Tally, label: str, on: bool) -> Any:
    """A copy of attack or defense `obj` whose `hooks` are counted in `tally` under `label`
    (in the counter of a program traced inside `tally.counting`) and answer with their own
    output (`on`) or the no-op output (not `on`; `switched` flips it).

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
        row = tally.row(label, hook)
        namespace[hook] = _counted(hook, getattr(cls, hook), base, tally, row)
    counted_cls = struct.dataclass(type(cls.__name__, (cls,), namespace))
    values = {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj) if f.init}
    return counted_cls(**values, canary_on=jnp.float32(1.0 if on else 0.0))


def switched(counted: Any, on: bool) -> Any:
    """The copy `counted` (`instrument`) answering with the hooks' own outputs (`on`) or
    the no-op's: the same class, so the same compiled program (the flag is traced)."""
    if not hasattr(counted, "canary_on"):
        return counted
    return dataclasses.replace(counted, canary_on=jnp.float32(1.0 if on else 0.0))


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
