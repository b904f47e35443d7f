"""report.md: the report as Markdown (GitHub's dialect: tables, HTML anchors for links
into the page)."""

from __future__ import annotations

from pimbot.analysis import layout
from pimbot.analysis.document import Report, Section
from pimbot.analysis.tables import Table, markdown_lines
from pimbot.analysis.verdicts import MARKERS


def render(report: Report) -> str:
    anchors = layout.headings(report)

    def anchor(text: str) -> str:
        return f'<a id="{anchors[text].pop(0)}"></a>'

    lines = [f"# pimbot: {report.kind} report", ""]
    lines += [p + "\n" for p in layout.intro(report)]
    if report.claims:
        lines += [anchor(layout.SUMMARY), f"## {layout.SUMMARY}", ""]
        lines += summary_lines(report)
    lines += ["**Contents**", ""]
    for level, text, target in layout.outline(report):
        lines.append(f"{'  ' * (level - 1)}- [{text}](#{target})")
    lines.append("")
    if report.claims:
        lines += [anchor(layout.CLAIMS), f"## {layout.CLAIMS}", ""]
        lines += claims_lines(report, anchor)
    lines += section_lines(report.provenance, anchor)
    for section in report.sections:
        lines += section_lines(section, anchor)
    return "\n".join(lines)


def section_lines(section: Section, anchor) -> list[str]:
    """A section's heading, paragraphs, figures (PNG, caption, SVG link) and tables;
    `anchor(title)` writes the next anchor of a heading."""
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


def summary_lines(report: Report) -> list[str]:
    """The summary: one row per claim row with its verdict, the number that carries it and
    why (a quick report's with the published report's verdict)."""
    rows = []
    for line in layout.summary_lines(report):
        rows.append(
            [f"[{line.id}](#{line.anchor})", f"**{line.verdict}**", line.headline, line.why]
            + ([line.published[1]] if line.published is not None else [])
        )
    return markdown_lines(Table(layout.summary_header(report), rows)) + [layout.SUMMARY_NOTE, ""]


def claims_lines(report: Report, anchor) -> list[str]:
    """The claims table (its cells short, each row linked to its details), its verdict
    legend, the parts and the paper | original code | pimbot tables, and every claim's
    details: its rule, every number measured and its verdict's reason in full."""
    rows = []
    for c in report.claims:
        verdict = f"**{layout.marked_verdict(c.verdict)}**"
        if layout.reason(c):
            verdict += f" — {layout.reason(c)}"
        verdict += f" ([details](#{layout.claim_anchor(c)}))"
        rows.append([c.id, c.claim, layout.measured_cell(c), verdict])
        if report.quick:
            rows[-1].append(layout.published_verdict(c)[1])
    lines = markdown_lines(Table(layout.claims_header(report), rows))
    legend = " · ".join(f"{MARKERS[kind]} {text}" for kind, text in layout.VERDICT_LEGEND.items())
    lines += [f"Verdicts: {legend}", ""]
    for table in (layout.shown_parts(report), report.numbers):
        if table is not None:
            lines.append(anchor(table.title))
            lines += markdown_lines(table)
    lines += [anchor(layout.DETAILS), f"### {layout.DETAILS}", ""]
    lines += ["Each claim row's rule, every number measured and its verdict's reason, in full.", ""]
    for c in report.claims:
        lines += [
            f'- <a id="{layout.claim_anchor(c)}"></a>**{c.id}** — {c.claim}',
            f"  - Rule: {c.rule}",
            f"  - Measured: {c.measured}",
            f"  - Verdict: {layout.full_reason(c)}",
        ]
    lines.append("")
    return lines
