"""The verdict vocabulary of the claims table, in one place.

A claim is judged as the paper states it, at the paper's budget, and gets one of:
- "reproduced": the measurement agrees, at the paper's budget and at ours;
- "reproduced at the paper's budget": it agrees at the paper's budget, not at our
  longer horizon (the later row says how);
- "refuted — cause: …": it disagrees, and the disagreement is classified as our
  implementation, our budget or setting, our spec, or the paper (its claim contradicts
  its own environment, metric or code);
- "inconclusive": the evidence cannot decide it; the reason says what is missing (seeds
  or iterations to tell the runs apart, a log of the original code at the same settings
  to name a cause, a baseline that succeeds without the attack, a machine to itself).
Every refuted or inconclusive verdict carries a one-line reason written from the
measured numbers; there is no bare "not reproduced".

`combine` joins the verdicts of a claim's parts; `at_quick_budget` is what the quick
suite (3 seeds, a fifth of the iterations) may conclude: a refutation that rests on
learning runs becomes inconclusive there, whatever cause it names; one that follows from
the environment's rules (`structural`) does not.
"""

from __future__ import annotations

import dataclasses

REPRODUCED = "reproduced"
AT_BUDGET = "reproduced-at-budget"
REFUTED = "refuted"
INCONCLUSIVE = "inconclusive"
NOT_RUN = "not-run"
KINDS = (REPRODUCED, AT_BUDGET, REFUTED, INCONCLUSIVE, NOT_RUN)

IMPLEMENTATION = "our implementation"
BUDGET = "our budget or setting"
SPEC = "our spec"
PAPER_ENVIRONMENT = "the paper (contradicts its own environment)"
PAPER_METRIC = "the paper (contradicts its own metric)"
PAPER_CODE = "the paper (contradicts its own code)"
CAUSES = (IMPLEMENTATION, BUDGET, SPEC, PAPER_ENVIRONMENT, PAPER_METRIC, PAPER_CODE)

LABELS = {
    REPRODUCED: "reproduced",
    AT_BUDGET: "reproduced at the paper's budget",
    REFUTED: "refuted",
    INCONCLUSIVE: "inconclusive",
    NOT_RUN: "not run",
}
MARKERS = {REPRODUCED: "✔", AT_BUDGET: "✔", REFUTED: "✘", INCONCLUSIVE: "◐", NOT_RUN: "○"}
LEGEND = {
    REPRODUCED: "reproduced",
    AT_BUDGET: "reproduced at the paper's budget (not at our longer horizon)",
    REFUTED: "refuted, with its cause: " + " | ".join(CAUSES),
    INCONCLUSIVE: "inconclusive: the evidence cannot decide it (the reason says what is missing)",
    NOT_RUN: "not run (some of the claim's runs have not finished)",
}


@dataclasses.dataclass(frozen=True)
class Verdict:
    kind: str
    reason: str = ""
    """One line from the measured numbers (required for refuted and inconclusive)."""
    causes: tuple[str, ...] = ()
    """Refuted only: why the measurement disagrees (CAUSES)."""
    qualifier: str = ""
    """Appended to the label in parentheses ("quick budget")."""
    structural: bool = False
    """Refuted only: it rests on what the env's rules allow, not on how far runs learned,
    so no budget changes it (a run that succeeds where the rules forbid success)."""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"verdict kind {self.kind!r} not in {KINDS}")
        if self.kind == REFUTED and not self.causes:
            raise ValueError("a refuted verdict needs a cause")
        if any(c not in CAUSES for c in self.causes):
            raise ValueError(f"verdict causes {self.causes} not all in {CAUSES}")
        if self.kind in (REFUTED, INCONCLUSIVE) and not self.reason:
            raise ValueError(f"a {self.kind} verdict needs a reason")

    @property
    def label(self) -> str:
        """ "refuted — cause: our implementation", "reproduced (quick budget)"."""
        text = LABELS[self.kind]
        if self.kind == REFUTED:
            text += " — cause: " + "; ".join(self.causes)
        return text + (f" ({self.qualifier})" if self.qualifier else "")

    @property
    def marker(self) -> str:
        return MARKERS[self.kind]

    def __str__(self) -> str:
        return f"{self.label}: {self.reason}" if self.reason else self.label


def reproduced(reason: str = "") -> Verdict:
    return Verdict(REPRODUCED, reason)


def at_budget(reason: str) -> Verdict:
    return Verdict(AT_BUDGET, reason)


def refuted(cause: str, reason: str, structural: bool = False) -> Verdict:
    return Verdict(REFUTED, reason, (cause,), structural=structural)


def inconclusive(reason: str) -> Verdict:
    return Verdict(INCONCLUSIVE, reason)


def not_run(reason: str) -> Verdict:
    return Verdict(NOT_RUN, reason)


def combine(parts: dict[str, Verdict]) -> Verdict:
    """One verdict for a claim of several parts (name -> verdict): refuted if any part is
    (every refuted part's cause kept), else inconclusive if any is, else reproduced at the
    paper's budget if any is, else reproduced. The reason names the deciding parts."""
    if not parts:
        return inconclusive("no part of the claim could be judged")
    for kind in (NOT_RUN, REFUTED, INCONCLUSIVE, AT_BUDGET):
        deciding = {name: v for name, v in parts.items() if v.kind == kind}
        if deciding:
            causes = tuple(dict.fromkeys(c for v in deciding.values() for c in v.causes))
            reason = "; ".join(
                f"{name}: {v.reason}" if v.reason else name for name, v in deciding.items()
            )
            structural = all(v.structural for v in deciding.values())
            return Verdict(kind, reason, causes, structural=kind == REFUTED and structural)
    return reproduced("; ".join(f"{name}: {v.reason}" for name, v in parts.items() if v.reason))


def at_quick_budget(verdict: Verdict) -> Verdict:
    """What the quick suite may conclude: a refutation that rests on learning runs becomes
    inconclusive (the reason kept), whatever its cause — short runs are no evidence that the
    paper contradicts itself either; a structural one stays; every verdict is marked
    "quick budget"."""
    if verdict.kind == REFUTED and not verdict.structural:
        return Verdict(
            INCONCLUSIVE, f"quick budget; as measured: {verdict.reason}", qualifier="quick budget"
        )
    if verdict.kind == NOT_RUN:
        return verdict
    return dataclasses.replace(verdict, qualifier="quick budget")
