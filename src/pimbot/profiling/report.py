"""Run directories of a profile: traces, latency samples, summary and figure.

Everything here works from plain rows and arrays; `plot_profiles` reads the
run directories back (figures are rebuilt from artifacts only).
"""

from __future__ import annotations

import csv
import re
from pathlib import Path
from typing import Any

import numpy as np

from pimbot.atomic_files import save_figure
from pimbot.profiling import process_cpu
from pimbot.training import store

TRACE = "trace.csv"
LATENCY = "latency.csv"
UPDATES = "updates.csv"
SEGMENTS = "segments.csv"
CPU_WINDOWS = "cpu_windows.csv"
SUMMARY = "summary.json"
FIGURE = "profile.png"
PER_CORE = re.compile(r"cpu\d+_percent")
"""psutil's per-core CPU % columns of a trace row."""


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


def other_load_cores(rows: list[dict[str, Any]]) -> float | None:
    """Mean CPU the rest of the machine used while these samples were taken, in cores: the
    system-wide busy cores (psutil's total % × its per-core count) less this process's
    own; None without both readings."""
    loads = []
    for row in rows:
        system, own = row.get("cpu_percent"), row.get("process_cpu_percent")
        cores = sum(1 for k in row if PER_CORE.fullmatch(k))
        if system is not None and own is not None and cores:
            loads.append(max(system / 100.0 * cores - own / 100.0, 0.0))
    return float(np.mean(loads)) if loads else None


def _amortized_ms(decisions: np.ndarray, updates: np.ndarray) -> float | None:
    return 1e3 * float(decisions.sum() + updates.sum()) / decisions.size if decisions.size else None


def _mean_ms(parts: list[np.ndarray]) -> float | None:
    values = np.concatenate(parts or [np.zeros(0)])
    return 1e3 * float(values.mean()) if values.size else None


def _cadence_summary(
    cadence: int, segments, rows: list[dict[str, Any]], cores: int
) -> dict[str, Any]:
    """One cadence's segments: decisions, updates, the amortized time per decision (its
    decision latencies and update times summed, over its decisions; `amortized_p50_ms`:
    the median decision latency + the median update time / cadence, which pre-emption by
    other work on the machine moves less; `amortized_cpu_ms`: the same from the process's
    CPU time over each decision and update, which other work on the machine does not
    lengthen but which misses a GPU's work), rates and CPU."""
    lat = np.concatenate([s.latencies_s for s in segments] or [np.zeros(0)])
    upd = np.concatenate([s.update_times_s for s in segments] or [np.zeros(0)])
    wall = float(sum(s.wall_s for s in segments))
    timed = float(lat.sum() + upd.sum())
    cpu = process_cpu.stats(
        np.vstack([s.cpu_windows for s in segments] or [np.zeros((0, 2))]), cores
    )
    update = percentiles(upd)
    return {
        "decisions": int(lat.size),
        "updates": int(upd.size),
        "segments": len(segments),
        "steady_wall_s": wall,
        "latency_ms": percentiles(lat),
        "update_ms": {k: update[k] for k in ("p50", "max", "mean", "count")},
        "amortized_ms": 1e3 * timed / lat.size if lat.size else None,
        "amortized_p50_ms": (
            update["p50"] / cadence + percentiles(lat)["p50"] if lat.size and upd.size else None
        ),
        "decisions_per_s": lat.size / wall if wall > 0 else None,
        "timed_decisions_per_s": lat.size / timed if timed > 0 else None,
        "decision_cpu_ms": _mean_ms([s.decision_cpu_s for s in segments]),
        "update_cpu_ms": _mean_ms([s.update_cpu_s for s in segments]),
        "amortized_cpu_ms": _amortized_ms(
            np.concatenate([s.decision_cpu_s for s in segments] or [np.zeros(0)]),
            np.concatenate([s.update_cpu_s for s in segments] or [np.zeros(0)]),
        ),
        "per_round_amortized_ms": {
            str(s.round): _amortized_ms(s.latencies_s, s.update_times_s)
            for s in segments
            if s.latencies_s.size
        },
        "per_round_amortized_cpu_ms": {
            str(s.round): _amortized_ms(s.decision_cpu_s, s.update_cpu_s)
            for s in segments
            if s.latencies_s.size
        },
        "other_load_cores": other_load_cores(rows),
        "process_cpu": cpu,
        "mean_system_cpu_percent": _mean([r.get("cpu") for r in rows]),
        "mean_gpu_percent": _mean([r.get("gpu") for r in rows]),
    }


def summarize(
    config: dict, loop, rows: list[dict[str, Any]], sensors: dict[str, bool], cores: int
) -> dict:
    """The summary of one controller's run (milliseconds, seconds, watts, joules, °C):
    pooled over its steady state, and per cadence under "cadences" (keys: the cadence
    as a string). CPU: the process's own, in % of the `cores` it may use (mean, p95, max
    over windows), and the machine's system-wide % (sampled) apart."""
    steady = [r for r in rows if r["phase"] == "steady"]
    decisions = int(loop.latencies_s.size)
    temps = [r["temp"] for r in rows if r.get("temp") is not None]
    update = percentiles(loop.update_times_s)
    windows = np.vstack([s.cpu_windows for s in loop.segments] or [np.zeros((0, 2))])
    cadences = sorted({s.cadence for s in loop.segments})
    return {
        "config": config,
        "latency_ms": percentiles(loop.latencies_s),
        "decisions_per_s": decisions / loop.steady_wall_s if loop.steady_wall_s > 0 else None,
        "update_ms": {k: update[k] for k in ("p50", "max", "mean", "count")},
        "steady_wall_s": loop.steady_wall_s,
        "compile_s": loop.compile_s,
        "warmup_s": loop.warmup_s,
        "env_steps": loop.env_steps,
        "played_decisions_per_update": loop.played_per_update,
        "usable_cores": cores,
        "process_cpu": process_cpu.stats(windows, cores),
        "mean_system_cpu_percent": _mean([r.get("cpu") for r in steady]),
        "other_load_cores": other_load_cores(steady),
        "mean_gpu_percent": _mean([r.get("gpu") for r in steady]),
        "mean_power_w": _mean([r.get("power") for r in steady]),
        "energy_j": energy_j(rows),
        "peak_temp_c": max(temps) if temps else None,
        "sensors": sensors,
        "live_sensors": [name for name, live in sensors.items() if live],
        "cadences": {
            str(c): _cadence_summary(
                c, loop.cadence(c), [r for r in steady if r.get("cadence") == c], cores
            )
            for c in cadences
        },
    }


def overhead(admo, benign) -> dict[str, float] | None:
    """ADMO against benign: both values, the difference and the percent change."""
    if admo is None or benign is None or benign == 0:
        return None
    return {
        "benign": benign,
        "admo": admo,
        "diff": admo - benign,
        "percent": 100.0 * (admo - benign) / benign,
    }


def _per_round(admo: dict, benign: dict, key: str) -> list[float]:
    """ADMO's overhead in % of benign per round, for the rounds both ran."""
    a, b = admo[key], benign[key]
    return [100.0 * (a[r] - b[r]) / b[r] for r in a if r in b and b[r]]


def compare(benign: dict, admo: dict, training: dict[str, int]) -> dict:
    """ADMO's overhead over the benign run, per cadence and at the training cadence.

    The amortized overhead at a cadence is ADMO's extra time per decision with its update
    cost spread over the decisions between updates: the difference of the amortized times
    per decision (decision latency + update time / cadence, both measured) in % of the
    benign one; `per_round_percent` is the same per round (the two controllers' segments
    of a round ran back to back); `amortized_cpu_ms` and `per_round_cpu_percent` the same
    from the process's CPU time. `judged_cadence` is the training cadence where it was
    profiled, else None.
    """
    cadences = {}
    for key in benign["cadences"]:
        if key not in admo["cadences"]:
            continue
        b, a = benign["cadences"][key], admo["cadences"][key]
        cadences[key] = {
            "amortized_ms": overhead(a["amortized_ms"], b["amortized_ms"]),
            "amortized_p50_ms": overhead(a["amortized_p50_ms"], b["amortized_p50_ms"]),
            "amortized_cpu_ms": overhead(a["amortized_cpu_ms"], b["amortized_cpu_ms"]),
            "decisions_per_s": overhead(a["decisions_per_s"], b["decisions_per_s"]),
            "latency_mean_ms": overhead(a["latency_ms"]["mean"], b["latency_ms"]["mean"]),
            "update_mean_ms": overhead(a["update_ms"]["mean"], b["update_ms"]["mean"]),
            "process_cpu_mean": overhead(a["process_cpu"]["mean"], b["process_cpu"]["mean"]),
            "per_round_percent": _per_round(a, b, "per_round_amortized_ms"),
            "per_round_cpu_percent": _per_round(a, b, "per_round_amortized_cpu_ms"),
        }
    judged = training["decisions_per_update"]
    judged = judged if str(judged) in cadences else None
    update_per_decision = None
    if judged is not None:
        at = cadences[str(judged)]
        if at["update_mean_ms"] is not None and benign["latency_ms"]["mean"]:
            per_decision = at["update_mean_ms"]["diff"] / judged
            update_per_decision = {
                "ms": per_decision,
                "percent_of_decision": 100.0 * per_decision / benign["latency_ms"]["mean"],
            }
    return {
        "training_cadence": {
            **training,
            "played_per_update": {
                "benign": benign["played_decisions_per_update"],
                "admo": admo["played_decisions_per_update"],
            },
        },
        "judged_cadence": judged,
        "cadences": cadences,
        "update_per_decision_ms": update_per_decision,
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
    """trace.csv (sensor samples), latency.csv and updates.csv (one row per decision and
    per update, with its round and cadence), segments.csv (one row per segment: counts,
    times, the process's CPU), cpu_windows.csv and summary.json."""
    run_dir.mkdir(parents=True, exist_ok=True)
    cores = summary["usable_cores"]
    write_csv(run_dir / TRACE, rows)
    latency, updates, segments, windows = [], [], [], []
    for s in loop.segments:
        tag = {"round": s.round, "cadence": s.cadence}
        latency += [
            {"decision": len(latency) + i, **tag, "latency_s": v}
            for i, v in enumerate(s.latencies_s)
        ]
        updates += [
            {"update": len(updates) + i, **tag, "time_s": v} for i, v in enumerate(s.update_times_s)
        ]
        segments.append(
            {
                **tag,
                "decisions": s.latencies_s.size,
                "updates": s.update_times_s.size,
                "wall_s": s.wall_s,
                "decision_s": float(s.latencies_s.sum()),
                "update_s": float(s.update_times_s.sum()),
                "cpu_s": s.cpu_s,
                "process_cpu_percent": 100.0 * s.cpu_s / s.wall_s / cores if s.wall_s else None,
            }
        )
        windows += [
            {**tag, "wall_s": w, "cpu_s": c, "process_cpu_percent": 100.0 * c / w / cores}
            for w, c in s.cpu_windows
            if w > 0
        ]
    write_csv(run_dir / LATENCY, [{"decision": i, **row} for i, row in enumerate(latency)])
    write_csv(run_dir / UPDATES, [{"update": i, **row} for i, row in enumerate(updates)])
    write_csv(run_dir / SEGMENTS, segments)
    write_csv(run_dir / CPU_WINDOWS, windows)
    store.write_json(run_dir / SUMMARY, summary)


def read_trace(run_dir: Path) -> dict[str, np.ndarray]:
    """time_s, cpu (system-wide), process_cpu, gpu, temp columns of a trace (NaN where
    unavailable), steady_start_s."""
    with open(Path(run_dir) / TRACE, newline="") as f:
        rows = list(csv.DictReader(f))

    def column(name):
        return np.array([float(r[name]) if r.get(name) else np.nan for r in rows])

    out = {name: column(name) for name in ("time_s", "cpu", "process_cpu", "gpu", "temp")}
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


def with_breaks(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(t, y) with a NaN point inside every gap longer than 1.5 sampling periods (the
    other controller's segments of an interleaved profile), so a line is not drawn
    across it."""
    if t.size < 3:
        return t, y
    dt = np.diff(t)
    gaps = np.flatnonzero(dt > 1.5 * np.median(dt))
    return np.insert(t, gaps + 1, t[gaps] + dt[gaps] / 2), np.insert(y, gaps + 1, np.nan)


def plot_profiles(run_dirs: dict[str, Path], out: Path, truncate_idle_gpu: bool = False) -> None:
    """Three stacked panels (CPU %: the process's, of the cores it may use, and the
    system's; GPU %; temperature), one column per controller; the warm-up (before
    steady state) is shaded."""
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
                ax.plot(
                    *with_breaks(trace["time_s"], trace[field]), ".-", lw=1.2, ms=3, label="system"
                )
            if field == "cpu" and np.isfinite(trace["process_cpu"]).any():
                process = with_breaks(trace["time_s"], trace["process_cpu"])
                ax.plot(*process, ".-", lw=1.2, ms=3, label="process")
                ax.legend(fontsize=7, loc="upper right")
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
    try:
        save_figure(fig, out, dpi=120)
    finally:
        plt.close(fig)
