"""`pimbot report`: report.md, a self-contained report.html and tables/*.csv from a suite.

Reads only what `pimbot reproduce` or `pimbot sweep` wrote (index.json and the
run directories); nothing is re-run. The training runs are loaded once into a
`RunTable` (analysis.runs); each section provider turns part of it into text,
tables, figures and the claims it can judge, and the generic provider reports
every run no paper section read. A claim whose runs are not all finished is
marked "not run" whatever its partial numbers say.

The report opens with its provenance (versions, commit, backend and devices
from the runs' config.json files, the budget of every group read from the runs,
the generation date) and a table of contents. Every figure is a PNG with an SVG
beside it; a figure without data is not written. The HTML embeds every PNG as a
data URI, so the one file can be mailed or archived.
"""

from __future__ import annotations

import base64
import dataclasses
import datetime
import html
import os
import re
from collections import Counter
from pathlib import Path

import pimbot
from pimbot.analysis import runs as run_table
from pimbot.analysis import verdicts
from pimbot.analysis.document import FIGURES as FIGURES
from pimbot.analysis.document import (
    TABLES,
    VERDICTS,
    Claim,
    Context,
    Figure,
    Provider,
    Section,
    count_text,
    iterations_text,
    marked_verdict,
    seeds_text,
    slug,
)
from pimbot.analysis.sections import attacks, defenses, device, generic, reciprocators, stag_hunt
from pimbot.analysis.tables import Table, html_table, markdown_lines, write_csv
from pimbot.suites import presets, sweep
from pimbot.training import store

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
    """C1–C8 in order, each suite claim's rows as its section wrote them (C1a, C1b, …);
    "not run" unless every job feeding the claim has finished; at the quick budget what
    `verdicts.at_quick_budget` allows. None outside the paper's suite."""
    if not is_paper_suite(index):
        return []
    measured: dict[str, list[Claim]] = {}
    for claim in (c for section in sections for c in section.claims):
        measured.setdefault(claim.suite_claim, []).append(claim)
    coverage = claim_coverage(index)
    quick = index.get("suite") == "quick"
    out = []
    for cid, text in CLAIM_TEXT.items():
        done, planned = coverage.get(cid, (0, 0))
        mine = measured.get(cid, [])
        if not mine or planned == 0 or done < planned:
            short = f"{done}/{planned} runs finished" if planned else "no runs planned"
            for claim in mine or [None]:
                note = short + (f"; so far: {claim.measured}" if claim is not None else "")
                out.append(
                    Claim(
                        claim.id if claim else cid,
                        claim.claim if claim else text,
                        claim.rule if claim else "–",
                        note,
                        verdicts.not_run(short),
                        short,
                        jobs_of=cid,
                    )
                )
            continue
        for claim in mine:
            judged = verdicts.at_quick_budget(claim.judged) if quick else claim.judged
            out.append(dataclasses.replace(claim, verdict=judged))
    return out


PROVENANCE_FIELDS = (
    ("pimbot version", "pimbot_version"),
    ("git commit", "git_commit"),
    ("JAX version", "jax_version"),
    ("JAX backend", "jax_backend"),
    ("devices", "devices"),
)
"""(row label, config.json key) of the provenance table: what every run records."""
VERDICT_TEXT = verdicts.LEGEND
"""Verdict kind -> its line in the legend under the claims table."""


@dataclasses.dataclass
class Report:
    index: dict
    provenance: Section
    claims: list[Claim]
    sections: list[Section]

    @property
    def kind(self) -> str:
        return "reproduction" if is_paper_suite(self.index) else "sweep"


def generated_at() -> str:
    """The report's date (UTC); SOURCE_DATE_EPOCH, where set, fixes it (reproducible builds)."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    when = (
        datetime.datetime.fromtimestamp(int(epoch), datetime.UTC)
        if epoch
        else datetime.datetime.now(datetime.UTC)
    )
    return when.strftime("%Y-%m-%d %H:%M UTC")


def _provenance_value(config: dict, key: str) -> str:
    value = config.get(key)
    if value is None:
        return "not recorded"
    return ", ".join(map(str, value)) if isinstance(value, list | tuple) else str(value)


def provenance(table: run_table.RunTable, ctx: Context, when: str) -> Section:
    """Versions, commit, backend and devices of the runs, and every group's budget, all read
    from the run directories; one row per distinct value, with the runs that recorded it."""
    records = table.records
    rows: list[list] = []
    for label, key in PROVENANCE_FIELDS:
        values = Counter(_provenance_value(r.config, key) for r in records)
        for value, count in sorted(values.items(), key=lambda kv: (-kv[1], kv[0])):
            rows.append([label, value, f"{count}/{len(records)}"])
    rows.append(["report generated", when, "–"])
    rows.append(["report written by", f"pimbot {pimbot.__version__}", "–"])
    environment = Table(["field", "value", "runs"], rows, "Software and devices", "", "provenance")
    budget = []
    for group in table.groups:
        mine = table.group(group)
        periods = count_text((int(r.identity.get("eval_period", 0)) for r in mine), "iterations")
        budget.append(
            [
                group,
                len(mine),
                seeds_text(mine),
                iterations_text(r.iterations for r in mine),
                f"every {periods}",
                ", ".join(sorted({r.learner for r in mine})),
            ]
        )
    robot = [store.read_json(p) for p in sorted(ctx.suite_dir.glob("robot/*/summary.json"))]
    if robot:
        episodes = count_text((s["episodes_per_seed"] for s in robot), "episodes")
        budget.append(
            [
                "robot",
                len(robot),
                count_text((len(s["seeds"]) for s in robot), "seeds"),
                "–",
                f"{episodes} per seed, physics and abstract",
                "trained runs",
            ]
        )
    profile = ctx.suite_dir / device.PROFILE_RUN / store.SUMMARY
    if profile.exists():
        summary = store.read_json(profile)
        runs = [summary[c] for c in device.CONTROLLERS if c in summary]
        seconds = sorted({float(r["config"]["duration_s"]) for r in runs})
        budget.append(
            [
                "profile",
                len(runs),
                "–",
                "–",
                " / ".join(f"{s:g} s" for s in seconds) + " steady state per controller",
                ", ".join(c for c in device.CONTROLLERS if c in summary),
            ]
        )
    header = ["group", "jobs", "seeds", "iterations", "evaluation", "learners / controllers"]
    budget_table = Table(
        header,
        budget,
        "Budget per group",
        "Seeds and iterations as the finished runs recorded them (summary.json and "
        "config.json), not as a preset says.",
        "provenance_budget",
    )
    jobs = ctx.index.get("jobs", [])
    text = [
        f"Read from the config.json of the {len(records)} finished training run(s) and from "
        f"{sweep.INDEX} ({len(jobs)} jobs, suite {ctx.index.get('suite')!r}); generated "
        f"{when}."
    ]
    return Section("Provenance", text=text, tables=[environment, budget_table])


def original_code_runs() -> tuple[run_table.RunRecord, ...]:
    """The run directories converted from the original PIMbot code's logs (analysis.
    original_code, packaged with pimbot), as run records; none where that package has none."""
    try:
        from pimbot.analysis import original_code
    except ImportError:  # the converted logs are not part of this install
        return ()
    root = Path(original_code.ROOT)
    if not root.is_dir() or not original_code.run_dirs(root):
        return ()
    return run_table.load_table(root).original


def clear_figures(out: Path) -> None:
    """Removes the figures of an earlier report in `out`: a figure this one does not write
    (its data gone) must not stay linked."""
    folder = out / FIGURES
    if folder.is_dir():
        for path in folder.iterdir():
            if path.is_file() and path.suffix in (".png", ".svg"):
                path.unlink()


def build(suite_dir: Path, out: Path) -> Report:
    index = sweep.read_index(suite_dir)
    if index is None:
        raise sweep.SweepError(
            f"suite_dir: {suite_dir} has no {sweep.INDEX}; run `pimbot reproduce --out "
            f"{suite_dir}` first"
        )
    table = run_table.load_table(suite_dir, index)
    table = dataclasses.replace(table, original=table.original + original_code_runs())
    ctx = Context(Path(suite_dir), Path(out), index)
    sections = [s for provide in PROVIDERS if (s := provide(table, ctx)) is not None]
    for section in sections:  # a figure with no data was not written: nothing to link
        section.figures = [f for f in section.figures if (ctx.out / f.path).exists()]
    front = provenance(table, ctx, generated_at())
    return Report(index, front, claims_table(sections, index), sections)


def csv_names(sections: list[Section]) -> dict[int, str]:
    """File name (without .csv) of every table, by id(table): its own name or the section's."""
    names: dict[int, str] = {}
    for section in sections:
        name = re.sub(r"[^a-z0-9]+", "_", section.title.lower()).strip("_")
        for k, table in enumerate(section.tables):
            names[id(table)] = re.sub(r"[^A-Za-z0-9.-]+", "_", table.name or f"{name}_{k}").strip(
                "_"
            )
    return names


def write_report(suite_dir: Path, out: Path) -> Path:
    """Writes out/report.md, out/report.html, out/figures/ (PNG and SVG) and out/tables/;
    returns `out`."""
    out.mkdir(parents=True, exist_ok=True)
    clear_figures(out)
    report = build(suite_dir, out)
    (out / TABLES).mkdir(exist_ok=True)
    if report.claims:
        write_csv(_claims_as_table(report.claims), out / TABLES / "claims.csv")
        numbers = comparison_table(report.claims)
        if numbers is not None:
            write_csv(numbers, out / TABLES / f"{numbers.name}.csv")
    everything = [report.provenance, *report.sections]
    names = csv_names(everything)
    for section in everything:
        for table in section.tables:
            write_csv(table, out / TABLES / f"{names[id(table)]}.csv")
    store.write_atomic(out / MARKDOWN, render_markdown(report).encode())
    store.write_atomic(out / HTML, render_html(report, out).encode())
    return out


# --- rendering -------------------------------------------------------------------------


def _intro(index: dict, budget: str = "") -> list[str]:
    jobs = index.get("jobs", [])
    finished = sum(j["status"] == "finished" for j in jobs)
    timed = [j["wall_s"] for j in jobs if "wall_s" in j]
    lines = [
        f"Suite: {index.get('suite')} — {finished}/{len(jobs)} jobs finished "
        f"({len(timed)} timed by `pimbot {'reproduce' if is_paper_suite(index) else 'sweep'}`, "
        f"{sum(timed) / 60:.1f} min of job wall "
        "time summed; the others were found finished in the directory). Generated by "
        f"`pimbot report` from the run directories only; every table is also in {TABLES}/ "
        "as CSV, every figure in figures/ as PNG and SVG."
    ]
    if index.get("suite") == "quick":
        lines.append(
            f"This is the quick budget ({budget or 'see Provenance'}; "
            f"{presets.QUICK.iteration_fraction * 100:g} % of the published iterations): it "
            "exercises every setting, figure and claim, but learning claims are judged on runs "
            "far shorter than the paper's. Run `pimbot reproduce` without --quick for the "
            "published budget."
        )
    failed = [j["name"] for j in jobs if j["status"] == "failed"]
    if failed:
        lines.append(f"Failed jobs (see index.json): {', '.join(failed)}.")
    return lines


def _budget(report: Report) -> str:
    """The seed count of the training runs, from the provenance's budget table."""
    budget = report.provenance.tables[1].rows
    seeds = [row[2] for row in budget if row[2] != "–"]
    return "; ".join(sorted(set(seeds))) + " per run" if seeds else ""


def _claims_as_table(claims: list[Claim]) -> Table:
    """The claims CSV: every number judged, the verdict's label and its reason."""
    return Table(
        ["claim", "published", "rule", "measured", "verdict", "reason"],
        [[c.id, c.claim, c.rule, c.measured, c.judged.label, c.judged.reason] for c in claims],
    )


COMPARISON_NOTE = (
    "Each number as the paper states it, as the original PIMbot code's log.csv files give it "
    "(converted into run directories and read by the same metric code as pimbot's runs; "
    "byte-identical copies counted once) and as pimbot measures it, at the same horizon. "
    "'no log': the original code's logs do not cover it."
)


def comparison_table(claims: list[Claim]) -> Table | None:
    """paper | original code | pimbot, one row per number a claim states; None if none."""
    rows = [
        [c.id, n.quantity, n.horizon, n.paper, "no log" if n.original is None else n.original]
        + [n.pimbot]
        for c in claims
        for n in c.numbers
    ]
    if not rows:
        return None
    header = ["claim", "quantity", "horizon", "paper", "original code", "pimbot"]
    return Table(header, rows, "Paper | original code | pimbot", COMPARISON_NOTE, "claims_numbers")


REASON_CHARS = 320
"""A verdict's reason longer than this is cut in the claims table (in full below it)."""


def _reason(claim: Claim) -> str:
    """The verdict's reason as the claims table shows it ("" for not run)."""
    reason = claim.judged.reason if claim.judged.kind != verdicts.NOT_RUN else ""
    if len(reason) <= REASON_CHARS:
        return reason
    cut = reason.rfind("; ", 0, REASON_CHARS)
    return reason[: cut if cut > 0 else REASON_CHARS] + "; … (in full below)"


def _details(claim: Claim) -> bool:
    """Whether the claim's measured numbers (or its verdict's reason) go below the table."""
    shorter = bool(claim.summary) and claim.summary != claim.measured
    return shorter or _reason(claim) != (
        claim.judged.reason if claim.judged.kind != verdicts.NOT_RUN else ""
    )


def _in_full(claim: Claim) -> str:
    """The details line: every number measured, and the verdict's reason where it was cut."""
    text = claim.measured
    if _reason(claim) != claim.judged.reason and claim.judged.kind != verdicts.NOT_RUN:
        text += f". Verdict: {claim.judged}"
    return text


def _claim_anchor(claim: Claim) -> str:
    return f"claim-{slug(claim.id)}"


def _verdict_legend() -> str:
    return "Verdicts: " + " · ".join(
        f"{VERDICTS[kind]} {text}" for kind, text in VERDICT_TEXT.items()
    )


class _Anchors:
    """Unique anchors for headings (a second "Defenses" becomes "defenses-2")."""

    def __init__(self):
        self.seen: Counter = Counter()

    def __call__(self, text: str) -> str:
        base = slug(text)
        self.seen[base] += 1
        return base if self.seen[base] == 1 else f"{base}-{self.seen[base]}"


def _figure_title(figure: Figure) -> str:
    return figure.caption.split(" (")[0].split("; ")[0]


def _outline(report: Report) -> list[tuple[int, str, str]]:
    """(level, text, anchor) of every entry of the table of contents, in order."""
    anchors = _Anchors()
    entries = [(1, "Provenance", anchors("Provenance"))]
    for table in report.provenance.tables:
        entries.append((2, table.title, anchors(table.title)))
    if report.claims:
        entries.append((1, "Claims", anchors("Claims")))
        numbers = comparison_table(report.claims)
        if numbers is not None:
            entries.append((2, numbers.title, anchors(numbers.title)))
    for section in report.sections:
        entries.append((1, section.title, anchors(section.title)))
        entries += [(2, _figure_title(f), f.anchor) for f in section.figures]
        entries += [(2, t.title, anchors(t.title)) for t in section.tables if t.title]
    return entries


def _headings(report: Report) -> dict[str, list[str]]:
    """Anchor of each heading text, in document order (repeated titles get their own)."""
    out: dict[str, list[str]] = {}
    for level, text, anchor in _outline(report):
        if not (level == 2 and anchor.startswith("fig")):
            out.setdefault(text, []).append(anchor)
    return out


def render_markdown(report: Report) -> str:
    anchors = _headings(report)

    def anchor(text: str) -> str:
        return f'<a id="{anchors[text].pop(0)}"></a>'

    lines = [f"# pimbot: {report.kind} report", ""]
    lines += [p + "\n" for p in _intro(report.index, budget=_budget(report))]
    lines += ["**Contents**", ""]
    for level, text, target in _outline(report):
        lines.append(f"{'  ' * (level - 1)}- [{text}](#{target})")
    lines.append("")

    def section_lines(section: Section) -> list[str]:
        out = [anchor(section.title), f"## {section.title}", ""]
        out += [p + "\n" for p in section.text]
        for figure in section.figures:
            out += [f'<a id="{figure.anchor}"></a>', ""]
            out += [f"![{figure.caption}]({figure.path.as_posix()})", ""]
            out += [f"*{figure.caption}* (vector: [SVG]({figure.svg.as_posix()}))", ""]
        for table in section.tables:
            if table.title:
                out.append(anchor(table.title))
            out += markdown_lines(table)
        return out

    lines += section_lines(report.provenance)
    if report.claims:
        lines += [anchor("Claims"), "## Claims", ""]
        rows = []
        for c in report.claims:
            measured = (c.summary or c.measured) if _details(c) else c.measured
            if _details(c):
                measured += f" ([details](#{_claim_anchor(c)}))"
            verdict = f"**{marked_verdict(c.verdict)}**"
            if _reason(c):
                verdict += f" — {_reason(c)}"
            rows.append([c.id, c.claim, c.rule, measured, verdict])
        header = ["claim", "published", "rule", "measured", "verdict"]
        lines += markdown_lines(Table(header, rows))
        lines += [_verdict_legend(), ""]
        numbers = comparison_table(report.claims)
        if numbers is not None:
            lines.append(anchor(numbers.title))
            lines += markdown_lines(numbers)
        details = [c for c in report.claims if _details(c)]
        if details:
            lines += ["Measured, in full:", ""]
            lines += [
                f'- <a id="{_claim_anchor(c)}"></a>**{c.id}**: {_in_full(c)}' for c in details
            ]
            lines.append("")
    for section in report.sections:
        lines += section_lines(section)
    return "\n".join(lines)


CSS = """
body { font-family: system-ui, sans-serif; max-width: 1200px; margin: 2em auto; padding: 0 1em;
       color: #222; line-height: 1.45; }
h2 { border-bottom: 1px solid #ddd; padding-bottom: 0.2em; margin-top: 2em; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.85em; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.5em; vertical-align: top; text-align: left; }
th { background: #f3f3f3; }
nav.toc { background: #f8f8f8; border: 1px solid #ddd; padding: 0.6em 1.2em; font-size: 0.9em; }
nav.toc ul { margin: 0.2em 0; padding-left: 1.2em; } nav.toc > ul { columns: 2; }
nav.toc ul ul { font-size: 0.92em; color: #555; }
table.claims td.rule { font-size: 0.9em; color: #555; max-width: 22em; }
table.claims td.measured { max-width: 24em; }
td.verdict { font-weight: 600; min-width: 11em; max-width: 26em; }
table.claims td.rule { min-width: 13em; }
td.verdict .mark { display: inline-block; width: 1.2em; text-align: center; }
.reproduced { background: #e3f4e6; color: #1b5e20; border-left: 5px solid #2e7d32; }
.reproduced-at-budget { background: #eef6e3; color: #33691e; border-left: 5px double #558b2f; }
.refuted { background: #fde8e8; color: #a31515; border-left: 5px solid #c62828; }
td.verdict .reason { font-weight: normal; font-size: 0.88em; }
.inconclusive { background: #fff3dc; color: #7a4f00; border-left: 5px dashed #e09b00; }
.not-run { background: #f0f0f0; color: #666; font-style: italic; border-left: 5px dotted #999; }
p.legend { font-size: 0.85em; } p.legend span { margin-right: 0.8em; padding: 0.15em 0.5em; }
ul.details { font-size: 0.85em; color: #333; } ul.details li { margin: 0.3em 0; }
figure { margin: 1.5em 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.9em; color: #555; }
"""


def _verdict_cell(claim: Claim) -> str:
    judged = claim.judged
    label = judged.label if isinstance(claim.verdict, verdicts.Verdict) else claim.verdict
    reason = _reason(claim)
    why = f"<br><span class='reason'>{html.escape(reason)}</span>" if reason else ""
    return (
        f"<td class='verdict {judged.kind}'><span class='mark'>{VERDICTS[judged.kind]}</span> "
        f"{html.escape(label)}{why}</td>"
    )


def _claims_html(claims: list[Claim]) -> str:
    head = "".join(f"<th>{h}</th>" for h in ("claim", "published", "rule", "measured", "verdict"))
    rows = []
    for c in claims:
        measured = html.escape((c.summary or c.measured) if _details(c) else c.measured)
        if _details(c):
            measured += f" <a href='#{_claim_anchor(c)}'>details</a>"
        rows.append(
            f"<tr><td>{html.escape(c.id)}</td><td>{html.escape(c.claim)}</td>"
            f"<td class='rule'>{html.escape(c.rule)}</td><td class='measured'>{measured}</td>"
            f"{_verdict_cell(c)}</tr>"
        )
    legend = "".join(
        f"<span class='{kind}'>{VERDICTS[kind]} {html.escape(text)}</span>"
        for kind, text in VERDICT_TEXT.items()
    )
    parts = [f"<table class='claims'><tr>{head}</tr>{''.join(rows)}</table>"]
    parts.append(f"<p class='legend'>Verdicts: {legend}</p>")
    details = [c for c in claims if _details(c)]
    if details:
        items = "".join(
            f"<li id='{_claim_anchor(c)}'><b>{html.escape(c.id)}</b>: {html.escape(_in_full(c))}"
            "</li>"
            for c in details
        )
        parts.append(f"<p>Measured, in full:</p><ul class='details'>{items}</ul>")
    return "".join(parts)


def _toc_html(report: Report) -> str:
    parts, level = ["<nav class='toc'><b>Contents</b><ul>"], 1
    for depth, text, anchor in _outline(report):
        if depth > level:
            parts.append("<ul>")
        elif depth < level:
            parts.append("</ul></li>")
        elif parts[-1] != "<nav class='toc'><b>Contents</b><ul>":
            parts.append("</li>")
        level = depth
        parts.append(f"<li><a href='#{anchor}'>{html.escape(text)}</a>")
    parts.append("</li></ul></li>" if level > 1 else "</li>")
    parts.append("</ul></nav>")
    return "".join(parts)


def render_html(report: Report, out: Path) -> str:
    anchors = _headings(report)

    def titled(table: Table, cell_class=None) -> str:
        rendered = html_table(table, cell_class)
        if table.title:
            target = anchors[table.title].pop(0)
            rendered = rendered.replace("<h3>", f"<h3 id='{target}'>", 1)
        return rendered

    def section_html(section: Section) -> list[str]:
        out_parts = [f"<h2 id='{anchors[section.title].pop(0)}'>{html.escape(section.title)}</h2>"]
        out_parts += [f"<p>{html.escape(p)}</p>" for p in section.text]
        for figure in section.figures:
            data = base64.b64encode((out / figure.path).read_bytes()).decode()
            out_parts.append(
                f"<figure id='{figure.anchor}'><img alt='{html.escape(figure.caption)}' "
                f"src='data:image/png;base64,{data}'><figcaption>"
                f"{html.escape(figure.caption)} (vector: <a href='{figure.svg.as_posix()}'>"
                "SVG</a>)</figcaption></figure>"
            )
        out_parts += [titled(t) for t in section.tables]
        return out_parts

    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>pimbot report</title>",
        f"<style>{CSS}</style></head><body><h1>pimbot: {report.kind} report</h1>",
    ]
    parts += [f"<p>{html.escape(p)}</p>" for p in _intro(report.index, budget=_budget(report))]
    parts.append(_toc_html(report))
    parts += section_html(report.provenance)
    if report.claims:
        parts += [f"<h2 id='{anchors['Claims'].pop(0)}'>Claims</h2>", _claims_html(report.claims)]
        numbers = comparison_table(report.claims)
        if numbers is not None:
            parts.append(titled(numbers))
    for section in report.sections:
        parts += section_html(section)
    parts.append("</body></html>")
    return "\n".join(parts)
