"""Atomic file writes: readers see the old file or the new one, never a mix.

A new file is staged under a name created exclusively in the target's directory (never a
file or link already there) and renamed over the target; a link at the target is replaced,
its target left alone. `write_atomic` writes bytes; `staged` hands the staged name to a
writer that insists on a path of its own (Pillow, ffmpeg).
"""

from __future__ import annotations

import contextlib
import os
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
