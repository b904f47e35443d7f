"""Markdown tables of final metrics and convergence, from run directories' summary.json."""

from __future__ import annotations

from pathlib import Path

from pimbot.analysis.plots import run_label
from pimbot.experiment import store
from pimbot.experiment.runner import summarize


def _cell(summary: dict, column: str) -> str:
    entry = summary["final"].get(column)
    if entry is None:
        return "–"
    lo, hi = entry["ci95"]
    return f"{entry['mean']:.3f} [{lo:.3f}, {hi:.3f}]"


def summary_table(run_dirs: list[Path]) -> str:
    """One row per run: final success, return ratio, team return, convergence, speed."""
    lines = [
        "| run | iterations | seeds | final success [95 % CI] | final return ratio [95 % CI] "
        "| converged seeds | convergence median [IQR] | first crossing median | it/s |",
        "| --- | ---: | ---: | --- | --- | ---: | --- | ---: | ---: |",
    ]
    for run_dir in run_dirs:
        # Final metrics and convergence recomputed from metrics.csv (the primary record).
        summary = {**store.read_json(run_dir / store.SUMMARY), **summarize(run_dir)}
        conv = summary["convergence"]
        crossing = conv["first_crossing_median"]
        first = "–" if crossing is None else f"{crossing:.0f}"
        median = "–" if conv["median"] is None else f"{conv['median']:.0f}"
        iqr = "[" + ", ".join("∞" if q is None else f"{q:.0f}" for q in conv["iqr"]) + "]"
        lines.append(
            f"| {run_label(run_dir)} | {summary['iterations']} | {len(summary['seeds'])} "
            f"| {_cell(summary, 'eval/success')} | {_cell(summary, 'eval/return_ratio')} "
            f"| {conv['converged_seeds']}/{len(summary['seeds'])} | {median} {iqr} | {first} "
            f"| {summary['iters_per_s_mean']:.0f} |"
        )
    return "\n".join(lines) + "\n"
