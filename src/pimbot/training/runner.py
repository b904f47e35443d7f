"""Training runs: vmapped seeds, `lax.scan` chunks, evaluation, checkpoint/resume.

Seeds are a batch axis (sharded over the available devices — on a CPU the
host is split into one device per core); a chunk of `evals_per_chunk`
evaluation periods is one compiled call (with a progress display, a few queued
calls of `periods_per_call`, so the bar moves within a chunk). After each chunk
the metric rows are appended, the learner state is checkpointed and the rows go
to the tracking backends, so a killed run resumes from the last chunk with
identical results: all randomness lives in the state, and the same periods give
the same numbers however they are split into calls.

One run has four shapes, each made once and passed on:
* the `pimbot train` command (`cli.commands.Train`): the options as typed;
* `RunConfig`: what to run, in plain values (a suite job's spec, config.json's
  `run_config`, what `--from` reloads);
* `ResolvedRun` (`config.resolve`): the run validated, with its env, learner config,
  attack and defenses as objects; its `identity` is what a resume must match;
* the program (`program_of`): the ResolvedRun as its compiled chunk runs it, the attack in
  its program form, so that runs differing only in numbers share one compiled program.
`check` makes the checks before anything is written (the tracking clients, `resolve`,
`check_run_dir`), once: a caller that makes them itself (the command line, before it
starts the audit log) passes its ResolvedRun to `train` with `checked=True`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any

import flax.serialization
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

import pimbot
from pimbot import plugins
from pimbot.attacks import strategy_union
from pimbot.contracts import preflight
from pimbot.contracts.attack import STATE_METRICS, state_metric_prefix, state_metrics
from pimbot.contracts.learner import program_config
from pimbot.envs.core import InvalidParameter, program_env
from pimbot.training import programs, provenance, store, tracking
from pimbot.training.config import ResolvedRun, RunConfig, env_parameters, resolve
from pimbot.training.progress import CompileNotice, Progress
from pimbot.training.summary import summarize

TARGET_CHUNK_ITERATIONS = 2000
CALL_ITERATIONS = 500
"""Iterations per compiled call, at least, while a progress display is on (a call costs
~1.5 ms on a CPU: under 1 % of 500 iterations; 500 iterations take 5 s at 100 it/s)."""


class RunDirConflict(InvalidParameter):
    """The output directory holds a different run."""


class Diverged(RuntimeError):
    """A run produced a non-finite metric or parameter; its last finite checkpoint is kept."""


OWN_STATES = (".attack_state", ".defense_state")
"""State fields an attack or defense owns; they may hold non-finite sentinels (e.g. an
empty history), so only the learner's own parameters and optimizer states are checked."""
UNCHECKED_COLUMNS = ("perf/", STATE_METRICS)
"""metrics.csv columns a non-finite value of which is no divergence: timings, and the
numbers an attack reports of its own state (`Attack.metrics`, which may be a sentinel)."""


def first_non_finite(rows: list[dict[str, Any]], host_states) -> str | None:
    """Where a chunk first stops being finite: "iteration I, seed S: COLUMN = nan" (the
    earliest evaluation row), or "the learner state: LEAF" when only a parameter or an
    optimizer state is; None when everything is finite."""
    for row in sorted(rows, key=lambda r: (r["iteration"], r["seed"])):
        for column, value in row.items():
            if not column.startswith(UNCHECKED_COLUMNS) and not math.isfinite(value):
                return f"iteration {row['iteration']}, seed {row['seed']}: {column} = {value}"
    leaves = jax.tree_util.tree_leaves_with_path(host_states)
    for path, leaf in leaves:
        where = jax.tree_util.keystr(path)
        if where.startswith(OWN_STATES):  # an attack's or defense's own bookkeeping
            continue
        leaf = np.asarray(leaf)
        if np.issubdtype(leaf.dtype, np.floating) and not np.isfinite(leaf).all():
            return f"the learner state: {where} is not finite"
    return None


@dataclasses.dataclass(frozen=True)
class TrainResult:
    run_dir: Path
    summary: dict[str, Any]
    already_finished: bool


def seed_keys(first_seed: int, count: int) -> jax.Array:
    """Per-seed root keys; seed s always gets the same key, whatever the batch."""
    return jax.vmap(jax.random.PRNGKey)(jnp.arange(first_seed, first_seed + count))


def seed_sharding(num_seeds: int) -> tuple[NamedSharding | None, int]:
    """Sharding of the seed axis over all devices, and the padded number of seeds."""
    devices = jax.devices()
    if len(devices) == 1:
        return None, num_seeds
    padded = math.ceil(num_seeds / len(devices)) * len(devices)
    return NamedSharding(Mesh(np.array(devices), ("seeds",)), PartitionSpec("seeds")), padded


def evals_per_chunk(num_evals: int, eval_period: int, target: int = TARGET_CHUNK_ITERATIONS) -> int:
    """Largest divisor of num_evals whose chunk stays within `target` iterations (≥ 1)."""
    best = 1
    for k in range(1, min(num_evals, target // eval_period) + 1):  # k·period ≤ target
        if num_evals % k == 0:
            best = k
    return best


def reduce_eval(
    env, per_episode: dict[str, jax.Array], adversary: int, numbers: dict
) -> dict[str, jax.Array]:
    """Means over evaluation episodes, the adversary's margins, and, where the optimum
    team return is known, the return ratio and the optimal rate (the optimum and the
    threshold from `numbers`, the program's `programs.optimum_numbers`)."""
    out = {name: value.mean(axis=0) for name, value in per_episode.items()}
    others = jnp.arange(env.num_agents) != adversary
    for name in ("return_env", "return_total"):
        values = out[name]
        margin = values[adversary] - jnp.sum(values * others) / (env.num_agents - 1)
        out[f"adversary_margin_{name.removeprefix('return_')}"] = margin
    if "optimal_threshold" in numbers:
        out["return_ratio"] = out["team_return"] * numbers["optimal_team_return_reciprocal"]
        threshold = numbers["optimal_threshold"]
        out["optimal_rate"] = (per_episode["team_return"] >= threshold).mean()
    return out


def make_chunk_fn(resolved: ResolvedRun, num_periods: int):
    """A jitted function running `num_periods` evaluation periods for every seed.

    The attack, the defenses, the env (`envs.core.program_env`), its optimum's numbers
    (`programs.optimum_numbers`) and the learner config (`contracts.learner.program_config`)
    are arguments, not constants: pytrees whose numeric leaves are traced and whose
    structure is static, so runs that differ only in numbers share the program. (An env
    or a config without traced numbers is passed as None and closed over.)

    Each evaluation row holds the evaluation's means ("eval"), the period's mean training
    metrics ("train") and the attack's metrics of its state ("attack", `state_metrics`).

    Returns fn(states [S], eval_roots [S], attack, defenses, env, optimum numbers, config)
    -> (states, metrics with leaves [S, num_periods, ...]).
    """
    learner = resolved.learner

    def one_seed(state, eval_root, attack, defenses, env, numbers, cfg):
        env = resolved.env if env is None else env
        cfg = resolved.learner_config if cfg is None else cfg

        def period(state, _):
            state, train = jax.lax.scan(
                lambda s, _: learner.update(s, env, cfg, attack, defenses),
                state,
                None,
                length=resolved.eval_period,
            )
            eval_key = jax.random.fold_in(eval_root, state.iteration)
            per_episode = learner.evaluate(
                eval_key, state, env, cfg, resolved.eval_episodes, attack
            )
            row = {
                "iteration": state.iteration,
                "eval": reduce_eval(env, per_episode, attack.adversary, numbers),
                "train": jax.tree.map(lambda x: x.mean(axis=0), train),
                "attack": state_metrics(attack, state, env.num_agents),
            }
            return state, row

        return jax.lax.scan(period, state, None, length=num_periods)

    # the states are donated: a chunk updates them in place (the caller keeps only the result)
    shared = (0, 0, None, None, None, None, None)
    return jax.jit(jax.vmap(one_seed, in_axes=shared), donate_argnums=0)


def make_init_fn(resolved: ResolvedRun):
    """A jitted fn(init_keys [S], attack, defenses, env, optimum numbers, config) -> every
    seed's initial state [S, ...] (the arguments of `make_chunk_fn`)."""
    learner = resolved.learner

    def init(key, attack, defenses, env, numbers, cfg):
        del numbers  # the chunk's (one argument list for both)
        env = resolved.env if env is None else env
        cfg = resolved.learner_config if cfg is None else cfg
        return learner.init(key, env, cfg, attack, defenses)

    return jax.jit(jax.vmap(init, in_axes=(0, None, None, None, None, None)))


def program_args(resolved: ResolvedRun) -> tuple:
    """What a run passes its compiled init and chunk besides keys and states: (attack,
    defenses, env, optimum numbers, learner config), pytrees whose numbers are the programs'
    traced arguments."""
    env = resolved.env
    return (
        resolved.attack,
        resolved.defenses,
        program_env(env),
        programs.optimum_numbers(env),
        program_config(resolved.learner_config),
    )


def init_states(resolved: ResolvedRun, init_keys: jax.Array):
    """Every seed's initial learner state [S, ...]."""
    return make_init_fn(resolved)(init_keys, *program_args(resolved))


@dataclasses.dataclass
class ProgramCache:
    """Compiled programs kept across runs (a sweep worker keeps one for all its jobs):
    runs with one `programs.program_key` share the init fn and the compiled chunk."""

    entries: dict[str, list] = dataclasses.field(default_factory=dict)
    """key -> [jitted init fn, compiled chunk (None until first lowered)]."""
    compiled: list[tuple[str, float]] = dataclasses.field(default_factory=list)
    """(key, seconds to trace, lower and compile it) of every program compiled here (a
    persistent-cache hit counts: the process still traces, lowers and loads it)."""
    reused: int = 0
    """Runs that found their program already compiled here."""

    def entry(self, resolved: ResolvedRun, periods: int, seeds: int, sharding):
        devices = 1 if sharding is None else sharding.mesh.devices.size
        key = programs.program_key(resolved, periods, seeds, devices)
        if key not in self.entries:
            self.entries[key] = [make_init_fn(resolved), None]
        return key, self.entries[key]


def metric_rows(resolved: ResolvedRun, chunk_metrics, seeds: list[int], perf: dict) -> list[dict]:
    """Flattens chunk metrics [S, E, ...] into CSV rows, one per seed × evaluation point
    (the attack's state metrics under `attack/<its name>/`)."""
    host = jax.device_get(chunk_metrics)
    n = resolved.env.num_agents
    groups = (
        ("eval", "eval/"),
        ("train", ""),
        ("attack", state_metric_prefix(resolved.attack.name)),
    )
    rows = []
    for s, seed in enumerate(seeds):
        for e in range(host["iteration"].shape[1]):
            row: dict[str, Any] = {"iteration": int(host["iteration"][s, e]), "seed": seed}
            for group, prefix in groups:
                for name, value in host.get(group, {}).items():
                    value = value[s, e]
                    if np.ndim(value) == 1 and value.shape[0] == n:
                        for agent in range(n):
                            row[f"{prefix}{name}/agent_{agent}"] = float(value[agent])
                    else:
                        row[f"{prefix}{name}"] = float(value)
            row.update(perf)
            rows.append(row)
    return rows


def run_description(resolved: ResolvedRun) -> dict[str, Any]:
    """What config.json says the run is (its identity, config and env); a resume checks
    the saved file against it, so an edited config.json is refused, not believed."""
    return {
        "identity": resolved.identity(),
        "run_config": dataclasses.asdict(resolved.run),
        "env": {
            "id": resolved.run.env_id,
            "version": resolved.run.env_id.rsplit("-v", 1)[-1],
            "params": env_parameters(resolved.env),
            "num_agents": resolved.env.num_agents,
            "optimal_team_return": getattr(resolved.env, "optimal_team_return", None),
        },
    }


def run_metadata(resolved: ResolvedRun) -> dict[str, Any]:
    return {
        **run_description(resolved),
        "pimbot_version": pimbot.__version__,
        "git_commit": store.git_commit(),
        "jax_version": jax.__version__,
        "jax_backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "plugins": plugins.provenance(),  # each loaded plugin's file and sha256
    }


def check_run_dir(run_dir: Path, resolved: ResolvedRun) -> None:
    """Fails if `run_dir` exists and holds something other than this run."""
    if not run_dir.exists():
        return
    if not run_dir.is_dir():
        raise RunDirConflict(f"out: {run_dir} exists and is not a directory")
    config_path = run_dir / store.CONFIG
    if not config_path.exists():
        if any(run_dir.iterdir()):
            raise RunDirConflict(
                f"out: {run_dir} is a non-empty directory without a pimbot run; "
                "choose a new or empty directory"
            )
        return
    config = store.read_json(config_path)
    if not isinstance(config, dict):
        raise store.DamagedRunDir(
            f"{config_path}: damaged (not a JSON object); {store.RESTART_HINT}"
        )
    described = json.loads(json.dumps(run_description(resolved), default=str))
    saved, wanted = config.get("identity"), described["identity"]
    if isinstance(saved, dict):
        saved = with_later_fields(saved, wanted, resolved)
    if saved != wanted:
        keys = sorted(set(saved or {}) | set(wanted))
        diff = [k for k in keys if (saved or {}).get(k) != wanted.get(k)]
        raise RunDirConflict(
            f"out: {run_dir} holds a different run (differs in: {', '.join(diff)}); "
            "choose another directory or repeat the original command to resume it"
        )
    edited = [key for key in ("run_config", "env") if _edited(config.get(key), described[key])]
    if edited:
        raise store.DamagedRunDir(
            f"{config_path}: damaged ({' and '.join(edited)} disagree with its identity: "
            f"the file was edited); {store.RESTART_HINT}"
        )


LATER_FIELD_SECTIONS = {
    "learner_config": lambda r: r.learner_config,
    "env_params": lambda r: r.env,
    "attack_params": lambda r: r.attack,
}
"""Identity sections that are a config object's fields, and that object of a run."""


def _field_defaults(obj: Any) -> dict[str, Any]:
    """The JSON form of each field default of `obj`'s dataclass (fields without one left out)."""
    defaults = {}
    for field in dataclasses.fields(obj):
        if field.default is not dataclasses.MISSING:
            defaults[field.name] = field.default
        elif field.default_factory is not dataclasses.MISSING:
            defaults[field.name] = field.default_factory()
    return json.loads(json.dumps(defaults, default=str))


def with_later_fields(saved: dict, wanted: dict, resolved: ResolvedRun) -> dict:
    """A saved identity with the fields a later pimbot added (a learner hyperparameter, an
    env or attack parameter) filled in where this run has them at their default: a new
    field's default is the behaviour from before it existed (new variants are options), so
    a run made then is the same run and resumes. A field set to anything else still
    differs."""
    out = dict(saved)
    for section, config_of in LATER_FIELD_SECTIONS.items():
        old, new = saved.get(section), wanted.get(section)
        obj = config_of(resolved)
        if not (isinstance(old, dict) and isinstance(new, dict)) or not dataclasses.is_dataclass(
            obj
        ):
            continue
        defaults = _field_defaults(obj)
        added = {
            k: v for k, v in new.items() if k not in old and k in defaults and v == defaults[k]
        }
        out[section] = {**old, **added}
    return out


def _edited(saved: Any, wanted: dict) -> bool:
    """Whether a saved config.json section disagrees with the run: a field both have
    differs (a field only one has is another pimbot version's, not an edit)."""
    if not isinstance(saved, dict):
        return True
    return any(saved[k] != wanted[k] for k in saved.keys() & wanted.keys())


def periods_per_call(per_chunk: int, eval_period: int, progress: bool) -> int:
    """Evaluation periods per compiled call: the whole chunk, or with a progress display
    the fewest periods that make `CALL_ITERATIONS` (a divisor of the chunk), so the bar
    moves within a chunk; the calls of a chunk are queued at once, so the device does
    not wait for the display. Results do not depend on it (one program either way)."""
    if not progress:
        return per_chunk
    for k in range(1, per_chunk + 1):
        if per_chunk % k == 0 and k * eval_period >= CALL_ITERATIONS:
            return k
    return per_chunk


def program_shape(
    resolved: ResolvedRun, chunk_iterations: int, progress: bool, devices: int
) -> tuple[int, int]:
    """(evaluation periods per compiled call, padded seeds) of `resolved` on `devices`
    devices: with the run's structure, what its compiled chunk depends on."""
    period = resolved.eval_period
    per_chunk = evals_per_chunk(resolved.num_evals, period, chunk_iterations)
    seeds = math.ceil(resolved.run.seeds / devices) * devices if devices > 1 else resolved.run.seeds
    return periods_per_call(per_chunk, period, progress), seeds


def _concat_periods(host: list) -> Any:
    """Metrics of consecutive calls [S, E_i, ...] (on the host) -> one chunk's metrics
    [S, ΣE_i, ...]."""
    return host[0] if len(host) == 1 else jax.tree.map(lambda *x: np.concatenate(x, 1), *host)


def _start(resolved: ResolvedRun, args: tuple, run_dir: Path, schedule: Schedule, cache):
    """The seeds' states (initial or from the checkpoint), their evaluation keys, the
    iterations done, and the compiled call of `schedule.per_call` evaluation periods
    (given `args`, `program_args(resolved)`) with its compile time (0 when this process
    had compiled the program already). Metric rows more than one chunk past the
    checkpoint mean the checkpoint was deleted or replaced by an older one: refused."""
    run = resolved.run
    sharding, padded = seed_sharding(run.seeds)
    keys = seed_keys(run.first_seed, padded)
    init_keys = jax.vmap(lambda k: jax.random.fold_in(k, 0))(keys)
    eval_roots = jax.vmap(lambda k: jax.random.fold_in(k, 1))(keys)
    t0 = time.perf_counter()
    key, entry = cache.entry(resolved, schedule.per_call, padded, sharding)
    fresh = entry[1] is None
    states, done = _restore(entry[0](init_keys, *args), run_dir, run.seeds)
    # One row per seed and evaluation; fewer (deleted, truncated) refuse to resume.
    store.truncate_rows(
        run_dir,
        done,
        expected_rows=run.seeds * (done // resolved.eval_period),
        rows_ahead=schedule.chunk_iterations,
    )
    if sharding is not None:  # from the host: placing device arrays compiles a slicing
        # program per leaf shape (~25 small compiles, 1.5 s, for a LIO state)
        states, eval_roots = jax.device_put(jax.device_get((states, eval_roots)), sharding)

    if fresh:
        lowered = make_chunk_fn(resolved, schedule.per_call).lower(states, eval_roots, *args)
        entry[1] = lowered.compile()
    compile_s = time.perf_counter() - t0
    if fresh:
        cache.compiled.append((key, compile_s))
    else:
        cache.reused += 1
    return states, eval_roots, done, entry[1], compile_s


def _restore(states, run_dir: Path, seeds: int):
    """(`states`, every seed's initial state, replaced by the checkpoint's; the iterations
    it has done), or (`states`, 0) without a checkpoint. DamagedRunDir when the checkpoint
    does not load, or holds a state at another iteration than its metadata says."""
    store.settle_checkpoint(run_dir)  # the writer (holding the run's lock) completes it
    saved = store.load_checkpoint(run_dir)
    if saved is None:
        return states, 0
    state_bytes, done = saved
    try:
        states = flax.serialization.from_bytes(states, state_bytes)
    except Exception as error:  # msgpack or structure mismatch: not this run's state
        raise store.DamagedRunDir(
            f"{run_dir / store.CHECKPOINT_DIR}: damaged (the state does not load: "
            f"{type(error).__name__}); {store.RESTART_HINT}"
        ) from None
    counted = getattr(states, "iteration", None)  # the learner's own count, if it keeps one
    if counted is not None and not (np.asarray(counted)[:seeds] == done).all():
        raise store.DamagedRunDir(
            f"{run_dir / store.CHECKPOINT_DIR}: damaged (its metadata says iteration "
            f"{done}, the state it holds is at iteration "
            f"{int(np.asarray(counted).reshape(-1)[0])}); {store.RESTART_HINT}"
        )
    return states, done


def train(
    run: RunConfig | ResolvedRun,
    run_dir: str | Path,
    *,
    progress: bool = True,
    chunk_iterations: int = TARGET_CHUNK_ITERATIONS,
    on_chunk=None,
    log: tuple[str, ...] = (),
    cache: ProgramCache | None = None,
    strategies: dict | None = None,
    checked: bool = False,
    accept_changed_code: bool = False,
) -> TrainResult:
    """Trains (or resumes, or reports finished) one run into `run_dir`.

    Args:
        run: what to train: a RunConfig, or the ResolvedRun its caller has made of it.
        run_dir: the run directory; rerunning on it resumes from the last checkpoint.
        progress: show a progress display on stderr (a compile notice, then a bar that
            moves every `CALL_ITERATIONS` iterations or evaluation period).
        chunk_iterations: iterations per checkpoint and metrics append (rounded down to
            whole evaluation periods, at least one); results do not depend on it.
        on_chunk: called as on_chunk(iterations done, states, metric rows) after each
            checkpoint (the audit log).
        log: tracking backends ("tensorboard", "wandb", "mlflow"; see
            `pimbot.training.tracking`) that receive every metric row and the config.
        cache: compiled programs to take the run's from and to keep it in (a sweep
            worker passes one for all its jobs); None: a fresh one.
        strategies: kind -> attack (`strategy_union.shared_attack`): a strategy attack runs
            as that member of `strategy_union.Strategies`, the one program of every run that
            differs from it only in numbers and in which of these attacks it is (same
            results; None: its own program).
        checked: the caller has made `check`'s checks (nothing written since): `run` is
            its ResolvedRun, `log` its parsed backends, and `run_dir` was checked under the
            directory's lock (the command line, which checks before it starts the audit
            log). False: `check` runs here.
        accept_changed_code: go on with a run made by other code (another pimbot version,
            a changed plugin: `provenance.check`), recording the change in config.json;
            False: such a run is refused in one line.
    """
    run_dir = Path(run_dir)
    resolved, log = (run, tuple(log)) if checked else check(run, run_dir, log, accept_changed_code)
    if (run_dir / store.SUMMARY).exists():
        return TrainResult(run_dir, store.read_json(run_dir / store.SUMMARY), True)

    run_dir.mkdir(parents=True, exist_ok=True)
    provenance.record(run_dir, provenance.check(run_dir, accept_changed_code))
    if not (run_dir / store.CONFIG).exists():
        store.write_json(run_dir / store.CONFIG, run_metadata(resolved))
    schedule = Schedule.of(resolved, chunk_iterations, progress)
    program = program_of(resolved, strategies)
    args = program_args(program)
    cache = cache if cache is not None else ProgramCache()

    trackers = tracking.Trackers(log, run_dir, seed_list(resolved.run))
    t0 = time.perf_counter()
    compile_s = _train_chunks(
        resolved, program, args, run_dir, schedule, cache, trackers, on_chunk, progress
    )
    summary = summarize(run_dir)
    summary["compile_s"] = compile_s
    summary["wall_s_this_session"] = time.perf_counter() - t0
    store.write_json(run_dir / store.SUMMARY, summary)
    return TrainResult(run_dir, summary, False)


def check(
    run: RunConfig | ResolvedRun,
    run_dir: Path,
    log: tuple[str, ...] = (),
    accept_changed_code: bool = False,
) -> tuple[ResolvedRun, tuple[str, ...]]:
    """What `train` checks before it writes anything, each once: the tracking backends
    (known, their clients installed), the run (`resolve`, unless it is resolved already)
    the run directory (`check_run_dir`), the code an unfinished run there was made with
    (`provenance.check`, unless `accept_changed_code`) and, where a part of the run is a
    plugin's, one abstractly traced iteration (`contracts.preflight.check_run`). Returns
    (the resolved run, the backends)."""
    backends = tracking.parse(log)
    tracking.require_clients(backends)
    resolved = run if isinstance(run, ResolvedRun) else resolve(run)
    check_run_dir(run_dir, resolved)
    if not (run_dir / store.SUMMARY).exists():  # a finished run is only reported
        provenance.check(run_dir, accept_changed_code)
    preflight.check_run(  # a plugin's hooks traced once: one line at its file, nothing written
        resolved.learner,
        resolved.env,
        resolved.learner_config,
        resolved.attack,
        resolved.defenses,
        resolved.eval_episodes,
    )
    return resolved, backends


def seed_list(run: RunConfig) -> list[int]:
    return list(range(run.first_seed, run.first_seed + run.seeds))


def run_title(resolved: ResolvedRun) -> str:
    """The progress display's name of a run: `lio escape_room-v0 ×2 admo +health_monitor`."""
    run = resolved.run
    title = f"{run.learner} {run.env_id} ×{run.seeds}"
    if run.attack:
        title += f" {run.attack}"
    if resolved.defenses:
        title += " +" + "+".join(d.name for d in resolved.defenses)
    return title


def program_of(resolved: ResolvedRun, strategies: dict | None) -> ResolvedRun:
    """The run as its compiled program runs it: its attack in the attack's program form,
    or, a strategy attack given `strategies`, as its member of their `Strategies`."""
    if strategies and strategy_union.shareable(resolved.attack):
        attack = strategy_union.shared_attack(resolved.attack, strategies)
        return programs.with_attack(resolved, attack)
    return programs.with_attack(resolved, resolved.attack.program_form())


@dataclasses.dataclass(frozen=True)
class Schedule:
    """How a session splits a run's iterations: evaluation periods of `period` iterations,
    `per_call` of them in one compiled call, `per_chunk` (whole calls) between
    checkpoints."""

    period: int
    per_chunk: int
    per_call: int

    @classmethod
    def of(cls, resolved: ResolvedRun, chunk_iterations: int, progress: bool) -> Schedule:
        period = resolved.eval_period
        per_chunk = evals_per_chunk(resolved.num_evals, period, chunk_iterations)
        return cls(period, per_chunk, periods_per_call(per_chunk, period, progress))

    @property
    def chunk_iterations(self) -> int:
        return self.per_chunk * self.period


def _train_chunks(
    resolved: ResolvedRun,
    program: ResolvedRun,
    args: tuple,
    run_dir: Path,
    schedule: Schedule,
    cache: ProgramCache,
    trackers: tracking.Trackers,
    on_chunk,
    progress: bool,
) -> float:
    """Trains `resolved` (compiled as `program`, called with `args`) from its checkpoint
    to its last iteration, a chunk at a time; after each, the rows are appended, the
    state is checkpointed, and the trackers and `on_chunk` get the rows. Ends the
    trackers with the session's status; returns the compile time."""
    run, title = resolved.run, run_title(resolved)
    status, bar = "failed", None
    try:
        with CompileNotice(title, enabled=progress):  # init and chunk compile: 10-20 s
            states, eval_roots, done, chunk_fn, compile_s = _start(
                program, args, run_dir, schedule, cache
            )
        trackers.catch_up(done)
        bar = Progress(title, run.iterations, done, enabled=progress)
        columns: list[str] | None = None
        while done < run.iterations:
            calls = (chunk_fn, eval_roots, args)
            states, host_states, rows = _run_chunk(resolved, calls, states, schedule, done, bar)
            _check_finite(rows, host_states, done)
            done += schedule.chunk_iterations
            columns = columns or list(rows[0])
            store.append_rows(run_dir, columns, rows)
            store.save_checkpoint(run_dir, flax.serialization.to_bytes(host_states), done)
            trackers.log(rows)
            if on_chunk is not None:
                on_chunk(done, states, rows)
            latest = [r["eval/success"] for r in rows if r["iteration"] == done]
            bar.update(done, float(np.mean(latest)))
        status = "finished"
    except KeyboardInterrupt:
        status = "killed"
        raise
    finally:
        if bar is not None:
            bar.close()
        trackers.close(status)
    return compile_s


def _run_chunk(resolved: ResolvedRun, calls: tuple, states, schedule: Schedule, done: int, bar):
    """One chunk from iteration `done`: its compiled calls (`calls`: the chunk fn, the
    evaluation keys and the program's arguments) queued back to back, the bar moved after
    each but the last. Returns (the states, on the device and on the host, and the chunk's
    metric rows, whose perf/ columns are its throughput)."""
    chunk_fn, eval_roots, args = calls
    run, iterations = resolved.run, schedule.chunk_iterations
    t_chunk = time.perf_counter()
    metrics = []
    for _ in range(schedule.per_chunk // schedule.per_call):  # queued: run back to back
        states, call_metrics = chunk_fn(states, eval_roots, *args)
        metrics.append(call_metrics)
    for i, call_metrics in enumerate(metrics[:-1] if bar.enabled else ()):
        success = np.asarray(call_metrics["eval"]["success"])[: run.seeds, -1]
        bar.update(done + (i + 1) * schedule.per_call * schedule.period, float(success.mean()))
    jax.block_until_ready(states)
    chunk_s = time.perf_counter() - t_chunk
    host_metrics, host_states = jax.device_get((metrics, states))  # one transfer
    perf = {
        "perf/iters_per_s": iterations / chunk_s,
        "perf/seed_iters_per_s": iterations * run.seeds / chunk_s,
    }
    rows = metric_rows(resolved, _concat_periods(host_metrics), seed_list(run), perf)
    return states, host_states, rows


def _check_finite(rows: list[dict[str, Any]], host_states, start: int) -> None:
    """Raises Diverged, before anything of the chunk from iteration `start` is written,
    where its rows or states are not finite."""
    where = first_non_finite(rows, host_states)
    if where is not None:
        raise Diverged(
            f"diverged: {where}; the last finite checkpoint (iteration {start}) is kept. "
            "Lower the learning rates (--hp) and rerun with --restart"
        )
