"""The paper-grade report: provenance, contents, SVG figures, counts read from the runs, one
colour per condition, verdict styles and no empty panels.

The suite is synthetic and written by hand (config.json, metrics.csv and summary.json of
2-seed runs; nothing is trained), so the whole file runs in seconds.
"""

from __future__ import annotations

import csv
import json
import re
import types
from pathlib import Path

import numpy as np
import pytest

from pimbot.analysis import (
    document,
    html_report,
    layout,
    markdown_report,
    plots,
    report,
    runs,
    verdicts,
)
from pimbot.analysis.claims import Claim
from pimbot.analysis.curves import read_curves
from pimbot.analysis.document import Report, Section
from pimbot.analysis.tables import Table
from pimbot.suites import sweep

SEEDS = 2
ITERATIONS = 300
COMMIT = "0123456789abcdef0123456789abcdef01234567"
SRC = Path(__file__).resolve().parents[1] / "src" / "pimbot" / "analysis"


def write_run(root: Path, name: str, attack: str | None, params=None, steps: bool = True) -> Path:
    """A finished ER(2,1) LIO run of SEEDS seeds, as the runner would have left it."""
    path = root / name
    path.mkdir(parents=True)
    env_params = {"max_steps": 5, "min_at_lever": 1, "n_agents": 2, "randomize_start": False}
    params = {"adversary": 0, **(params or {})} if attack else {}
    config = {
        "identity": {
            "attack": attack,
            "attack_params": params,
            "env_id": "escape_room-v0",
            "env_params": env_params,
            "eval_episodes": 10,
            "eval_period": 20,
            "first_seed": 0,
            "iterations": ITERATIONS,
            "learner": "lio",
            "learner_config": {"incentive_updates": "shared"},
            "seeds": SEEDS,
        },
        "run_config": {"attack_params": [], "hparams": [], "defenses": []},
        "env": {"id": "escape_room-v0", "num_agents": 2, "params": env_params},
        "pimbot_version": "0.1.0",
        "git_commit": COMMIT,
        "jax_version": "0.0.test",
        "jax_backend": "cpu",
        "devices": ["cpu:0"],
    }
    (path / "config.json").write_text(json.dumps(config))
    (path / "summary.json").write_text(json.dumps({"finished": True}))
    rng = np.random.default_rng(len(name))
    header = ["iteration", "seed", "eval/success", "eval/return_ratio"]
    header += ["eval/return_env/agent_0", "eval/return_env/agent_1"]
    header += ["eval/adversary_margin_env", "perf/iters_per_s"] + (["eval/steps"] if steps else [])
    with open(path / "metrics.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        for seed in range(SEEDS):
            for it in range(20, ITERATIONS + 1, 20):
                a, b = rng.normal(0, 1, 2)
                row = [it, seed, rng.uniform(), rng.uniform(-1, 1), a, b, a - b, 1000.0]
                writer.writerow(row + ([rng.uniform(1, 5)] if steps else []))
    return path


@pytest.fixture(scope="module")
def suite(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("polish")
    write_run(root, "attacks/er21_clean", None)
    write_run(root, "attacks/er21_bypass", "bypass", {"adversary": 1})
    write_run(root, "attacks/er21_reverse", "reverse")
    write_run(root, "mygrid/er21_reverse", "reverse")
    jobs = [
        {"name": n, "group": n.split("/")[0], "kind": "train", "status": "finished",
         "claims": ["C3"] if n.startswith("attacks") else []}
        for n in ("attacks/er21_clean", "attacks/er21_bypass", "attacks/er21_reverse",
                  "mygrid/er21_reverse")
    ]  # fmt: skip
    sweep.write_index(root, {"suite": "full", "jobs": jobs})
    return root


@pytest.fixture(scope="module")
def built(suite, tmp_path_factory) -> Path:
    return report.write_report(suite, tmp_path_factory.mktemp("report"))


def test_provenance_and_contents(built):
    markdown = (built / report.MARKDOWN).read_text()
    page = (built / report.HTML).read_text()
    assert "## Provenance" in markdown and "**Contents**" in markdown
    # The verdicts first: the summary, the contents, the claims (and their details), then
    # the provenance.
    order = ["## Summary", "**Contents**", "## Claims", "### Claim details", "## Provenance"]
    assert [markdown.index(h) for h in order] == sorted(markdown.index(h) for h in order)
    assert page.index("<h2 id='summary'>") < page.index("<nav class='toc'>")
    assert page.index("<nav class='toc'>") < page.index("<h2 id='claims'>")
    assert page.index("<h2 id='claims'>") < page.index("<h2 id='provenance'>")
    for value in (COMMIT, "0.0.test", "| JAX backend | cpu | 4/4 |", "cpu:0", "report generated"):
        assert value in markdown, value
    # The budget of each group, read from the runs.
    assert "| attacks | 3 | 2 seeds | 300 iterations | every 20 iterations | lio |" in markdown
    assert "| mygrid | 1 | 2 seeds | 300 iterations |" in markdown
    # Every entry of the contents points at an anchor that exists, in both files.
    md_links = re.findall(r"\]\(#([a-z0-9-]+)\)", markdown)
    md_ids = set(re.findall(r'<a id="([a-z0-9-]+)"></a>', markdown))
    assert "provenance" in md_links and set(md_links) <= md_ids
    assert "<nav class='toc'>" in page
    html_links = re.findall(r"href='#([a-z0-9-]+)'", page)
    html_ids = set(re.findall(r"id='([a-z0-9-]+)'", page))
    assert "attacks-on-lio-c1-c5" in html_links and set(html_links) <= html_ids
    assert (built / report.TABLES / "provenance.csv").exists()


def test_every_figure_has_an_svg_beside_it(built):
    markdown = (built / report.MARKDOWN).read_text()
    figures = sorted((built / report.FIGURES).glob("*.png"))
    assert len(figures) >= 3  # fig1, fig2, fig3 and the group's success curves
    for png in figures:
        svg = png.with_suffix(".svg")
        assert svg.exists() and svg.read_text().lstrip().startswith("<?xml"), svg.name
        assert f"{report.FIGURES}/{png.name}" in markdown
        assert f"{report.FIGURES}/{svg.name}" in markdown
    assert not list((built / report.FIGURES).glob("fig8*"))  # no profile: not written


def test_seed_counts_come_from_the_runs(built):
    markdown = (built / report.MARKDOWN).read_text()
    assert "over 2 seeds" in markdown
    # Below 5 seeds an interval is the seeds' range, never called a CI.
    assert "(range …) = the range (min … max) over seeds, no CI: fewer than 5 seeds" in markdown
    assert "95 % CI" not in markdown and "[95 %" not in markdown
    assert "last 10 evaluation points" in markdown  # summarize's window, read back
    assert not re.search(r"\b(10|3) seeds\b", markdown)
    # No section spells out a seed count: every one is formatted from the runs.
    for path in SRC.rglob("*.py"):
        text = path.read_text()
        assert not re.search(r"(over|of|median of|medians of) \d+ seeds", text), path.name


def test_one_colour_per_condition_in_every_figure(suite, built):
    colours = runs.condition_colors(["reverse", "bypass", "zeta"])
    assert list(colours) == ["clean", "bypass", "reverse", "zeta"]  # clean first
    # A paper condition keeps its colour whatever else the report holds.
    assert runs.condition_colors(["bypass"])["bypass"] == colours["bypass"]
    assert len(set(colours.values())) == len(colours)
    table = runs.load_table(suite)
    assert table.colors == runs.condition_colors(r.condition for r in table.records)
    # The same hex colour draws "reverse" in the attack figures and in the generic one
    # (whose group has no clean run), and "clean" in both attack figures.
    for name in ("fig1_success.svg", "fig3_steps.svg", "mygrid_success.svg"):
        svg = (built / report.FIGURES / name).read_text().lower()
        assert colours["reverse"] in svg, name
        assert (colours["clean"] in svg) == name.startswith("fig"), name


def test_verdict_kinds_are_styled_and_marked(built):
    claims = [
        Claim("C1", "a", "r", "m", verdicts.at_quick_budget(verdicts.reproduced())),
        Claim(
            "C2", "b", "r", "long measured text", verdicts.refuted(verdicts.BUDGET, "x"), "short"
        ),
        Claim("C3", "c", "r", "m", verdicts.inconclusive("3 seeds")),
        Claim("C4", "d", "r", "m", verdicts.not_run("0/1 runs finished")),
        Claim("C5", "e", "r", "m", verdicts.refuted(verdicts.SPEC, "0.2 < 0.8")),
        Claim("C6", "f", "r", "m", verdicts.at_budget("0.01 at 25k, 0.4 at 50k")),
        Claim(
            "C7", "g", "r", "m", verdicts.inconclusive("; ".join(f"part {k}" for k in range(99)))
        ),
    ]
    assert [c.verdict.kind for c in claims] == [
        "reproduced",
        "refuted",
        "inconclusive",
        "not-run",
        "refuted",
        "reproduced-at-budget",
        "inconclusive",
    ]
    provenance = Section("Provenance", tables=[])
    provenance.tables = [Table(["a"], [], "x"), Table(["a"], [], "y")]
    rendered = Report({"jobs": [{"claims": ["C1"], "status": "finished"}]},
                      provenance, claims, [])  # fmt: skip
    page = html_report.render(rendered, built)
    for kind in verdicts.KINDS:
        assert f"class='verdict {kind}'" in page
        assert f".{kind} {{" in page  # its own style
    markdown = markdown_report.render(rendered)
    assert "**✔ reproduced (quick budget)**" in markdown
    assert "**✘ refuted — cause: our budget or setting** — x ([details](#claim-c2))" in markdown
    assert "◐ inconclusive** — 3 seeds" in markdown
    assert "○ not run" in markdown
    assert "**✘ refuted — cause: our spec** — 0.2 < 0.8" in markdown
    assert "**✔ reproduced at the paper's budget** — 0.01 at 25k" in markdown
    assert "<span class='reason'>0.2 &lt; 0.8</span>" in page
    # A long reason is cut in the table to a clause that links the claim's details, where
    # it stands in full.
    table = markdown.split("### Claim details")[0].split("## Claims")[1]
    c7 = next(line for line in table.splitlines() if line.startswith("| C7 |"))
    assert "part 22…" in c7 and "part 98" not in table and c7.endswith("([details](#claim-c7)) |")
    assert len(c7.split("**")[2]) < layout.REASON_CHARS + 40
    assert "  - Verdict: ◐ inconclusive: part 0;" in markdown and "part 98" in markdown
    assert "href='#claim-c7'>details</a>" in page and "<li id='claim-c7'>" in page
    # A compact measured cell; the full text in the details, with the claim's rule.
    assert "| short | **✘ refuted" in markdown
    assert '- <a id="claim-c2"></a>**C2** — b' in markdown
    assert "  - Measured: long measured text" in markdown and "  - Rule: r" in markdown
    # The summary: one line per claim row, its verdict, number and why.
    summary = markdown.split("## Summary")[1].split("**Contents**")[0]
    assert "| [C5](#claim-c5) | **✘ refuted — cause: our spec** | m | 0.2 < 0.8 |" in summary
    assert "| [C4](#claim-c4) | **○ not run** | – | 0/1 runs finished |" in summary
    # The real report's claims table has the classes too.
    assert "class='verdict not-run'" in (built / report.HTML).read_text()


def test_a_panel_without_data_is_dropped_and_an_empty_figure_not_written(suite, tmp_path):
    with_steps = types.SimpleNamespace(curves=read_curves(suite / "attacks/er21_clean"))
    no_steps = write_run(tmp_path, "g/no_steps", None, steps=False)
    without = types.SimpleNamespace(curves=read_curves(no_steps))
    path = tmp_path / "steps.png"
    assert not plots.curve_panels([("A", [(without, "clean", "#000000")])], "eval/steps", "", path)
    assert not path.exists() and not path.with_suffix(".svg").exists()
    panels = [("A", [(with_steps, "clean", "#000000")]), ("B", [(without, "clean", "#000000")])]
    assert plots.curve_panels(panels, "eval/steps", "steps", path)
    svg = path.with_suffix(".svg").read_text()
    assert svg.count('id="axes_') == 1  # panel B had no data: dropped


def test_counts_and_iterations_text():
    assert document.count_text([3, 3], "seeds") == "3 seeds"
    assert document.count_text([2, 3], "seeds") == "2–3 seeds"
    assert document.count_text([1], "episodes") == "1 episode"
    assert document.iterations_text(4000) == "4k iterations"
    assert document.iterations_text(400) == "400 iterations"  # never "0k"
    assert document.iterations_text([5000, 10000]) == "5k–10k iterations"


def test_every_run_is_read_once_into_the_run_table(suite, tmp_path, monkeypatch):
    """metrics.csv is read once, by the run table (which also recomputes the summary from
    those rows), never again by a section or a figure."""
    from collections import Counter

    from pimbot.training import store

    reads: Counter = Counter()
    read = store.read_metrics

    def counted(run_dir):
        reads[Path(run_dir).resolve()] += 1
        return read(run_dir)

    monkeypatch.setattr(store, "read_metrics", counted)
    report.write_report(suite, tmp_path / "report")
    mine = {path: n for path, n in reads.items() if suite.resolve() in path.parents}
    assert len(mine) == 4 and set(mine.values()) == {1}, mine
    assert max(reads.values()) == 1  # the original code's packaged logs too


def test_legends_sit_outside_the_axes_and_say_what_the_bands_are(suite, tmp_path, monkeypatch):
    figures = {}
    save = plots.save

    def kept(fig, path, *args, **kwargs):
        save(fig, path, *args, **kwargs)
        figures[path.name] = fig

    monkeypatch.setattr(plots, "save", kept)
    monkeypatch.setattr(plots.plt, "close", lambda fig: None)  # kept to be measured below
    out = report.write_report(suite, tmp_path / "report")
    runs_of_suite = [suite / "attacks/er21_clean", suite / "attacks/er21_reverse"]
    plots.plot_runs(runs_of_suite, tmp_path / "plot.png")  # `pimbot plot`
    curves = {"fig1_success.png", "fig2_agent_returns.png", "fig3_steps.png"}
    curves |= {"mygrid_success.png", "plot.png"}
    assert curves <= set(figures), sorted(figures)
    for name, fig in figures.items():
        renderer = fig.canvas.get_renderer()
        assert all(ax.get_legend() is None for ax in fig.axes), name
        (legend,) = fig.legends
        box = legend.get_window_extent(renderer)
        assert not any(box.overlaps(ax.get_window_extent(renderer)) for ax in fig.axes), name
        labels = [text.get_text() for text in legend.get_texts()]
        assert (name not in curves) or "band: min–max over 2 seeds" in labels, (name, labels)
    monkeypatch.undo()
    for fig in figures.values():
        plots.plt.close(fig)
    markdown = (out / report.MARKDOWN).read_text()
    for caption in ("Fig. 1:", "Fig. 2:", "Fig. 3:", "mygrid: success per condition"):
        line = next(line for line in markdown.splitlines() if line.startswith(f"*{caption}"))
        assert "band: min–max over 2 seeds" in line, line


def test_band_text_names_the_interval_and_the_seeds():
    assert plots.band_text([("range", 3), ("range", 3)]) == "band: min–max over 3 seeds"
    assert plots.band_text([("ci", 5), ("ci", 7)]) == (
        "band: 95 % BCa bootstrap CI of the mean over 5–7 seeds"
    )
    assert plots.band_text([("range", 2), ("ci", 5)], "error bar") == (
        "error bar: 95 % BCa bootstrap CI of the mean over 5 seeds; min–max over 2 seeds"
    )
    assert plots.band_text([]) == ""
