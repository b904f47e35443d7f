"""Runs a suite of jobs into one directory, on a local process pool or a Ray cluster.

    DIR/index.json            the plan: every job, its config, status and wall time;
                              the grid cells skipped and why; every suite that wrote here
    DIR/<group>/<setting>/    one run directory per job (as `pimbot train` writes it)

Both backends call the same `execute_job` on the same job and write the same
run directories, so their metrics are identical for the same configs and
seeds. Rerunning on DIR skips finished jobs and resumes interrupted ones from
their checkpoints; a job directory holding a different config is refused
before anything runs. Each job holds an exclusive lock on its directory while
it runs, and local workers exit as soon as the process that started them dies,
so a killed sweep leaves nothing behind that could race a rerun. Workers load
the plugins of `SweepOptions.plugins` (and the installed entry-point plugins)
before running a job, so jobs may use plugin-registered envs, learners,
attacks and defenses on either backend.
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import fnmatch
import json
import os
import signal
import sys
import threading
import time
from collections.abc import Iterable
from concurrent import futures
from pathlib import Path
from typing import Any

from pimbot import plugins as plugin_loader
from pimbot.envs.core import InvalidParameter
from pimbot.suites.jobs import KINDS, Job, JobConflict, JobOptions, Skipped
from pimbot.training import store

INDEX = "index.json"
BACKENDS = ("local", "ray")


class SweepError(Exception):
    """A suite that cannot start (bad pattern, conflicting directory, missing Ray)."""


@dataclasses.dataclass(frozen=True)
class SweepOptions:
    """How a suite runs; none of it changes the results."""

    backend: str = "local"
    """"local" (a process pool on this machine) or "ray" (one Ray task per job)."""
    workers: int = 0
    """Jobs at a time; 0 = one per CPU core (local) or as many as the cluster takes (ray)."""
    devices_per_job: int = 0
    """XLA host devices (CPU cores) each job shards its seeds over; 0 = cores / workers."""
    ray_address: str | None = None
    """Ray cluster address ("auto", "HOST:PORT"); None starts a local Ray instance."""
    progress: bool = True
    chunk_iterations: int = 2000
    """Iterations per checkpoint of every training job."""
    plugins: tuple[str, ...] = ()
    """Plugin modules every worker loads (as `plugins.load_plugins` returned them)."""
    log: tuple[str, ...] = ()
    """Tracking backends every training job streams its own run to (`experiment.tracking`)."""
    accept_changed_code: bool = False
    """Resume jobs made by other code (`training.provenance`), recording the change."""

    @property
    def job_options(self) -> JobOptions:
        return JobOptions(
            chunk_iterations=self.chunk_iterations,
            log=self.log,
            accept_changed_code=self.accept_changed_code,
        )


def matching(names: Iterable[Any], patterns: Iterable[str] | None) -> list[Any]:
    """The jobs (or `Skipped` cells) whose names match any of the shell-style `patterns`
    (all if None or empty)."""
    patterns = list(patterns or [])
    return [n for n in names if not patterns or any(fnmatch.fnmatch(n.name, p) for p in patterns)]


def select(
    jobs: list[Job], patterns: Iterable[str] | None, skipped: Iterable[Skipped] = ()
) -> list[Job]:
    """The jobs whose names match any of the shell-style `patterns` (all if None).

    Raises:
        SweepError: no job matches (naming the skipped cells that do, if any).
    """
    patterns = list(patterns or [])
    if not patterns:
        return jobs
    chosen = matching(jobs, patterns)
    if not chosen and (passed := matching(skipped, patterns)):
        raise SweepError(
            f"only: every cell matching {', '.join(patterns)} is skipped ({len(passed)} cells), "
            f"e.g. {passed[0].name}: {passed[0].reason}"
        )
    if not chosen:
        groups = sorted({j.group for j in jobs})
        raise SweepError(
            f"only: no job matches {', '.join(patterns)}; job names are <group>/<setting> "
            f"with groups {', '.join(groups)} (e.g. --only 'attacks/er21_*')"
        )
    return chosen


# --- job status and execution (runs in the worker processes) ---------------------------


def job_dir(suite_dir: Path, job: Job) -> Path:
    return Path(suite_dir) / job.name


def job_status(suite_dir: Path, job: Job) -> str:
    """Status "finished", "partial" (resumable) or "pending"; SweepError on a conflict."""
    try:
        return KINDS[job.kind].status(job_dir(suite_dir, job), job.spec)
    except JobConflict as error:
        raise SweepError(f"{job.name}: {error}") from None


def _jax_backends_started() -> bool:
    """Whether XLA's backends exist already (XLA_FLAGS is read when they start, not when
    jax is imported: a spawned worker imports jax with this module)."""
    if "jax" not in sys.modules:
        return False
    try:
        from jax._src import xla_bridge
    except ImportError:  # pragma: no cover - a jax without the module: assume started
        return True
    return bool(xla_bridge.backends_are_initialized())


def _configure_worker(devices: int, plugins: tuple[str, ...] = ()) -> None:
    """Process setup, in this order: the host devices (before XLA starts), the plugins,
    then the compilation cache (its directory is keyed by the plugin files). A local
    worker does it once, when it starts (`_local_worker_init`); each task repeats it, a
    no-op by then (a Ray task, a fresh process, does it there)."""
    if not _jax_backends_started():
        kept = os.environ.get("XLA_FLAGS", "").split()
        flags = " ".join(f for f in kept if "xla_force_host_platform_device_count" not in f)
        if devices > 1:
            flags += f" --xla_force_host_platform_device_count={devices}"
        os.environ["XLA_FLAGS"] = flags.strip()
        # Several workers may share one GPU: allocate on demand instead of 75 % each.
        os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    plugin_loader.load_plugins(plugins, from_env=False)  # once per process
    from pimbot import jax_setup

    jax_setup.enable_compilation_cache()


def execute_job(
    job: Job,
    suite_dir: str,
    devices: int,
    options: JobOptions | None = None,
    plugins: tuple[str, ...] = (),
    shared: Any = None,
) -> dict[str, Any]:
    """Runs (or resumes, or confirms finished) one job; returns its status record.
    `shared`: what the jobs of its group share (see `Kind.execute`)."""
    options = options or JobOptions()
    _configure_worker(devices, plugins)
    path = job_dir(Path(suite_dir), job)
    path.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with open(store.lock_path(path), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # waits out a leftover worker of a killed sweep
        record = KINDS[job.kind].execute(path, job.spec, Path(suite_dir), options, shared)
    record["wall_s"] = time.perf_counter() - t0
    return record


_COMPILES = {"xla_compiles": 0, "xla_compile_s": 0.0, "persistent_cache_hits": 0}
"""This process's XLA compiles (every executable built, a persistent-cache hit included)."""


def _watch_compiles() -> None:
    """Counts this process's XLA compiles into `_COMPILES` (registered once)."""
    if _COMPILES.get("watching"):
        return
    import jax.monitoring

    def duration(event: str, seconds: float, **_) -> None:
        if event == "/jax/core/compile/backend_compile_duration":
            _COMPILES["xla_compiles"] += 1
            _COMPILES["xla_compile_s"] += seconds

    def count(event: str, **_) -> None:
        if event == "/jax/compilation_cache/cache_hits":
            _COMPILES["persistent_cache_hits"] += 1

    jax.monitoring.register_event_duration_secs_listener(duration)
    jax.monitoring.register_event_listener(count)
    _COMPILES["watching"] = True


PROGRAM_COUNTS = (
    "chunk_programs",
    "chunk_compile_s",
    "xla_compiles",
    "xla_compile_s",
    "persistent_cache_hits",
)


def execute_group(
    jobs: tuple[Job, ...],
    suite_dir: str,
    devices: int,
    options: JobOptions | None = None,
    plugins: tuple[str, ...] = (),
) -> dict[str, Any]:
    """Runs a group's jobs (one compiled program, see `groups`) one after the other in
    this process. Returns {"records": name -> status record or {"error": line},
    "programs": the programs compiled (`PROGRAM_COUNTS`)}; one failed job does not stop
    the others."""
    options = options or JobOptions()
    _configure_worker(devices, plugins)
    _watch_compiles()
    before = dict(_COMPILES)
    shared = cache = None
    if KINDS[jobs[0].kind].compiles_a_training_program:
        from pimbot.suites.jobs import train_strategies
        from pimbot.training.runner import ProgramCache

        cache = ProgramCache()
        strategies = train_strategies([j.spec for j in jobs]) if len(jobs) > 1 else None
        shared = (cache, strategies)
    records: dict[str, Any] = {}
    for job in jobs:
        try:
            records[job.name] = execute_job(job, suite_dir, devices, options, plugins, shared)
        except Exception as error:  # a failed job must not lose the others
            records[job.name] = {"error": _one_line(error)}
    programs = {k: _COMPILES[k] - before[k] for k in PROGRAM_COUNTS[2:]}
    programs["chunk_programs"] = len(cache.compiled) if cache else 0
    programs["chunk_compile_s"] = sum(t for _, t in cache.compiled) if cache else 0.0
    return {"records": records, "programs": programs}


def groups(jobs: list[Job], options: JobOptions, devices: int) -> list[tuple[Job, ...]]:
    """The jobs as tasks, in job order: jobs of one kind with one `Kind.share` key (one
    compiled program) form a group, which its `Kind.partition` may split, every other job
    is alone; a job that needs another job of its group leaves it."""
    by_key: dict[tuple[str, str], list[Job]] = {}
    tasks: list[list[Job]] = []
    for job in jobs:
        key = KINDS[job.kind].share(job.spec, options, devices)
        if key is None:
            tasks.append([job])
        elif (job.kind, key) in by_key:
            by_key[job.kind, key].append(job)
        else:
            by_key[job.kind, key] = [job]
            tasks.append(by_key[job.kind, key])
    tasks = [part for task in tasks for part in KINDS[task[0].kind].partition(task)]
    result: list[tuple[Job, ...]] = []
    for task in tasks:
        names = {j.name for j in task}
        inner = tuple(j for j in task if not names & set(j.after))
        result += [inner] if inner else []
        result += [(j,) for j in task if names & set(j.after)]
    return result


def job_progress(suite_dir: Path, job: Job) -> float:
    """Fraction of a job done (from its checkpoint where it has one)."""
    path = job_dir(suite_dir, job)
    if (path / store.SUMMARY).exists():
        return 1.0
    return KINDS[job.kind].progress(path, job.spec)


def job_cost(job: Job) -> float:
    """Relative cost of a job, for the ETA."""
    return KINDS[job.kind].cost(job.spec)


# --- local and Ray backends ------------------------------------------------------------


def _exit_with_parent(parent: int) -> None:
    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def _local_worker_init(parent: int, devices: int, plugins: tuple[str, ...] = ()) -> None:
    """A local worker's start: it ignores Ctrl-C (the sweep answers it, in one line, and
    ends its workers: `LocalBackend.shutdown`), exits with the sweep, imports JAX and loads
    the plugins and the compilation cache once, for every task it will run."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked since its spawn
    _exit_with_parent(parent)
    # An error here would break the pool, failing every task unnamed: each task retries
    # the set-up and reports the error as its own.
    with contextlib.suppress(Exception):
        _configure_worker(devices, plugins)


@contextlib.contextmanager
def _interrupts_held():
    """SIGINT blocked in this thread for the block, and delivered when it ends: a worker
    the pool spawns meanwhile inherits the blocked signal, so a Ctrl-C that reaches the
    whole process group while it starts (importing JAX, before `_local_worker_init` ignores
    SIGINT) cannot print its traceback; the sweep itself loses no Ctrl-C."""
    held = threading.current_thread() is threading.main_thread()
    if held:
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        if held:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


class LocalBackend:
    """A process pool on this machine (fresh `spawn`ed processes, so jax starts clean),
    each worker kept for the whole sweep: JAX is imported, the plugins loaded and the
    cache enabled once per worker (`_local_worker_init`), not once per task."""

    def __init__(self, workers: int, devices: int, options: SweepOptions):
        import multiprocessing

        self.pool = futures.ProcessPoolExecutor(
            max_workers=workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_local_worker_init,
            initargs=(os.getpid(), devices, options.plugins),
        )
        self.devices, self.options = devices, options

    def submit(self, task: tuple[Job, ...], suite_dir: Path) -> futures.Future:
        with _interrupts_held():  # a worker spawned here starts deaf to Ctrl-C
            return self.pool.submit(
                execute_group,
                task,
                str(suite_dir),
                self.devices,
                self.options.job_options,
                self.options.plugins,
            )

    def shutdown(self, abandon: bool = False) -> None:
        """Ends the pool. `abandon` (the sweep stops early: an interrupt, an error) also
        ends the jobs still training, which would otherwise go on after the sweep has given
        up, holding their directories' locks, and keep the interpreter from exiting until
        they are done; a rerun resumes them from their last checkpoints."""
        # The executor's own list of its workers (no public accessor before Python 3.14's
        # terminate_workers); shutdown() drops it, so it is read first.
        workers = list((getattr(self.pool, "_processes", None) or {}).values())
        self.pool.shutdown(wait=False, cancel_futures=True)
        if not abandon:
            return
        for worker in workers:
            worker.terminate()
        for worker in workers:
            worker.join(timeout=10)
            if worker.is_alive():
                worker.kill()


class RayBackend:
    """One Ray task per job; tasks write the same run directories (a shared filesystem)."""

    def __init__(self, devices: int, options: SweepOptions):
        try:
            import ray
        except ImportError:
            raise SweepError(
                "backend: ray is not installed; pip install 'pimbot[ray]' or use --backend local"
            ) from None
        self.ray = ray
        if not ray.is_initialized():
            ray.init(address=options.ray_address, include_dashboard=False, log_to_driver=False)
        self.remote = ray.remote(num_cpus=devices, max_calls=1)(execute_group)
        self.devices, self.options = devices, options

    def submit(self, task: tuple[Job, ...], suite_dir: Path) -> futures.Future:
        path = str(Path(suite_dir).resolve())
        job_options, plugins = self.options.job_options, self.options.plugins
        return self.remote.remote(task, path, self.devices, job_options, plugins).future()

    def shutdown(self, abandon: bool = False) -> None:
        """Nothing to end: Ray ends a driver's tasks when the driver disconnects."""


def cpu_count() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


# --- the sweep -------------------------------------------------------------------------


@dataclasses.dataclass
class SweepResult:
    index: dict[str, Any]
    failed: list[str]
    wall_s: float
    ran: list[str] = dataclasses.field(default_factory=list)
    """The jobs this call ran or resumed (empty: every selected job had finished)."""
    programs: dict[str, Any] = dataclasses.field(default_factory=dict)
    """The programs this call compiled: "tasks" (groups of jobs on one program),
    "training_programs" (training tasks: the distinct training programs planned) and the
    sums of `PROGRAM_COUNTS` over the tasks."""


def _job_entry(job: Job, status: str) -> dict[str, Any]:
    return {
        "name": job.name,
        "group": job.group,
        "kind": job.kind,
        "claims": list(job.claims),
        "config": json.loads(json.dumps(dataclasses.asdict(job.spec), default=str)),
        "status": status,
    }


def write_index(suite_dir: Path, index: dict[str, Any]) -> None:
    store.write_json(Path(suite_dir) / INDEX, index)


def read_index(suite_dir: Path) -> dict[str, Any] | None:
    path = Path(suite_dir) / INDEX
    return store.read_json(path) if path.exists() else None


def plan(jobs: list[Job], suite_dir: Path, accept_changed_code: bool = False) -> dict[str, str]:
    """Status of every job; fails before anything runs if a directory conflicts or, unless
    `accept_changed_code`, a job to resume was made by other code (`provenance.check`).
    Time linear in the jobs: what each job's status needs of its run is resolved once per
    distinct part (`config.resolving`)."""
    from pimbot.training import provenance
    from pimbot.training.config import resolving

    statuses = {}
    listed: dict[str, set[str]] = {}  # a folder of the suite -> what it holds

    def on_disk(name: str) -> bool:  # one listing per folder, not one look per job
        parent, _, leaf = name.rpartition("/")
        if parent not in listed:
            try:
                listed[parent] = set(os.listdir(os.path.join(suite_dir, parent)))
            except OSError:
                listed[parent] = set()
        return leaf in listed[parent]

    with resolving():
        for job in jobs:
            if on_disk(job.name):
                status = job_status(suite_dir, job)
            else:
                status = KINDS[job.kind].status_new(job.spec)
            statuses[job.name] = status
            if status == "partial":
                try:
                    provenance.check(job_dir(suite_dir, job), accept_changed_code)
                except provenance.CodeChanged as error:
                    raise SweepError(f"{job.name}: {error}") from None
    return statuses


def check_dependencies(jobs: list[Job], statuses: dict[str, str], suite_dir: Path) -> None:
    """Every job a selected job needs is selected too or already finished on disk."""
    selected = {job.name for job in jobs}
    for job in jobs:
        if statuses[job.name] == "finished":
            continue
        for need in job.after:
            if need not in selected and not (Path(suite_dir) / need / store.SUMMARY).exists():
                raise SweepError(
                    f"only: {job.name} needs {need}, which is neither selected nor finished; "
                    f"add --only '{need}'"
                )


def run(
    jobs: list[Job],
    suite_dir: str | Path,
    suite_name: str,
    options: SweepOptions = SweepOptions(),
    skipped: Iterable[Skipped] = (),
) -> SweepResult:
    """Runs every job not yet finished; returns the index (also written to DIR/index.json,
    with the grid cells `skipped`)."""
    suite_dir = Path(suite_dir)
    if options.backend not in BACKENDS:
        raise InvalidParameter(
            f"backend: unknown backend {options.backend!r}; allowed: {', '.join(BACKENDS)}"
        )
    statuses = plan(jobs, suite_dir, options.accept_changed_code)
    check_dependencies(jobs, statuses, suite_dir)
    suite_dir.mkdir(parents=True, exist_ok=True)
    index = start_index(jobs, statuses, suite_dir, suite_name, skipped)

    todo = [job for job in jobs if statuses[job.name] != "finished"]
    workers, devices = workers_and_devices(options, len(todo))
    tasks = groups(todo, options.job_options, devices)
    display = SweepDisplay(jobs, suite_dir, statuses, enabled=options.progress)
    ledger = Ledger(suite_dir, index, planned_programs(tasks), display)
    t0 = time.perf_counter()
    backend = None
    stopped_early = True  # until every task has ended
    try:
        if todo:
            backend = make_backend(options, min(workers, len(tasks)), devices)
            display.start([job.name for job in todo])
            run_tasks(tasks, {job.name for job in jobs}, backend, ledger)
            ledger.write()
        stopped_early = False
    finally:
        display.close(ledger.programs if todo else None)
        if backend is not None:
            backend.shutdown(abandon=stopped_early)
    ran = [job.name for job in todo]
    return SweepResult(index, ledger.failed, time.perf_counter() - t0, ran, ledger.programs)


def start_index(
    jobs: list[Job],
    statuses: dict[str, str],
    suite_dir: Path,
    suite_name: str,
    skipped: Iterable[Skipped] = (),
) -> dict[str, Any]:
    """The index a sweep starts from, written: every job of `jobs` with its status (and
    its wall time from an earlier sweep), and the jobs of earlier sweeps as they were; the
    cells skipped (this sweep's and earlier sweeps' other cells); every suite that wrote."""
    previous = read_index(suite_dir) or {}
    entries = {e["name"]: e for e in previous.get("jobs", [])}
    for job in jobs:
        entry = _job_entry(job, statuses[job.name])
        if job.name in entries and "wall_s" in entries[job.name]:
            entry["wall_s"] = entries[job.name]["wall_s"]
        entries[job.name] = entry
    index = {
        "suite": suite_name,
        "suites": [*(n for n in suite_names(previous) if n != suite_name), suite_name],
        "pimbot_version": _version(),
        "jobs": sorted(entries.values(), key=lambda e: e["name"]),
    }
    if listed := skipped_entries(previous, skipped, set(entries)):
        index["skipped"] = listed
    write_index(suite_dir, index)
    return index


def suite_names(index: dict[str, Any]) -> list[str]:
    """Every suite (grid or preset) that wrote into a suite directory, earliest first (an
    index written before "suites" was recorded: its one "suite")."""
    names = index.get("suites")
    if isinstance(names, list):
        return [str(n) for n in names]
    return [str(index["suite"])] if index.get("suite") else []


def skipped_entries(
    previous: dict[str, Any], skipped: Iterable[Skipped], jobs: set[str]
) -> list[dict[str, str]]:
    """index.json "skipped": the cells skipped now, and those an earlier sweep skipped that
    are neither skipped now nor jobs now, by name."""
    now = {s.name: {"name": s.name, "reason": s.reason} for s in skipped}
    earlier = [e for e in previous.get("skipped", []) if isinstance(e, dict) and "name" in e]
    kept = {e["name"]: e for e in earlier if e["name"] not in now and e["name"] not in jobs}
    return sorted((kept | now).values(), key=lambda e: e["name"])


def workers_and_devices(options: SweepOptions, jobs_to_run: int) -> tuple[int, int]:
    """(jobs at a time, XLA host devices each job shards its seeds over)."""
    workers = options.workers or (cpu_count() if options.backend == "local" else jobs_to_run or 1)
    workers = max(1, min(workers, jobs_to_run or 1))
    devices = options.devices_per_job or max(1, cpu_count() // workers)
    return workers, devices


def planned_programs(tasks: list[tuple[Job, ...]]) -> dict[str, Any]:
    """index.json "programs" before any task has run: the tasks, the training programs
    planned (a task of a kind that compiles one), and `PROGRAM_COUNTS` at zero."""
    training = sum(1 for t in tasks if KINDS[t[0].kind].compiles_a_training_program)
    return {"tasks": len(tasks), "training_programs": training} | {k: 0 for k in PROGRAM_COUNTS}


def make_backend(options: SweepOptions, workers: int, devices: int) -> LocalBackend | RayBackend:
    if options.backend == "local":
        return LocalBackend(workers, devices, options)
    return RayBackend(devices, options)


@dataclasses.dataclass
class Ledger:
    """What a running sweep records: its index (rewritten as each task ends), the programs
    its tasks compiled, the jobs that failed, and the display."""

    suite_dir: Path
    index: dict[str, Any]
    programs: dict[str, Any]
    display: SweepDisplay
    failed: list[str] = dataclasses.field(default_factory=list)
    entries: dict[str, dict[str, Any]] = dataclasses.field(init=False)
    """Job name -> its entry: the dict in `index["jobs"]`, updated in place."""

    def __post_init__(self) -> None:
        self.entries = {entry["name"]: entry for entry in self.index["jobs"]}

    def failed_job(self, job: Job, error: str) -> None:
        entry = self.entries[job.name]
        entry.update(status="failed", error=error)
        self.failed.append(job.name)
        self.display.finished(job.name, entry)

    def finished_job(self, job: Job, wall_s: float) -> None:
        entry = self.entries[job.name]
        entry.update(status="finished", wall_s=wall_s)
        entry.pop("error", None)
        self.display.finished(job.name, entry)

    def task_ended(self, task: tuple[Job, ...], future: futures.Future) -> None:
        """Records a task's jobs (all failed if its worker was lost) and writes the index."""
        try:
            result = future.result()
            records = result["records"]
            for name in PROGRAM_COUNTS:
                self.programs[name] += result["programs"][name]
        except Exception as error:  # a lost worker must not lose the others
            records = {job.name: {"error": _one_line(error)} for job in task}
        for job in task:
            record = records[job.name]
            if "error" in record:
                self.failed_job(job, record["error"])
            else:
                self.finished_job(job, record["wall_s"])
        self.write()

    def write(self) -> None:
        self.index["programs"] = self.programs
        write_index(self.suite_dir, self.index)


def run_tasks(tasks: list[tuple[Job, ...]], selected: set[str], backend, ledger: Ledger) -> None:
    """Runs `tasks` on `backend`, largest first (the shortest makespan), each once the
    selected jobs it needs have finished (a task whose inputs failed fails unrun), and
    records each as it ends."""
    waiting = sorted(tasks, key=lambda t: -sum(job_cost(j) for j in t))
    pending: dict[futures.Future, tuple[Job, ...]] = {}
    while waiting or pending:
        for task in list(waiting):  # submit every task whose inputs are finished
            inputs = input_statuses(task, selected, ledger)
            if "failed" in inputs:
                waiting.remove(task)
                for job in task:
                    ledger.failed_job(job, "a job it needs failed")
            elif all(state == "finished" for state in inputs):
                waiting.remove(task)
                pending[backend.submit(task, ledger.suite_dir)] = task
        if not pending:
            continue
        done, _ = futures.wait(pending, timeout=0.5, return_when=futures.FIRST_COMPLETED)
        for future in done:
            ledger.task_ended(pending.pop(future), future)
        ledger.display.refresh()


def input_statuses(task: tuple[Job, ...], selected: set[str], ledger: Ledger) -> list[str]:
    """The statuses of the selected jobs outside `task` that its jobs need (a need outside
    the selection was checked to be finished on disk)."""
    inside = {job.name for job in task}
    needs = {d for job in task for d in job.after if d in selected} - inside
    return [ledger.entries[d]["status"] for d in needs]


def _one_line(error: BaseException) -> str:
    """`Type: message`, the message's first line: the error itself, never a note added to
    it (JAX appends one on how it filtered the traceback) or a later line of detail."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return f"{type(error).__name__}: {lines[0]}" if lines else type(error).__name__


def _version() -> str:
    import pimbot

    return pimbot.__version__


class SweepDisplay:
    """Overall progress (jobs done / total, ETA) and each running job's progress."""

    def __init__(self, jobs: list[Job], suite_dir: Path, statuses: dict[str, str], enabled: bool):
        self.jobs = {j.name: j for j in jobs}
        self.suite_dir = suite_dir
        self.done = {n for n, s in statuses.items() if s == "finished"}
        self.enabled = enabled
        self.active: list[str] = []
        self.t0 = time.perf_counter()
        self.start_work = self._work_done()
        self.total_work = sum(job_cost(j) for j in jobs)
        self.last_line = 0.0
        self._live = None

    def _work_done(self) -> float:
        return sum(
            job_cost(job) * (1.0 if name in self.done else job_progress(self.suite_dir, job))
            for name, job in self.jobs.items()
        )

    def start(self, todo: list[str]) -> None:
        self.active = list(todo)
        if not self.enabled:
            return
        print(
            f"{len(self.jobs)} jobs: {len(self.done)} finished, {len(todo)} to run",
            file=sys.stderr,
            flush=True,
        )
        if sys.stderr.isatty():
            from rich.console import Console
            from rich.live import Live

            self._live = Live(self._render(), console=Console(stderr=True), refresh_per_second=2)
            self._live.start()

    def eta(self) -> tuple[float, float | None]:
        elapsed = time.perf_counter() - self.t0
        work = self._work_done()
        gained = work - self.start_work
        if gained <= 0:
            return elapsed, None
        return elapsed, elapsed / gained * (self.total_work - work)

    def _finished_on_disk(self) -> set[str]:
        """Jobs reported finished, and those of a still-running task (a group runs its
        jobs one after the other and reports when the last one ends) that have written
        their summary."""
        written = {
            n
            for n in self.active
            if (job_dir(self.suite_dir, self.jobs[n]) / store.SUMMARY).exists()
        }
        return self.done | written

    def running(self) -> list[tuple[str, float]]:
        """(name, fraction done) of the jobs a worker is running now: those whose lock is
        held (`store.in_use`). Queued jobs are left out, a job an earlier sitting started
        included, and so are the finished jobs of a task still running."""
        finished = self._finished_on_disk()
        return [
            (n, job_progress(self.suite_dir, self.jobs[n]))
            for n in self.active
            if n not in finished and store.in_use(job_dir(self.suite_dir, self.jobs[n]))
        ]

    def headline(self) -> str:
        elapsed, eta = self.eta()
        eta_text = f"{eta / 60:.1f} min" if eta is not None else "-"
        done = len(self._finished_on_disk())
        return f"jobs {done}/{len(self.jobs)} done, elapsed {elapsed / 60:.1f} min, ETA {eta_text}"

    def _render(self):
        from rich.table import Table

        table = Table.grid(padding=(0, 2))
        table.add_row(self.headline())
        for name, fraction in self.running()[:8]:
            bar = "#" * int(fraction * 20)
            table.add_row(f"  {name:<34} [{bar:<20}] {fraction:4.0%}")
        return table

    def finished(self, name: str, entry: dict[str, Any]) -> None:
        if name in self.active:
            self.active.remove(name)
        if entry["status"] == "finished":
            self.done.add(name)
        if not self.enabled:
            return
        wall = entry.get("wall_s")
        detail = f" in {wall:.0f} s" if wall is not None else ""
        if entry["status"] == "failed":
            detail = f": FAILED: {entry['error']}"
        line = f"{name}{detail} | {self.headline()}"
        if self._live is not None:
            self._live.console.print(line)
        else:
            print(line, file=sys.stderr, flush=True)

    def refresh(self) -> None:
        if not self.enabled:
            return
        if self._live is not None:
            self._live.update(self._render())
            return
        now = time.perf_counter()
        if now - self.last_line >= 10.0:
            self.last_line = now
            running = [f"{n} {fraction:.0%}" for n, fraction in self.running()]
            extra = f"; running: {', '.join(running)}" if running else ""
            print(self.headline() + extra, file=sys.stderr, flush=True)

    def close(self, programs: dict[str, Any] | None = None) -> None:
        if self._live is not None:
            self._live.stop()
        if self.enabled and programs:
            print(programs_line(programs), file=sys.stderr, flush=True)


def programs_line(programs: dict[str, Any]) -> str:
    """One line on the programs a sweep compiled (index.json "programs")."""
    return (
        f"programs: {programs['training_programs']} training programs for "
        f"{programs['tasks']} tasks; chunk programs compiled {programs['chunk_programs']} "
        f"({programs['chunk_compile_s']:.0f} s); XLA compiles {programs['xla_compiles']} "
        f"({programs['xla_compile_s']:.0f} s, {programs['persistent_cache_hits']} from the "
        "persistent cache)"
    )
