"""report.html: the report as one self-contained page (every PNG embedded as a data URI,
the stylesheet `report.css` inlined), so the one file can be mailed or archived."""

from __future__ import annotations

import base64
import html
from importlib import resources
from pathlib import Path

from pimbot.analysis import layout, summary
from pimbot.analysis.claims import Claim
from pimbot.analysis.document import Report, Section
from pimbot.analysis.tables import Table, html_table
from pimbot.analysis.verdicts import MARKERS

STYLESHEET = "report.css"
"""Package data of pimbot.analysis: the page's style; each verdict kind is a CSS class."""


def stylesheet() -> str:
    return resources.files("pimbot.analysis").joinpath(STYLESHEET).read_text(encoding="utf-8")


def render(report: Report, out: Path) -> str:
    """The page; `out` is the report directory the figures' PNGs are read from."""
    anchors = layout.headings(report)

    def titled(table: Table) -> str:
        rendered = html_table(table)
        if table.title:
            target = anchors[table.title].pop(0)
            rendered = rendered.replace("<h3>", f"<h3 id='{target}'>", 1)
        return rendered

    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>pimbot report</title>",
        f"<style>\n{stylesheet()}</style></head><body><h1>pimbot: {report.kind} report</h1>",
    ]
    parts += [f"<p>{html.escape(p)}</p>" for p in layout.intro(report)]
    if report.claims:
        parts.append(summary_html(report, anchors[layout.SUMMARY].pop(0)))
    parts.append(contents(report))
    if report.claims:
        parts += [f"<h2 id='{anchors[layout.CLAIMS].pop(0)}'>Claims</h2>", claims_html(report)]
        parts += [titled(t) for t in (layout.shown_parts(report), report.numbers) if t is not None]
        parts.append(details_html(report, anchors[layout.DETAILS].pop(0)))
    parts += section_html(report.provenance, out, anchors, titled)
    for section in report.sections:
        parts += section_html(section, out, anchors, titled)
    parts.append("</body></html>")
    return "\n".join(parts)


def section_html(section: Section, out: Path, anchors: dict, titled) -> list[str]:
    """A section's heading, paragraphs, figures (embedded PNG, caption, SVG link) and
    tables (`titled` writes one with its heading's anchor)."""
    parts = [f"<h2 id='{anchors[section.title].pop(0)}'>{html.escape(section.title)}</h2>"]
    parts += [f"<p>{html.escape(p)}</p>" for p in section.text]
    for figure in section.figures:
        data = base64.b64encode((out / figure.path).read_bytes()).decode()
        parts.append(
            f"<figure id='{figure.anchor}'><img alt='{html.escape(figure.caption)}' "
            f"src='data:image/png;base64,{data}'><figcaption>"
            f"{html.escape(figure.caption)} (vector: <a href='{figure.svg.as_posix()}'>"
            "SVG</a>)</figcaption></figure>"
        )
    parts += [titled(t) for t in section.tables]
    return parts


def contents(report: Report) -> str:
    """The table of contents as nested lists."""
    parts, level = ["<nav class='toc'><b>Contents</b><ul>"], 1
    for depth, text, anchor in layout.outline(report):
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


def summary_html(report: Report, anchor: str) -> str:
    """The summary: one row per claim row with its verdict, the number that carries it and
    why (a quick report's with the published report's verdict), each linked to its
    details."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in layout.summary_header(report))
    rows = []
    for line in layout.summary_lines(report):
        beside = ""
        if line.published is not None:
            kind, text = line.published
            beside = f"<td class='verdict published {kind}'>{html.escape(text)}</td>"
        rows.append(
            f"<tr><td class='id'><a href='#{line.anchor}'>{html.escape(line.id)}</a>"
            f"<span class='claim'>{html.escape(line.claim)}</span></td>"
            f"<td class='verdict {line.kind}'>{html.escape(line.verdict)}</td>"
            f"<td class='number'>{unbroken(html.escape(line.headline))}</td>"
            f"<td class='why'>{html.escape(line.why)}</td>{beside}</tr>"
        )
    return (
        f"<h2 id='{anchor}'>{layout.SUMMARY}</h2><table class='summary'><tr>{head}</tr>"
        f"{''.join(rows)}</table><p class='legend'>{html.escape(layout.SUMMARY_NOTE)}</p>"
    )


def unbroken(text: str) -> str:
    """Each number with its interval in `text` kept on one line."""
    return summary.NUMBER.sub(lambda m: f"<span class='n'>{m.group(0)}</span>", text)


def details_link(claim: Claim) -> str:
    return f"<a class='more' href='#{layout.claim_anchor(claim)}'>details</a>"


def verdict_cell(claim: Claim) -> str:
    """The verdict, its reason cut to a clause and the link to the claim's details."""
    verdict = claim.verdict
    reason = layout.reason(claim)
    why = f"<span class='reason'>{html.escape(reason)}</span> " if reason else ""
    return (
        f"<td class='verdict {verdict.kind}'><span class='mark'>{MARKERS[verdict.kind]}</span> "
        f"{html.escape(verdict.label)}<br>{why}{details_link(claim)}</td>"
    )


def published_cell(claim: Claim) -> str:
    """A quick report's cell of the published report's verdict, styled by its kind."""
    kind, text = layout.published_verdict(claim)
    return f"<td class='verdict published {kind}'>{html.escape(text)}</td>"


def claims_html(report: Report) -> str:
    """The claims table (a quick report's with the published report's verdicts) and its
    verdict legend; every cell short, each row linked to its details."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in layout.claims_header(report))
    rows = []
    for c in report.claims:
        beside = published_cell(c) if report.quick else ""
        rows.append(
            f"<tr><td>{html.escape(c.id)}</td><td>{html.escape(c.claim)}</td>"
            f"<td class='measured'>{html.escape(layout.measured_cell(c))}</td>"
            f"{verdict_cell(c)}{beside}</tr>"
        )
    legend = "".join(
        f"<span class='{kind}'>{MARKERS[kind]} {html.escape(text)}</span>"
        for kind, text in layout.VERDICT_LEGEND.items()
    )
    parts = [f"<table class='claims'><tr>{head}</tr>{''.join(rows)}</table>"]
    parts.append(f"<p class='legend'>Verdicts: {legend}</p>")
    return "".join(parts)


def details_html(report: Report, anchor: str) -> str:
    """Every claim row's rule, every number measured and its verdict's reason, in full."""
    items = []
    for c in report.claims:
        items.append(
            f"<li id='{layout.claim_anchor(c)}'><b>{html.escape(c.id)}</b> — "
            f"{html.escape(c.claim)}<dl><dt>Rule</dt><dd>{html.escape(c.rule)}</dd>"
            f"<dt>Measured</dt><dd>{html.escape(c.measured)}</dd><dt>Verdict</dt>"
            f"<dd class='{c.verdict.kind}'>{html.escape(layout.full_reason(c))}</dd></dl></li>"
        )
    return (
        f"<h3 id='{anchor}'>{layout.DETAILS}</h3><p>Each claim row's rule, every number "
        f"measured and its verdict's reason, in full.</p><ul class='details'>{''.join(items)}</ul>"
    )
