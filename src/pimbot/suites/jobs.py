"""The kinds of suite job: how each one runs, resumes and reports its status.

A `Job` is one run directory of a suite: a name, a kind and the kind's spec.
A kind is four small functions on (job directory, spec): `status` (finished,
partial or pending; raises `JobConflict` when the directory holds a different
job), `execute` (runs or resumes it, with the suite's `JobOptions`), `progress`
(fraction done, for the display) and `cost` (relative work, for the ETA).
Adding a kind of job to `pimbot reproduce` means adding one entry to `KINDS`.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pimbot.training import store


@dataclasses.dataclass(frozen=True)
class Job:
    """One run directory of a suite."""

    name: str
    """`<group>/<setting>`; also the run directory relative to the suite directory."""
    kind: str
    """A key of `KINDS`: "train" (spec is a RunConfig), "profile" (a ProfileConfig, paired)
    or "robot_eval" (a presets.RobotEval)."""
    spec: Any
    claims: tuple[str, ...] = ()
    """The published claims (C1–C8) this job feeds."""
    after: tuple[str, ...] = ()
    """Jobs whose results this one reads (it starts once they have finished)."""

    @property
    def group(self) -> str:
        return self.name.split("/", 1)[0]


@dataclasses.dataclass(frozen=True)
class Skipped:
    """A cell of a grid that is not run, and why (index.json "skipped", `sweep --list`, the
    report): its attack or defense acts at a hook point its learner does not have."""

    name: str
    """The job name the cell would have had (`<group>/<setting>`)."""
    reason: str
    """One line."""


@dataclasses.dataclass(frozen=True)
class JobOptions:
    """How every job of a suite runs (the same for all of them); none of it changes results."""

    chunk_iterations: int = 2000
    """Iterations per checkpoint of every training job."""
    log: tuple[str, ...] = ()
    """Tracking backends each training job streams its own run to (`experiment.tracking`)."""
    accept_changed_code: bool = False
    """Resume a job made by other code (`training.provenance`), recording the change."""


class JobConflict(Exception):
    """A job directory holds a different job."""


def _as_json(obj: Any) -> Any:
    return json.loads(json.dumps(dataclasses.asdict(obj), default=str))


def _summary_status(path: Path, identity: Any, read_identity: Callable[[dict], Any]) -> str:
    summary = path / store.SUMMARY
    if not summary.exists():
        return "pending"
    if read_identity(store.read_json(summary)) != identity:
        raise JobConflict(f"{path} holds a different job; choose another --out")
    return "finished"


def _clear(path: Path) -> None:
    """Removes what an interrupted, non-resumable job left."""
    if path.exists() and not (path / store.SUMMARY).exists():
        shutil.rmtree(path)


# --- train: one `pimbot train` run ------------------------------------------------------


def train_status(path: Path, spec) -> str:
    from pimbot.training import memory
    from pimbot.training.config import resolve
    from pimbot.training.runner import RunDirConflict, check_run_dir

    resolved = resolve(spec)
    try:
        check_run_dir(path, resolved)
    except RunDirConflict as error:
        raise JobConflict(str(error)) from None
    if (path / store.SUMMARY).exists():
        return "finished"
    memory.check_fits(resolved)  # before the sweep writes its index or any run
    return "partial" if (path / store.CHECKPOINT_DIR).exists() else "pending"


def train_status_new(spec) -> str:
    """`train_status` of a job whose directory does not exist: "pending", once it fits."""
    from pimbot.training import memory
    from pimbot.training.config import resolve

    memory.check_fits(resolve(spec))
    return "pending"


def train_execute(
    path: Path, spec, suite_dir: Path, options: JobOptions, shared: Any = None
) -> dict[str, Any]:
    from pimbot.training.runner import train

    cache, strategies = shared if shared is not None else (None, None)
    result = train(
        spec,
        path,
        progress=False,
        chunk_iterations=options.chunk_iterations,
        log=options.log,
        cache=cache,
        strategies=strategies,
        accept_changed_code=options.accept_changed_code,
    )
    return {"success": result.summary["final"]["eval/success"]["mean"]}


def train_share(spec, options: JobOptions, devices: int) -> str | None:
    """The compiled program a training job runs on (`programs.share_key`): jobs with one
    key run as one task on one program; None if the spec does not resolve (it fails
    alone, with its own message)."""
    from pimbot.envs.core import InvalidParameter
    from pimbot.training import programs
    from pimbot.training.config import memoized, resolve
    from pimbot.training.runner import program_shape

    try:
        resolved = resolve(spec)
    except (InvalidParameter, KeyError, ValueError):
        return None
    periods, seeds = program_shape(resolved, options.chunk_iterations, False, devices)
    return memoized(  # once per resolved run and shape inside `config.resolving()`
        "share_key",
        (id(resolved), periods, seeds, devices),
        lambda: (resolved, programs.share_key(resolved, periods, seeds, devices)),
    )[1]


def train_strategies(specs: list) -> dict[str, Any] | None:
    """kind -> attack of the strategy attacks among `specs` (a group's jobs), when there
    are several kinds (the runner then runs them on one `strategy_union.Strategies` program)."""
    from pimbot.attacks import strategy_union
    from pimbot.training.config import resolve

    templates: dict[str, Any] = {}
    for spec in specs:
        attack = resolve(spec).attack
        if strategy_union.shareable(attack):
            templates.setdefault(strategy_union.member_kind(attack), attack)
    return templates if len(templates) > 1 else None


def train_partition(jobs: list) -> list[list]:
    """The tasks a group of training jobs (one `programs.share_key`) runs as: one, unless
    the group mixes strategy attack kinds (one `strategy_union.Strategies` program) and
    learner entries; then one task per entry, so a run joins a `Strategies` program only
    with runs of its own learner entry. A run on a `Strategies` program takes its
    learner's path for an attack that acts at `act` (the Reciprocator then plays matrix
    games through the rollout instead of its tabular sampler: the same distribution,
    another random stream), so `nl`'s clean IPD run, folded into the Reciprocator's
    clean and self-centered one, would change its results."""
    if len(jobs) < 2 or train_strategies([j.spec for j in jobs]) is None:
        return [jobs]
    by_learner: dict[str, list] = {}
    for job in jobs:
        by_learner.setdefault(job.spec.learner, []).append(job)
    return list(by_learner.values())


def train_progress(path: Path, spec) -> float:
    meta = path / store.CHECKPOINT_DIR / store.STATE_META
    try:
        return min(1.0, store.read_json(meta)["iteration"] / spec.iterations)
    except (OSError, ValueError, KeyError):
        return 0.0


def train_cost(spec) -> float:
    return float(spec.iterations * spec.seeds) + 2e4  # + compilation


# --- profile: a paired (benign, ADMO) on-device profile --------------------------------


def _profile_identity(config: dict | None) -> dict | None:
    return None if config is None else {k: v for k, v in config.items() if k != "controller"}


def profile_status(path: Path, spec) -> str:
    return _summary_status(
        path,
        _profile_identity(_as_json(spec)),
        lambda s: _profile_identity(s.get("benign", {}).get("config")),
    )


def _controllers() -> tuple[str, ...]:
    from pimbot.profiling import CONTROLLERS  # jax and the learners: only when needed

    return CONTROLLERS


def profile_execute(
    path: Path, spec, suite_dir: Path, options: JobOptions, shared: Any = None
) -> dict[str, Any]:
    from pimbot.profiling import profile

    _clear(path)
    profile(spec, path, paired=True)
    return {}


# --- robot_eval: a trained Escape Room run evaluated in MuJoCo physics ------------------


def robot_status(path: Path, spec) -> str:
    return _summary_status(path, _as_json(spec), lambda s: s.get("spec"))


def robot_execute(
    path: Path, spec, suite_dir: Path, options: JobOptions, shared: Any = None
) -> dict[str, Any]:
    from pimbot.robot.evaluate import evaluate_run

    _clear(path)
    result = evaluate_run(Path(suite_dir) / spec.run, spec.episodes, dict(spec.physics))
    summary = result.summary()
    summary["spec"] = _as_json(spec)
    path.mkdir(parents=True, exist_ok=True)
    store.write_json(path / store.SUMMARY, summary)
    return {"physics": summary["physics"]["mean"]}


def train_describe(run) -> str:
    params = "".join(f" {k}={v}" for k, v in run.env_params)
    attack = run.attack or "clean"
    if run.attack_params:
        attack += "(" + ",".join(f"{k}={v}" for k, v in run.attack_params) + ")"
    defended = "".join(f" +{name}" for name, _ in run.defenses)
    return (
        f"{run.learner} {run.env_id}{params} {attack}{defended} ×{run.seeds} seeds, "
        f"{run.iterations} it"
    )


@dataclasses.dataclass(frozen=True)
class Kind:
    status: Callable[[Path, Any], str]
    execute: Callable[..., dict[str, Any]]
    """execute(path, spec, suite_dir, options, shared=None): `shared` is what the jobs of
    one group share (train: (runner.ProgramCache, strategies))."""
    progress: Callable[[Path, Any], float]
    cost: Callable[[Any], float]
    describe: Callable[[Any], str]
    share: Callable[[Any, JobOptions, int], str | None] = lambda spec, options, devices: None
    """The program a job runs on: jobs of one kind with one (non-None) key form a group,
    run as one task that compiles it once; None: alone."""
    partition: Callable[[list], list[list]] = lambda jobs: [jobs]
    """The tasks a group (jobs with one `share` key, in job order) runs as."""
    compiles_a_training_program: bool = False
    """Its jobs train (spec: a RunConfig): a group shares one `runner.ProgramCache`, whose
    compiles the suite counts, and its strategy attacks (`train_strategies`)."""
    status_new: Callable[[Any], str] = lambda spec: "pending"
    """`status` of a job whose directory does not exist yet (no look at the disk: a plan
    lists each folder once, `sweep.plan`)."""


KINDS = {
    "train": Kind(
        train_status,
        train_execute,
        train_progress,
        train_cost,
        train_describe,
        train_share,
        train_partition,
        compiles_a_training_program=True,
        status_new=train_status_new,
    ),
    "profile": Kind(
        profile_status,
        profile_execute,
        lambda path, spec: 0.0,
        lambda spec: len(_controllers()) * spec.duration_s * 5e3,
        lambda spec: f"paired profile ({', '.join(_controllers())}), {spec.duration_s:g} s each",
    ),
    "robot_eval": Kind(
        robot_status,
        robot_execute,
        lambda path, spec: 0.0,
        lambda spec: 3e4 * spec.episodes,
        lambda spec: f"{spec.run} in MuJoCo physics, {spec.episodes} episodes per seed",
    ),
}
