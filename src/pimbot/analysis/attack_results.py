"""Attack experiments: results table, claims C1–C5 and figures 1–5, from run directories.

    python -m pimbot.analysis.attack_results RUNS_DIR OUT_DIR

RUNS_DIR holds one run directory per (environment, condition); everything is
read from config.json, metrics.csv and summary.json (nothing is re-run).
Writes OUT_DIR/attacks.csv, OUT_DIR/attacks.md and OUT_DIR/fig{1..5}_*.png.
"""

from __future__ import annotations

import csv
import sys
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from pimbot.analysis.curves import load_curve, mean_and_band  # noqa: E402
from pimbot.analysis.metrics import bootstrap_ci  # noqa: E402
from pimbot.experiment import store  # noqa: E402
from pimbot.experiment.runner import summarize  # noqa: E402

CONDITIONS = [
    "clean",
    "self_centered",
    "fake_incentive",
    "bypass",
    "reverse",
    "admo_stealthy",
    "admo_disrupt",
]
COLORS = dict(zip(CONDITIONS, plt.get_cmap("tab10").colors, strict=False))
ER_ENVS = ["ER(2,1)", "ER(4,2)", "ER(4,3)"]
# Uniformly random team (spec/experiments.md), drawn as reference lines.
RANDOM_SUCCESS = {"ER(2,1)": 0.72, "ER(4,2)": 0.80, "ER(4,3)": 0.22}


@dataclass(frozen=True)
class Run:
    path: Path
    env: str
    condition: str
    adversary: int
    num_agents: int
    summary: dict
    config: dict


def load_runs(runs_dir: Path) -> list[Run]:
    runs = []
    for path in sorted(p for p in runs_dir.iterdir() if (p / store.SUMMARY).exists()):
        config = store.read_json(path / store.CONFIG)
        identity = config["identity"]
        params = identity["env_params"]
        if "n_agents" in params:
            env = f"ER({params['n_agents']},{params['min_at_lever']})"
        else:
            env = f"{config['env']['id'].removesuffix('-v0').upper()}(N={params['n_players']})"
        condition = identity["attack"] or "clean"
        if condition == "admo":
            condition = f"admo_{identity['attack_params']['mode']}"
        adversary = identity["attack_params"].get("adversary", 0) if identity["attack"] else 0
        # Final metrics and convergence recomputed from metrics.csv (the primary record).
        summary = {**store.read_json(path / store.SUMMARY), **summarize(path)}
        runs.append(
            Run(path, env, condition, adversary, config["env"]["num_agents"], summary, config)
        )
    return runs


def per_seed(run: Run, column: str) -> np.ndarray:
    entry = run.summary["final"].get(column)
    return np.array(entry["per_seed"]) if entry else np.array([])


def diff_ci(a: np.ndarray, b: np.ndarray, resamples: int = 10_000, seed: int = 0):
    """Mean of a − mean of b and its 95 % bootstrap CI (seeds resampled independently)."""
    rng = np.random.default_rng(seed)
    da = rng.choice(a, (resamples, a.size)).mean(axis=1)
    db = rng.choice(b, (resamples, b.size)).mean(axis=1)
    diff = da - db
    return (
        float(a.mean() - b.mean()),
        float(np.quantile(diff, 0.025)),
        float(np.quantile(diff, 0.975)),
    )


def convergence(run: Run) -> tuple[float | None, float | None, int]:
    conv = run.summary["convergence"]
    return conv["median"], conv["first_crossing_median"], conv["converged_seeds"]


def results_rows(runs: list[Run]) -> list[dict]:
    clean = {r.env: r for r in runs if r.condition == "clean"}
    rows = []
    for run in sorted(runs, key=lambda r: (r.env, CONDITIONS.index(r.condition))):
        success = per_seed(run, "eval/success")
        margin = per_seed(run, "eval/adversary_margin_env")
        margin_total = per_seed(run, "eval/adversary_margin_total")
        ratio = per_seed(run, "eval/return_ratio")
        steps = per_seed(run, "eval/steps")
        median, first, converged = convergence(run)
        row = {
            "env": run.env,
            "condition": run.condition,
            "seeds": len(success),
            "iterations": run.summary["iterations"],
            "success": success.mean(),
            "success_ci": bootstrap_ci(success),
            "return_ratio": ratio.mean() if ratio.size else None,
            "steps": steps.mean(),
            "margin_env": margin.mean(),
            "margin_env_ci": bootstrap_ci(margin),
            "margin_total": margin_total.mean(),
            "convergence_median": median,
            "first_crossing_median": first,
            "converged_seeds": converged,
            "iters_per_s": run.summary["iters_per_s_mean"],
        }
        base = clean.get(run.env)
        if base is not None and run.condition != "clean":
            row["d_success"] = diff_ci(success, per_seed(base, "eval/success"))
            row["d_margin_env"] = diff_ci(margin, per_seed(base, "eval/adversary_margin_env"))
            row["time_ratio"] = base.summary["iters_per_s_mean"] / run.summary["iters_per_s_mean"]
        rows.append(row)
    return rows


def _fmt(value, digits=3) -> str:
    if value is None:
        return "–"
    if isinstance(value, tuple | list):
        if len(value) == 3:
            return f"{value[0]:+.{digits}f} [{value[1]:+.{digits}f}, {value[2]:+.{digits}f}]"
        return f"[{value[0]:.{digits}f}, {value[1]:.{digits}f}]"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def write_csv(rows: list[dict], path: Path) -> None:
    flat = []
    for row in rows:
        out = {}
        for key, value in row.items():
            if isinstance(value, tuple | list):
                names = ("", "_lo", "_hi") if len(value) == 3 else ("_lo", "_hi")
                for suffix, v in zip(names, value, strict=True):
                    out[f"{key}{suffix}"] = v
            else:
                out[key] = value
        flat.append(out)
    columns = list(dict.fromkeys(k for row in flat for k in row))
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        writer.writerows(flat)


def markdown_table(rows: list[dict]) -> str:
    lines = [
        "| env | condition | final success [95 % CI] | Δ success vs clean [95 % CI] "
        "| adversary env margin [95 % CI] | Δ margin vs clean [95 % CI] | return ratio "
        "| steps/ep | convergence median (converged) | first crossing median |",
        "| --- | --- | --- | --- | --- | --- | ---: | ---: | --- | ---: |",
    ]
    for r in rows:
        median = "–" if r["convergence_median"] is None else f"{r['convergence_median']:.0f}"
        first = "–" if r["first_crossing_median"] is None else f"{r['first_crossing_median']:.0f}"
        lines.append(
            f"| {r['env']} | {r['condition']} | {_fmt(r['success'])} {_fmt(r['success_ci'])} "
            f"| {_fmt(r.get('d_success'))} | {_fmt(r['margin_env'], 2)} "
            f"{_fmt(r['margin_env_ci'], 2)} | {_fmt(r.get('d_margin_env'), 2)} "
            f"| {_fmt(r['return_ratio'])} | {_fmt(r['steps'], 2)} "
            f"| {median} ({r['converged_seeds']}/{r['seeds']}) | {first} |"
        )
    return "\n".join(lines) + "\n"


def claims(rows: list[dict]) -> list[tuple[str, str, str, str]]:
    """(claim, rule, measurement, verdict) for C1–C5, computed from the rows."""
    by = {(r["env"], r["condition"]): r for r in rows}
    out = []

    def get(env, cond):
        return by.get((env, cond))

    # C1
    envs_c1 = ["ER(2,1)", "ER(4,2)", "IPD(N=2)"]
    parts, ok = [], True
    for env in envs_c1:
        r = get(env, "self_centered")
        if r is None:
            ok = False
            parts.append(f"{env}: not run")
            continue
        lo = r["margin_env_ci"][0]
        ok &= lo > 0
        parts.append(f"{env}: margin {r['margin_env']:+.2f} (CI low {lo:+.2f})")
    speed = []
    for env in ("ER(2,1)", "ER(4,2)"):
        c, s = get(env, "clean"), get(env, "self_centered")
        if c and s:
            speed.append(
                f"{env}: first crossing {_fmt(c['first_crossing_median'], 0)} → "
                f"{_fmt(s['first_crossing_median'], 0)}, convergence "
                f"{_fmt(c['convergence_median'], 0)} → {_fmt(s['convergence_median'], 0)}"
            )
    out.append(
        (
            "C1 self-centered: adversary above the others; ER converges faster",
            "margin: 95 % CI of the adversary's final env-return margin over the mean of the "
            "others > 0 in ER(2,1), ER(4,2), IPD; speed reported, not judged (medians of 10 seeds)",
            "; ".join(parts + speed),
            "reproduced (margin)" if ok else "not reproduced (margin)",
        )
    )
    # C2
    parts, ok = [], True
    for env in ER_ENVS:
        r = get(env, "fake_incentive")
        if r is None:
            ok, parts = False, parts + [f"{env}: not run"]
            continue
        ok &= r["success"] <= 0.05
        parts.append(f"{env}: {r['success']:.3f}")
    out.append(
        (
            "C2 fake incentive (C = 50): success collapses to ~0 in ER",
            "final success ≤ 0.05 in every ER config",
            "; ".join(parts),
            "reproduced" if ok else "not reproduced",
        )
    )
    # C3, C4
    for cond, label in (("bypass", "C3 bypass"), ("reverse", "C4 reverse")):
        parts, ok = [], True
        for env, want_low in (("ER(2,1)", True), ("ER(4,3)", True), ("ER(4,2)", False)):
            r = get(env, cond)
            if r is None:
                ok, parts = False, parts + [f"{env}: not run"]
                continue
            ok &= r["success"] <= 0.05 if want_low else r["success"] >= 0.9
            parts.append(f"{env}: {r['success']:.3f}")
        out.append(
            (
                f"{label}: 0 success in ER(2,1), ER(4,3); ER(4,2) still solved",
                "final success ≤ 0.05 in ER(2,1) and ER(4,3), ≥ 0.9 in ER(4,2)",
                "; ".join(parts),
                "reproduced" if ok else "not reproduced",
            )
        )
    # C5
    parts, ok = [], True
    for env in ER_ENVS:
        s, d = get(env, "admo_stealthy"), get(env, "admo_disrupt")
        if s is None or d is None or "d_margin_env" not in s:
            ok, parts = False, parts + [f"{env}: not run"]
            continue
        ok &= s["d_margin_env"][1] > 0 and d["d_success"][2] < 0
        parts.append(
            f"{env}: stealthy Δmargin {_fmt(s['d_margin_env'], 2)}, "
            f"disrupt Δsuccess {_fmt(d['d_success'], 3)}"
        )
    ratios = [
        f"{r['env']} {r['condition'].removeprefix('admo_')} {r['time_ratio']:.2f}"
        for r in rows
        if r["condition"].startswith("admo") and "time_ratio" in r
    ]
    parts.append(
        "iteration time ADMO / clean, from the runs' it/s (the sweep's own timing; "
        "benchmarks/throughput.py --attack admo measures it cleanly): " + ", ".join(ratios)
    )
    out.append(
        (
            "C5 ADMO: stealthy raises the adversary's margin, disrupt lowers team success",
            "ER: 95 % CI of Δ margin (stealthy − clean) > 0 and of Δ success (disrupt − clean) < 0 "
            "in every ER config",
            "; ".join(parts),
            "reproduced" if ok else "not reproduced",
        )
    )
    return out


# --- figures ---------------------------------------------------------------------------


def _runs_for(runs, env):
    return sorted((r for r in runs if r.env == env), key=lambda r: CONDITIONS.index(r.condition))


def _band(ax, run, column, label=None, color=None, lw=1.2):
    iterations, values = load_curve(run.path, column)
    mean, lo, hi = mean_and_band(values)
    (line,) = ax.plot(iterations, mean, label=label, color=color, lw=lw)
    ax.fill_between(iterations, lo, hi, color=line.get_color(), alpha=0.15, lw=0)


def fig_metric_by_condition(runs, envs, column, ylabel, path, reference=None):
    fig, axes = plt.subplots(1, len(envs), figsize=(5.2 * len(envs), 3.8), squeeze=False)
    for ax, env in zip(axes[0], envs, strict=True):
        for run in _runs_for(runs, env):
            _band(ax, run, column, run.condition, COLORS[run.condition])
        if reference and env in reference:
            ax.axhline(reference[env], color="grey", ls=":", lw=1, label="random team")
        ax.set_title(env)
        ax.set_xlabel("iteration")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def fig_agent_returns(runs, envs, path):
    conditions = [c for c in CONDITIONS if any(r.condition == c for r in runs)]
    fig, axes = plt.subplots(
        len(conditions),
        len(envs),
        figsize=(4.6 * len(envs), 2.3 * len(conditions)),
        squeeze=False,
        sharex="col",
    )
    for i, cond in enumerate(conditions):
        for j, env in enumerate(envs):
            ax = axes[i][j]
            match = [r for r in runs if r.env == env and r.condition == cond]
            if match:
                run = match[0]
                for agent in range(run.num_agents):
                    adv = agent == run.adversary
                    _band(
                        ax,
                        run,
                        f"eval/return_env/agent_{agent}",
                        f"agent {agent}" + (" (adversary)" if adv else ""),
                        "tab:red" if adv else None,
                        lw=2.0 if adv else 0.9,
                    )
            if i == 0:
                ax.set_title(env)
            if j == 0:
                ax.set_ylabel(f"{cond}\nenv return")
            ax.grid(alpha=0.3)
            if i == 0 and j == 0:
                ax.legend(fontsize=6)
    for ax in axes[-1]:
        ax.set_xlabel("iteration")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def fig_convergence(runs, path):
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    labels, positions = [], 0
    for env in ("ER(2,1)", "ER(4,2)"):
        for cond in ("clean", "self_centered"):
            match = [r for r in runs if r.env == env and r.condition == cond]
            if not match:
                continue
            conv = match[0].summary["convergence"]
            for key, marker in (("first_crossing_per_seed", "o"), ("per_seed", "s")):
                values = [v for v in conv[key] if v is not None]
                jitter = np.linspace(-0.12, 0.12, len(values)) + (0.18 if marker == "s" else -0.18)
                ax.scatter(
                    positions + jitter, values, marker=marker, s=18, color=COLORS[cond], alpha=0.8
                )
            labels.append(f"{env}\n{cond}")
            positions += 1
    ax.set_xticks(range(len(labels)), labels, fontsize=8)
    ax.set_ylabel("iteration")
    ax.set_title("per-seed convergence: ○ first crossing, □ stays ≥ 0.9 (smoothed return ratio)")
    ax.title.set_fontsize(8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def fig_admo(runs, envs, path):
    columns = [
        ("eval/success", "success"),
        ("eval/adversary_margin_env", "adversary env margin"),
        ("admo/alpha_1", "α1 (incentive objective)"),
        ("admo/c_1", "bounds c1 (solid), c2 (dashed)"),
    ]
    fig, axes = plt.subplots(
        len(envs), len(columns), figsize=(4.4 * len(columns), 3 * len(envs)), squeeze=False
    )
    for i, env in enumerate(envs):
        for j, (column, title) in enumerate(columns):
            ax = axes[i][j]
            for run in _runs_for(runs, env):
                if column.startswith("admo/") and not run.condition.startswith("admo"):
                    continue
                if not column.startswith("admo/") and run.condition not in (
                    "clean",
                    "admo_stealthy",
                    "admo_disrupt",
                ):
                    continue
                _band(ax, run, column, run.condition, COLORS[run.condition])
                if column == "admo/c_1":
                    iterations, values = load_curve(run.path, "admo/c_2")
                    ax.plot(iterations, values.mean(axis=0), ls="--", color=COLORS[run.condition])
            ax.set_title(f"{env}: {title}", fontsize=9)
            ax.grid(alpha=0.3)
            if i == len(envs) - 1:
                ax.set_xlabel("iteration")
        axes[i][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: python -m pimbot.analysis.attack_results RUNS_DIR OUT_DIR", file=sys.stderr)
        return 2
    runs_dir, out_dir = Path(argv[0]), Path(argv[1])
    runs = load_runs(runs_dir)
    if not runs:
        print(f"error: no finished runs in {runs_dir}", file=sys.stderr)
        return 2
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = results_rows(runs)
    write_csv(rows, out_dir / "attacks.csv")
    ers = [e for e in ER_ENVS if any(r.env == e for r in runs)]
    fig_metric_by_condition(
        runs, ers, "eval/success", "success", out_dir / "fig1_success.png", RANDOM_SUCCESS
    )
    fig_agent_returns(runs, ers, out_dir / "fig2_agent_returns.png")
    fig_metric_by_condition(
        runs, ers, "eval/steps", "steps per episode", out_dir / "fig3_steps.png"
    )
    fig_convergence(runs, out_dir / "fig4_convergence.png")
    fig_admo(runs, ers, out_dir / "fig5_admo.png")
    ipd = sorted({r.env for r in runs} - set(ER_ENVS))
    if ipd:
        fig_metric_by_condition(
            runs, ipd, "eval/success", "cooperation rate", out_dir / "fig1b_ipd_cooperation.png"
        )

    lines = [
        "# Attacks on LIO: results (10 seeds per condition)",
        "",
        "Generated by `python -m pimbot.analysis.attack_results` from the run directories",
        "(`docs/results/make_attacks.sh`). Final = mean of the last 10 evaluation points",
        "per seed; [95 % bootstrap CI over seeds]; Δ = attacked − clean with a bootstrap CI",
        "(seeds resampled independently). Adversary = agent 0. Margin = adversary's env",
        "return minus the mean of the others'. Convergence: smoothed return ratio stays",
        "≥ 0.9 (success for IPD). N ≥ 3 runs use the original shared incentive updates.",
        "",
        markdown_table(rows),
        "## Claims",
        "",
        "| claim | rule | measured | verdict |",
        "| --- | --- | --- | --- |",
    ]
    for claim, rule, measured, verdict in claims(rows):
        lines.append(f"| {claim} | {rule} | {measured} | {verdict} |")
    lines += [
        "",
        "## Figures",
        "",
        "1. Success vs iterations ![fig1](fig1_success.png)",
        "   IPD cooperation ![fig1b](fig1b_ipd_cooperation.png)",
        "2. Per-agent env returns (adversary in red) ![fig2](fig2_agent_returns.png)",
        "3. Steps per episode ![fig3](fig3_steps.png)",
        "4. Convergence, clean vs self-centered ![fig4](fig4_convergence.png)",
        "5. ADMO vs LIO: success, margin, α1, c1/c2 ![fig5](fig5_admo.png)",
        "",
    ]
    (out_dir / "attacks.md").write_text("\n".join(lines))
    print(f"wrote {out_dir}/attacks.md, attacks.csv and figures")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
