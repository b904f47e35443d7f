"""Run directories: config.json, metrics.csv, summary.json and checkpoint/.

Writes are crash-safe: the checkpoint and JSON files are replaced atomically,
and metrics rows past the last checkpoint are dropped on resume, so a run
killed at any moment resumes with no duplicated or missing rows.

Reads are checked: a JSON file that does not parse, a checkpoint whose bytes do
not match the SHA-256 its metadata records, and a metrics.csv that lacks rows the
checkpoint has passed raise `DamagedRunDir`, one line saying what is wrong and
how to recover, instead of resuming from something silently different. Reads never
change a run directory, which may be training: only the run's writer, holding its lock,
completes a checkpoint write that a killed process left (`settle_checkpoint`).
"""

from __future__ import annotations

import contextlib
import csv
import fcntl
import hashlib
import io
import json
import math
import os
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from pimbot.atomic_files import remove_leftovers, write_atomic
from pimbot.envs.core import InvalidParameter

CONFIG = "config.json"
METRICS = "metrics.csv"
SUMMARY = "summary.json"
CHECKPOINT_DIR = "checkpoint"
STATE_FILE = "state.msgpack"
STATE_META = "meta.json"
PENDING_META = "meta.pending.json"
"""The metadata of a checkpoint being written, until its state and meta.json are in place."""
RESTART_HINT = "rerun with --restart to start this run over, or restore the file"


class DamagedRunDir(InvalidParameter):
    """A run directory whose files are unreadable or disagree with each other."""


class RunDirBusy(InvalidParameter):
    """Another process holds the run directory's lock."""


def lock_path(run_dir: Path) -> Path:
    """The lock file of a run directory (beside it; the sweep's job lock is the same)."""
    run_dir = Path(run_dir)
    return run_dir.parent / f".{run_dir.name}.lock"


@contextlib.contextmanager
def locked(run_dir: Path) -> Iterator[None]:
    """Holds `run_dir`'s exclusive lock, or raises RunDirBusy at once if another process
    holds it (two `pimbot train` into one directory would write every row twice)."""
    path = lock_path(run_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise RunDirBusy(
                f"out: {run_dir} is in use by another pimbot process; wait for it to finish "
                "or stop it, then rerun"
            ) from None
        yield


def in_use(run_dir: Path) -> bool:
    """Whether a process holds `run_dir`'s lock now (training it: `locked`, or a sweep
    worker running its job). Tested with a shared lock that is released at once."""
    path = lock_path(run_dir)
    if not path.exists():
        return False
    with open(path) as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        fcntl.flock(lock, fcntl.LOCK_UN)
    return False


def clear_run(run_dir: Path) -> None:
    """Removes what a run wrote in `run_dir` (for --restart); other files stay."""
    run_dir = Path(run_dir)
    for name in (CONFIG, METRICS, METRICS + ".tmp", SUMMARY, "tracking.json"):
        (run_dir / name).unlink(missing_ok=True)
    for name in (CHECKPOINT_DIR, "tensorboard"):
        if (run_dir / name).is_dir():
            shutil.rmtree(run_dir / name)


def check_inside(root: Path, names: tuple[str, ...]) -> None:
    """Raises InvalidParameter when `root/name` (or anything directly in it, for a folder)
    is a symbolic link: a writer of `root` writes only inside it, never through a link
    that may lead elsewhere. Checked before anything is written."""
    for name in names:
        path = root / name
        inside = list(path.iterdir()) if path.is_dir() and not path.is_symlink() else []
        for candidate in (path, *inside):
            if candidate.is_symlink():
                raise InvalidParameter(
                    f"{candidate}: a symbolic link (to {os.readlink(candidate)}); pimbot "
                    f"writes only inside {root}, never through a link: remove it"
                )


def finite_json(obj: Any) -> Any:
    """`obj` with every non-finite float replaced by None (strict JSON has no NaN)."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [finite_json(v) for v in obj]
    return obj


def write_json(path: Path, obj: Any) -> None:
    """Strictly valid JSON (non-finite numbers written as null), atomically."""
    text = json.dumps(finite_json(obj), indent=2, sort_keys=True, default=str, allow_nan=False)
    write_atomic(path, (text + "\n").encode())


def read_json(path: Path) -> dict[str, Any]:
    """The JSON object in `path` (every JSON file pimbot writes holds one); DamagedRunDir
    (one line) if it is not valid JSON or holds something else (a list, a number)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        reason = getattr(error, "msg", None) or "not UTF-8 text"
        raise DamagedRunDir(f"{path}: damaged (not valid JSON: {reason}); {RESTART_HINT}") from None
    if not isinstance(data, dict):
        raise DamagedRunDir(
            f"{path}: damaged (a JSON {type(data).__name__}, expected an object); {RESTART_HINT}"
        )
    return data


def git_commit() -> str | None:
    """The commit of the source tree pimbot runs from, if it is a git checkout."""
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=Path(__file__).resolve().parent,
            capture_output=True,
            text=True,
            timeout=5,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None if out.returncode == 0 else None


def save_checkpoint(run_dir: Path, state_bytes: bytes, iteration: int) -> None:
    """The state and its metadata (iteration, size and SHA-256 of the state bytes), as
    one unit: the new metadata is written first as PENDING_META, then the state, then
    meta.json, then the pending file goes. Each file is replaced atomically, so a process
    killed between two steps leaves either the old checkpoint whole or the new state with
    its pending metadata, which `load_checkpoint` completes (`_settle_pending`)."""
    ckpt = run_dir / CHECKPOINT_DIR
    ckpt.mkdir(exist_ok=True)
    meta = {
        "iteration": iteration,
        "bytes": len(state_bytes),
        "sha256": hashlib.sha256(state_bytes).hexdigest(),
    }
    metrics = run_dir / METRICS
    if metrics.exists():  # the rows up to this checkpoint (fsynced before it)
        rows = metrics.read_bytes()
        meta.update(metrics_bytes=len(rows), metrics_sha256=hashlib.sha256(rows).hexdigest())
    write_json(ckpt / PENDING_META, meta)
    write_atomic(ckpt / STATE_FILE, state_bytes)
    write_json(ckpt / STATE_META, meta)
    (ckpt / PENDING_META).unlink()


def settle_checkpoint(run_dir: Path) -> None:
    """Completes or drops a checkpoint write that a killed process left (`save_checkpoint`):
    where the state is the pending one (killed after replacing the state), its metadata
    becomes meta.json; otherwise the state was not replaced and the old checkpoint stands.
    Only the run's writer calls this, holding the run's lock (`locked`): readers never
    change a run directory, which may be in use. The files a killed write left staged
    (`atomic_files.leftovers`: a state, a meta.json, metrics.csv, config.json half
    written) are removed here too."""
    ckpt = run_dir / CHECKPOINT_DIR
    remove_leftovers(run_dir)
    remove_leftovers(ckpt)
    if not (ckpt / PENDING_META).exists():
        return
    pending = read_json(ckpt / PENDING_META)
    state = ckpt / STATE_FILE
    if state.exists() and pending.get("sha256") == hashlib.sha256(state.read_bytes()).hexdigest():
        os.replace(ckpt / PENDING_META, ckpt / STATE_META)
    else:
        (ckpt / PENDING_META).unlink()


_READ_ATTEMPTS = 10
"""How often a reader rereads a checkpoint whose state matches neither metadata file
(0.1 s apart): the run's process may be between two steps of `save_checkpoint`."""


def load_checkpoint(run_dir: Path) -> tuple[bytes, int] | None:
    """(state bytes, iteration) of the last checkpoint, or None. Reads only, so it is safe
    beside a run that is training: a write that a killed process left half done reads as
    what `settle_checkpoint` will make of it, and one in progress is waited out.

    Raises:
        DamagedRunDir: the metadata is unreadable or the state bytes do not match it.
    """
    ckpt = run_dir / CHECKPOINT_DIR
    if ckpt.exists() and not ckpt.is_dir():
        raise DamagedRunDir(f"{ckpt}: damaged (not a directory); {RESTART_HINT}")
    for attempt in range(_READ_ATTEMPTS):
        try:
            return _read_checkpoint(ckpt, last=attempt == _READ_ATTEMPTS - 1)
        except _TornRead:
            time.sleep(0.1)
    raise DamagedRunDir(
        f"{ckpt}: damaged (its files changed on each of {_READ_ATTEMPTS} reads, or a write "
        f"was left without its {STATE_META}); {RESTART_HINT}"
    )


class _TornRead(Exception):
    """The checkpoint's files changed while they were read (a write in progress)."""


def _read_checkpoint(ckpt: Path, last: bool) -> tuple[bytes, int] | None:
    """One read of `load_checkpoint`; _TornRead where the state matches neither the
    pending nor the committed metadata and `last` is False."""
    try:
        pending = read_json(ckpt / PENDING_META) if (ckpt / PENDING_META).exists() else None
        if not (ckpt / STATE_FILE).exists():
            if (ckpt / STATE_META).exists():
                raise DamagedRunDir(f"{ckpt}: damaged ({STATE_FILE} is missing); {RESTART_HINT}")
            return None  # nothing saved yet, or the first save has not written its state
        state_bytes = (ckpt / STATE_FILE).read_bytes()
        digest = hashlib.sha256(state_bytes).hexdigest()
        if pending is not None and pending.get("sha256") == digest:
            meta, meta_path = pending, ckpt / PENDING_META
        elif (ckpt / STATE_META).exists():
            meta, meta_path = read_json(ckpt / STATE_META), ckpt / STATE_META
        elif pending is None:
            raise DamagedRunDir(f"{ckpt}: damaged ({STATE_META} is missing); {RESTART_HINT}")
        else:
            raise _TornRead  # the first save, between its state and its meta.json
    except FileNotFoundError:  # a file went between our looking and reading: a write
        raise _TornRead from None
    iteration = meta.get("iteration")
    if isinstance(iteration, bool) or not isinstance(iteration, int) or iteration < 0:
        raise DamagedRunDir(f"{meta_path}: damaged (no valid iteration); {RESTART_HINT}")
    recorded = meta.get("sha256")
    if recorded is not None and recorded != digest:
        if not last:
            raise _TornRead
        raise DamagedRunDir(
            f"{ckpt / STATE_FILE}: damaged (its SHA-256 differs from the one recorded at "
            f"iteration {iteration}: the file was changed); {RESTART_HINT}"
        )
    return state_bytes, iteration


def append_rows(run_dir: Path, columns: list[str], rows: list[dict[str, Any]]) -> None:
    """Appends metric rows, writing the header when the file is new."""
    path = run_dir / METRICS
    new = not path.exists()
    if not new:
        with open(path, newline="") as f:
            header = next(csv.reader(f), [])
        if header != columns:
            raise DamagedRunDir(
                f"{path}: damaged (its header is not this run's columns: the file was "
                f"edited or another run wrote it); {RESTART_HINT}"
            )
    with open(path, "a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        if new:
            writer.writeheader()
        writer.writerows(rows)
        f.flush()
        os.fsync(f.fileno())


def _complete(row: dict[str, Any], columns: list[str]) -> bool:
    """A row with every column (a row cut by a crash mid-write lacks the last ones)."""
    if None in row or any(row.get(c) is None for c in columns):
        return False
    try:
        int(row["iteration"])
    except (KeyError, TypeError, ValueError):
        return False
    return True


def truncate_rows(
    run_dir: Path,
    max_iteration: int,
    expected_rows: int | None = None,
    rows_ahead: int | None = None,
) -> None:
    """Drops metric rows written after the checkpoint at `max_iteration`.

    Rows are fsynced before the checkpoint is saved, so only rows past the checkpoint can
    be missing or cut short by a crash; with `expected_rows` (the rows the checkpoint has
    passed) fewer or incomplete rows up to it raise DamagedRunDir. A crash leaves at most
    one chunk of rows past the checkpoint: with `rows_ahead` (a chunk's iterations), rows
    further ahead raise DamagedRunDir (the checkpoint was deleted or is an older one).
    """
    path = run_dir / METRICS
    if not path.exists():
        if expected_rows:
            raise DamagedRunDir(
                f"{path}: missing, but the checkpoint is at iteration {max_iteration} "
                f"({expected_rows} rows); {RESTART_HINT}"
            )
        return
    if _keep_checkpointed_bytes(run_dir, max_iteration):
        return
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        columns = list(reader.fieldnames or [])
        rows = []
        for number, row in enumerate(reader, start=2):
            if not _complete(row, columns):
                if expected_rows is not None and number - 2 < expected_rows:
                    raise DamagedRunDir(
                        f"{path}: damaged (line {number} is incomplete, before the "
                        f"checkpoint at iteration {max_iteration}); {RESTART_HINT}"
                    )
                break  # cut by a crash while appending rows past the checkpoint
            iteration = int(row["iteration"])
            if rows_ahead is not None and iteration > max_iteration + rows_ahead:
                raise DamagedRunDir(
                    f"{path}: holds rows up to iteration {iteration} or later, past the "
                    f"checkpoint at iteration {max_iteration} (the checkpoint was deleted "
                    f"or replaced by an older one); {RESTART_HINT}"
                )
            if iteration <= max_iteration:
                rows.append(row)
    if expected_rows is not None and len(rows) != expected_rows:
        raise DamagedRunDir(
            f"{path}: holds {len(rows)} rows up to the checkpoint at iteration "
            f"{max_iteration}, expected {expected_rows} (rows deleted or truncated); "
            f"{RESTART_HINT}"
        )
    if not columns:
        path.unlink()
        return
    buffer = io.StringIO(newline="")
    writer = csv.DictWriter(buffer, fieldnames=columns)
    writer.writeheader()
    writer.writerows(rows)
    write_atomic(path, buffer.getvalue().encode())


def _keep_checkpointed_bytes(run_dir: Path, max_iteration: int) -> bool:
    """Cuts metrics.csv back to the bytes the checkpoint recorded, after checking their
    SHA-256 (any edited, deleted or reordered row before the checkpoint is refused);
    False when the checkpoint recorded none (written by an older pimbot)."""
    meta_path = run_dir / CHECKPOINT_DIR / STATE_META
    meta = read_json(meta_path) if meta_path.exists() else None
    size, digest = (meta.get("metrics_bytes"), meta.get("metrics_sha256")) if meta else (0, 0)
    if not isinstance(size, int) or isinstance(size, bool) or not isinstance(digest, str):
        return False
    path = run_dir / METRICS
    with open(path, "r+b") as f:
        head = f.read(size)
        if len(head) < size or hashlib.sha256(head).hexdigest() != digest:
            raise DamagedRunDir(
                f"{path}: damaged (the rows up to the checkpoint at iteration {max_iteration} "
                f"were changed, cut or deleted); {RESTART_HINT}"
            )
        f.truncate(size)  # rows appended after the checkpoint (a crash) go
        f.flush()
        os.fsync(f.fileno())
    return True


def read_metrics(run_dir: Path) -> list[dict[str, str]]:
    """metrics.csv's rows; DamagedRunDir (one line) for a file that is a symbolic link (it
    would be another run's) or holds a row cut short, too long or not numeric."""
    path = Path(run_dir) / METRICS
    if path.is_symlink():
        raise DamagedRunDir(f"{path}: a symbolic link, not this run's own file; {RESTART_HINT}")
    if not path.exists():
        return []
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    for number, row in enumerate(rows, start=2):
        if None in row or None in row.values():
            raise DamagedRunDir(f"{path}: damaged (line {number} has the wrong number of cells)")
        try:
            [float(value) for value in row.values()]
        except ValueError:
            raise DamagedRunDir(f"{path}: damaged (line {number} holds a non-number)") from None
    return rows


def check_rows_complete(run_dir: Path, rows: list, identity: dict[str, Any]) -> None:
    """A finished run's metrics.csv holds one row per seed and evaluation; DamagedRunDir
    (one line) otherwise (rows lost or added after the run finished)."""
    evaluations = int(identity["iterations"]) // int(identity["eval_period"])
    expected = int(identity["seeds"]) * evaluations
    if len(rows) != expected:
        raise DamagedRunDir(
            f"{Path(run_dir) / METRICS}: damaged ({len(rows)} rows, expected {expected}: "
            f"{identity['seeds']} seeds × {evaluations} evaluations); {RESTART_HINT}"
        )
