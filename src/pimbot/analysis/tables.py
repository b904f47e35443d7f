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
from pathlib import Path
from typing import Any

import numpy as np

from pimbot import statistics
from pimbot.training import store

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


# --- `pimbot table` --------------------------------------------------------------------


def _final(summary: dict, column: str) -> Estimate | None:
    """The final value of `column` with its interval, from the per-seed finals."""
    entry = summary["final"].get(column)
    return None if entry is None else estimate(np.array(entry["per_seed"]))


def summary_table(run_dirs: list[Path]) -> str:
    """One row per run: final success, return ratio, team return, convergence, speed."""
    from pimbot.analysis.plots import run_label
    from pimbot.training import store
    from pimbot.training.summary import summarize

    rows = []
    for run_dir in run_dirs:
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
    ]
    lines = markdown_lines(Table(header, rows))[:-1]
    return "\n".join(lines + ["", statistics.interval_text(row[2] for row in rows)]) + "\n"
