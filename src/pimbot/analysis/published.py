"""The published report's verdicts, shipped with pimbot as package data, so that a quick
report can show each quick verdict beside the published one.

The published report is `pimbot report` on the published suite (docs/report, made as
docs/report/README.md says). `from_report` reads its claims tables (tables/claims.csv:
one verdict per claim row; tables/claims_numbers.csv: the paper | original code | pimbot
figures; tables/claims_parts.csv, where the report has it: one verdict per part) into
`DATA`, the file shipped beside this module. Regenerate it after docs/report changes:

    python -m pimbot.analysis.published docs/report

(a test checks that the shipped file equals what docs/report's tables give).

A part's published verdict is the published parts table's where it has the part; a report
without that table gives it from the claim row (`derived_part_verdict`): the row's verdict
names its deciding parts in its reason, as `verdicts.combine` writes it.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import functools
import json
from importlib import resources
from pathlib import Path

from pimbot.analysis import verdicts

DATA = "published_verdicts.json"
"""Package data of pimbot.analysis: the published report's verdicts and figures."""
TABLES = "tables"
CLAIMS_CSV = "claims.csv"
NUMBERS_CSV = "claims_numbers.csv"
PARTS_CSV = "claims_parts.csv"
CLAIM_FIELDS = ("claim", "verdict", "reason")
NUMBER_FIELDS = ("claim", "quantity", "horizon", "pimbot")
PART_FIELDS = ("claim", "part", "verdict", "reason")
SOURCE = (
    "docs/report/tables (claims.csv, claims_numbers.csv, claims_parts.csv where present): "
    "`pimbot report` on the published suite"
)
REGENERATE = "python -m pimbot.analysis.published docs/report"


# --- making the data file ---------------------------------------------------------------


def read_rows(path: Path, fields: tuple[str, ...]) -> list[dict[str, str]]:
    """`fields` of every row of the CSV at `path` ([] where the file is absent)."""
    if not path.is_file():
        return []
    with open(path, newline="", encoding="utf-8") as f:
        return [{k: row[k] for k in fields} for row in csv.DictReader(f)]


def from_report(report_dir: Path) -> dict:
    """The data `DATA` holds, read from a report directory's claims tables."""
    tables = Path(report_dir) / TABLES
    if not (tables / CLAIMS_CSV).is_file():
        raise FileNotFoundError(f"{tables / CLAIMS_CSV}: not a report of the paper's suite")
    return {
        "source": SOURCE,
        "regenerate": REGENERATE,
        "claims": read_rows(tables / CLAIMS_CSV, CLAIM_FIELDS),
        "numbers": read_rows(tables / NUMBERS_CSV, NUMBER_FIELDS),
        "parts": read_rows(tables / PARTS_CSV, PART_FIELDS),
    }


def data_text(data: dict) -> str:
    """`data` as the shipped file's text (stable: one sitting's output equals another's)."""
    return json.dumps(data, ensure_ascii=False, indent=1) + "\n"


def shipped_path() -> Path:
    """Where the shipped file lies in a source checkout (what `main` writes by default)."""
    return Path(__file__).with_name(DATA)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m pimbot.analysis.published",
        description="Write the published report's verdicts as pimbot's package data.",
    )
    parser.add_argument("report_dir", type=Path, help="the published report (docs/report)")
    parser.add_argument("--out", type=Path, default=shipped_path(), help="the file to write")
    args = parser.parse_args(argv)
    args.out.write_text(data_text(from_report(args.report_dir)), encoding="utf-8")
    print(f"wrote {args.out}")


# --- reading it -------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Published:
    """The published report's claims tables, looked up by claim row, part and quantity."""

    claims: dict[str, dict[str, str]]
    numbers: dict[tuple[str, str], dict[str, str]]
    parts: dict[tuple[str, str], dict[str, str]]

    @classmethod
    def of(cls, data: dict) -> Published:
        return cls(
            {row["claim"]: row for row in data.get("claims", [])},
            {(row["claim"], row["quantity"]): row for row in data.get("numbers", [])},
            {(row["claim"], row["part"]): row for row in data.get("parts", [])},
        )

    def verdict(self, claim: str) -> str | None:
        """The published verdict's label of a claim row (None: no such row)."""
        row = self.claims.get(claim)
        return None if row is None else row["verdict"]

    def part_verdict(self, claim: str, part: str) -> str | None:
        """The published verdict of one part of a claim row (None: no such row)."""
        if (claim, part) in self.parts:
            return self.parts[(claim, part)]["verdict"]
        row = self.claims.get(claim)
        return None if row is None else derived_part_verdict(row, part)

    def figure(self, claim: str, quantity: str) -> str | None:
        """The published pimbot figure of a claim's quantity, with its horizon ("0.022
        [0.013, 0.035] at 25,000 it"); None where the published report has none."""
        row = self.numbers.get((claim, quantity))
        return None if row is None else f"{row['pimbot']} at {row['horizon']}"


def named_in(reason: str, part: str) -> bool:
    """Whether a claim's reason names `part` as `verdicts.combine` writes a deciding part:
    "part: its reason", at the start or after "; "."""
    return reason.startswith(f"{part}: ") or f"; {part}: " in reason


NOT_REFUTED = "not refuted (reproduced or inconclusive)"


def derived_part_verdict(row: dict[str, str], part: str) -> str:
    """A part's published verdict from its claim row alone (`verdicts.combine`'s reason
    names every part of the deciding kind): a part the reason names has the row's kind;
    in a row published as reproduced every part is reproduced; in an inconclusive row a
    part it does not name is reproduced; in a refuted row, not refuted (it may be
    inconclusive or reproduced); in a row not run, not run."""
    kind = verdicts.kind_of_label(row["verdict"])
    if named_in(row["reason"], part) or kind in (verdicts.REPRODUCED, verdicts.NOT_RUN):
        return verdicts.LABELS[kind]
    if kind == verdicts.REFUTED:
        return NOT_REFUTED
    return verdicts.LABELS[verdicts.REPRODUCED]


@functools.cache
def shipped() -> Published:
    """The published report's verdicts shipped with this install (empty without the file)."""
    resource = resources.files("pimbot.analysis").joinpath(DATA)
    if not resource.is_file():
        return Published.of({})
    return Published.of(json.loads(resource.read_text(encoding="utf-8")))


if __name__ == "__main__":
    main()
