"""What a report is: its sections (text, tables, figures and the claims they judge) and
the `Report` the renderers lay out.

A section provider is a function `(RunTable, Context) -> Section | None`; it
returns None when its runs are absent, and claims (`Context.claim`) the runs it
reports, so that the generic section shows only the others.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable, Iterable
from pathlib import Path

from pimbot.analysis.claims import Claim, comparison_table, is_paper_suite, is_quick, parts_table
from pimbot.analysis.runs import RunRecord, RunTable
from pimbot.analysis.tables import Table
from pimbot.training.summary import FINAL_WINDOW

FIGURES = "figures"
TABLES = "tables"


@dataclasses.dataclass
class Figure:
    path: Path
    """The PNG, relative to the report directory; the SVG of the same figure lies beside it."""
    caption: str

    @property
    def svg(self) -> Path:
        return self.path.with_suffix(".svg")

    @property
    def anchor(self) -> str:
        return slug(self.path.stem)


@dataclasses.dataclass
class Section:
    title: str
    text: list[str] = dataclasses.field(default_factory=list)
    tables: list[Table] = dataclasses.field(default_factory=list)
    figures: list[Figure] = dataclasses.field(default_factory=list)
    claims: list[Claim] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class Context:
    suite_dir: Path
    out: Path
    index: dict
    claimed: set[str] = dataclasses.field(default_factory=set)
    """Names of the runs a section has reported."""

    def figure(self, name: str, caption: str = "") -> tuple[Path, Figure]:
        """(where to save the PNG, the Figure that links it). A caption that says what the
        drawing found (its bands) is set once the figure is drawn."""
        path = self.out / FIGURES
        path.mkdir(parents=True, exist_ok=True)
        return path / name, Figure(Path(FIGURES) / name, caption)

    def claim(self, records: Iterable[RunRecord]) -> None:
        self.claimed.update(r.name for r in records)


Provider = Callable[[RunTable, Context], Section | None]


@dataclasses.dataclass
class Report:
    """The whole report: its provenance, the suite's claims table and the sections."""

    index: dict
    provenance: Section
    claims: list[Claim]
    sections: list[Section]

    @property
    def kind(self) -> str:
        return "reproduction" if is_paper_suite(self.index) else "sweep"

    @property
    def quick(self) -> bool:
        """Whether it reports the paper's suite at the quick budget (the published report's
        verdicts and figures are shown beside its own)."""
        return is_quick(self.index)

    @property
    def numbers(self) -> Table | None:
        """The claims' paper | original code | pimbot table (None: no claim states one)."""
        return comparison_table(self.claims, self.quick)

    @property
    def parts(self) -> Table | None:
        """Every claim row's parts with their verdicts (None: no claims)."""
        return parts_table(self.claims, self.quick)


# --- counts read from the runs ----------------------------------------------------------


def count_text(values: Iterable[int], noun: str) -> str:
    """ "3 seeds", or "2–3 seeds" where the runs differ; `noun` is the plural."""
    values = sorted(set(values))
    if not values:
        return f"no {noun}"
    one = noun[:-1] if noun.endswith("s") and values == [1] else noun
    if len(values) == 1:
        return f"{values[0]} {one}"
    return f"{values[0]}–{values[-1]} {noun}"


def iterations_text(values: Iterable[int] | int) -> str:
    """ "10k iterations", "800 iterations", "5k–10k iterations" (never "0k")."""
    values = sorted({values} if isinstance(values, int) else set(values))

    def short(n: int) -> str:
        return f"{n / 1000:g}k" if n >= 1000 and n % 100 == 0 else f"{n:,}"

    if not values:
        return "no iterations"
    if len(values) == 1:
        return f"{short(values[0])} iterations"
    return f"{short(values[0])}–{short(values[-1])} iterations"


def seeds_text(records: Iterable[RunRecord]) -> str:
    """The seed count of `records`, read from their summaries: "3 seeds"."""
    return count_text((r.seeds for r in records), "seeds")


def final_window_text(records: Iterable[RunRecord]) -> str:
    """How many evaluation points the final value averages, read from the summaries."""
    return count_text(
        (int(r.summary.get("final_window_evals", FINAL_WINDOW)) for r in records),
        "evaluation points",
    )


def slug(text: str) -> str:
    """An HTML id / Markdown anchor: lower case letters, digits and hyphens."""
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "section"
