"""Figures from run directories: mean learning curves with 95 % bootstrap bands."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from pimbot.analysis.curves import load_curve, mean_and_band  # noqa: E402
from pimbot.experiment import store  # noqa: E402

# Uniformly random team, 200k simulated episodes (spec/experiments.md).
RANDOM_POLICY = {
    (2, 1): {"eval/success": 0.72, "eval/return_ratio": 0.38},
    (4, 2): {"eval/success": 0.80, "eval/return_ratio": 0.17},
    (4, 3): {"eval/success": 0.22, "eval/return_ratio": -1.38},
}


def run_label(run_dir: Path) -> str:
    config = store.read_json(run_dir / store.CONFIG)
    params = config["env"]["params"]
    env = config["env"]["id"].removesuffix("-v0")
    if "n_agents" in params:
        env = f"ER({params['n_agents']},{params['min_at_lever']})"
    elif "n_players" in params:
        env = f"{env}(N={params['n_players']})"
    label = f"{config['identity']['learner']} {env}"
    first, count = config["identity"]["first_seed"], config["identity"]["seeds"]
    if first:
        label += f" seeds {first}–{first + count - 1}"
    if config["identity"]["learner_config"].get("original_shared_incentive_updates"):
        label += " shared-η"
    return label


def plot_runs(run_dirs: list[Path], out: Path, columns=("eval/success", "eval/return_ratio")):
    """One panel per metric column, one line (mean ± 95 % band over seeds) per run."""
    fig, axes = plt.subplots(1, len(columns), figsize=(6 * len(columns), 4), squeeze=False)
    for ax, column in zip(axes[0], columns, strict=True):
        for run_dir in run_dirs:
            try:
                iterations, values = load_curve(run_dir, column)
            except ValueError:
                continue
            mean, lo, hi = mean_and_band(values)
            (line,) = ax.plot(iterations, mean, label=run_label(run_dir), lw=1.2)
            ax.fill_between(iterations, lo, hi, color=line.get_color(), alpha=0.2, lw=0)
        ax.set_xlabel("iteration")
        ax.set_ylabel(column)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
