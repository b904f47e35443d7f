"""The report's summary (analysis.summary): one line per claim row with its verdict, the
number that carries it and a clause of why, set by the claim's builder or derived from
its verdict."""

from __future__ import annotations

from pimbot.analysis import claims, summary, verdicts
from pimbot.analysis.claims import Claim, Comparison


def in_parts(**parts: verdicts.Verdict) -> verdicts.Verdict:
    return verdicts.combine({name.replace("_", " "): v for name, v in parts.items()})


MARGIN = (
    "margin +5.27 [+0.81, +7.17] (sign-flip permutation p = 0.062 for > 0, 0.969 for < 0): "
    "the seeds cannot tell it from 0"
)


def test_the_number_and_why_come_from_the_deciding_part():
    verdict = in_parts(
        ER21=verdicts.reproduced("margin +9.40 [+8.53, +10.28]"),
        ER42=verdicts.inconclusive(MARGIN),
    )
    claim = Claim("C5", "c", "r", "m", verdict)
    assert claims.deciding_part(verdict)[0] == "ER42"
    assert summary.headline(claim) == "ER42: margin +5.27 [+0.81, +7.17], p = 0.062"
    assert summary.why(claim) == "the seeds cannot tell it from 0"
    # At the quick budget the deciding part is still found (the label says "quick").
    quick = Claim("C5", "c", "r", "m", verdicts.at_quick_budget(verdict))
    assert summary.headline(quick) == summary.headline(claim)


def test_a_refutation_the_quick_budget_made_inconclusive_says_as_measured():
    verdict = verdicts.refuted(verdicts.BUDGET, "final 0.148 [0.046, 0.290] lies above 0.01")
    quick = verdicts.at_quick_budget(verdict)
    assert quick.kind == verdicts.INCONCLUSIVE
    claim = Claim("C4", "c", "r", "m", quick)
    assert summary.headline(claim) == "final 0.148 [0.046, 0.290]"
    assert summary.why(claim) == "as measured, final 0.148 lies above 0.01"
    own = Claim("C4", "c", "r", "m", quick, why="success stays up")
    assert summary.why(own) == "as measured, success stays up"


def test_a_builders_number_and_clause_come_first():
    verdict = in_parts(ER42=verdicts.inconclusive(MARGIN))
    claim = Claim(
        "C5", "c", "r", "m", verdict, headline="ER(4,2) margin +5.27 [+0.81, +7.17]", why="w"
    )
    # The test's p value of the same number joins it.
    assert summary.headline(claim) == "ER(4,2) margin +5.27 [+0.81, +7.17], p = 0.062"
    assert summary.why(claim) == "w"
    long = Claim("C5", "c", "r", "m", verdict, why="word " * 60)
    assert len(summary.why(long)) <= summary.WHY_CHARS and summary.why(long).endswith("…")


def test_without_an_interval_in_the_reason_the_claims_row_gives_the_number():
    numbers = [
        Comparison("ER(2,1) clean → ADMO success", "60 updates", "≥ 0.8", None, "0.42 → 0.30"),
        Comparison("ER(4,2) clean → ADMO success", "60 updates", "≥ 0.8", None, "0.19 → 0.19"),
    ]
    verdict = in_parts(
        ER21=verdicts.reproduced("fine"),
        **{"ER(4,2)_baseline": verdicts.inconclusive("no baseline to attack: 0.19 < 0.8")},
    )
    claim = Claim("C7", "c", "r", "m", verdict, numbers=numbers)
    assert summary.headline(claim) == "ER(4,2) clean → ADMO success 0.19 → 0.19"
    assert summary.why(claim) == "no baseline to attack: 0.19 < 0.8"
    bare = Claim("C9", "c", "r", "all measured", verdicts.inconclusive("too few seeds"))
    assert summary.headline(bare) == "all measured"


def test_a_row_not_run_has_no_number():
    claim = Claim("C8", "c", "–", "m", verdicts.not_run("0/1 runs finished"), headline="x")
    assert summary.headline(claim) == "–" and summary.why(claim) == "0/1 runs finished"


def test_summarized_picks_the_deciding_or_the_weakest_part():
    numbers = {"A": "A 1.0 [0.9, 1.1]", "B": "B 0.5 [0.1, 0.9]"}
    agreed = in_parts(A=verdicts.reproduced("a"), B=verdicts.reproduced("b"))
    fields = claims.summarized(agreed, numbers, weakest="B", agreed="both hold", why="no")
    assert fields == {"headline": "B 0.5 [0.1, 0.9]", "why": "both hold"}
    split = in_parts(A=verdicts.reproduced("a"), B=verdicts.inconclusive("b"))
    fields = claims.summarized(split, numbers, weakest="A", agreed="both hold", why="")
    assert fields == {"headline": "B 0.5 [0.1, 0.9]", "why": ""}
    assert claims.summarized(verdicts.inconclusive("x"), {}) == {"headline": "", "why": ""}


def test_a_cut_never_splits_an_interval():
    text = "final 0.148 [0.046, 0.290] and more words after it, then " + "x" * 40
    for chars in range(20, len(text)):
        cut = summary.cut(text, chars)
        assert len(cut) <= chars
        assert cut.count("[") == cut.count("]"), cut
