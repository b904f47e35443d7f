"""Process-level JAX setup for the command line, benchmarks and tests.

Both settings must be applied before the first computation (the core count
before jax is even imported); library code never calls them implicitly.
"""

from __future__ import annotations

import os
from pathlib import Path

CACHE_ENV = "PIMBOT_CACHE_DIR"


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

    The directory is $PIMBOT_CACHE_DIR, else ~/.cache/pimbot/jax; set
    PIMBOT_CACHE_DIR=off to disable it.
    """
    import jax

    unroll_cpu_threefry()
    setting = os.environ.get(CACHE_ENV, "")
    if setting.lower() == "off":
        return None
    path = Path(setting) if setting else Path.home() / ".cache" / "pimbot" / "jax"
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    return path


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
