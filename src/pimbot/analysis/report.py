"""`pimbot report`: report.md, a self-contained report.html and tables/*.csv from a suite.

Reads only what `pimbot reproduce` or `pimbot sweep` wrote (index.json and the
run directories); nothing is re-run. The suite's runs are loaded once into a
`RunTable` (analysis.runs); each section provider turns part of it into text,
tables, figures and the claims it can judge, and the generic provider reports
every run no paper section read. The claims table (analysis.claims) marks a claim
whose runs are not all finished "not run" whatever its partial numbers say.

A report of the paper's suite opens with its verdicts: a summary of one line per
claim row (analysis.summary), the table of contents, the claims table and every
claim's details; then its provenance (versions, commit, backend and devices from
the runs' config.json files, the budget of every group read from the runs, the
generation date) and the sections. A sweep's report opens with the contents and
the provenance. Every figure is a PNG with an SVG
beside it; a figure without data is not written. The renderers are
analysis.markdown_report and analysis.html_report (which embeds every PNG as a
data URI, so the one file can be mailed or archived).
"""

from __future__ import annotations

import dataclasses
import datetime
import os
import re
from collections import Counter
from pathlib import Path

import pimbot
from pimbot.analysis import claims, html_report, markdown_report
from pimbot.analysis import runs as run_table
from pimbot.analysis.document import FIGURES as FIGURES
from pimbot.analysis.document import (
    TABLES,
    Context,
    Provider,
    Report,
    Section,
    count_text,
    iterations_text,
    seeds_text,
)
from pimbot.analysis.sections import (
    attacks,
    defenses,
    device,
    generic,
    reciprocators,
    scorecard,
    stag_hunt,
)
from pimbot.analysis.tables import Table, write_csv
from pimbot.suites import sweep
from pimbot.training import provenance as code_provenance
from pimbot.training import store

MARKDOWN = "report.md"
HTML = "report.html"

PROVIDERS: list[Provider] = [
    attacks.section,
    stag_hunt.section,
    reciprocators.section,
    defenses.section,
    scorecard.section,
    generic.section,
    device.profile_section,
    device.robot_section,
]
"""Report sections in order; each returns None when its runs are absent. The generic one
reports the training runs the paper sections before it did not claim (the scorecard, which
compares every training run, claims none)."""


PROVENANCE_FIELDS = (
    ("pimbot version", "pimbot_version"),
    ("git commit", "git_commit"),
    ("JAX version", "jax_version"),
    ("JAX backend", "jax_backend"),
    ("devices", "devices"),
    ("plugins", "plugins"),
)
"""(row label, config.json key) of the provenance table: what every run records."""


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
    if key == "plugins" and isinstance(value, list):  # config.json's plugin records
        return ", ".join(_plugin_text(p) for p in value) or "none"
    return ", ".join(map(str, value)) if isinstance(value, list | tuple) else str(value)


def _plugin_text(record: object) -> str:
    """A plugin as the provenance table names it: its file (or name) and sha256's start."""
    if not isinstance(record, dict):
        return str(record)
    name, digest = record.get("file") or record.get("plugin"), record.get("sha256")
    return f"{name} (sha256 {digest[:12]})" if digest else str(name)


def _suites_text(index: dict) -> str:
    """The suites that wrote into the directory: "suite 'a'", or "suites 'a', 'b'"."""
    names = sweep.suite_names(index)
    if len(names) <= 1:
        return f"suite {index.get('suite')!r}"
    return "suites " + ", ".join(repr(n) for n in names)


def provenance(table: run_table.RunTable, ctx: Context, when: str) -> Section:
    """Versions, commit, backend and devices of the runs, and every group's budget, all read
    from the run directories."""
    jobs = ctx.index.get("jobs", [])
    text = [
        f"Read from the config.json of the {len(table.records)} finished training run(s) and "
        f"from {sweep.INDEX} ({len(jobs)} jobs, {_suites_text(ctx.index)}); generated "
        f"{when}."
    ]
    budget = Table(
        ["group", "jobs", "seeds", "iterations", "evaluation", "learners / controllers"],
        budget_rows(table),
        "Budget per group",
        "Seeds and iterations as the finished runs recorded them (summary.json and "
        "config.json), not as a preset says.",
        "provenance_budget",
    )
    changed = [r.name for r in table.records if code_provenance.differences(r.config)]
    if changed:
        text.append(
            f"{len(changed)} run(s) were made by other code than this report's pimbot or "
            "plugins (another version, or a plugin file that changed; their config.json says "
            "how, docs/usage.md#provenance-the-code-a-run-was-made-with): "
            + ", ".join(changed[:5])
            + (f" and {len(changed) - 5} more" if len(changed) > 5 else "")
            + "."
        )
    return Section("Provenance", text=text, tables=[environment(table.records, when), budget])


def environment(records: tuple[run_table.RunRecord, ...], when: str) -> Table:
    """One row per distinct value of each `PROVENANCE_FIELDS` field, with the runs that
    recorded it; the report's own date and version."""
    rows: list[list] = []
    for label, key in PROVENANCE_FIELDS:
        values = Counter(_provenance_value(r.config, key) for r in records)
        for value, count in sorted(values.items(), key=lambda kv: (-kv[1], kv[0])):
            rows.append([label, value, f"{count}/{len(records)}"])
    rows.append(["report generated", when, "–"])
    rows.append(["report written by", f"pimbot {pimbot.__version__}", "–"])
    return Table(["field", "value", "runs"], rows, "Software and devices", "", "provenance")


def budget_rows(table: run_table.RunTable) -> list[list]:
    """Jobs, seeds, iterations and evaluation of every training group, the robot
    evaluations and the profile, as their files recorded them."""
    rows = []
    for group in table.groups:
        mine = table.group(group)
        periods = count_text((int(r.identity.get("eval_period", 0)) for r in mine), "iterations")
        rows.append(
            [
                group,
                len(mine),
                seeds_text(mine),
                iterations_text(r.iterations for r in mine),
                f"every {periods}",
                ", ".join(sorted({r.learner for r in mine})),
            ]
        )
    if table.robot:
        episodes = count_text((s["episodes_per_seed"] for s in table.robot), "episodes")
        seeds = count_text((len(s["seeds"]) for s in table.robot), "seeds")
        physics = f"{episodes} per seed, physics and abstract"
        rows.append(["robot", len(table.robot), seeds, "–", physics, "trained runs"])
    if table.profile is not None:
        present = [c for c in device.CONTROLLERS if c in table.profile]
        seconds = sorted({float(table.profile[c]["config"]["duration_s"]) for c in present})
        steady = " / ".join(f"{s:g} s" for s in seconds) + " steady state per controller"
        rows.append(["profile", len(present), "–", "–", steady, ", ".join(present)])
    return rows


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
    measured = [claim for section in sections for claim in section.claims]
    return Report(index, front, claims.suite_claims(measured, index), sections)


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
    store.check_inside(out, (FIGURES, TABLES, MARKDOWN, HTML))
    clear_figures(out)
    report = build(suite_dir, out)
    (out / TABLES).mkdir(exist_ok=True)
    if report.claims:
        write_csv(claims.csv_table(report.claims, report.quick), out / TABLES / "claims.csv")
        for table in (report.parts, report.numbers):
            if table is not None:
                write_csv(table, out / TABLES / f"{table.name}.csv")
    everything = [report.provenance, *report.sections]
    names = csv_names(everything)
    for section in everything:
        for table in section.tables:
            write_csv(table, out / TABLES / f"{names[id(table)]}.csv")
    store.write_atomic(out / MARKDOWN, markdown_report.render(report).encode())
    store.write_atomic(out / HTML, html_report.render(report, out).encode())
    return out
