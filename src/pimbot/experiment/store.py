"""Run directories: config.json, metrics.csv, summary.json and checkpoint/.

Writes are crash-safe: the checkpoint and JSON files are replaced atomically,
and metrics rows past the last checkpoint are dropped on resume, so a run
killed at any moment resumes with no duplicated or missing rows.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
from pathlib import Path
from typing import Any

CONFIG = "config.json"
METRICS = "metrics.csv"
SUMMARY = "summary.json"
CHECKPOINT_DIR = "checkpoint"
STATE_FILE = "state.msgpack"
STATE_META = "meta.json"


def write_atomic(path: Path, data: bytes) -> None:
    """Writes `data` to `path` so that readers see the old or the new file, never a mix."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def write_json(path: Path, obj: Any) -> None:
    write_atomic(path, (json.dumps(obj, indent=2, sort_keys=True, default=str) + "\n").encode())


def read_json(path: Path) -> Any:
    return json.loads(path.read_text())


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
    ckpt = run_dir / CHECKPOINT_DIR
    ckpt.mkdir(exist_ok=True)
    write_atomic(ckpt / STATE_FILE, state_bytes)
    write_json(ckpt / STATE_META, {"iteration": iteration})


def load_checkpoint(run_dir: Path) -> tuple[bytes, int] | None:
    """(state bytes, iteration) of the last checkpoint, or None."""
    ckpt = run_dir / CHECKPOINT_DIR
    if not (ckpt / STATE_META).exists() or not (ckpt / STATE_FILE).exists():
        return None
    return (ckpt / STATE_FILE).read_bytes(), int(read_json(ckpt / STATE_META)["iteration"])


def append_rows(run_dir: Path, columns: list[str], rows: list[dict[str, Any]]) -> None:
    """Appends metric rows, writing the header when the file is new."""
    path = run_dir / METRICS
    new = not path.exists()
    with open(path, "a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        if new:
            writer.writeheader()
        writer.writerows(rows)
        f.flush()
        os.fsync(f.fileno())


def truncate_rows(run_dir: Path, max_iteration: int) -> None:
    """Drops metric rows written after the checkpoint at `max_iteration`."""
    path = run_dir / METRICS
    if not path.exists():
        return
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        columns = reader.fieldnames or []
        rows = [r for r in reader if int(r["iteration"]) <= max_iteration]
    if not columns:
        path.unlink()
        return
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    os.replace(tmp, path)


def read_metrics(run_dir: Path) -> list[dict[str, str]]:
    path = Path(run_dir) / METRICS
    if not path.exists():
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))
