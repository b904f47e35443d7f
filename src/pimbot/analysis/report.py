"""`pimbot report`: report.md, a self-contained report.html and tables/*.csv from a suite.

Reads only what `pimbot reproduce` or `pimbot sweep` wrote (index.json and the
run directories); nothing is re-run. The training runs are loaded once into a
`RunTable` (analysis.runs); each section provider turns part of it into text,
tables, figures and the claims it can judge, and the generic provider reports
every run no paper section read. A claim whose runs are not all finished is
marked "not run" whatever its partial numbers say. The HTML embeds every figure
as a data URI, so the one file can be mailed or archived.
"""

from __future__ import annotations

import base64
import dataclasses
import html
import re
from pathlib import Path

from pimbot.analysis import runs as run_table
from pimbot.analysis.document import FIGURES as FIGURES
from pimbot.analysis.document import TABLES, Claim, Context, Provider, Section
from pimbot.analysis.sections import attacks, defenses, device, generic, reciprocators, stag_hunt
from pimbot.analysis.tables import Table, html_table, markdown_lines, write_csv
from pimbot.experiment import presets, store, sweep

MARKDOWN = "report.md"
HTML = "report.html"

PROVIDERS: list[Provider] = [
    attacks.section,
    stag_hunt.section,
    reciprocators.section,
    defenses.section,
    generic.section,
    device.profile_section,
    device.robot_section,
]
"""Report sections in order; each returns None when its runs are absent. The generic one
reports the training runs the paper sections before it did not claim."""

CLAIM_TEXT = {
    "C1": "self-centered: adversary above the others; ER converges faster",
    "C2": "fake incentive (C = 50): success collapses to ~0 in ER",
    "C3": "bypass: 0 success in ER(2,1), ER(4,3); ER(4,2) still solved",
    "C4": "reverse: success → 0 except ER(4,2)",
    "C5": "ADMO vs LIO: adversary's reward and success measures elevated in ER",
    "C6": "Stag Hunt N = 2, 3, 4: LIO baseline rises; ADMO drives it toward 0",
    "C7": reciprocators.C7_TEXT,
    "C8": "on-device profile: ADMO overhead modest, CPU-side, bursty; no sustained saturation",
}


# --- assembling ------------------------------------------------------------------------


def claim_coverage(index: dict) -> dict[str, tuple[int, int]]:
    """(finished, planned) jobs per claim: the whole suite of the index's budget counts."""
    status = {job["name"]: job["status"] for job in index.get("jobs", [])}
    coverage: dict[str, list[int]] = {c: [0, 0] for c in CLAIM_TEXT}
    for job in presets.suite(quick=index.get("suite") == "quick"):
        for claim in job.claims:
            coverage.setdefault(claim, [0, 0])
            coverage[claim][1] += 1
            coverage[claim][0] += status.get(job.name) == "finished"
    return {c: (done, planned) for c, (done, planned) in coverage.items()}


def is_paper_suite(index: dict) -> bool:
    """Whether the directory holds jobs of the paper's suite (they name the claims they
    feed); a `pimbot sweep` grid's jobs feed none and get no claims table."""
    return any(job.get("claims") for job in index.get("jobs", []))


def claims_table(sections: list[Section], index: dict) -> list[Claim]:
    """C1–C8 in order; "not run" unless every job feeding the claim has finished. None
    outside the paper's suite."""
    if not is_paper_suite(index):
        return []
    measured = {claim.id: claim for section in sections for claim in section.claims}
    coverage = claim_coverage(index)
    quick = index.get("suite") == "quick"
    out = []
    for cid, text in CLAIM_TEXT.items():
        done, planned = coverage.get(cid, (0, 0))
        claim = measured.get(cid)
        if claim is None or planned == 0 or done < planned:
            note = f"{done}/{planned} runs finished" if planned else "no runs planned"
            if claim is not None:
                note += f"; so far: {claim.measured}"
            out.append(Claim(cid, text, claim.rule if claim else "–", note, "not run"))
            continue
        if quick:
            claim = dataclasses.replace(claim, verdict=f"{claim.verdict} (quick budget)")
        out.append(claim)
    return out


def build(suite_dir: Path, out: Path) -> tuple[list[Section], list[Claim], dict]:
    index = sweep.read_index(suite_dir)
    if index is None:
        raise sweep.SweepError(
            f"suite_dir: {suite_dir} has no {sweep.INDEX}; run `pimbot reproduce --out "
            f"{suite_dir}` first"
        )
    table = run_table.load_table(suite_dir, index)
    ctx = Context(Path(suite_dir), Path(out), index)
    sections = [s for provide in PROVIDERS if (s := provide(table, ctx)) is not None]
    return sections, claims_table(sections, index), index


def csv_names(sections: list[Section]) -> dict[int, str]:
    """File name (without .csv) of every table, by id(table): its own name or the section's."""
    names: dict[int, str] = {}
    for section in sections:
        slug = re.sub(r"[^a-z0-9]+", "_", section.title.lower()).strip("_")
        for k, table in enumerate(section.tables):
            names[id(table)] = re.sub(r"[^A-Za-z0-9.-]+", "_", table.name or f"{slug}_{k}").strip(
                "_"
            )
    return names


def write_report(suite_dir: Path, out: Path) -> Path:
    """Writes out/report.md, out/report.html, out/figures/ and out/tables/; returns `out`."""
    out.mkdir(parents=True, exist_ok=True)
    sections, claims, index = build(suite_dir, out)
    (out / TABLES).mkdir(exist_ok=True)
    if claims:
        write_csv(_claims_as_table(claims), out / TABLES / "claims.csv")
    names = csv_names(sections)
    for section in sections:
        for table in section.tables:
            write_csv(table, out / TABLES / f"{names[id(table)]}.csv")
    store.write_atomic(out / MARKDOWN, render_markdown(sections, claims, index).encode())
    store.write_atomic(out / HTML, render_html(sections, claims, index, out).encode())
    return out


# --- rendering -------------------------------------------------------------------------


def _intro(index: dict) -> list[str]:
    jobs = index.get("jobs", [])
    finished = sum(j["status"] == "finished" for j in jobs)
    timed = [j["wall_s"] for j in jobs if "wall_s" in j]
    lines = [
        f"Suite: {index.get('suite')} — {finished}/{len(jobs)} jobs finished "
        f"({len(timed)} timed by `pimbot {'reproduce' if is_paper_suite(index) else 'sweep'}`, "
        f"{sum(timed) / 60:.1f} min of job wall "
        "time summed; the others were found finished in the directory). Generated by "
        f"`pimbot report` from the run directories only; every table is also in {TABLES}/ "
        "as CSV."
    ]
    if index.get("suite") == "quick":
        lines.append(
            "This is the quick budget (3 seeds, a fifth of the iterations): it exercises every "
            "setting, figure and claim, but learning claims are judged on runs far shorter than "
            "the paper's. Run `pimbot reproduce` without --quick for the published budget."
        )
    failed = [j["name"] for j in jobs if j["status"] == "failed"]
    if failed:
        lines.append(f"Failed jobs (see index.json): {', '.join(failed)}.")
    return lines


def _kind(index: dict) -> str:
    return "reproduction" if is_paper_suite(index) else "sweep"


def _claims_as_table(claims: list[Claim]) -> Table:
    return Table(
        ["claim", "published", "rule", "measured", "verdict"],
        [[c.id, c.claim, c.rule, c.measured, c.verdict] for c in claims],
    )


def render_markdown(sections: list[Section], claims: list[Claim], index: dict) -> str:
    lines = [f"# pimbot: {_kind(index)} report", ""]
    lines += [p + "\n" for p in _intro(index)]
    if claims:
        lines += ["## Claims", ""] + markdown_lines(_claims_as_table(claims))
    for section in sections:
        lines += [f"## {section.title}", ""]
        lines += [p + "\n" for p in section.text]
        for figure in section.figures:
            link = f"![{figure.caption}]({figure.path.as_posix()})"
            lines += [link, "", f"*{figure.caption}*", ""]
        for table in section.tables:
            lines += markdown_lines(table)
    return "\n".join(lines)


CSS = """
body { font-family: system-ui, sans-serif; max-width: 1200px; margin: 2em auto; padding: 0 1em;
       color: #222; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.85em; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.5em; vertical-align: top; text-align: left; }
th { background: #f3f3f3; }
td.reproduced { background: #e6f4e6; } td.not-reproduced { background: #fbe9e9; }
td.not-run { background: #f0f0f0; color: #777; }
figure { margin: 1.5em 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.9em; color: #555; }
"""


def _verdict_class(column: int, text: str) -> str | None:
    if column != 4:
        return None
    if text.startswith("not run"):
        return "not-run"
    return "not-reproduced" if text.startswith("not reproduced") else "reproduced"


def render_html(sections: list[Section], claims: list[Claim], index: dict, out: Path) -> str:
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>pimbot report</title>",
        f"<style>{CSS}</style></head><body><h1>pimbot: {_kind(index)} report</h1>",
    ]
    parts += [f"<p>{html.escape(p)}</p>" for p in _intro(index)]
    if claims:
        parts += ["<h2>Claims</h2>", html_table(_claims_as_table(claims), _verdict_class)]
    for section in sections:
        parts.append(f"<h2>{html.escape(section.title)}</h2>")
        parts += [f"<p>{html.escape(p)}</p>" for p in section.text]
        for figure in section.figures:
            data = base64.b64encode((out / figure.path).read_bytes()).decode()
            parts.append(
                f"<figure><img alt='{html.escape(figure.caption)}' "
                f"src='data:image/png;base64,{data}'><figcaption>"
                f"{html.escape(figure.caption)}</figcaption></figure>"
            )
        parts += [html_table(t) for t in section.tables]
    parts.append("</body></html>")
    return "\n".join(parts)
