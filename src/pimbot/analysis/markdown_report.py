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
    lines += ["**Contents**", ""]
    for level, text, target in layout.outline(report):
        lines.append(f"{'  ' * (level - 1)}- [{text}](#{target})")
    lines.append("")
    lines += section_lines(report.provenance, anchor)
    if report.claims:
        lines += [anchor("Claims"), "## Claims", ""]
        lines += claims_lines(report, anchor)
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


def claims_lines(report: Report, anchor) -> list[str]:
    """The claims table, its verdict legend, the paper | original code | pimbot table and
    every number measured where the table gives a short form."""
    rows = []
    for c in report.claims:
        measured = layout.measured_cell(c)
        if layout.has_details(c):
            measured += f" ([details](#{layout.claim_anchor(c)}))"
        verdict = f"**{layout.marked_verdict(c.verdict)}**"
        if layout.reason(c):
            verdict += f" — {layout.reason(c)}"
        rows.append([c.id, c.claim, c.rule, measured, verdict])
        if report.quick:
            rows[-1].append(layout.published_verdict(c)[1])
    lines = markdown_lines(Table(layout.claims_header(report), rows))
    legend = " · ".join(f"{MARKERS[kind]} {text}" for kind, text in layout.VERDICT_LEGEND.items())
    lines += [f"Verdicts: {legend}", ""]
    for table in (layout.shown_parts(report), report.numbers):
        if table is not None:
            lines.append(anchor(table.title))
            lines += markdown_lines(table)
    details = [c for c in report.claims if layout.has_details(c)]
    if details:
        lines += ["Measured, in full:", ""]
        lines += [
            f'- <a id="{layout.claim_anchor(c)}"></a>**{c.id}**: {layout.in_full(c)}'
            for c in details
        ]
        lines.append("")
    return lines
