"""`pimbot check FILE.py`: a canary run of every part a plugin file registers.

A null result ("the attack did not hurt") and a plugin that did nothing read the same in
metrics.csv. The canary tells them apart, in memory, writing nothing:

* each **attack** and **defense** of the file runs a tiny paired run (a few iterations,
  1–2 seeds) on a small env with a learner that has its hook points. Its hooks are counted
  (`canary_probes.instrument`): how many times the compiled program executed each one, and
  in how many of those calls its output differed from the no-op output for the same inputs
  (what the base `Attack` or `Defense` returns). The run is made twice from the same keys,
  once with the hooks' own outputs and once with their no-op outputs (one compiled
  program), and the two runs' metrics are compared. With several hooks, each hook also
  acts alone (the others answer their no-op) in a run of its own: its output must change
  the learner's final state or metrics, so an output the learner ignores is found. A
  defense runs clean and, where one is named, under an attack too.
* each **learner** trains on the env with a probe attack and a probe defense that do
  nothing at every hook point the learner declares, so each point it lists is counted
  where the learner actually consults it; its parameters must change. Then, in one run
  per hook point, that probe's output is perturbed (`canary_probes.PERTURB`): the
  learner's final state or metrics must differ from the unperturbed run's, bit for bit,
  or the learner asks the hook and ignores its answer.
* each **env** trains a learner for a few iterations; its metrics must be finite.

All runs of a part share one compiled program: what they change are traced numbers.

A problem is one line: a hook that never ran, a hook whose output never differed from
doing nothing (in any setting), a hook output that changed nothing the learner kept, a
learner that never consults a hook point it declares, ignores what one returns, or whose
parameters did not move, non-finite metrics. As Gymnasium's `env_checker` and
PettingZoo's `parallel_api_test` call an env and check what comes back, this calls a
plugin's hooks inside the program that trains (docs/extending.md, "Checking what a plugin
does: pimbot check").
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np

from pimbot import attacks, defenses, envs, learners
from pimbot.contracts import conformance
from pimbot.errors import InvalidParameter
from pimbot.training import canary_probes, runner
from pimbot.training.config import RunConfig, resolve


@dataclasses.dataclass(frozen=True)
class Size:
    """How long each canary run is, within `MAX_SEEDS` and `MAX_ITERATIONS`; with
    `progress`, each seed's run is announced on stderr as it starts (`paired_run`)."""

    seeds: int = 2
    iterations: int = 20
    eval_episodes: int = 2
    progress: bool = False

    def __post_init__(self) -> None:
        for name, high in (("seeds", MAX_SEEDS), ("iterations", MAX_ITERATIONS)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= high:
                raise InvalidParameter(
                    f"{name}: a canary runs 1 to {high} {name}, got {value!r}; it checks "
                    "that each hook acts, in seconds (pimbot train runs a long one)"
                )


MAX_SEEDS = 16
MAX_ITERATIONS = 10_000
"""The canary's bounds: each part runs up to 4 runs (a defense clean and attacked, each with
and without its hooks), one seed after another, so `check` takes at most about
4 × parts × MAX_SEEDS × MAX_ITERATIONS iterations (minutes on a CPU), never hours."""


@dataclasses.dataclass(frozen=True)
class Parts:
    """What one plugin file registered, by kind: registry names."""

    envs: tuple[str, ...] = ()
    learners: tuple[str, ...] = ()
    attacks: tuple[str, ...] = ()
    defenses: tuple[str, ...] = ()

    def __bool__(self) -> bool:
        return bool(self.envs or self.learners or self.attacks or self.defenses)


@dataclasses.dataclass(frozen=True)
class Row:
    """One hook of one part in one setting (or a part without hooks: hook "-")."""

    part: str
    """e.g. "attack adaptive_fake_incentive"."""
    setting: str
    """env, learner and what else ran, e.g. "escape_room-v0 · lio · clean"."""
    hook: str
    calls: int | None = None
    changed: int | None = None
    """Calls whose output differed from the no-op's; None where not asked (a learner's
    probes do nothing by design)."""
    run_differs: bool | None = None
    """Whether the paired runs' metrics differ (with the hooks' outputs vs the no-op's)."""
    used: bool | None = None
    """Whether the learner's final state or metrics changed with this hook's output: an
    attack's or defense's hook acting alone against none acting; a learner's hook point
    with its output perturbed (`canary_probes.PERTURB`) against not."""
    note: str = ""


@dataclasses.dataclass(frozen=True)
class Result:
    rows: tuple[Row, ...]
    problems: tuple[str, ...]
    checked: tuple[str, ...] = ()
    """What was checked of each part without a problem, a line each."""


@dataclasses.dataclass(frozen=True)
class Options:
    """What the command line chose: the env of the runs (else the file's, else the
    default), a learner, an attack to check defenses under as well as clean, and the
    size of the runs."""

    default_env: str
    """The env where neither `env` nor the file names one."""
    env: str | None = None
    learner: str | None = None
    defense_attack: str | None = None
    size: Size = Size()


# --- what the file registered ------------------------------------------------------------


def _from(path: Path, obj: Any) -> bool:
    found = conformance.source_file(obj)
    return found is not None and Path(found).resolve() == path


def registered_in(path: str) -> Parts:
    """The envs, learners, attacks and defenses whose code is in the file `path`."""
    where = Path(path).resolve()
    return Parts(
        envs=tuple(e for e in envs.registered() if _from(where, envs.spec(e).constructor)),
        learners=tuple(n for n in learners.registered() if _from(where, learners.get(n).init)),
        attacks=tuple(a for a in attacks.registered() if _from(where, attacks.attack_class(a))),
        defenses=tuple(d for d in defenses.registered() if _from(where, defenses.defense_class(d))),
    )


# --- one paired run ----------------------------------------------------------------------


def _same(a, b) -> bool:
    pairs = zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
    return all(np.array_equal(x, y, equal_nan=True) for x, y in pairs)


@dataclasses.dataclass(frozen=True)
class Trained:
    """One canary run: its metrics, every seed's final learner state, and whether the
    learner's parameters moved."""

    metrics: Any
    states: Any
    params_moved: bool

    def same_as(self, other: Trained) -> bool:
        """Whether the two runs (from the same keys) ended in the same learner state with
        the same metrics, bit for bit."""
        return _same(self.metrics, other.metrics) and _same(self.states, other.states)


@dataclasses.dataclass(frozen=True)
class Outcome:
    """A paired run: the metrics with the hooks' own outputs and with the no-op's, and
    whether the learner's parameters moved (with the hooks' own)."""

    metrics_on: Any
    metrics_off: Any
    params_moved: bool

    @property
    def differs(self) -> bool:
        return not _same(self.metrics_on, self.metrics_off)

    @property
    def finite(self) -> bool:
        return all(np.isfinite(x).all() for x in jax.tree.leaves(self.metrics_on))

    def success(self, on: bool = True) -> float:
        metrics = self.metrics_on if on else self.metrics_off
        return float(np.mean(metrics["eval"]["success"]))


Build = Callable[[bool], tuple[Any, tuple]]
"""flag -> (attack, defenses) of one half of a paired run."""

Variant = tuple[str, Callable[[], tuple[Any, tuple]]]
"""(what it is, for the progress lines; () -> its (attack, defenses))."""


def train_variants(resolved, variants: list[Variant], size: Size) -> list[Trained]:
    """Trains `resolved`'s learner `size.iterations` iterations on `size.seeds` seeds once
    per variant, every variant from the same keys (one compiled program: the variants
    differ only in numbers). Writes nothing.

    The seeds run one after another through a program compiled for one seed: under a
    vmap over seeds, a hook whose inputs are the same for every seed would be executed
    (and counted) once for all of them."""
    init = runner.make_init_fn(resolved)
    chunk = runner.make_chunk_fn(resolved, 1)
    shared = runner.program_args(resolved)[2:]  # env, its optimum's numbers, learner config
    results = []
    for what, build in variants:
        args = (*build(), *shared)
        per_seed, finals, moved = [], [], False
        for seed in range(size.seeds):
            if size.progress:
                print(
                    f"check: {runner.run_title(resolved)}, {what}: seed {seed + 1}/{size.seeds}, "
                    f"{size.iterations} iterations",
                    file=sys.stderr,
                    flush=True,
                )
            keys = runner.seed_keys(seed, 1)
            states = init(jax.vmap(lambda k: jax.random.fold_in(k, 0))(keys), *args)
            before = jax.device_get(states)  # the chunk takes (donates) the states
            eval_roots = jax.vmap(lambda k: jax.random.fold_in(k, 1))(keys)
            states, metrics = chunk(states, eval_roots, *args)
            per_seed.append(jax.device_get(metrics))
            finals.append(jax.device_get(states))
            moved = moved or _params_moved(before, finals[-1])
        joined = [jax.tree.map(lambda *x: np.concatenate(x), *runs) for runs in (per_seed, finals)]
        results.append(Trained(*joined, moved))
    jax.effects_barrier()  # every hook's callback has run
    return results


def paired_run(resolved, build: Build, size: Size, paired: bool = True) -> Outcome:
    """`train_variants` with `build(True)`'s attack and defenses, then `build(False)`'s; once,
    with `build(True)`'s, unless `paired` (the second half's metrics are then the
    first's)."""
    halves = [("with its hooks", lambda: build(True)), ("hooks as no-ops", lambda: build(False))]
    if not paired:
        halves = [("trained", lambda: build(True))]
    runs = train_variants(resolved, halves, size)
    return Outcome(runs[0].metrics, runs[-1].metrics, runs[0].params_moved)


def _params_moved(before, after) -> bool:
    """Whether any float leaf of the learner state outside the attack's and defenses'
    own state changed."""
    leaves = jax.tree_util.tree_leaves_with_path(before)
    for (path, old), new in zip(leaves, jax.tree.leaves(after), strict=True):
        if jax.tree_util.keystr(path).startswith(runner.OWN_STATES):
            continue
        if np.issubdtype(np.asarray(old).dtype, np.floating) and not np.array_equal(old, new):
            return True
    return False


def resolved_run(env_id: str, learner: str, size: Size, attack: str | None = None, defense=None):
    """The run of `learner` on `env_id` with the registered `attack` and `defense` (names,
    their default parameters), `size` long, evaluated once at its end."""
    run = RunConfig(
        env_id,
        learner=learner,
        seeds=size.seeds,
        iterations=size.iterations,
        eval_period=size.iterations,
        eval_episodes=size.eval_episodes,
        attack=attack,
        defenses=((defense, ()),) if defense else (),
    )
    return resolve(run)


# --- the settings a part is checked in ---------------------------------------------------


def learner_order(parts: Parts, options: Options) -> list[str]:
    """Learners to try, first the one asked for, else the file's, the default, the rest."""
    if options.learner is not None:
        return [options.learner]
    first = [*parts.learners, learners.DEFAULT_LEARNER]
    return list(dict.fromkeys([*first, *learners.registered()]))


def first_run(env_id: str, candidates: list[str], size: Size, **names) -> tuple[Any, str]:
    """The first of `candidates` that can run on `env_id` with `names` (attack=, defense=),
    resolved; else (None, why the last one could not)."""
    why = "no learner registered"
    for name in candidates:
        try:
            return resolved_run(env_id, name, size, **names), ""
        except InvalidParameter as error:
            why = str(error)
    return None, why


def _setting(resolved, context: str) -> str:
    return f"{resolved.run.env_id} · {resolved.run.learner} · {context}"


def check_attack(name: str, env_id: str, order: list[str], size: Size, tally) -> Result:
    """The paired run of attack `name` (its hooks counted, with vs without), and each
    hook acting alone."""
    part = f"attack {name}"
    resolved, why = first_run(env_id, order, size, attack=name)
    if resolved is None:
        return Result((), (f"{part}: no learner can run it on {env_id}: {why}",))
    hooks = _own_hooks(resolved.attack, resolved.learner.attack_hooks)
    setting = _setting(resolved, "no defense")

    def build(how: canary_probes.Setting):
        label = f"{part} {setting}"
        counted = canary_probes.instrument(resolved.attack, hooks, tally, label, how)
        return counted, resolved.defenses

    rows = _proved_rows(part, setting, hooks, tally, (resolved, build, size))
    return _hook_result(part, rows)


def check_defense(name: str, env_id: str, order, options: Options, tally) -> Result:
    """The paired runs of defense `name`, and each hook acting alone: clean, and under
    `options.defense_attack`."""
    part, rows, problems = f"defense {name}", [], []
    contexts = [None] + ([options.defense_attack] if options.defense_attack else [])
    for attack in contexts:
        resolved, why = first_run(env_id, order, options.size, attack=attack, defense=name)
        if resolved is None and attack is not None:  # the clean setting is the one required
            rows.append(Row(part, f"{env_id} · under attack {attack}", "-", note=f"skipped: {why}"))
            continue
        if resolved is None:
            problems.append(f"{part}: no learner can run it on {env_id}: {why}")
            continue
        defense = resolved.defenses[0]
        hooks = _own_hooks(defense, resolved.learner.defense_hooks)
        setting = _setting(resolved, f"under attack {attack}" if attack else "clean")

        def build(how, resolved=resolved, defense=defense, hooks=hooks, label=setting):
            counted = canary_probes.instrument(defense, hooks, tally, f"{part} {label}", how)
            return resolved.attack, (counted,)

        rows += _proved_rows(part, setting, hooks, tally, (resolved, build, options.size))
    result = _hook_result(part, rows)
    checked = () if problems else result.checked  # no ok line beside the part's problem
    return Result(result.rows, tuple(problems) + result.problems, checked)


def _own_hooks(obj, consulted: tuple[str, ...]) -> tuple[str, ...]:
    """The hooks an attack or defense lists, and the optional ones it overrides that the
    learner consults (`consulted`)."""
    optional = [h for h in getattr(obj, "optional_hooks", ()) if h in consulted]
    return tuple(dict.fromkeys([*obj.hooks, *optional]))


def _proved_rows(part, setting, hooks, tally, run) -> tuple[Row, ...]:
    """A row per hook: the paired run (every hook's own output vs every no-op's, counted)
    and, with several hooks, one run per hook with only its own output; `run` is
    (resolved, build(Setting) -> (attack, defenses), size)."""
    resolved, build, size = run
    Setting = canary_probes.Setting
    variants = [
        ("with its hooks", lambda: build(Setting(on=True))),
        ("hooks as no-ops", lambda: build(Setting(on=False))),
    ]
    if len(hooks) > 1:
        variants += [
            (
                f"only {hook} acting",
                lambda h=hook: build(Setting(tuple(h == k for k in hooks), count=False)),
            )
            for hook in hooks
        ]
    on, off, *alone = train_variants(resolved, variants, size)
    outcome = Outcome(on.metrics, off.metrics, on.params_moved)
    note = f"success {outcome.success():.2f} vs {outcome.success(False):.2f} without"
    rows = []
    for hook, acted in zip(hooks, alone or [on], strict=True):
        calls, changed = tally.of(f"{part} {setting}", hook)
        used = not acted.same_as(off)
        rows.append(Row(part, setting, hook, calls, changed, outcome.differs, used, note))
    return tuple(rows)


def _hook_result(part: str, rows) -> Result:
    """A hook that never ran in some setting; one whose output never changed in any; one
    whose changed output changed nothing the learner kept or measured. Else what was
    checked, a line."""
    problems = []
    for hook in dict.fromkeys(r.hook for r in rows if r.calls is not None):
        mine = [r for r in rows if r.hook == hook]
        for row in mine:
            if not row.calls:
                problems.append(f"{part}: hook {hook} never ran ({row.setting})")
            elif row.changed and not row.used:
                problems.append(
                    f"{part}: hook {hook} returned something other than doing nothing "
                    f"{row.changed} times, yet with it alone acting the learner ended in the "
                    f"same state with the same metrics as with nothing acting ({row.setting})"
                )
        if all(r.calls for r in mine) and not any(r.changed for r in mine):
            calls = sum(r.calls for r in mine)
            problems.append(
                f"{part}: hook {hook} ran {calls} times and its output never differed from "
                "doing nothing (the base class's output for the same inputs)"
            )
    counted = [r for r in rows if r.calls is not None]
    if problems or not counted:  # nothing checked: no ok line
        return Result(tuple(rows), tuple(problems))
    hooks = ", ".join(dict.fromkeys(r.hook for r in counted))
    settings = "; ".join(dict.fromkeys(r.setting for r in counted))
    checked = (
        f"{part}: each hook ({hooks}) ran, returned something other than doing nothing, and "
        f"acting alone changed the learner's final state or metrics ({settings})"
    )
    return Result(tuple(rows), (), (checked,))


def check_learner(name: str, env_id: str, size: Size, tally) -> Result:
    """Learner `name` trains with probes at every hook point it declares: each is counted,
    and each probe's output perturbed in a run of its own must change the learner's final
    state or metrics."""
    part = f"learner {name}"
    try:
        resolved = resolved_run(env_id, name, size)
    except InvalidParameter as error:
        return Result((), (f"{part}: cannot run on {env_id}: {error}",))
    definition = resolved.learner
    attack_hooks, defense_hooks = definition.attack_hooks, definition.defense_hooks
    hooks = (*attack_hooks, *defense_hooks)

    attack = canary_probes.probe_attack(attack_hooks)  # made once: one program for all runs
    defense = canary_probes.probe_defense(defense_hooks)

    def build(how: canary_probes.Setting):
        counted_attack = canary_probes.instrument(attack, attack_hooks, tally, part, how)
        counted_defense = canary_probes.instrument(defense, defense_hooks, tally, part, how)
        return counted_attack, (counted_defense,) if defense_hooks else ()

    variants = [("probes doing nothing", lambda: build(canary_probes.Setting()))]
    variants += [
        (
            f"{hook}'s output perturbed",
            lambda h=hook: build(canary_probes.Setting(nudge=h, count=False)),
        )
        for hook in hooks
    ]
    base, *nudged = train_variants(resolved, variants, size)
    outcome = Outcome(base.metrics, base.metrics, base.params_moved)
    setting = _setting(resolved, "probes doing nothing")
    rows = [Row(part, setting, "(trains)", note=_trained_note(outcome))]
    for hook, run in zip(hooks, nudged, strict=True):
        calls, _ = tally.of(part, hook)
        note = f"perturbed: {canary_probes.PERTURBED_AS[hook]}"
        rows.append(Row(part, setting, hook, calls, used=not run.same_as(base), note=note))
    problems = _learner_hook_problems(part, rows, size) + _training_problems(part, outcome)
    checked = (
        f"{part}: trained ({_trained_note(outcome)}); consulted every hook point it declares "
        f"({', '.join(hooks)}), and with each one's output perturbed in a run of its own its "
        f"final state or metrics changed ({setting})"
    )
    return Result(tuple(rows), problems, () if problems else (checked,))


def _learner_hook_problems(part: str, rows, size: Size) -> tuple[str, ...]:
    """A hook point declared and never consulted; one consulted whose output is ignored."""
    problems = []
    for row in rows[1:]:
        if row.calls == 0:
            problems.append(f"{part}: declares hook point {row.hook} but never consulted it")
        elif not row.used:
            problems.append(
                f"{part}: consults hook point {row.hook} but ignores what it returns: with its "
                f"output perturbed ({canary_probes.PERTURBED_AS[row.hook]}) the learner's "
                f"state and metrics after {size.iterations} iterations are the same, bit for bit"
            )
    return tuple(problems)


def check_env(env_id: str, order: list[str], size: Size) -> Result:
    """Env `env_id` trains the first learner that runs on it, clean."""
    part = f"env {env_id}"
    resolved, why = first_run(env_id, order, size)
    if resolved is None:
        return Result((), (f"{part}: no learner can run on it: {why}",))
    outcome = paired_run(resolved, lambda on: (resolved.attack, resolved.defenses), size, False)
    setting = _setting(resolved, "clean")
    row = Row(part, setting, "(trains)", note=_trained_note(outcome))
    problems = _training_problems(part, outcome)
    checked = f"{part}: a learner trained on it ({_trained_note(outcome)}; {setting})"
    return Result((row,), problems, () if problems else (checked,))


def _trained_note(outcome: Outcome) -> str:
    moved = "parameters moved" if outcome.params_moved else "parameters did not move"
    finite = "metrics finite" if outcome.finite else "metrics NOT finite"
    return f"{moved}; {finite}; success {outcome.success():.2f}"


def _training_problems(part: str, outcome: Outcome) -> tuple[str, ...]:
    problems = []
    if not outcome.params_moved:
        problems.append(f"{part}: the learner's parameters did not change in training")
    if not outcome.finite:
        problems.append(f"{part}: a metric is not finite (nan or inf)")
    return tuple(problems)


# --- the whole file ----------------------------------------------------------------------


def parts_of(path: str) -> Parts:
    """What the file `path` (loaded already) registered.

    Raises:
        InvalidParameter: it registers nothing.
    """
    parts = registered_in(path)
    if not parts:
        raise InvalidParameter(
            f"check: {path} registers no env, learner, attack or defense "
            "(a plugin calls pimbot's register functions when it is imported)"
        )
    return parts


def describe(parts: Parts) -> str:
    """e.g. "attack adaptive_fake_incentive, env public_goods_game-v0"."""
    named = [
        f"{kind} {name}"
        for kind, names in (
            ("env", parts.envs),
            ("learner", parts.learners),
            ("attack", parts.attacks),
            ("defense", parts.defenses),
        )
        for name in names
    ]
    return ", ".join(named)


def check_file(path: str, options: Options) -> Result:
    """Checks every part registered from `path` (loaded already).

    Raises:
        InvalidParameter: the file registers nothing.
    """
    parts = parts_of(path)
    env_id = options.env or (parts.envs[0] if parts.envs else options.default_env)
    order = learner_order(parts, options)
    tally = canary_probes.Tally()
    results = [check_env(e, order, options.size) for e in parts.envs]
    results += [check_learner(n, env_id, options.size, tally) for n in parts.learners]
    results += [check_attack(a, env_id, order, options.size, tally) for a in parts.attacks]
    results += [check_defense(d, env_id, order, options, tally) for d in parts.defenses]
    rows = tuple(row for r in results for row in r.rows)
    problems = tuple(p for r in results for p in r.problems)
    return Result(rows, problems, tuple(c for r in results for c in r.checked))


def _yes_no(flag: bool | None) -> str:
    return "-" if flag is None else ("yes" if flag else "no")


def table(result: Result) -> str:
    """The rows as an aligned text table."""
    head = ("part", "setting", "hook", "calls", "changed", "run differs", "used", "")
    lines = [head]
    for r in result.rows:
        calls = "-" if r.calls is None else str(r.calls)
        changed = "-" if r.changed is None else str(r.changed)
        differs, used = (_yes_no(r.run_differs), _yes_no(r.used))
        lines.append((r.part, r.setting, r.hook, calls, changed, differs, used, r.note))
    widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
    return "\n".join(
        "  ".join(cell.ljust(w) for cell, w in zip(line, widths, strict=True)).rstrip()
        for line in lines
    )
