"""Run directories of a profile: traces, latency samples, summary and figure.

Everything here works from plain rows and arrays; `plot_profiles` reads the
run directories back (figures are rebuilt from artifacts only).
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np

from pimbot.experiment import store

TRACE = "trace.csv"
LATENCY = "latency.csv"
UPDATES = "updates.csv"
SUMMARY = "summary.json"
FIGURE = "profile.png"


def percentiles(values: np.ndarray, scale: float = 1e3) -> dict[str, float | int | None]:
    """p50/p95/p99/max/mean (× `scale`, ms by default) and count; None when empty."""
    values = np.asarray(values, dtype=float)
    if values.size == 0:
        return {"p50": None, "p95": None, "p99": None, "max": None, "mean": None, "count": 0}
    p50, p95, p99 = np.percentile(values, [50, 95, 99]) * scale
    return {
        "p50": float(p50),
        "p95": float(p95),
        "p99": float(p99),
        "max": float(values.max() * scale),
        "mean": float(values.mean() * scale),
        "count": int(values.size),
    }


def _mean(values: list) -> float | None:
    present = [v for v in values if v is not None]
    return float(np.mean(present)) if present else None


def energy_j(rows: list[dict[str, Any]]) -> float | None:
    """Energy over the steady-state samples: counter deltas where any counter is live
    (NVML, RAPL), else the `power` column integrated over time; None without power."""
    rows = [r for r in rows if r["phase"] == "steady"]
    counters = [
        [r[c] for r in rows if r.get(c) is not None] for c in ("gpu_energy_j", "rapl_energy_j")
    ]
    if any(counters):
        return float(sum(sum(c) for c in counters))
    points = [(r["time_s"], r["power"]) for r in rows if r.get("power") is not None]
    if len(points) < 2:
        return None
    t, p = np.array(points).T
    return float(np.sum(np.diff(t) * (p[1:] + p[:-1]) / 2))


def summarize(config: dict, loop, rows: list[dict[str, Any]], sensors: dict[str, bool]) -> dict:
    """The summary of one controller's run (milliseconds, seconds, watts, joules, °C)."""
    steady = [r for r in rows if r["phase"] == "steady"]
    decisions = int(loop.latencies_s.size)
    temps = [r["temp"] for r in rows if r.get("temp") is not None]
    update = percentiles(loop.update_times_s)
    return {
        "config": config,
        "latency_ms": percentiles(loop.latencies_s),
        "decisions_per_s": decisions / loop.steady_wall_s if loop.steady_wall_s > 0 else None,
        "update_ms": {k: update[k] for k in ("p50", "max", "mean", "count")},
        "steady_wall_s": loop.steady_wall_s,
        "compile_s": loop.compile_s,
        "warmup_s": loop.warmup_s,
        "env_steps": loop.env_steps,
        "mean_cpu_percent": _mean([r.get("cpu") for r in steady]),
        "mean_gpu_percent": _mean([r.get("gpu") for r in steady]),
        "mean_power_w": _mean([r.get("power") for r in steady]),
        "energy_j": energy_j(rows),
        "peak_temp_c": max(temps) if temps else None,
        "sensors": sensors,
        "live_sensors": [name for name, live in sensors.items() if live],
    }


def compare(benign: dict, admo: dict) -> dict:
    """ADMO's overhead over the benign run: decision time and per update step."""

    def overhead(a, b):
        if a is None or b is None or b == 0:
            return None
        return {"benign": b, "admo": a, "diff": a - b, "percent": 100.0 * (a - b) / b}

    update_every = benign["config"]["update_every"]
    update = overhead(admo["update_ms"]["mean"], benign["update_ms"]["mean"])
    amortized = None
    if update is not None and benign["latency_ms"]["mean"]:
        per_decision = update["diff"] / update_every
        amortized = {
            "ms": per_decision,
            "percent_of_decision": 100.0 * per_decision / benign["latency_ms"]["mean"],
        }
    return {
        "update_per_decision_ms": amortized,
        "latency_p50_ms": overhead(admo["latency_ms"]["p50"], benign["latency_ms"]["p50"]),
        "latency_mean_ms": overhead(admo["latency_ms"]["mean"], benign["latency_ms"]["mean"]),
        "update_p50_ms": overhead(admo["update_ms"]["p50"], benign["update_ms"]["p50"]),
        "decisions_per_s": overhead(admo["decisions_per_s"], benign["decisions_per_s"]),
        "mean_power_w": overhead(admo["mean_power_w"], benign["mean_power_w"]),
    }


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    """Rows to CSV; None becomes an empty cell (unavailable, never 0)."""
    columns: list[str] = []
    for row in rows:
        columns += [c for c in row if c not in columns]
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, restval="")
        writer.writeheader()
        writer.writerows({k: ("" if v is None else v) for k, v in r.items()} for r in rows)


def write_run(run_dir: Path, loop, rows, summary: dict) -> None:
    run_dir.mkdir(parents=True, exist_ok=True)
    write_csv(run_dir / TRACE, rows)
    write_csv(
        run_dir / LATENCY, [{"decision": i, "latency_s": v} for i, v in enumerate(loop.latencies_s)]
    )
    write_csv(
        run_dir / UPDATES, [{"update": i, "time_s": v} for i, v in enumerate(loop.update_times_s)]
    )
    store.write_json(run_dir / SUMMARY, summary)


def read_trace(run_dir: Path) -> dict[str, np.ndarray]:
    """time_s, cpu, gpu, temp columns of a trace (NaN where unavailable), steady_start_s."""
    with open(Path(run_dir) / TRACE, newline="") as f:
        rows = list(csv.DictReader(f))

    def column(name):
        return np.array([float(r[name]) if r.get(name) else np.nan for r in rows])

    out = {name: column(name) for name in ("time_s", "cpu", "gpu", "temp")}
    steady = [float(r["time_s"]) for r in rows if r.get("phase") == "steady"]
    out["steady_start_s"] = steady[0] if steady else None
    return out


def truncate_idle(trace: dict[str, np.ndarray], min_idle_s: float = 5.0) -> dict[str, np.ndarray]:
    """Cuts zero-GPU stretches longer than `min_idle_s` down to `min_idle_s` (time re-based)."""
    t, gpu = trace["time_s"], trace["gpu"]
    if t.size == 0 or np.all(np.isnan(gpu)):
        return trace
    keep = np.ones(t.size, bool)
    shift = np.zeros(t.size)
    start = None
    for i in range(t.size + 1):
        idle = i < t.size and gpu[i] == 0
        if idle and start is None:
            start = i
        elif not idle and start is not None:
            if t[i - 1] - t[start] > min_idle_s:
                cut = (t[start] + min_idle_s < t[start:i]) & (t[start:i] <= t[i - 1])
                keep[start:i] &= ~cut
                removed = t[i - 1] - t[start] - min_idle_s
                shift[i:] += removed
            start = None
    out = {k: (v[keep] if isinstance(v, np.ndarray) else v) for k, v in trace.items()}
    out["time_s"] = (t - shift)[keep]
    if out.get("steady_start_s") is not None:
        out["steady_start_s"] -= float(np.interp(out["steady_start_s"], t, shift))
    return out


def plot_profiles(run_dirs: dict[str, Path], out: Path, truncate_idle_gpu: bool = False) -> None:
    """Three stacked panels (CPU %, GPU %, temperature), one column per controller;
    the warm-up (before steady state) is shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(run_dirs)
    fig, axes = plt.subplots(
        3, len(names), figsize=(5 * len(names), 7), sharex="col", squeeze=False
    )
    labels = [("cpu", "CPU %"), ("gpu", "GPU %"), ("temp", "temperature °C")]
    for col, name in enumerate(names):
        trace = read_trace(run_dirs[name])
        if truncate_idle_gpu:
            trace = truncate_idle(trace)
        for row, (field, label) in enumerate(labels):
            ax = axes[row][col]
            if np.all(np.isnan(trace[field])):
                ax.text(0.5, 0.5, "unavailable", ha="center", va="center", transform=ax.transAxes)
            else:
                ax.plot(trace["time_s"], trace[field], lw=1.2)
            if field != "temp":
                ax.set_ylim(0, 105)
            steady = trace["steady_start_s"]
            if steady is not None:
                ax.axvspan(trace["time_s"][0], steady, color="0.9", lw=0)
            if col == 0:
                ax.set_ylabel(label)
            if row == 0:
                ax.set_title(name)
        axes[-1][col].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)
