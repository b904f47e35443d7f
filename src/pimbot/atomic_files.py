"""Atomic file writes: readers see the old file or the new one, never a mix.

A new file is staged under a name created exclusively in the target's directory (never a
file or link already there) and renamed over the target; a link at the target is replaced,
its target left alone. `write_atomic` writes bytes; `staged` hands the staged name to a
writer that insists on a path of its own (Pillow, ffmpeg); `staged_directory` does the
same for a directory (a ROS 2 bag, an export).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def staged(path: Path) -> Iterator[Path]:
    """A fresh, empty file beside `path` for the caller to write; renamed over `path` when
    the block ends without an exception, removed otherwise. Its suffix is `path`'s, so a
    writer that picks its format by suffix picks the right one."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_atomic(path: Path, data: bytes) -> None:
    """Writes `data` to `path` atomically, flushed to disk before the rename."""
    with staged(path) as tmp, open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


@contextlib.contextmanager
def staged_directory(path: Path) -> Iterator[Path]:
    """A path beside `path`, inside a directory created exclusively, for the caller to
    create and fill (it does not exist yet); moved to `path` when the block ends without
    an exception. What was at `path` is replaced: a link removed (its target left alone),
    an old file or directory moved aside and deleted, so `path` is missing only between two
    renames. The staging directory is removed either way."""
    path = Path(path)
    staging = Path(tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}."))
    try:
        new = staging / path.name
        yield new
        if path.is_symlink():
            path.unlink()
        elif path.exists():
            path.rename(staging / ".replaced")
        os.rename(new, path)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
