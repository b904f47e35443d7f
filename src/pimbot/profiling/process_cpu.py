"""The profiled process's own CPU use, relative to the cores it may run on.

`seconds()` is the process's user + system CPU time over all its threads
(time.process_time: CLOCK_PROCESS_CPUTIME_ID, nanosecond resolution where the
platform has it; children excluded); a window's CPU % is its CPU
seconds over its wall seconds, 100 % = one core busy. `stats` puts it against
the cores the process may use (its affinity mask), which is what saturation
means for this process; the machine's system-wide CPU % is a different
quantity, sampled by `samplers.PsutilSensor`.
"""

from __future__ import annotations

import os
import time

import numpy as np


def seconds() -> float:
    """CPU seconds (user + system, all threads) this process has used."""
    return time.process_time()


def usable_cores() -> int:
    """Cores this process may run on (its affinity mask; the CPU count elsewhere)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def stats(windows: np.ndarray, cores: int) -> dict[str, float | int | None]:
    """Process CPU over windows [k, 2] of (wall s, CPU s), as % of `cores` cores:
    the time-weighted mean, p95 and max over windows, and the mean in % of one core."""
    windows = np.asarray(windows, dtype=float).reshape(-1, 2)
    wall, cpu = windows[:, 0], windows[:, 1]
    keep = wall > 0
    if not keep.any():
        return {"mean": None, "p95": None, "max": None, "one_core_mean": None, "windows": 0}
    percent = 100.0 * cpu[keep] / wall[keep] / cores
    mean = 100.0 * cpu[keep].sum() / wall[keep].sum() / cores
    return {
        "mean": float(mean),
        "p95": float(np.percentile(percent, 95)),
        "max": float(percent.max()),
        "one_core_mean": float(mean * cores),
        "windows": int(keep.sum()),
    }
