"""Where a training program's compile time goes, and XLA CPU options that trade it for run time.

    taskset -c 0 python benchmarks/compile_options.py            # 6 programs, both parts
    taskset -c 0 python benchmarks/compile_options.py --quick    # 3 small programs
    python benchmarks/compile_options.py --programs lio_er21 --no-options   # attribution only

The programs are the quick suite's compiled chunks as `pimbot reproduce --quick` builds
them (`presets.suite(quick=True)`, `resolve`, `runner.program_shape`, the group's
`strategy_union.Strategies` form where the group mixes strategy attacks, else the attack's
program form; `runner.make_chunk_fn(...).trace(...).lower()`, `runner.program_args`):

  lio_er21       LIO, ER(2,1), the strategy attacks' group (attacks/er21_clean)
  lio_er21_admo  LIO, ER(2,1) with ADMO (attacks/er21_admo_disrupt)
  lio_er42       LIO, ER(4,2), the strategy attacks' group (attacks/er42_clean)
  lio_ipd        LIO, IPD, the strategy attacks' group (attacks/ipd_clean)
  rec_er21       Reciprocator, ER(2,1) (reciprocators/rec_er21_clean)
  rec_ipd        Reciprocator, IPD(2), the strategy group (reciprocators/rec_ipd2_clean)

Part 1, attribution (skip with --no-attribution). The chunk is lowered once more with
`jax.named_scope`s around its parts (module functions wrapped while it traces; a scope
only names the ops, the program is otherwise the same): `rollout` (the training
episodes: LIO's τ and τ̂, the Reciprocator's batch), `recipients` (LIO's θ → θ̂ on τ),
`meta_gradient` (LIO's givers' step: the incentive update through the recipients'
updates, evaluated on τ̂, and the cost step), `voi` and `ppo` (the Reciprocator's refit and
policy step), `attack_step` (a learning attack's `adversary_step`, inside the above), and
`evaluate` (the evaluation episodes). The rest (`other`) is the chunk's scan, the
evaluation's reduction, the epsilon schedule, the attack's observe, key splits. It counts
HLO instructions by part before XLA's passes (`lowered.as_text(dialect="hlo")`) and after
them (the compiled module, fused computations included), with the `while` loops and
`dot`s of each part, and it compiles standalone pieces to time them: the whole chunk;
the chunk with the evaluation replaced by zeros of its shape; one `update` (no scan);
one `update` with the meta-gradient step left out (LIO); one training rollout; one
evaluation. Compile times of the pieces are not additive (XLA's passes are superlinear
in places), so read them beside the instruction counts.

Part 2, options (skip with --no-options). Each candidate `compiler_options` dict (XLA
DebugOptions fields, given per compile to `lowered.compile(compiler_options=...)`; an
unknown field raises, so every one here exists in this jaxlib) compiles the runner's
chunk (the unscoped one, as the runner lowers it). Then, interleaved (default, A, B, ...,
default, A, B, ...) so that load on the machine affects all alike, each executable is
called on copies of the same initial states: the first call's outputs (states and metric
rows) are compared leaf by leaf with `numpy.array_equal` against the default compile's
(bit-identical or not; the default executable is called twice as a control), and later
calls (each on its own previous states, as training does) give the seconds per call, the
median; the states after all of them (1 + --repeats calls) must be identical too. An
option that changes results cannot be used in training runs.

Break-even (on CPU seconds of the process, which load on the machine inflates less than
wall seconds): an option saves (compile s − its compile s) and costs calls × (its call s −
call s), so it wins for a group whose planned calls (its jobs' ceil(iterations / (periods
per call × eval period)), summed, as `suite_programs.py` counts them) are below
saving / extra-per-call. A saving within the noise (under the spread of the default's own
compiles, or under 10 %) counts as none, and a faster call as no change. Every quick-suite
group is matched to the measured program of its learner and env family (the Stag Hunt to
the IPD: both small matrix games; the call time scaled to the group's iterations per
call), and the table says which option, if any, is bit-identical and wins for it.
`--json FILE` keeps part 2's measurements, `--from-json FILE` prints its tables again.

The options measured (`OPTIONS`; XLA's defaults: backend optimization level 3, cheap
LLVM passes off, 32 codegen splits, fusion emitters and the concurrency-optimized
scheduler on, inlining before the split on): `O1`, `O0` (LLVM's level),
`cheap_llvm` (`xla_llvm_disable_expensive_passes`), `split1` (one codegen split),
`no_fusion_emitters`, and, with `--options`, `no_concurrency_scheduler`,
`no_inline_before_split`, `O1+cheap_llvm`. This jaxlib has no `xla_cpu_use_thunk_runtime`
or `xla_cpu_use_xla_runtime` (refused as unknown); `xla_cpu_enable_fast_math` stays off.

The persistent compilation cache is off (PIMBOT_CACHE_DIR=off). Pin it to one core
(`taskset -c 0`), as each of the sweep's two workers has one; compile times on an
otherwise loaded machine are upper bounds, the interleaving keeps the comparisons fair.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import re
import statistics
import time
from collections import Counter, defaultdict

os.environ.setdefault("PIMBOT_CACHE_DIR", "off")

PROGRAMS = {
    "lio_er21": "attacks/er21_clean",
    "lio_er21_admo": "attacks/er21_admo_disrupt",
    "lio_er42": "attacks/er42_clean",
    "lio_ipd": "attacks/ipd_clean",
    "rec_er21": "reciprocators/rec_er21_clean",
    "rec_ipd": "reciprocators/rec_ipd2_clean",
}
QUICK = ("lio_ipd", "rec_er21", "rec_ipd")
DEFAULT_OPTIONS = ("default", "O1", "O0", "cheap_llvm", "split1", "no_fusion_emitters")

OPTIONS = {
    "default": {},
    "O1": {"xla_backend_optimization_level": 1},
    "O0": {"xla_backend_optimization_level": 0},
    "cheap_llvm": {"xla_llvm_disable_expensive_passes": True},
    "O1+cheap_llvm": {  # not in the default list (O1 alone changes results)
        "xla_backend_optimization_level": 1,
        "xla_llvm_disable_expensive_passes": True,
    },
    "split1": {"xla_cpu_parallel_codegen_split_count": 1},  # XLA's default: 32
    "no_concurrency_scheduler": {"xla_cpu_enable_concurrency_optimized_scheduler": False},
    "no_inline_before_split": {"xla_llvm_force_inline_before_split": False},
    "no_fusion_emitters": {"xla_cpu_use_fusion_emitters": False},
}
PARTS = ("evaluate", "attack_step", "meta_gradient", "recipients", "voi", "ppo", "rollout")
"""Scopes, the first found in an op's name wins (an attack's step runs inside LIO's
meta-gradient step, the evaluation's episodes are rollouts too)."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help=f"only {', '.join(QUICK)}")
    parser.add_argument("--programs", help=f"comma-separated, of {', '.join(PROGRAMS)}")
    parser.add_argument("--options", help=f"comma-separated, of {', '.join(OPTIONS)}")
    parser.add_argument("--repeats", type=int, default=3, help="timed calls per option")
    parser.add_argument(
        "--compile-rounds", type=int, default=2, help="compiles per option (the fastest counts)"
    )
    parser.add_argument("--no-attribution", action="store_true", help="skip part 1")
    parser.add_argument("--no-options", action="store_true", help="skip part 2")
    parser.add_argument("--chunk-iterations", type=int, default=2000)
    parser.add_argument("--json", help="also write part 2's measurements to this file")
    parser.add_argument(
        "--from-json", help="instead: print part 2's tables from a file --json wrote"
    )
    args = parser.parse_args()
    if args.from_json:
        import json
        from pathlib import Path

        saved = json.loads(Path(args.from_json).read_text())
        summary(saved["results"], saved["options"])
        break_even(Plan(args.chunk_iterations), saved["results"], saved["options"])
        return
    names = args.programs.split(",") if args.programs else list(QUICK if args.quick else PROGRAMS)
    options = ["default"] + [
        o for o in (args.options.split(",") if args.options else DEFAULT_OPTIONS) if o != "default"
    ]
    for name in names + options:
        if name not in PROGRAMS and name not in OPTIONS:
            parser.error(f"unknown program or option {name!r}")

    from pimbot import jax_setup

    jax_setup.unroll_cpu_threefry()  # the programs `pimbot train` and the sweep compile
    warm_up()
    load = os.getloadavg()
    print(f"load average at the start: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    plan = Plan(args.chunk_iterations)
    results: dict[str, dict] = {}
    for name in names:
        program = plan.program(PROGRAMS[name])
        print(f"\n=== {name}: {program.describe()}", flush=True)
        if not args.no_attribution:
            attribution(program)
        if not args.no_options:
            results[name] = compare_options(program, options, args.repeats, args.compile_rounds)
    if results and args.json:
        import json

        with open(args.json, "w") as f:
            json.dump({"options": options, "results": results}, f, indent=1)
    if results:
        summary(results, options)
        break_even(plan, results, options)
    load = os.getloadavg()
    print(f"\nload average at the end: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")


def tiny_program():
    """A scan of a matmul, lowered."""
    import jax
    import jax.numpy as jnp

    f = jax.jit(lambda x: jax.lax.scan(lambda c, _: (jnp.tanh(c @ c), None), x, None, 3)[0])
    return f.lower(jnp.ones((8, 8)))


def warm_up() -> None:
    """One small compile first, so that no timed compile pays the process's first one."""
    tiny_program().compile()


@dataclasses.dataclass
class Program:
    job: str
    resolved: object  # the ResolvedRun in its program form
    periods: int
    seeds: int
    calls: int  # the group's planned calls
    group: int
    group_jobs: int

    def describe(self) -> str:
        r = self.resolved
        env = r.run.env_id + "".join(f" {k}={v}" for k, v in r.run.env_params)
        return (
            f"{r.run.learner} {env}, attack {r.attack.name}, {self.periods}×{r.eval_period} "
            f"it/call, {self.seeds} seeds; group [{self.group}] of {self.group_jobs} job(s), "
            f"{self.calls} planned calls"
        )


class Plan:
    """The quick suite's training jobs grouped as the sweep groups them."""

    def __init__(self, chunk_iterations: int):
        from pimbot.suites import presets
        from pimbot.suites.jobs import JobOptions
        from pimbot.suites.sweep import groups
        from pimbot.training import runner
        from pimbot.training.config import resolve

        self.chunk_iterations = chunk_iterations
        jobs = [j for j in presets.suite(quick=True) if j.kind == "train"]
        self.resolved = {j.name: resolve(j.spec) for j in jobs}
        self.shape = {
            n: runner.program_shape(r, chunk_iterations, False, 1) for n, r in self.resolved.items()
        }
        self.tasks = groups(jobs, JobOptions(chunk_iterations=chunk_iterations), 1)

    def calls(self, task) -> int:
        periods = self.shape[task[0].name][0]
        period = self.resolved[task[0].name].eval_period
        return sum(-(-j.spec.iterations // (periods * period)) for j in task)

    def program(self, job_name: str) -> Program:
        from pimbot.suites.jobs import train_strategies
        from pimbot.training import runner

        number, task = next((i, t) for i, t in enumerate(self.tasks) if job_name in names_of(t))
        strategies = train_strategies([j.spec for j in task]) if len(task) > 1 else None
        resolved = runner.program_of(self.resolved[job_name], strategies)
        periods, seeds = self.shape[job_name]
        return Program(job_name, resolved, periods, seeds, self.calls(task), number, len(task))

    def family(self, task) -> str:
        """The measured program standing for `task`'s group."""
        r = self.resolved[task[0].name]
        learner = "lio" if r.run.learner == "lio" else "rec"
        n = dict(r.run.env_params).get("n_agents", 2)
        escape_room = r.run.env_id.startswith("escape_room")
        # the IPD and the Stag Hunt: small matrix games
        env = ("er21" if n == 2 else "er42") if escape_room else "ipd"
        if learner == "rec" and env == "er42":
            env = "er21"
        admo = learner == "lio" and env == "er21" and "admo" in r.attack.name
        return f"{learner}_{env}" + ("_admo" if admo else "")


def names_of(task) -> list[str]:
    return [j.name for j in task]


# ----------------------------------------------------------------------------- building


def initial(program: Program):
    """(states, evaluation roots, program args) as the runner makes them."""
    import jax

    from pimbot.training import runner

    r = program.resolved
    keys = runner.seed_keys(r.run.first_seed, program.seeds)
    args = runner.program_args(r)
    init_keys = jax.vmap(lambda k: jax.random.fold_in(k, 0))(keys)
    states = jax.block_until_ready(runner.make_init_fn(r)(init_keys, *args))
    roots = jax.vmap(lambda k: jax.random.fold_in(k, 1))(keys)
    return states, roots, args


def lower_chunk(resolved, periods: int, inputs):
    from pimbot.training import runner

    states, roots, args = inputs
    return runner.make_chunk_fn(resolved, periods).trace(states, roots, *args).lower()


def lower_piece(resolved, piece, inputs):
    """`piece(state, eval_root, attack, defenses, env, numbers, cfg)` of one seed, vmapped
    over the seeds and jitted as the runner's chunk is (no donation)."""
    import jax

    states, roots, args = inputs

    def one_seed(state, eval_root, attack, defenses, env, numbers, cfg):
        env = resolved.env if env is None else env
        cfg = resolved.learner_config if cfg is None else cfg
        return piece(state, eval_root, attack, defenses, env, numbers, cfg)

    shared = (0, 0, None, None, None, None, None)
    return jax.jit(jax.vmap(one_seed, in_axes=shared)).trace(states, roots, *args).lower()


def scoped(fn, name: str):
    import functools

    import jax

    @functools.wraps(fn)
    def wrapped(*a, **k):
        with jax.named_scope(name):
            return fn(*a, **k)

    return wrapped


@contextlib.contextmanager
def patched(targets: list[tuple[object, str, object]]):
    """Sets attribute `name` of each `owner` to `value` while the block runs."""
    saved = [(owner, name, vars(owner).get(name, _ABSENT)) for owner, name, _ in targets]
    try:
        for owner, name, value in targets:
            setattr(owner, name, value)
        yield
    finally:
        for owner, name, value in saved:
            if value is _ABSENT:  # inherited: the class's own attribute goes again
                delattr(owner, name)
            else:
                setattr(owner, name, value)


_ABSENT = object()


def scope_targets(resolved) -> list[tuple[object, str, object]]:
    from pimbot.learners import lio, reciprocator

    named = [
        (lio, "play", "rollout"),
        (lio, "recipients_step", "recipients"),
        (lio, "givers_step", "meta_gradient"),
        (lio, "evaluate_actor", "evaluate"),
        (reciprocator, "play_batch", "rollout"),
        (reciprocator, "influence_step", "voi"),
        (reciprocator, "ppo_step", "ppo"),
        (reciprocator, "adversary_turn", "attack_step"),
        (reciprocator, "evaluate_actor", "evaluate"),
    ]
    targets = [(owner, name, scoped(getattr(owner, name), part)) for owner, name, part in named]
    attack_cls = type(resolved.attack)
    if "adversary_step" in resolved.attack.hooks:
        step = getattr(attack_cls, "adversary_step", None)
        if step is not None:  # set on the class itself (removed again after)
            targets.append((attack_cls, "adversary_step", scoped(step, "attack_step")))
    return targets


def without_meta_gradient(env, cfg, attack, state, traj, new_traj, new_policy, *rest):
    """LIO's givers' step left out: η and the optimizers unchanged (the second rollout is
    kept alive through env_steps)."""
    del env, cfg, attack, traj, new_traj, rest
    opts = (state.incentive_opt, state.cost_opt)
    return state.incentive, opts, new_policy, state.attack_state, {}


# ----------------------------------------------------------------------------- part 1

INSTRUCTION = re.compile(r"^\s*(?:ROOT\s+)?%?[\w.\-]+\s*=\s*\S+.*?\s([a-z][\w\-]*)\(")
OP_NAME = re.compile(r'op_name="([^"]*)"')
LOC_DEF = re.compile(r"^#(loc\d*) = loc\((.*)\)\s*$")
MLIR_OP = re.compile(r"\b(?:stablehlo|chlo|func|mhlo|sdy|shardy)\.([a-z_]+)")
CALL = re.compile(r'(?:func\.)?call @("[^"]+"|[\w.$-]+)\(')
FUNC = re.compile(r'func\.func\s+(?:public\s+|private\s+)?@("[^"]+"|[\w.$-]+)')
LOC_USE = re.compile(r"loc\(#(loc\d*)\)")


def part_of(op_name: str | None) -> str:
    if op_name is None:
        return "(no metadata)"
    for part in PARTS:
        if re.search(rf"(?<![\w]){part}(?![\w])", op_name):
            return part
    return "other"


def count_hlo(text: str) -> dict[str, Counter]:
    """part -> Counter(instructions, while, dot, ...) over every computation of an HLO
    module's text (the compiled module: each instruction's metadata op_name)."""
    counts: dict[str, Counter] = defaultdict(Counter)
    for line in text.splitlines():
        m = INSTRUCTION.match(line)
        if not m:
            continue
        opcode = m.group(1)
        name = OP_NAME.search(line)
        part = part_of(name.group(1) if name else None)
        counts[part]["instructions"] += 1
        if opcode in ("while", "dot", "fusion", "call", "custom-call", "conditional"):
            counts[part][opcode] += 1
    return counts


def count_stablehlo(text: str) -> dict[str, Counter]:
    """The same for a lowered module's StableHLO with debug info (`as_text(debug_info=True)`:
    every op's location names its op_name), with every `call` inlined as XLA inlines it:
    a private function's ops count once per call site, under the call site's name (a
    function's own locations name only the scopes inside it). A region op (while, case)
    carries its location after its region: it is counted by its closing line's."""
    defs = {}
    for line in text.splitlines():
        m = LOC_DEF.match(line)
        if m:
            defs[m.group(1)] = m.group(2)

    def name_of(loc: str | None, depth: int = 0) -> str | None:
        body = defs.get(loc) if loc else None
        if body is None or depth > 50:
            return None
        if body.startswith('"'):
            return body[1 : body.index('"', 1)]
        for inner in re.findall(r"#(loc\d*)", body):
            found = name_of(inner, depth + 1)
            if found is not None:
                return found
        return None

    # function -> [(opcode, its own op name, callee or None)]
    functions: dict[str, list[tuple[str, str | None, str | None]]] = defaultdict(list)
    current = None
    pending: list[tuple[str, str | None]] = []  # ops whose location comes with their closing line
    for line in text.splitlines():
        if line.startswith("#loc"):
            continue
        use = LOC_USE.findall(line)
        m = MLIR_OP.search(line)
        call = CALL.search(line)
        opcode = "call" if call else (m.group(1) if m else None)
        if opcode == "func":
            current = FUNC.search(line).group(1)
            pending.append(("func", None))
        elif opcode is not None:
            if opcode == "return":
                continue
            callee = call.group(1) if call else None
            if use:
                functions[current].append((opcode, name_of(use[-1]), callee))
            else:
                pending.append((opcode, callee))
        elif pending and line.lstrip().startswith("}") and use:
            opcode, callee = pending.pop()
            if opcode != "func":
                functions[current].append((opcode, name_of(use[-1]), callee))

    counts: dict[str, Counter] = defaultdict(Counter)

    def expand(function: str, prefix: str, depth: int = 0) -> None:
        for opcode, own, callee in functions.get(function, ()):
            name = "/".join(x for x in (prefix, own) if x) or None
            if callee is not None and depth < 64:
                expand(callee, name or "", depth + 1)
                continue
            part = part_of(name)
            counts[part]["instructions"] += 1
            opcode = "dot" if opcode == "dot_general" else opcode
            if opcode in ("while", "dot", "case"):
                counts[part][opcode] += 1

    expand("main", "")
    counts["_functions"]["instructions"] = len(functions)
    counts["_functions"]["ops"] = sum(len(v) for v in functions.values())
    return counts


def timed_compile(lowered, options: dict | None = None):
    """(the executable, wall seconds, CPU seconds of the process: every thread's)."""
    t0, c0 = time.perf_counter(), time.process_time()
    compiled = lowered.compile(compiler_options=options) if options else lowered.compile()
    return compiled, time.perf_counter() - t0, time.process_time() - c0


def attribution(program: Program) -> None:
    import jax
    import jax.numpy as jnp

    from pimbot.learners import lio

    r = program.resolved
    learner = r.learner
    inputs = initial(program)
    is_lio = r.run.learner == "lio"

    with patched(scope_targets(r)):
        t0 = time.perf_counter()
        lowered = lower_chunk(r, program.periods, inputs)
        lower_s = time.perf_counter() - t0
    before = count_stablehlo(lowered.as_text(debug_info=True))
    compiled, chunk_s, chunk_cpu = timed_compile(lowered)
    after = count_hlo(compiled.as_text())
    del compiled
    functions = before.pop("_functions", Counter())
    total_before = sum(c["instructions"] for c in before.values())
    total_after = sum(c["instructions"] for c in after.values())
    print(
        f"  chunk traced+lowered in {lower_s:.1f} s, compiled in {chunk_s:.1f} s "
        f"({chunk_cpu:.1f} s CPU)"
    )
    print(
        "  HLO by part: ops before XLA's passes (share), instructions after them (share); "
        "while loops and dots before (after)"
    )
    print(f"    {'part':<14} {'before':>7} {'%':>5} {'after':>7} {'%':>5} {'while':>9} {'dot':>9}")
    for part in (*PARTS, "other", "(no metadata)"):
        b, a = before.get(part, Counter()), after.get(part, Counter())
        if not b and not a:
            continue
        print(
            f"    {part:<14} {b['instructions']:>7} {b['instructions'] / total_before:>5.0%} "
            f"{a['instructions']:>7} {a['instructions'] / total_after:>5.0%} "
            f"{b['while']:>4} ({a['while']:>2}) {b['dot']:>4} ({a['dot']:>2})"
        )
    print(f"    {'total':<14} {total_before:>7} {'':>5} {total_after:>7}")
    print(
        f"    (before: calls inlined; the StableHLO text itself has {functions['ops']} ops "
        f"in {functions['instructions']} functions)"
    )

    def zeros_like_shape(fn):
        def stub(key, state, *rest):
            shapes = jax.eval_shape(lambda k, s: fn(k, s, *rest), key, state)
            return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)

        return stub

    no_eval = dataclasses.replace(
        r, learner=dataclasses.replace(learner, evaluate=zeros_like_shape(learner.evaluate))
    )

    def update(state, root, attack, defenses, env, numbers, cfg):
        return learner.update(state, env, cfg, attack, defenses)

    def evaluate(state, root, attack, defenses, env, numbers, cfg):
        key = jax.random.fold_in(root, state.iteration)
        return learner.evaluate(key, state, env, cfg, r.eval_episodes, attack)

    def rollout(state, root, attack, defenses, env, numbers, cfg):
        if is_lio:
            return lio.play(
                env, cfg, attack, state, state.policy, jnp.float32(0.1), root, state.env_steps
            )
        from pimbot.learners import reciprocator

        return reciprocator.play_batch(
            env, cfg, state.policy, root, attack, state.env_steps, state.attack_state
        )

    pieces = [
        ("chunk, evaluation left out", lambda: lower_chunk(no_eval, program.periods, inputs)),
        ("one update", lambda: lower_piece(r, update, inputs)),
    ]
    if is_lio:

        def update_no_meta():
            with patched([(lio, "givers_step", without_meta_gradient)]):
                return lower_piece(r, update, inputs)

        pieces.append(("one update, meta-gradient left out", update_no_meta))
    pieces += [
        ("one training rollout", lambda: lower_piece(r, rollout, inputs)),
        (f"one evaluation ({r.eval_episodes} episodes)", lambda: lower_piece(r, evaluate, inputs)),
    ]
    _, tiny_s, tiny_cpu = timed_compile(tiny_program())
    print(
        f"  compile s of standalone pieces (the whole chunk: {chunk_s:.1f} s, "
        f"{chunk_cpu:.1f} s CPU; a trivial program, the fixed cost of a compile: "
        f"{tiny_s:.2f} s, {tiny_cpu:.2f} s CPU)"
    )
    for label, make in pieces:
        piece = make()
        counted = count_stablehlo(piece.as_text(debug_info=True))
        counted.pop("_functions", None)
        size = sum(c["instructions"] for c in counted.values())
        _, seconds, cpu = timed_compile(piece)
        print(
            f"    {label:<40} {seconds:>6.1f} s ({cpu:>5.1f} s CPU)  {size:>6} StableHLO ops "
            "(calls inlined)",
            flush=True,
        )


# ----------------------------------------------------------------------------- part 2


def leaves_equal(a, b) -> tuple[bool, int, float]:
    """(every leaf bit-identical, leaves that differ, largest relative difference)."""
    import jax
    import numpy as np

    differ, worst = 0, 0.0
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        x, y = np.asarray(x), np.asarray(y)
        if not np.array_equal(x, y, equal_nan=True):
            differ += 1
            if np.issubdtype(x.dtype, np.floating):
                scale = np.maximum(np.abs(x), np.abs(y))
                rel = np.abs(x - y) / np.where(scale > 0, scale, 1)
                worst = max(worst, float(np.nanmax(rel)))
            else:
                worst = max(worst, float("inf"))
    return differ == 0, differ, worst


def compare_options(program: Program, options: list[str], repeats: int, rounds: int) -> dict:
    import jax
    import jax.numpy as jnp

    inputs = initial(program)
    states0, roots, args = inputs
    compiled, walls, cpus = {}, defaultdict(list), defaultdict(list)
    # a fresh lowering each, as a fresh process would compile; `rounds` rounds, interleaved
    # (default, A, B, ..., default, A, B, ...): the fastest of each option's compiles
    for round_ in range(rounds):
        for name in options:
            lowered = lower_chunk(program.resolved, program.periods, inputs)
            try:
                executable, wall, cpu = timed_compile(lowered, OPTIONS[name])
            except Exception as error:  # an option this jaxlib refuses
                print(f"  {name}: refused: {str(error).splitlines()[0]}")
                continue
            compiled.setdefault(name, executable)
            walls[name].append(wall)
            cpus[name].append(cpu)
            print(
                f"  compile {round_ + 1}: {name:<20} {wall:6.1f} s ({cpu:5.1f} s CPU)", flush=True
            )
    names = [n for n in options if n in compiled]

    def fresh():
        return jax.tree.map(jnp.copy, states0)

    first, states, times, call_cpus = {}, {}, defaultdict(list), defaultdict(list)
    for name in names:  # the first call of each from the same initial states
        out = compiled[name](fresh(), roots, *args)
        first[name] = jax.device_get(out)
        states[name] = out[0]
    control = jax.device_get(compiled["default"](fresh(), roots, *args))
    for _ in range(repeats):  # interleaved: default, A, B, ..., default, A, B, ...
        for name in names:
            t0, c0 = time.perf_counter(), time.process_time()
            out = compiled[name](states[name], roots, *args)
            jax.block_until_ready(out)
            times[name].append(time.perf_counter() - t0)
            call_cpus[name].append(time.process_time() - c0)
            states[name] = out[0]
    rows = {}
    same, _, _ = leaves_equal(first["default"], control)
    print(f"  default called twice on the same states: bit-identical {same}")
    print(
        f"    {'option':<26} {'compile s':>9} {'CPU s':>7} {'call s':>8} {'CPU s':>7} "
        f"{'bit-identical':>14}  (differing leaves, largest relative difference)"
    )
    last = {name: jax.device_get(states[name]) for name in names}  # after 1 + repeats calls
    for name in names:
        identical, differ, worst = leaves_equal(first["default"], first[name])
        identical = identical and leaves_equal(last["default"], last[name])[0]
        rows[name] = {
            "compile": min(walls[name]),
            "compile_cpu": min(cpus[name]),
            "call": statistics.median(times[name]),
            "call_cpu": statistics.median(call_cpus[name]),
            "identical": identical,
        }
        row = rows[name]
        note = "" if identical else f"  ({differ} leaves, {worst:.2g})"
        print(
            f"    {name:<26} {row['compile']:>9.1f} {row['compile_cpu']:>7.1f} "
            f"{row['call']:>8.3f} {row['call_cpu']:>7.3f} "
            f"{'yes' if identical else 'NO':>14}{note}",
            flush=True,
        )
    rows["_noise"] = max(cpus["default"]) - min(cpus["default"])
    rows["_calls"] = program.calls
    rows["_iterations"] = program.periods * program.resolved.eval_period
    return rows


def summary(results: dict, options: list[str]) -> None:
    print("\ncompile CPU s / call CPU s / bit-identical, option × program")
    names = list(results)
    print(f"  {'option':<26}" + "".join(f" {n:>22}" for n in names))
    for option in options:
        cells = []
        for n in names:
            row = results[n].get(option)
            if row is None:
                cells.append("—")
                continue
            same = "yes" if row["identical"] else "NO"
            cells.append(f"{row['compile_cpu']:.1f} / {row['call_cpu']:.3f} / {same}")
        print(f"  {option:<26}" + "".join(f" {c:>22}" for c in cells))


def saving(rows: dict, option: str, calls: int, scale: float = 1.0) -> float | None:
    """CPU seconds `option` saves over the default for `calls` calls of the program (call
    times × `scale`), or None where its compile saving is within the noise: below the
    spread of the default's own compiles or 10 % of its compile. A faster call is not
    counted (noise too, at these loads), a slower one is."""
    base, row = rows["default"], rows[option]
    saved = base["compile_cpu"] - row["compile_cpu"]
    if saved <= max(rows["_noise"], 0.1 * base["compile_cpu"]):
        return None
    return saved - calls * scale * max(row["call_cpu"] - base["call_cpu"], 0.0)


def break_even(plan: Plan, results: dict, options: list[str]) -> None:
    """Per option and measured program the break-even calls; per quick-suite group the
    options (bit-identical only) that win with its planned calls, and the seconds saved."""
    print(
        "\nbreak-even calls (compile CPU s saved / extra CPU s per call; 'noise' where the "
        "saving is within the default's own spread or under 10 %; 'always' where no slower)"
    )
    for name, rows in results.items():
        base = rows["default"]
        cells = []
        for option in options[1:]:
            row = rows.get(option)
            if row is None:
                continue
            extra = row["call_cpu"] - base["call_cpu"]
            if saving(rows, option, 0) is None:
                verdict = "noise"
            elif extra <= 0:
                verdict = "always"
            else:
                verdict = f"{(base['compile_cpu'] - row['compile_cpu']) / extra:.0f}"
            flag = "" if row["identical"] else "*"
            cells.append(f"{option}{flag} {verdict}")
        print(
            f"  {name:<14} (its group: {rows['_calls']} calls; default's compile spread "
            f"{rows['_noise']:.1f} s): " + "; ".join(cells)
        )
    print("  (* results not bit-identical: unusable whatever the break-even)")

    print(
        "\nper quick-suite group: planned calls, its measured stand-in (its call s scaled to"
        " the group's iterations per call), the best bit-identical option beyond the noise"
    )
    total_saved = 0.0
    for number, task in enumerate(plan.tasks):
        family = plan.family(task)
        calls = plan.calls(task)
        rows = results.get(family)
        if rows is None:
            print(f"  [{number:2d}] {calls:4d} calls  {family:<14} (not measured)")
            continue
        first = plan.resolved[task[0].name]
        scale = plan.shape[task[0].name][0] * first.eval_period / rows["_iterations"]
        best, best_gain = "default", 0.0
        for option in options[1:]:
            if option not in rows or not rows[option]["identical"]:
                continue
            gain = saving(rows, option, calls, scale)
            if gain is not None and gain > best_gain:
                best, best_gain = option, gain
        total_saved += best_gain
        print(
            f"  [{number:2d}] {calls:4d} calls  {family:<14} {best:<24} "
            f"saves {best_gain:6.1f} s  ({task[0].name}, {len(task)} job(s))"
        )
    print(f"  estimated saving over the quick suite's groups: {total_saved:.0f} s of one core")


if __name__ == "__main__":
    main()
