"""Figures from runs: mean learning curves with their bands over seeds (95 % BCa bootstrap
at ≥ 5 seeds, the min–max range below; pimbot.statistics).

Every figure says what its bands are on the figure itself (`band_text`, an entry of its
legend) and keeps its legends outside the axes (`legend_below`), so no legend covers a
curve.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

from pimbot import statistics  # noqa: E402
from pimbot.analysis.curves import Curves, read_curves  # noqa: E402
from pimbot.analysis.document import count_text  # noqa: E402
from pimbot.analysis.runs import RunRecord, condition_key, run_label  # noqa: E402
from pimbot.analysis.tables import check_metrics  # noqa: E402
from pimbot.atomic_files import save_figure  # noqa: E402

RANDOM_POLICY = {
    "ER(2,1)": {"eval/success": 0.72, "eval/return_ratio": 0.38},
    "ER(4,2)": {"eval/success": 0.80, "eval/return_ratio": 0.17},
    "ER(4,3)": {"eval/success": 0.22, "eval/return_ratio": -1.38},
    "SH(2)": {"eval/stag_captures": 0.068},
    "SH(3)": {"eval/stag_captures": 0.0028},
    "SH(4)": {"eval/stag_captures": 1.2e-4},
}
"""A uniformly random team, simulated (docs/experiments.md; the Stag Hunt capture rates of
the original rules as measured for issue 14: N hares, the stag moving before the capture
check), by env label."""


BAND_ALPHA = 0.15
"""Opacity of a band; its legend entry is drawn in grey at the same opacity."""


def band(
    ax, curves: Curves, column: str, label=None, color=None, lw=1.2, style="-"
) -> tuple[str, int]:
    """One run's mean curve of `column` over seeds and its band (statistics.band); returns
    what the band is: its kind (statistics.CI or RANGE) and the seeds it is over."""
    iterations, values = curves.matrix(column)
    mean, lo, hi, kind = statistics.band(values)
    (line,) = ax.plot(iterations, mean, style, label=label, color=color, lw=lw)
    ax.fill_between(iterations, lo, hi, color=line.get_color(), alpha=BAND_ALPHA, lw=0)
    return kind, len(curves.seeds)


def band_text(drawn: Iterable[tuple[str, int]], what: str = "band") -> str:
    """What a figure's bands (or error bars: `what`) are, from the (kind, seeds) of every
    one it drew: "band: 95 % BCa bootstrap CI of the mean over N seeds", "band: min–max
    over N seeds", or both ("" where none was drawn)."""
    seeds: dict[str, set[int]] = {}
    for kind, count in drawn:
        seeds.setdefault(kind, set()).add(count)
    parts = []
    if statistics.CI in seeds:
        ci = count_text(seeds[statistics.CI], "seeds")
        parts.append(f"95 % BCa bootstrap CI of the mean over {ci}")
    if statistics.RANGE in seeds:
        parts.append(f"min–max over {count_text(seeds[statistics.RANGE], 'seeds')}")
    return f"{what}: " + "; ".join(parts) if parts else ""


def band_handle(text: str):
    """The legend entry that says what the bands are (a grey band)."""
    return Patch(facecolor="0.35", alpha=2 * BAND_ALPHA, lw=0, label=text)


def _legend_key(handle, label: str) -> tuple:
    if isinstance(handle, Line2D):
        return label, handle.get_color(), handle.get_linestyle(), handle.get_marker()
    return (label,)


def legend_below(fig, axes: Iterable, extra: Iterable = (), title: str | None = None) -> None:
    """One legend for the whole figure, under its panels (never over a curve): every
    labelled artist of `axes` once (the same label, colour and style in several panels is
    one entry), then the `extra` handles (a band's meaning). Nothing without entries."""
    extra = list(extra)
    entries: dict[tuple, tuple[Any, str]] = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            entries.setdefault(_legend_key(handle, label), (handle, label))
    handles = [h for h, _ in entries.values()] + list(extra)
    labels = [label for _, label in entries.values()] + [h.get_label() for h in extra]
    if not handles:
        return
    width = max(len(label) for label in labels)
    # columns that fit the figure's width: 8 pt text, a generous 7 pt per character of the
    # longest label and 40 pt for its handle and spacing (a wider legend would be cut off)
    fits = max(1, int(fig.get_figwidth() * 72 / (7 * width + 40)))
    fig.legend(
        handles,
        labels,
        loc="lower center",
        bbox_to_anchor=(0.5, 0.0),
        ncol=min(len(handles), fits),
        fontsize=8,
        title=title,
        title_fontsize=8,
        frameon=False,
    )


def runs_of(runs: list[RunRecord], env: str) -> list[RunRecord]:
    """The runs of one env label, conditions in order."""
    return sorted((r for r in runs if r.env == env), key=lambda r: condition_key(r.condition))


def condition_panels(runs: list[RunRecord], envs: list[str], colors: dict) -> list:
    """`curve_panels` input: one panel per env, one line per run labelled by its condition."""
    return [
        (env, [(r, r.condition, colors[r.condition]) for r in runs_of(runs, env)]) for env in envs
    ]


def curve_panels(
    panels: list[tuple[str, list[tuple[Any, str, Any]]]],
    column: str,
    ylabel: str,
    path: Path,
    cols: int | None = None,
    ylim: tuple[float, float] | None = None,
    title: str = "",
) -> str:
    """One panel per (title, lines); a line is (run record, label, colour[, line style]),
    drawn with its band. A panel whose title has a random-team value for `column` gets a
    reference line. One legend under the panels names the lines and what the bands are.

    Lines of runs that did not log `column` are left out, a panel left with none is
    dropped, and with no panel at all nothing is written. Returns the bands' meaning
    (`band_text`), "" where nothing was written."""
    panels = [
        (name, kept)
        for name, lines in panels
        if (kept := [line for line in lines if line[0].curves.has(column)])
    ]
    if not panels:
        return ""
    cols = min(cols or len(panels), len(panels))
    rows = (len(panels) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 3.8 * rows), squeeze=False)
    drawn, extra = [], []
    random_team = Line2D([], [], color="grey", ls=":", lw=1, label="random team")
    for ax, (name, lines) in zip(axes.flat, panels, strict=False):
        for run, label, color, *style in lines:
            drawn.append(band(ax, run.curves, column, label, color, style=(style or ["-"])[0]))
        reference = RANDOM_POLICY.get(name, {}).get(column)
        if reference is not None:
            ax.axhline(reference, color="grey", ls=":", lw=1)
            extra = [random_team]  # named once, after the runs
        ax.set_title(name)
        ax.set_xlabel("iteration")
        ax.set_ylabel(ylabel)
        if ylim:
            ax.set_ylim(*ylim)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(panels) :]:
        ax.remove()
    if title:
        fig.suptitle(title)
    bands = band_text(drawn)
    legend_below(fig, axes.flat[: len(panels)], [*extra, band_handle(bands)])
    save(fig, path)
    return bands


def mark_zero_bars(ax, xs, heights, color) -> None:
    """Writes "0" on bars of height 0: a measured zero, not a missing bar."""
    for x, h in zip(xs, heights, strict=True):
        if abs(h) < 0.005:
            ax.annotate(
                "0", (x, 0), xytext=(0, 2), textcoords="offset points", ha="center", fontsize=7,
                color=color,
            )  # fmt: skip


def save(fig, path: Path, dpi: int = 110, svg: bool = True) -> None:
    """Writes the figure as `path` (PNG) and, with `svg`, as the SVG beside it (same name,
    .svg: the report's vector copy of every figure), each staged (`atomic_files.save_figure`:
    a full disk leaves the old figure, never a cut one). A figure-wide legend
    (`legend_below`) gets a strip of its own under the panels: the figure grows by its
    height."""
    below = 0.0
    if fig.legends:
        renderer = fig.canvas.get_renderer()
        below = max(legend.get_window_extent(renderer).height for legend in fig.legends)
        below = below / fig.dpi + 0.05  # inches
        fig.set_figheight(fig.get_figheight() + below)
    fig.tight_layout(rect=(0, below / fig.get_figheight(), 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        save_figure(fig, path, dpi=dpi)
        if svg:
            save_figure(fig, path.with_suffix(".svg"), metadata={"Date": None})
    finally:
        plt.close(fig)


# --- `pimbot plot` ---------------------------------------------------------------------


PLOTTED = ("eval/success", "eval/return_ratio")
"""The columns `pimbot plot` draws unless `--metric` names others."""


def plot_runs(run_dirs: list[Path], out: Path, metrics: tuple[str, ...] = ()) -> None:
    """`pimbot plot`: one panel per metric column (`metrics`, any column of metrics.csv;
    none named: `PLOTTED`), one line per run (its mean over seeds and its band, in one
    colour in every panel; a run that did not log a column is left out of its panel). The
    legend under the panels names the runs and what the bands are.

    Raises:
        InvalidParameter: a name in `metrics` no run logged (nothing is written).
    """
    runs = [(read_curves(run_dir), run_label(run_dir)) for run_dir in run_dirs]
    check_metrics(metrics, [curves for curves, _ in runs])
    columns = metrics or PLOTTED
    fig, axes = plt.subplots(1, len(columns), figsize=(6 * len(columns), 4), squeeze=False)
    drawn = []
    for ax, column in zip(axes[0], columns, strict=True):
        for k, (curves, label) in enumerate(runs):
            if curves.has(column):
                drawn.append(band(ax, curves, column, label, f"C{k % 10}"))
        ax.set_xlabel("iteration")
        ax.set_ylabel(column)
        ax.grid(alpha=0.3)
    bands = band_text(drawn)
    legend_below(fig, axes[0], [band_handle(bands)] if bands else [])
    save(fig, out, dpi=120, svg=False)
