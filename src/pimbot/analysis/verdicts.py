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

`combine` joins the verdicts of a claim's parts (and keeps them, by name, for the parts
table); `at_quick_budget` is what the quick suite (5 seeds, a fifth of the iterations) may
conclude: a refutation that rests on learning runs becomes inconclusive there, whatever
cause it names; one that follows from the environment's rules (`structural`) does not.
A part whose rule is stated at an iteration the paper names, which its runs stop short
of (`stated_at`), is one the quick budget cannot decide by design: where it is
inconclusive, the quick label says so (`by_design`).
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
    parts: tuple[tuple[str, Verdict], ...] = dataclasses.field(default=(), compare=False)
    """(part name, its verdict) of a claim judged in parts (`combine`); () for one part."""
    short_horizon: tuple[int, int] | None = dataclasses.field(default=None, compare=False)
    """(the runs' horizon, the paper's) in iterations, where the rule is stated at an
    iteration the paper names and the runs stop before it (`stated_at`); None otherwise."""

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


def kind_of_label(label: str) -> str:
    """The kind of a verdict from its label as a claims table writes it ("refuted — cause:
    our spec", "reproduced (quick budget)")."""
    bare = label.split(" (")[0].split(" — ")[0]
    if label.startswith(LABELS[AT_BUDGET]):
        return AT_BUDGET
    for kind, text in LABELS.items():
        if bare == text:
            return kind
    raise ValueError(f"not a verdict label: {label!r}")


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


def stated_at(verdict: Verdict, runs_horizon: int, paper_horizon: int) -> Verdict:
    """`verdict` of a part whose rule is stated at the paper's `paper_horizon` iterations,
    marked `short_horizon` where its runs stop at `runs_horizon` < `paper_horizon`; the
    kind and reason unchanged."""
    if runs_horizon >= paper_horizon:
        return verdict
    return dataclasses.replace(verdict, short_horizon=(runs_horizon, paper_horizon))


def combine(parts: dict[str, Verdict]) -> Verdict:
    """One verdict for a claim of several parts (name -> verdict): refuted if any part is
    (every refuted part's cause kept), else inconclusive if any is, else reproduced at the
    paper's budget if any is, else reproduced. The reason names the deciding parts; the
    parts are kept (`Verdict.parts`)."""
    return dataclasses.replace(_joined(parts), parts=tuple(parts.items()))


def _joined(parts: dict[str, Verdict]) -> Verdict:
    """`combine`'s verdict, before the parts are attached."""
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


QUICK = "quick budget"
"""The qualifier of every verdict of the quick suite."""
BY_DESIGN = "quick budget; by design: a horizon shorter than the paper's"
"""The qualifier of a quick verdict left inconclusive by a horizon the paper's rule names
and the quick runs do not reach (`by_design`)."""


def by_design(verdict: Verdict) -> bool:
    """Whether an inconclusive verdict is one its budget cannot decide by design: the part
    is stated at a horizon its runs do not reach (`short_horizon`), or, for a claim in
    parts, every inconclusive part is."""
    if verdict.kind != INCONCLUSIVE:
        return False
    if verdict.short_horizon is not None:
        return True
    undecided = [v for _, v in verdict.parts if v.kind == INCONCLUSIVE]
    return bool(undecided) and all(by_design(v) for v in undecided)


def horizon_text(verdict: Verdict) -> str:
    """ "5,000 it, short of the paper's 25,000 it" ("" where the runs reach it)."""
    if verdict.short_horizon is None:
        return ""
    runs, paper = verdict.short_horizon
    return f"{runs:,} it, short of the paper's {paper:,} it"


def at_quick_budget(verdict: Verdict) -> Verdict:
    """What the quick suite may conclude: a refutation that rests on learning runs becomes
    inconclusive (the reason kept), whatever its cause — short runs are no evidence that the
    paper contradicts itself either; a structural one stays; every verdict is marked
    "quick budget", an inconclusive one its budget cannot decide by design (`by_design`)
    as such. The parts are judged alike."""
    parts = tuple((name, at_quick_budget(v)) for name, v in verdict.parts)
    if verdict.kind == REFUTED and not verdict.structural:
        verdict = Verdict(
            INCONCLUSIVE,
            f"quick budget; as measured: {verdict.reason}",
            short_horizon=verdict.short_horizon,
        )
    if verdict.kind == NOT_RUN:
        return dataclasses.replace(verdict, parts=parts)
    verdict = dataclasses.replace(verdict, parts=parts)
    return dataclasses.replace(verdict, qualifier=BY_DESIGN if by_design(verdict) else QUICK)
