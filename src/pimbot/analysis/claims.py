"""The claim model: the paper's claims C1–C8, the rows a section judges (a `Claim`, with
its verdict and the paper | original code | pimbot numbers behind it), and the suite's
claims table built from them.

A claim is judged by the section that reads its runs (analysis.sections); its parts are
joined and classified by `analysis.verdicts`. This module knows nothing of Markdown or
HTML: the renderers (analysis.markdown_report, analysis.html_report) lay it out.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

from pimbot.analysis import published, verdicts
from pimbot.analysis.tables import Table
from pimbot.analysis.verdicts import Verdict
from pimbot.suites import presets

CLAIM_TEXT = {
    "C1": "self-centered: adversary above the others; ER converges faster",
    "C2": "fake incentive (C = 10, the code; C = 50, the paper): early success, then ~0 in ER",
    "C3": "bypass: 0 success in ER(2,1), ER(4,3); ER(4,2) still solved",
    "C4": "reverse: success → 0 except ER(4,2)",
    "C5": "ADMO vs LIO: adversary's reward and success measures elevated in ER",
    "C6": "Stag Hunt N = 2, 3, 4: LIO baseline rises; ADMO drives it toward 0",
    "C7": "Reciprocators: baseline 80–90 % → ADMO near 0 (ER(4,3), Stag Hunt), < 30 % "
    "(ER(4,2)), < 10 % (IPD)",
    "C8": "on-device profile: ADMO overhead modest, CPU-side, bursty; no sustained saturation",
}
"""The paper's claims as the suite's jobs name them, in the claims table's order."""


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
    """One row of the claims table, as the section that judged it wrote it."""

    id: str
    claim: str
    rule: str
    measured: str
    """Every number the verdict was judged on (the claims CSV and the details list)."""
    verdict: Verdict
    summary: str = ""
    """A short form of `measured` for the claims table (empty: `measured` is short)."""
    numbers: list[Comparison] = dataclasses.field(default_factory=list)
    """The paper | original code | pimbot rows of the claim."""
    jobs_of: str = ""
    """The suite claim whose jobs feed it ("C1" for C1a and C1b); empty: its id."""
    headline: str = ""
    """The one number that carries the verdict, with its interval, as the report's summary
    shows it ("ER(2,1) final 0.148 [0.046, 0.290] at 10,000 it"); empty: derived from the
    verdict's deciding part and `numbers` (`analysis.summary.headline`)."""
    why: str = ""
    """A clause of why, for the summary (≤ `summary.WHY_CHARS` characters; "the seeds
    cannot tell it from 0"); empty: the first clause of the verdict's reason
    (`analysis.summary.why`)."""

    @property
    def judged(self) -> Verdict:
        """The verdict (the name the rules and the renderers read it by)."""
        return self.verdict

    @property
    def suite_claim(self) -> str:
        return self.jobs_of or self.id


def deciding_part(verdict: Verdict) -> tuple[str, Verdict] | None:
    """(name, verdict) of the part that decides a claim row's verdict: the first part of
    the row's kind, the one `verdicts.combine` names first; None for a row judged in one
    piece (or with no part of its kind)."""
    return next(((n, v) for n, v in verdict.parts if v.kind == verdict.kind), None)


def summarized(
    verdict: Verdict, numbers: dict[str, str], weakest: str = "", agreed: str = "", why: str = ""
) -> dict[str, str]:
    """A claim row's summary fields (`Claim.headline`, `Claim.why`) from the number of each
    of its parts (`numbers`, by part name, each with its interval): the deciding part's
    number (`deciding_part`); where every part is reproduced, the number of `weakest` (the
    part nearest to failing; else the first) and `agreed` as the why. `why` is the why
    otherwise; left empty, the summary derives it from the deciding part's reason."""
    agrees = verdict.kind in (verdicts.REPRODUCED, verdicts.AT_BUDGET)
    found = deciding_part(verdict)
    name = weakest if agrees and weakest in numbers else (found[0] if found else "")
    if name not in numbers:
        name = next(iter(numbers), "")
    return {"headline": numbers.get(name, ""), "why": agreed if agrees else why}


# --- the suite's claims table -----------------------------------------------------------


QUICK_SUITE = "quick"
"""index.json's "suite" of `pimbot reproduce --quick`."""


def is_quick(index: dict) -> bool:
    """Whether the directory holds the paper's suite at the quick budget."""
    return index.get("suite") == QUICK_SUITE


def is_paper_suite(index: dict) -> bool:
    """Whether the directory holds jobs of the paper's suite (they name the claims they
    feed); a `pimbot sweep` grid's jobs feed none and get no claims table."""
    return any(job.get("claims") for job in index.get("jobs", []))


def claim_coverage(index: dict) -> dict[str, tuple[int, int]]:
    """(finished, planned) jobs per claim: the whole suite of the index's budget counts, so
    a directory where `--only` ran part of it is not judged on that part. The suite is
    planned here, once per report (`presets.suite`); a job renamed since counts under its
    former name too (`presets.FORMER_JOB_NAMES`)."""
    status = {job["name"]: job["status"] for job in index.get("jobs", [])}
    coverage: dict[str, list[int]] = {c: [0, 0] for c in CLAIM_TEXT}
    for job in presets.suite(quick=is_quick(index)):
        former = presets.FORMER_JOB_NAMES.get(job.name)
        finished = "finished" in (status.get(job.name), status.get(former))
        for claim in job.claims:
            coverage.setdefault(claim, [0, 0])
            coverage[claim][1] += 1
            coverage[claim][0] += finished
    return {c: (done, planned) for c, (done, planned) in coverage.items()}


def suite_claims(measured: Iterable[Claim], index: dict) -> list[Claim]:
    """C1–C8 in order, each suite claim's rows as its section wrote them (C1a, C1b, …);
    "not run" unless every job feeding the claim has finished; at the quick budget what
    `verdicts.at_quick_budget` allows. None outside the paper's suite."""
    if not is_paper_suite(index):
        return []
    by_claim: dict[str, list[Claim]] = {}
    for claim in measured:
        by_claim.setdefault(claim.suite_claim, []).append(claim)
    coverage = claim_coverage(index)
    quick = is_quick(index)
    out = []
    for cid, text in CLAIM_TEXT.items():
        done, planned = coverage.get(cid, (0, 0))
        mine = by_claim.get(cid, [])
        if not mine or planned == 0 or done < planned:
            out += _not_run(cid, text, mine, done, planned)
            continue
        for claim in mine:
            judged = verdicts.at_quick_budget(claim.verdict) if quick else claim.verdict
            out.append(dataclasses.replace(claim, verdict=judged))
    return out


def _not_run(cid: str, text: str, mine: list[Claim], done: int, planned: int) -> list[Claim]:
    """The rows of a claim whose jobs have not all finished (its partial numbers kept)."""
    short = f"{done}/{planned} runs finished" if planned else "no runs planned"
    if not mine:
        return [Claim(cid, text, "–", short, verdicts.not_run(short), short, jobs_of=cid)]
    return [
        Claim(
            c.id,
            c.claim,
            c.rule,
            f"{short}; so far: {c.measured}",
            verdicts.not_run(short),
            short,
            jobs_of=cid,
        )
        for c in mine
    ]


PUBLISHED_COLUMN = "published report"
"""The column of a quick report that shows the published report's verdict or figure."""
PUBLISHED_NOTE = (
    "'published report': the published report's figure of the same quantity, at the "
    "published budget and its horizon (docs/report, shipped with pimbot as "
    "pimbot/analysis/published_verdicts.json); '–': it has none."
)


def csv_table(claims: list[Claim], quick: bool = False) -> Table:
    """The claims CSV: every number judged, the verdict's label and its reason (at the
    quick budget, the published report's verdict beside them)."""
    shown = published.shipped()
    return Table(
        ["claim", "published", "rule", "measured", "verdict", "reason"]
        + ([PUBLISHED_COLUMN] if quick else []),
        [
            [c.id, c.claim, c.rule, c.measured, c.verdict.label, c.verdict.reason]
            + ([shown.verdict(c.id)] if quick else [])
            for c in claims
        ],
    )


COMPARISON_NOTE = (
    "Each number as the paper states it, as the original PIMbot code's log.csv files give it "
    "(converted into run directories and read by the same metric code as pimbot's runs; "
    "byte-identical copies and reruns of one random seed counted once) and as pimbot "
    "measures it, at the same horizon. "
    "'no log': the original code's logs do not cover it."
)


def comparison_table(claims: list[Claim], quick: bool = False) -> Table | None:
    """paper | original code | pimbot, one row per number a claim states (at the quick
    budget, the published report's figure beside it); None if none."""
    shown = published.shipped()
    rows = [
        [c.id, n.quantity, n.horizon, n.paper, "no log" if n.original is None else n.original]
        + [n.pimbot]
        + ([shown.figure(c.id, n.quantity)] if quick else [])
        for c in claims
        for n in c.numbers
    ]
    if not rows:
        return None
    header = ["claim", "quantity", "horizon", "paper", "original code", "pimbot"]
    header += [PUBLISHED_COLUMN] if quick else []
    note = f"{COMPARISON_NOTE} {PUBLISHED_NOTE}" if quick else COMPARISON_NOTE
    return Table(header, rows, "Paper | original code | pimbot", note, "claims_numbers")


WHOLE_CLAIM = "(the claim as one)"
"""The part column of a claim row judged in one piece."""
PARTS_NOTE = (
    "Every part of each claim row with its own verdict; a claim row's verdict joins them "
    "(refuted if a part is, else inconclusive if a part is, else reproduced)."
)
PARTS_QUICK_NOTE = (
    " A part whose rule is stated at an iteration the paper names (C1b: the paper's clean "
    "convergence; C4: its 25,000 it budget), which the quick runs stop short of, says so; "
    "left inconclusive there, the quick budget cannot decide it by design. 'published "
    "report': the part's verdict in the published report (docs/report, shipped with "
    "pimbot as pimbot/analysis/published_verdicts.json)."
)


def claim_parts(claim: Claim) -> tuple[tuple[str, Verdict], ...]:
    """(part name, verdict) of a claim row: its judged parts, or the row as one part."""
    return claim.verdict.parts or ((WHOLE_CLAIM, claim.verdict),)


def part_reason(verdict: Verdict) -> str:
    """A part's reason, led by its horizon where the runs stop short of the paper's (unless
    the reason opens with it)."""
    if verdict.short_horizon is None:
        return verdict.reason
    opening = f"{verdict.short_horizon[0]:,} it < the paper's"  # as the C1b and C4 rules say
    if verdict.reason.startswith(opening):
        return verdict.reason
    return "; ".join(text for text in (verdicts.horizon_text(verdict), verdict.reason) if text)


def parts_table(claims: list[Claim], quick: bool = False) -> Table | None:
    """claim | part | verdict | reason, one row per part of every claim row (at the quick
    budget, the published report's verdict of the part beside it); None without claims."""
    if not claims:
        return None
    shown = published.shipped()
    rows = []
    for claim in claims:
        for name, verdict in claim_parts(claim):
            row = [claim.id, name, verdict.label, part_reason(verdict)]
            if quick:
                whole = name == WHOLE_CLAIM
                row.append(shown.verdict(claim.id) if whole else shown.part_verdict(claim.id, name))
            rows.append(row)
    header = ["claim", "part", "verdict", "reason"] + ([PUBLISHED_COLUMN] if quick else [])
    note = PARTS_NOTE + (PARTS_QUICK_NOTE if quick else "")
    return Table(header, rows, "Claim parts", note, "claims_parts")
