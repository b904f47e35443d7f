"""Figures from run directories: mean learning curves with their bands over seeds (95 % BCa
bootstrap at ≥ 5 seeds, the min–max range below; pimbot.statistics)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from pimbot.analysis.curves import columns, load_curve, mean_and_band  # noqa: E402
from pimbot.analysis.runs import RunRecord, condition_key, env_label  # noqa: E402
from pimbot.training import store  # noqa: E402

RANDOM_POLICY = {
    "ER(2,1)": {"eval/success": 0.72, "eval/return_ratio": 0.38},
    "ER(4,2)": {"eval/success": 0.80, "eval/return_ratio": 0.17},
    "ER(4,3)": {"eval/success": 0.22, "eval/return_ratio": -1.38},
    "SH(2)": {"eval/stag_captures": 0.068},
    "SH(3)": {"eval/stag_captures": 0.0028},
    "SH(4)": {"eval/stag_captures": 1.2e-4},
}
"""A uniformly random team, simulated (spec/experiments.md; the Stag Hunt capture rates of
the original rules as measured for issue 14: N hares, the stag moving before the capture
check), by env label."""


def band(ax, run_dir: Path, column: str, label=None, color=None, lw=1.2, style="-") -> None:
    """One run's mean curve of `column` over seeds and its band (`mean_and_band`)."""
    iterations, values = load_curve(run_dir, column)
    mean, lo, hi = mean_and_band(values)
    (line,) = ax.plot(iterations, mean, style, label=label, color=color, lw=lw)
    ax.fill_between(iterations, lo, hi, color=line.get_color(), alpha=0.15, lw=0)


def has_curve(run_dir: Path, column: str) -> bool:
    """Whether the run logged `column` (a panel of it would not be empty)."""
    return column in columns(run_dir)


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
) -> bool:
    """One panel per (title, lines); a line is (run record, label, colour), drawn with its
    band. A panel whose title has a random-team value for `column` gets a reference line.

    Lines of runs that did not log `column` are left out, a panel left with none is
    dropped, and with no panel at all nothing is written: returns whether it was."""
    panels = [
        (name, kept)
        for name, lines in panels
        if (kept := [line for line in lines if has_curve(line[0].path, column)])
    ]
    if not panels:
        return False
    cols = min(cols or len(panels), len(panels))
    rows = (len(panels) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 3.8 * rows), squeeze=False)
    for ax, (name, lines) in zip(axes.flat, panels, strict=False):
        for run, label, color, *style in lines:
            band(ax, run.path, column, label, color, style=style[0] if style else "-")
        reference = RANDOM_POLICY.get(name, {}).get(column)
        if reference is not None:
            ax.axhline(reference, color="grey", ls=":", lw=1, label="random team")
        ax.set_title(name)
        ax.set_xlabel("iteration")
        ax.set_ylabel(ylabel)
        if ylim:
            ax.set_ylim(*ylim)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    for ax in list(axes.flat)[len(panels) :]:
        ax.remove()
    if title:
        fig.suptitle(title)
    save(fig, path)
    return True


def mark_zero_bars(ax, xs, heights, color) -> None:
    """Writes "0" on bars of height 0: a measured zero, not a missing bar."""
    for x, h in zip(xs, heights, strict=True):
        if abs(h) < 0.005:
            ax.annotate(
                "0", (x, 0), xytext=(0, 2), textcoords="offset points", ha="center", fontsize=7,
                color=color,
            )  # fmt: skip


def save(fig, path: Path, dpi: int = 110, svg: bool = True, top: float = 0.0) -> None:
    """Writes the figure as `path` (PNG) and, with `svg`, as the SVG beside it (same name,
    .svg: the report's vector copy of every figure). `top`: inches kept free above the
    axes (a figure-wide legend)."""
    fig.tight_layout(rect=(0, 0, 1, 1 - top / fig.get_figheight()))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    if svg:
        fig.savefig(path.with_suffix(".svg"), metadata={"Date": None})
    plt.close(fig)


# --- `pimbot plot` ---------------------------------------------------------------------


def run_label(run_dir: Path) -> str:
    config = store.read_json(run_dir / store.CONFIG)
    env = env_label(config["env"]["id"], config["env"]["params"])
    label = f"{config['identity']['learner']} {env}"
    first, count = config["identity"]["first_seed"], config["identity"]["seeds"]
    if first:
        label += f" seeds {first}–{first + count - 1}"
    if incentive_updates(config) == "own":
        label += " own-η"
    return label


def incentive_updates(config: dict[str, Any]) -> str | None:
    """ "shared" or "own": how a LIO run's givers updated incentives where the two differ
    (N ≥ 3); None otherwise. Run directories written before the option had a name carry
    `original_shared_incentive_updates` (true = shared, false = own)."""
    learner_config = config["identity"].get("learner_config", {})
    if config.get("env", {}).get("num_agents", 0) < 3:
        return None
    if "incentive_updates" in learner_config:
        return learner_config["incentive_updates"]
    if "original_shared_incentive_updates" in learner_config:
        return "shared" if learner_config["original_shared_incentive_updates"] else "own"
    return None


def plot_runs(run_dirs: list[Path], out: Path, columns=("eval/success", "eval/return_ratio")):
    """One panel per metric column, one line (mean ± 95 % band over seeds) per run."""
    fig, axes = plt.subplots(1, len(columns), figsize=(6 * len(columns), 4), squeeze=False)
    for ax, column in zip(axes[0], columns, strict=True):
        for run_dir in run_dirs:
            try:
                band(ax, run_dir, column, run_label(run_dir))
            except ValueError:
                continue
        ax.set_xlabel("iteration")
        ax.set_ylabel(column)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    save(fig, out, dpi=120, svg=False)
