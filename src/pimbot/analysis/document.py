"""What a report section is: text, tables, figures and the claims it judges.

A section provider is a function `(RunTable, Context) -> Section | None`; it
returns None when its runs are absent, and claims (`Context.claim`) the runs it
reports, so that the generic section shows only the others.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable, Iterable
from pathlib import Path

from pimbot.analysis.runs import RunRecord, RunTable
from pimbot.analysis.tables import Table
from pimbot.analysis.verdicts import KINDS, MARKERS, Verdict, from_text
from pimbot.statistics import MIN_SEEDS_FOR_CI
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


@dataclasses.dataclass(frozen=True)
class Comparison:
    """One number of a claim as the paper states it, as the original code's logs give it and
    as pimbot measures it, at one horizon (both logs read by the same metric code)."""

    quantity: str
    horizon: str
    paper: str
    original: str | None
    """None: no original-code log covers it (written "no log")."""
    pimbot: str | None


@dataclasses.dataclass
class Claim:
    id: str
    claim: str
    rule: str
    measured: str
    """Every number the verdict was judged on (the claims CSV and the details list)."""
    verdict: Verdict | str
    """A `Verdict`; plain text from a section that predates the vocabulary is read by
    `verdicts.from_text`."""
    summary: str = ""
    """A short form of `measured` for the claims table (empty: `measured` is short)."""
    numbers: list[Comparison] = dataclasses.field(default_factory=list)
    """The paper | original code | pimbot rows of the claim."""
    jobs_of: str = ""
    """The suite claim whose jobs feed it ("C1" for C1a and C1b); empty: its id."""

    @property
    def judged(self) -> Verdict:
        return self.verdict if isinstance(self.verdict, Verdict) else from_text(self.verdict)

    @property
    def suite_claim(self) -> str:
        return self.jobs_of or self.id


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
    """The old two-word verdict, for a section not yet on `analysis.verdicts` (it reads as
    refuted with its cause unclassified); new rules build a `Verdict`."""
    return "reproduced" if ok else "not reproduced"


VERDICTS = {kind: MARKERS[kind] for kind in KINDS}
"""Verdict kind (its CSS class) -> the marker written before the verdict in Markdown and HTML."""


def verdict_kind(verdict: Verdict | str) -> str:
    """The kind of a verdict (its CSS class); text is read by `verdicts.from_text`."""
    return (verdict if isinstance(verdict, Verdict) else from_text(verdict)).kind


def marked_verdict(verdict: Verdict | str) -> str:
    """The verdict's label with its kind's marker in front: "✘ refuted — cause: …"."""
    judged = verdict if isinstance(verdict, Verdict) else from_text(verdict)
    label = judged.label if isinstance(verdict, Verdict) else verdict
    return f"{judged.marker} {label}"


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


def band_text(records: Iterable[RunRecord]) -> str:
    """What a figure's bands are, from the seed counts of its runs."""
    counts = {r.seeds for r in records}
    if all(n >= MIN_SEEDS_FOR_CI for n in counts):
        return "95 % BCa bootstrap band"
    if all(n < MIN_SEEDS_FOR_CI for n in counts):
        return "band: min–max over seeds"
    return f"band: 95 % BCa bootstrap at ≥ {MIN_SEEDS_FOR_CI} seeds, min–max below"


def slug(text: str) -> str:
    """An HTML id / Markdown anchor: lower case letters, digits and hyphens."""
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "section"
