"""Atomic file writes: readers see the old file or the new one, never a mix.

A new file is staged under a name created exclusively in the target's directory (never a
file or link already there) and renamed over the target; a link at the target is replaced,
its target left alone. `write_atomic` writes bytes; `staged` hands the staged name to a
writer that insists on a path of its own (Pillow, ffmpeg; `save_figure`, Matplotlib's);
`staged_directory` does the same for a directory (a ROS 2 bag, an export). `leftovers`
finds what a killed writer left staged, for the next writer to remove (`remove_leftovers`).
"""

from __future__ import annotations

import contextlib
import os
import re
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


def save_figure(fig, path: Path, **options) -> None:
    """A Matplotlib figure saved as `path` through `staged` (its format from the suffix;
    `options` are `savefig`'s): the one way pimbot writes a figure, so a full disk or a kill
    leaves the old figure or none, never a truncated one (tests/test_hardening_v3.py checks
    that nothing else calls `savefig`)."""
    with staged(path) as tmp:
        fig.savefig(tmp, **options)


@contextlib.contextmanager
def staged_directory(path: Path) -> Iterator[Path]:
    """A path beside `path`, inside a directory created exclusively, for the caller to
    create and fill (it does not exist yet); moved to `path` when the block ends without
    an exception. What was at `path` is replaced: a link removed (its target left alone),
    an old file or directory moved aside and deleted, so `path` is missing only between two
    renames. The staging directory is removed either way."""
    path = Path(os.path.abspath(path))  # "." or "x/..": the directory's own name
    if not path.name:
        raise ValueError(f"{path}: the root directory cannot be staged")
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


_STAGED = re.compile(r"\.(?P<name>.+)\.[a-z0-9_]{8}(?P<suffix>\.[^.]*)?")
"""A staged name: `staged`'s ``.NAME.XXXXXXXX`` + NAME's suffix, `staged_directory`'s
``.NAME.XXXXXXXX`` (tempfile's eight characters)."""


def leftovers(directory: Path) -> list[Path]:
    """What a killed `staged`, `write_atomic` or `staged_directory` left in `directory`: the
    files (and staging directories) whose names are the staged names of a file there."""
    directory = Path(directory)
    if not directory.is_dir():
        return []
    found = []
    for entry in directory.iterdir():
        match = _STAGED.fullmatch(entry.name)
        if match is None or entry.is_symlink():
            continue
        suffix = match["suffix"] or ""
        if (
            entry.is_dir()
            and not suffix
            or entry.is_file()
            and Path(match["name"]).suffix == suffix
        ):
            found.append(entry)
    return sorted(found)


def remove_leftovers(directory: Path) -> list[Path]:
    """Removes `leftovers(directory)`; returns what it removed. Only a directory's writer
    calls this, holding the directory's lock: a staged file of a write in progress looks the
    same as a killed one's."""
    removed = leftovers(directory)
    for path in removed:
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
    return removed
