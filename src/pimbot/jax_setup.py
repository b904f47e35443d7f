"""Process-level JAX setup for the command line, benchmarks and tests.

Both settings must be applied before the first computation (the core count
before jax is even imported); library code never calls them implicitly. The cache's
directory is keyed by pimbot's sources and the loaded plugin files (`cache_dir`), so a
plugin loaded after it was enabled moves it (`refresh_compilation_cache`).
"""

from __future__ import annotations

import functools
import hashlib
import os
import shutil
import sys
import time
from collections.abc import Iterable
from pathlib import Path

CACHE_ENV = "PIMBOT_CACHE_DIR"
"""The root of the persistent compilation cache ("off" disables it)."""
CACHE_PREFIX = "pimbot-"
"""The name of every cache directory under the root starts with it (`cache_dir`)."""
KEEP_VERSIONS = 4
"""Cache directories (code versions) kept under the root whatever their age."""
STALE_AFTER_S = 24 * 3600.0
"""A cache directory beyond `KEEP_VERSIONS` is removed once unused for this long (a
process writing entries marks its directory used: a day covers a long suite)."""


def use_all_cpu_cores() -> None:
    """Exposes one XLA host device per CPU core, so seeds can be sharded over cores.

    Must run before jax is imported; it does not affect GPU backends.
    """
    if hasattr(os, "sched_getaffinity"):
        cores = len(os.sched_getaffinity(0))
    else:
        cores = os.cpu_count() or 1
    flags = os.environ.get("XLA_FLAGS", "")
    if cores > 1 and "xla_force_host_platform_device_count" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={cores}".strip()


def enable_compilation_cache() -> Path | None:
    """Turns on JAX's persistent compilation cache (a rerun or resume skips recompiling),
    and `unroll_cpu_threefry` (every process that trains calls this).

    The cache lives in one directory per code version (`cache_dir`) under the root
    $PIMBOT_CACHE_DIR, else ~/.cache/pimbot/jax (PIMBOT_CACHE_DIR=off disables it): an
    entry is only ever served to the pimbot sources and plugin files that made it. Every
    program is cached, however small or quick to compile. Loading a plugin later moves
    the cache to its new directory (`refresh_compilation_cache`). Returns the directory,
    or None when the cache is off or its directory cannot be made.
    """
    import jax

    unroll_cpu_threefry()
    root = cache_root()
    if root is None:
        return None
    path = cache_dir(root)
    try:
        path.mkdir(parents=True, exist_ok=True)
        os.utime(path)  # its last use, for `prune_cache_dirs`
    except OSError:
        return None
    _point_jax_at(str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)  # no size floor
    prune_cache_dirs(root, keep=path)
    return path


def refresh_compilation_cache() -> Path | None:
    """Moves an enabled cache to the directory of the plugins loaded now (called after a
    plugin loads); None, changing nothing, where this process has not enabled it."""
    if active_cache_dir() is None:
        return None
    return enable_compilation_cache()


def active_cache_dir() -> Path | None:
    """The cache directory this process enabled (`enable_compilation_cache`), else None."""
    if "jax" not in sys.modules:
        return None
    import jax

    current = jax.config.jax_compilation_cache_dir
    if not current or not Path(current).name.startswith(CACHE_PREFIX):
        return None
    return Path(current)


def marker(kind: str, text: str) -> Path | None:
    """A file under the active cache directory that stands for `text` (by its sha256),
    kept beside the compiled programs of the same code: e.g. a check that passed once
    for this code (`kind`: its folder). None without an active cache."""
    base = active_cache_dir()
    if base is None:
        return None
    return base / kind / hashlib.sha256(text.encode()).hexdigest()


def _point_jax_at(path: str) -> None:
    """Sets JAX's cache directory; a cache JAX opened at another directory is closed first
    (it opens the new one at its next compile)."""
    import jax
    from jax.experimental.compilation_cache import compilation_cache

    if jax.config.jax_compilation_cache_dir != path:
        compilation_cache.reset_cache()
        jax.config.update("jax_compilation_cache_dir", path)


def cache_root() -> Path | None:
    """The root of the cache directories: $PIMBOT_CACHE_DIR, else ~/.cache/pimbot/jax;
    None for PIMBOT_CACHE_DIR=off."""
    setting = os.environ.get(CACHE_ENV, "")
    if setting.lower() == "off":
        return None
    return Path(setting).expanduser() if setting else Path.home() / ".cache" / "pimbot" / "jax"


def cache_dir(root: Path, plugin_digests: Iterable[str] | None = None) -> Path:
    """The cache directory of this code: ``ROOT/pimbot-VERSION-KEY``, KEY a digest of
    `source_digest` (pimbot's version and sources), the JAX version and the sha256 of each
    plugin file (those this process has loaded where `plugin_digests` is None)."""
    import pimbot

    if plugin_digests is None:
        plugin_digests = loaded_plugin_digests()
    key = hashlib.sha256(source_digest().encode())
    key.update(_jax_version().encode())
    for digest in sorted(set(plugin_digests)):
        key.update(digest.encode())
    return root / f"{CACHE_PREFIX}{pimbot.__version__}-{key.hexdigest()[:16]}"


def loaded_plugin_digests() -> list[str]:
    """The sha256 of each plugin file this process has loaded (`plugins.provenance`)."""
    from pimbot import plugins

    return [r["sha256"] or r["plugin"] for r in plugins.provenance()]


@functools.cache
def source_digest() -> str:
    """sha256 of pimbot's version and of every .py file of the package (path and bytes):
    a source checkout changes it with every edit, an install with every release."""
    import pimbot

    package = Path(pimbot.__file__).parent
    digest = hashlib.sha256(pimbot.__version__.encode())
    for path in sorted(package.rglob("*.py")):
        digest.update(path.relative_to(package).as_posix().encode() + b"\0")
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _jax_version() -> str:
    import jax

    return jax.__version__


def prune_cache_dirs(root: Path, keep: Path, versions: int = KEEP_VERSIONS) -> list[Path]:
    """Removes the cache directories under `root` beyond the `versions` used last that have
    not been used for `STALE_AFTER_S` (a process of another version may still be running
    on a recent one), never `keep`; returns those removed. Only ``pimbot-*`` directories
    are touched, whatever else `root` holds."""
    try:
        dirs = [p for p in root.iterdir() if p.is_dir() and p.name.startswith(CACHE_PREFIX)]
        dirs.sort(key=lambda p: p.stat().st_mtime, reverse=True)
    except OSError:
        return []
    removed = []
    now = time.time()
    for path in dirs[versions:]:
        try:
            stale = now - path.stat().st_mtime > STALE_AFTER_S
        except OSError:
            continue
        if stale and path != keep:
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    return removed


def unroll_cpu_threefry() -> bool:
    """Lowers the threefry PRNG on the CPU with its five rounds unrolled, as on GPU.

    JAX's CPU lowering rolls them into a five-trip while loop per random call; a LIO
    iteration makes dozens of small random calls (key splits, action sampling, inside the
    rollout's loop), each then a nested loop of tiny kernels with its carried buffers
    copied every trip (~2300 of a clean ER(2,1) iteration's ~3000 executed HLO ops). The
    unrolled hash is the same integer arithmetic, so every random number, and every
    result, is bit-identical; XLA fuses it into one kernel, and the programs compile
    faster. Returns False (nothing changed) where this JAX has no such lowering.
    """
    try:
        from jax._src.interpreters import mlir
        from jax._src.random import threefry2x32
    except ImportError:
        return False
    rule = getattr(threefry2x32, "_threefry2x32_lowering_rule", None)
    primitive = getattr(threefry2x32, "threefry2x32_p", None)
    if rule is None or primitive is None:
        return False
    mlir.register_lowering(primitive, rule, platform="cpu")
    return True
