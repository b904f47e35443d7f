"""The report's summary, the first thing it shows: one line per claim row with its verdict,
the one number that carries it (with its interval) and a clause of why; a quick report's
with the published report's verdict beside it.

A claim builder sets the number and the clause (`Claim.headline`, `Claim.why`); where it
does not, they are derived here from the verdict: its deciding part (the first part of
the row's kind, as `verdicts.combine` names it), the first number with an interval in
that part's reason (or the claim's paper | original code | pimbot row of that part), and
the reason's explanation of it.
"""

from __future__ import annotations

import dataclasses
import re

from pimbot.analysis import published, verdicts
from pimbot.analysis.claims import Claim, Comparison

WHY_CHARS = 160
"""A summary's clause of why is cut at a clause boundary before this many characters."""
HEADLINE_CHARS = 110
"""A derived headline longer than this is cut (a builder's own is shown whole)."""
QUICK_PREFIX = "quick budget; as measured: "
"""How `verdicts.at_quick_budget` opens the reason of a refutation it made inconclusive."""
NUMBER = re.compile(
    r"[-+−]?\d[\d,]*(?:\.\d+)?(?: ?%)?(?P<interval> \[[^\]]+\]| \(range [^)]+\))(?: ?%)?"
)
"""A number with its interval, as `statistics.text` writes it: "0.148 [0.046, 0.290]",
"+9.45 [+5.99, +10.66]", "0.41 (range 0.20 … 0.60)"."""
P_VALUE = re.compile(r"\bp = (\d\.\d+)")
LEAD = re.compile(r".*(?:: |; |, |\(| < | > | vs )")
"""Everything up to the last boundary before a number: what is left names the number."""


@dataclasses.dataclass(frozen=True)
class Line:
    """One claim row as the summary shows it."""

    id: str
    claim: str
    kind: str
    verdict: str
    """The verdict's marked label ("◐ inconclusive (quick budget)")."""
    headline: str
    why: str
    anchor: str
    """The claim's details anchor in the report."""
    published: tuple[str, str] | None
    """(kind, marked label) of the published report's verdict (a quick report); None
    otherwise; ("", "–") where the published report has no such row."""


def lines(claims: list[Claim], quick: bool, anchor) -> list[Line]:
    """The summary of `claims`; `anchor(claim)` is its details anchor."""
    return [
        Line(
            c.id,
            c.claim,
            c.verdict.kind,
            f"{c.verdict.marker} {c.verdict.label}",
            headline(c),
            why(c),
            anchor(c),
            published_verdict(c) if quick else None,
        )
        for c in claims
    ]


def published_verdict(claim: Claim) -> tuple[str, str]:
    """(kind, marked label) of the published report's verdict of a claim row; ("", "–")
    where the published report has no such row."""
    label = published.shipped().verdict(claim.id)
    if label is None:
        return "", "–"
    kind = verdicts.kind_of_label(label)
    return kind, f"{verdicts.MARKERS[kind]} {label}"


# --- the number and the clause ------------------------------------------------------------


def headline(claim: Claim) -> str:
    """The number that carries the claim row's verdict: the builder's (`Claim.headline`),
    else the first number with an interval in the deciding part's reason, else that part's
    paper | original code | pimbot row; "–" for a row not run."""
    if claim.verdict.kind == verdicts.NOT_RUN:
        return "–"
    name, reason = deciding(claim)
    phrase = number_phrase(first_clause(reason))
    if claim.headline:
        return with_p(claim.headline, phrase)
    if phrase:
        return cut(f"{name}: {phrase}" if name else phrase, HEADLINE_CHARS)
    row = deciding_number(claim, name)
    if row is not None:
        return cut(f"{row.quantity} {row.pimbot}", HEADLINE_CHARS)
    return cut(claim.summary or claim.measured, HEADLINE_CHARS)


def why(claim: Claim) -> str:
    """A clause of why: the builder's (`Claim.why`), else the deciding part's explanation
    of its number (what follows the number after ": "), else its reason's first clause
    with the intervals left out; clauses added while they fit `WHY_CHARS`."""
    if claim.verdict.kind == verdicts.NOT_RUN:
        return cut(claim.verdict.reason or claim.verdict.label, WHY_CHARS)
    measured = "as measured, " if claim.verdict.reason.startswith(QUICK_PREFIX) else ""
    if claim.why:
        return cut(measured + claim.why, WHY_CHARS)
    name, reason = deciding(claim)
    clauses = reason.split("; ")
    text = explanation(clauses[0])
    for more in clauses[1:]:
        longer = f"{text}; {NUMBER.sub(_point, more)}"
        if len(text) >= WHY_CHARS // 2 or len(longer) > WHY_CHARS:
            break
        text = longer
    return cut(measured + text, WHY_CHARS) if text else ""


def deciding(claim: Claim) -> tuple[str, str]:
    """(the deciding part's name, its reason) of a claim row; ("", the row's reason) for
    a row in one piece. The quick budget's "as measured" opening is left out (the label
    says "quick budget")."""
    reason = claim.verdict.reason.removeprefix(QUICK_PREFIX)
    for name, part in claim.verdict.parts:
        if reason.startswith(f"{name}: "):
            return name, part.reason.removeprefix(QUICK_PREFIX)
    if not claim.verdict.parts or claim.verdict.kind not in (
        verdicts.REPRODUCED,
        verdicts.AT_BUDGET,
    ):
        return "", reason
    name, part = claim.verdict.parts[0]  # every part reproduced: the first
    return name, part.reason.removeprefix(QUICK_PREFIX)


def with_p(headline: str, phrase: str) -> str:
    """A builder's headline with the p value of its number's test appended, where the
    deciding part's reason gives one for the same number and the headline does not."""
    match = NUMBER.search(phrase)
    p = P_VALUE.search(phrase)
    if match is None or p is None or "p = " in headline or match.group(0) not in headline:
        return headline
    return f"{headline}, p = {p.group(1)}"


def first_clause(text: str) -> str:
    return text.split("; ")[0]


def number_phrase(clause: str) -> str:
    """The first number with its interval in `clause`, with the words that name it and the
    p value of its test where one follows in parentheses: "margin +5.27 [+0.81, +7.17],
    p = 0.062"; "" without such a number."""
    match = NUMBER.search(clause)
    if match is None:
        return ""
    lead = LEAD.sub("", clause[: match.start()])
    phrase = f"{lead}{match.group(0)}".strip()
    after = clause[match.end() :]
    if after.startswith(" (") and (p := P_VALUE.search(after.split(")")[0])):
        phrase += f", p = {p.group(1)}"
    return phrase


def explanation(clause: str) -> str:
    """Why a clause's number decides: what follows it after ": " ("the seeds cannot tell
    it from 0"), else the clause with its intervals left out."""
    match = NUMBER.search(clause)
    if match is not None:
        after = clause[match.end() :]
        depth, at = 0, -1
        for i, char in enumerate(after):  # the last ": " outside brackets
            if char in "([":
                depth += 1
            elif char in ")]":
                depth -= 1
            if depth == 0 and after.startswith(": ", i):
                at = i
        if at >= 0 and len(after) - at > 12:
            return after[at + 2 :]
    return NUMBER.sub(_point, clause)


def _point(match: re.Match) -> str:
    """A number with its interval, the interval left out."""
    return match.group(0).replace(match.group("interval"), "")


def deciding_number(claim: Claim, part: str) -> Comparison | None:
    """The paper | original code | pimbot row of the deciding part (the first whose
    quantity opens with the part's first word, an env such as "ER(2,1)"), else the claim's
    first row with a pimbot number."""
    rows = [n for n in claim.numbers if n.pimbot]
    env = part.split(" ")[0].rstrip(":") if part else ""
    mine = [n for n in rows if env and n.quantity.startswith(env)]
    return (mine or rows or [None])[0]


def cut(text: str, chars: int) -> str:
    """`text` cut before `chars` characters at the last clause boundary ("; ", ", ") or
    space, "…" appended where it was cut."""
    if len(text) <= chars:
        return text
    room = chars - 1
    for mark in ("; ", ", ", " "):
        at = text.rfind(mark, 0, room)
        while at > room // 2 and _open(text[:at]):  # never inside an interval
            at = text.rfind(mark, 0, at)
        if at > room // 2:
            return text[:at].rstrip(" ,;:") + "…"
    at = room
    while at > 0 and _open(text[:at]):  # before the interval that would be split
        at = max(text.rfind("[", 0, at), text.rfind("(", 0, at))
    return text[:at].rstrip(" ,;:") + "…"


def _open(text: str) -> bool:
    """Whether `text` ends inside brackets or parentheses."""
    return text.count("[") > text.count("]") or text.count("(") > text.count(")")
