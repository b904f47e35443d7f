"""What a report section is: text, tables, figures and the claims it judges.

A section provider is a function `(RunTable, Context) -> Section | None`; it
returns None when its runs are absent, and claims (`Context.claim`) the runs it
reports, so that the generic section shows only the others.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable
from pathlib import Path

from pimbot.analysis.runs import RunRecord, RunTable
from pimbot.analysis.tables import Table

FIGURES = "figures"
TABLES = "tables"


@dataclasses.dataclass
class Figure:
    path: Path
    """Relative to the report directory."""
    caption: str


@dataclasses.dataclass
class Claim:
    id: str
    claim: str
    rule: str
    measured: str
    verdict: str


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

    def figure(self, name: str, caption: str) -> tuple[Path, Figure]:
        """(where to save the PNG, the Figure that links it)."""
        path = self.out / FIGURES
        path.mkdir(parents=True, exist_ok=True)
        return path / name, Figure(Path(FIGURES) / name, caption)

    def claim(self, records: Iterable[RunRecord]) -> None:
        self.claimed.update(r.name for r in records)


Provider = Callable[[RunTable, Context], Section | None]


def verdict(ok: bool) -> str:
    return "reproduced" if ok else "not reproduced"
