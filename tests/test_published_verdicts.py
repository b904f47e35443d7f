"""The published report's verdicts, shipped as package data, beside a quick report's own.

The shipped file must equal what docs/report's claims tables give (so the two cannot
drift); a quick report shows each claim row's and each part's published verdict, the
published figure of each quantity, and names the parts its horizon cannot decide by
design. The quick suite here is written by hand (config.json and metrics.csv of 3-seed
runs; nothing is trained).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from pimbot.analysis import claims, published, report, verdicts
from pimbot.suites import presets, sweep

ROOT = Path(__file__).resolve().parents[1]
PUBLISHED_REPORT = ROOT / "docs" / "report"
SEEDS = 3
QUICK_HORIZON = 5_000


def test_the_shipped_file_is_what_the_published_report_gives():
    shipped = published.shipped_path().read_text(encoding="utf-8")
    made = published.data_text(published.from_report(PUBLISHED_REPORT))
    assert shipped == made, f"docs/report changed: regenerate with `{published.REGENERATE}`"
    data = json.loads(shipped)
    assert [row["claim"] for row in data["claims"]][:3] == ["C1a", "C1b", "C2"]
    # The installed package reads the same file.
    assert published.shipped() == published.Published.of(data)


def test_a_parts_published_verdict_from_its_claim_row():
    shown = published.shipped()
    assert shown.verdict("C4") == "inconclusive"
    assert shown.part_verdict("C4", "ER(2,1)") == "inconclusive"  # named in the reason
    assert shown.part_verdict("C4", "ER(4,2)") == "reproduced"  # not named: reproduced
    assert shown.part_verdict("C1a", "IPD(2)") == "reproduced"
    assert shown.part_verdict("C6", "SH(2) admo_disrupt → 0") == "refuted"
    assert shown.part_verdict("C6", "SH(2) clean rises") == published.NOT_REFUTED
    assert shown.part_verdict("C9", "ER(2,1)") is None
    assert shown.figure("C4", "ER(2,1) reverse success") == "0.022 [0.013, 0.035] at 25,000 it"
    # A published parts table, where the report has one, is read as it is.
    own = published.Published.of(
        {"claims": [{"claim": "C4", "verdict": "inconclusive", "reason": "x"}],
         "parts": [{"claim": "C4", "part": "ER(4,2)", "verdict": "refuted", "reason": "y"}]}
    )  # fmt: skip
    assert own.part_verdict("C4", "ER(4,2)") == "refuted"


def test_a_part_short_of_the_papers_horizon_is_undecidable_by_design_at_the_quick_budget():
    short = verdicts.stated_at(verdicts.inconclusive("seeds cannot tell"), 5_000, 25_000)
    assert verdicts.stated_at(short, 25_000, 25_000).short_horizon == (5_000, 25_000)
    assert verdicts.stated_at(verdicts.reproduced(), 25_000, 25_000).short_horizon is None
    whole = verdicts.combine({"ER(2,1)": short, "ER(4,2)": verdicts.reproduced("1.0")})
    assert [name for name, _ in whole.parts] == ["ER(2,1)", "ER(4,2)"]
    assert whole == verdicts.inconclusive(whole.reason)  # the rules' verdict unchanged
    quick = verdicts.at_quick_budget(whole)
    assert quick.kind == verdicts.INCONCLUSIVE
    assert quick.label == f"inconclusive ({verdicts.BY_DESIGN})"
    assert dict(quick.parts)["ER(4,2)"].label == "reproduced (quick budget)"
    # An inconclusive part its runs' horizon does not explain keeps the plain label.
    seeds = verdicts.combine({"a": short, "b": verdicts.inconclusive("3 seeds")})
    assert verdicts.at_quick_budget(seeds).label == "inconclusive (quick budget)"
    assert verdicts.horizon_text(short) == "5,000 it, short of the paper's 25,000 it"


# --- a quick suite's report -------------------------------------------------------------


def er(n: int, m: int) -> dict:
    return {"max_steps": 5, "min_at_lever": m, "n_agents": n, "randomize_start": False}


def write_reverse_run(root: Path, name: str, env_params: dict, success: float) -> None:
    """A finished 3-seed LIO reverse run of QUICK_HORIZON iterations, its success 0.5
    during the exploration period and `success` after."""
    path = root / "attacks" / name
    path.mkdir(parents=True)
    identity = {
        "attack": "reverse",
        "attack_params": {"adversary": 0},
        "env_id": "escape_room-v0",
        "env_params": env_params,
        "eval_episodes": 10,
        "eval_period": 500,
        "first_seed": 0,
        "iterations": QUICK_HORIZON,
        "learner": "lio",
        "learner_config": {"epsilon_decay_iters": 1000},
        "seeds": SEEDS,
    }
    config = {
        "identity": identity,
        "run_config": {"attack_params": [], "hparams": [], "defenses": [], "env_params": []},
        "env": {"id": "escape_room-v0", "num_agents": env_params["n_agents"], "params": env_params},
    }
    (path / "config.json").write_text(json.dumps(config))
    (path / "summary.json").write_text(json.dumps({"finished": True}))
    with open(path / "metrics.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["iteration", "seed", "eval/success", "eval/steps", "perf/iters_per_s"])
        for seed in range(SEEDS):
            for it in range(500, QUICK_HORIZON + 1, 500):
                writer.writerow([it, seed, 0.5 if it <= 1000 else success, 3.0, 1000.0])


@pytest.fixture(scope="module")
def quick_report(tmp_path_factory) -> Path:
    """The report of a quick suite whose every job is finished and whose reverse runs
    (C4) stop at QUICK_HORIZON, a fifth of the paper's 25,000 iterations."""
    root = tmp_path_factory.mktemp("quick")
    write_reverse_run(root, "er21_reverse", er(2, 1), 0.3)
    write_reverse_run(root, "er42_reverse", er(4, 2), 1.0)
    write_reverse_run(root, "er43_reverse", er(4, 3), 0.0)
    jobs = [
        {"name": j.name, "group": j.name.split("/")[0], "kind": "train",
         "claims": list(j.claims), "status": "finished"}
        for j in presets.suite(quick=True)
    ]  # fmt: skip
    sweep.write_index(root, {"suite": claims.QUICK_SUITE, "jobs": jobs})
    return report.write_report(root, tmp_path_factory.mktemp("report"))


def row_of(markdown: str, start: str) -> str:
    return next(line for line in markdown.splitlines() if line.startswith(start))


def test_a_quick_report_row_carries_the_published_verdict(quick_report):
    markdown = (quick_report / report.MARKDOWN).read_text()
    assert "| claim | published | measured | verdict | published report's verdict |" in markdown
    # The summary, first, with the published verdict beside each quick one.
    summary = markdown.split("## Summary")[1].split("**Contents**")[0]
    header = "| claim | verdict | the number that carries it | why | published report's verdict |"
    assert header in summary
    line = row_of(summary, "| [C4](#claim-c4) |")
    assert "| ER(2,1) final 0.340" in line and "at 5,000 it" in line
    assert line.endswith("| ◐ inconclusive |")
    c4 = row_of(markdown, "| C4 |")
    assert "(quick budget; by design: a horizon shorter than the paper's)" in c4
    assert c4.endswith("| ◐ inconclusive |")  # the published report's verdict of C4
    assert row_of(markdown, "| C1a |").endswith("| ✔ reproduced |")
    page = (quick_report / report.HTML).read_text()
    assert "<th>published report&#x27;s verdict</th>" in page
    assert "<td class='verdict published inconclusive'>◐ inconclusive</td>" in page
    # The published figure beside the quick one, at the published horizon.
    number = row_of(markdown, "| C4 | ER(2,1) reverse success |")
    assert "| 5,000 it |" in number and number.endswith("| 0.022 [0.013, 0.035] at 25,000 it |")
    with open(quick_report / report.TABLES / "claims.csv", newline="") as f:
        rows = {row["claim"]: row for row in csv.DictReader(f)}
    assert rows["C4"]["published report"] == "inconclusive"


def test_a_part_undecidable_by_design_says_so(quick_report):
    markdown = (quick_report / report.MARKDOWN).read_text()
    assert "### Claim parts" in markdown
    er21 = row_of(markdown, "| C4 | ER(2,1) |")
    assert "inconclusive (quick budget; by design: a horizon shorter than the paper's)" in er21
    assert "| 5,000 it < the paper's 25,000: final 0.340" in er21  # the rule's own words
    assert er21.endswith("| inconclusive |")  # the published part
    er42 = row_of(markdown, "| C4 | ER(4,2) |")
    assert "| reproduced (quick budget) | 5,000 it, short of the paper's 25,000 it;" in er42
    assert er42.endswith("| reproduced |")
    with open(quick_report / report.TABLES / "claims_parts.csv", newline="") as f:
        parts = {(row["claim"], row["part"]): row for row in csv.DictReader(f)}
    assert parts[("C4", "ER(2,1)")]["published report"] == "inconclusive"
