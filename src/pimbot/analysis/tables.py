"""Tables of results: estimates with their intervals, their one formatter, Markdown, HTML, CSV.

Every table of `pimbot report` and `pimbot table` is a `Table` of cells; a cell is
text, a number, None (written "–") or an `Estimate` (a mean and its interval over
seeds: a 95 % BCa bootstrap CI at ≥ 5 seeds, the min–max range below; see
pimbot.statistics). The same table is written as Markdown, as HTML and as CSV (an
estimate becomes four columns there: the value, its low and high end, unrounded, and
the interval's kind).
"""

from __future__ import annotations

import csv
import dataclasses
import html
import io
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from pimbot import statistics
from pimbot.analysis.curves import Curves, read_curves
from pimbot.analysis.runs import run_label
from pimbot.errors import InvalidParameter
from pimbot.training import store
from pimbot.training.summary import FINAL_WINDOW

MISSING = "–"
INTERVAL = "[interval]"
"""Header suffix of an estimate column: a 95 % CI or, below 5 seeds, the range."""


@dataclasses.dataclass(frozen=True)
class Estimate:
    """A mean (or a difference of means) and its interval over seeds."""

    mean: float
    lo: float
    hi: float
    digits: int = 3
    signed: bool = False
    """Write every number with its sign (differences, margins)."""
    kind: str = statistics.CI
    """statistics.CI (95 % CI, written "m [lo, hi]") or statistics.RANGE (min–max over
    seeds, written "m (range lo … hi)")."""

    def __str__(self) -> str:
        return statistics.text(self.mean, self.lo, self.hi, self.kind, self.digits, self.signed)


def estimate(samples: np.ndarray, digits: int = 3, signed: bool = False) -> Estimate | None:
    """Mean of per-seed `samples` with its interval (statistics.mean_interval); None
    without samples."""
    samples = np.asarray(samples, dtype=float)
    if samples.size == 0:
        return None
    interval = statistics.mean_interval(samples)
    return Estimate(float(samples.mean()), interval.lo, interval.hi, digits, signed, interval.kind)


def difference(a: np.ndarray, b: np.ndarray, digits: int = 3) -> Estimate | None:
    """Mean of a − mean of b with its interval (seeds resampled independently)."""
    if np.size(a) == 0 or np.size(b) == 0:
        return None
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    interval = statistics.difference_interval(a, b)
    mean = float(a.mean() - b.mean())
    return Estimate(mean, interval.lo, interval.hi, digits, True, interval.kind)


def fmt(value: Any, digits: int = 3) -> str:
    """The one cell formatter: None → "–", floats to `digits` places, estimates as
    "mean [lo, hi]"."""
    if value is None:
        return MISSING
    if isinstance(value, float | np.floating):
        return f"{value:.{digits}f}"
    return str(value)


@dataclasses.dataclass
class Table:
    header: list[str]
    rows: list[list[Any]]
    title: str = ""
    """A heading of its own inside the section (empty: none)."""
    note: str = ""
    """A paragraph written above the table."""
    name: str = ""
    """File name of its CSV (without .csv); empty: derived from the section."""


def markdown_lines(table: Table, level: int = 3) -> list[str]:
    lines = [f"{'#' * level} {table.title}", ""] if table.title else []
    lines += [table.note, ""] if table.note else []
    lines += ["| " + " | ".join(map(markdown_cell, table.header)) + " |"]
    lines += ["|" + " --- |" * len(table.header)]
    lines += ["| " + " | ".join(markdown_cell(fmt(c)) for c in row) + " |" for row in table.rows]
    return lines + [""]


def markdown_cell(text: str) -> str:
    """`text` as one Markdown table cell: HTML and the cell separator escaped, lines joined
    (a plugin's env id or parameter is data, never markup; report.html escapes alike)."""
    text = " ".join(str(text).splitlines())
    text = re.sub(r"&(?=#?\w+;)", "&amp;", text)  # what would read as an entity
    text = re.sub(r"<(?=[A-Za-z/!?])", "&lt;", text)  # what would open a tag ("0.2 < 0.8" stays)
    return text.replace("|", "\\|")


def html_table(table: Table, level: int = 3) -> str:
    parts = [f"<h{level}>{html.escape(table.title)}</h{level}>"] if table.title else []
    parts += [f"<p>{html.escape(table.note)}</p>"] if table.note else []
    head = "".join(f"<th>{html.escape(h)}</th>" for h in table.header)
    body = [
        "<tr>" + "".join(f"<td>{html.escape(fmt(cell))}</td>" for cell in row) + "</tr>"
        for row in table.rows
    ]
    return "".join(parts) + f"<table><tr>{head}</tr>{''.join(body)}</table>"


def write_csv(table: Table, path: Path) -> None:
    """One CSV row per table row; an estimate column becomes `col`, `col lo`, `col hi`,
    `col interval` (unrounded; the interval's kind: ci or range; the column's "[…]"
    suffix dropped)."""
    estimates = [
        any(isinstance(row[i], Estimate) for row in table.rows) for i in range(len(table.header))
    ]
    header: list[str] = []
    for name, is_estimate in zip(table.header, estimates, strict=True):
        base = re.sub(r"\s*\[[^\]]*\]$", "", name)  # "success [CI]" -> success, lo, hi
        header += [base, f"{base} lo", f"{base} hi", f"{base} interval"] if is_estimate else [name]
    buffer = io.StringIO(newline="")
    writer = csv.writer(buffer)
    writer.writerow(header)
    for row in table.rows:
        out: list[Any] = []
        for cell, is_estimate in zip(row, estimates, strict=True):
            if not is_estimate:
                out.append("" if cell is None else cell)
            elif isinstance(cell, Estimate):
                out += [cell.mean, cell.lo, cell.hi, cell.kind]
            else:
                out += ["", "", "", ""]
        writer.writerow(out)
    store.write_atomic(path, buffer.getvalue().encode())


# --- any metrics.csv column: `--metric`, plugins' metrics ------------------------------

ROW_KEYS = ("iteration", "seed")
"""metrics.csv columns that say where a row is, not what was measured."""
PER_AGENT = re.compile(r"^(.*)/agent_(\d+)$")


def metric_columns(curves: Iterable[Curves]) -> list[str]:
    """Every measured column of the runs' metrics.csv, in order of first appearance."""
    seen: dict[str, None] = {}
    for run in curves:
        seen.update((c, None) for c in run.columns if c not in ROW_KEYS)
    return list(seen)


def columns_text(columns: list[str]) -> str:
    """The columns, comma-separated; a metric's per-agent columns written once, as
    `NAME/agent_0…K`."""
    agents: dict[str, list[int]] = {}
    for column in columns:
        match = PER_AGENT.match(column)
        if match:
            agents.setdefault(match[1], []).append(int(match[2]))
    out: dict[str, None] = {}
    for column in columns:
        match = PER_AGENT.match(column)
        indices = sorted(agents[match[1]]) if match else []
        if len(indices) > 1:
            column = f"{match[1]}/agent_{indices[0]}…{indices[-1]}"
        out[column] = None
    return ", ".join(out)


def check_metrics(metrics: Iterable[str], curves: list[Curves]) -> None:
    """Raises InvalidParameter (one line listing the columns there are) for a name in
    `metrics` that no run's metrics.csv has."""
    available = metric_columns(curves)
    for name in metrics:
        if name not in available:
            raise InvalidParameter(
                f"metric: no column {name!r} in the runs' metrics.csv; available: "
                f"{columns_text(available)}"
            )


def final_per_seed(curves: Curves, column: str) -> np.ndarray:
    """Per seed, the mean of the finite values among the last FINAL_WINDOW evaluations of
    `column` (a NaN an attack logs for "not yet" is left out; a seed with none is
    dropped); [] where the run did not log it."""
    if not curves.has(column):
        return np.array([])
    out = []
    for seed in curves.seeds:
        last = np.asarray(curves.values[seed][column][-FINAL_WINDOW:], dtype=float)
        last = last[np.isfinite(last)]
        if last.size:
            out.append(float(last.mean()))
    return np.array(out)


def final_estimate(curves: Curves, column: str, digits: int = 3) -> Estimate | None:
    """The final value of any metrics.csv column with its interval over seeds (None: not
    logged, or never finite)."""
    return estimate(final_per_seed(curves, column), digits)


# --- `pimbot table` --------------------------------------------------------------------


def _final(summary: dict, column: str) -> Estimate | None:
    """The final value of `column` with its interval, from the per-seed finals."""
    entry = summary["final"].get(column)
    return None if entry is None else estimate(np.array(entry["per_seed"]))


def summary_table(run_dirs: list[Path], metrics: tuple[str, ...] = ()) -> str:
    """One row per run: final success, return ratio, team return, convergence, speed, and
    the final value of every column named in `metrics` (any column of metrics.csv).

    Raises:
        InvalidParameter: a name in `metrics` no run logged (before anything is made).
    """
    from pimbot.training.summary import summarize

    curves = [read_curves(run_dir) for run_dir in run_dirs] if metrics else []
    check_metrics(metrics, curves)
    rows = []
    for k, run_dir in enumerate(run_dirs):
        # Final metrics and convergence recomputed from metrics.csv (the primary record).
        summary = {**store.read_json(run_dir / store.SUMMARY), **summarize(run_dir)}
        conv = summary["convergence"]
        iqr = "[" + ", ".join("∞" if q is None else f"{q:.0f}" for q in conv["iqr"]) + "]"
        rows.append(
            [
                run_label(run_dir),
                summary["iterations"],
                len(summary["seeds"]),
                _final(summary, "eval/success"),
                _final(summary, "eval/return_ratio"),
                f"{conv['converged_seeds']}/{len(summary['seeds'])}",
                f"{fmt(conv['median'], 0)} {iqr}",
                fmt(conv["first_crossing_median"], 0),
                fmt(summary["iters_per_s_mean"], 0),  # None: not timed (an original-code log)
                *(final_estimate(curves[k], metric) for metric in metrics),
            ]
        )
    header = [
        "run",
        "iterations",
        "seeds",
        f"final success {INTERVAL}",
        f"final return ratio {INTERVAL}",
        "converged seeds",
        "convergence median [IQR]",
        "first crossing median",
        "it/s",
        *(f"final {metric} {INTERVAL}" for metric in metrics),
    ]
    lines = markdown_lines(Table(header, rows))[:-1]
    return "\n".join(lines + ["", statistics.interval_text(row[2] for row in rows)]) + "\n"
