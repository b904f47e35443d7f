"""The on-device sections: the paired profile (claim C8, Fig. 8) and the robot case study
(Fig. 9). Their job directories hold a summary.json of their own kind, not training runs."""

from __future__ import annotations

import numpy as np

from pimbot.analysis import plots
from pimbot.analysis.document import Claim, Context, Section, count_text, verdict
from pimbot.analysis.runs import RunTable, condition_colors, condition_key, natural_key
from pimbot.analysis.tables import Estimate, Table, fmt
from pimbot.experiment import store
from pimbot.profiling import report as profile_files

PROFILE_RUN = "profile/er21_paired"
CONTROLLERS = ("benign", "admo")
TRACES = (("cpu", "CPU %"), ("gpu", "GPU %"), ("temp", "temperature °C"))
"""The sensor columns of a profile trace, drawn where at least one controller has data."""


def plot_profile(path, controllers, out) -> bool:
    """One column per controller, one row per sensor that has data (CPU %, GPU %,
    temperature), the warm-up shaded; rebuilt from the trace files. False (nothing
    written) where no controller left a trace with data."""
    traces = {
        name: profile_files.read_trace(path / name)
        for name in controllers
        if (path / name / profile_files.TRACE).exists()
    }
    fields = [
        (field, label)
        for field, label in TRACES
        if any(np.isfinite(t[field]).any() for t in traces.values())
    ]
    if not fields:
        return False
    names = list(traces)
    fig, axes = plots.plt.subplots(
        len(fields),
        len(names),
        figsize=(5 * len(names), 1.2 + 2.2 * len(fields)),
        sharex="col",
        squeeze=False,
    )
    for col, name in enumerate(names):
        trace = traces[name]
        for row, (field, label) in enumerate(fields):
            ax = axes[row][col]
            if not np.isfinite(trace[field]).any():
                ax.remove()
                continue
            ax.plot(trace["time_s"], trace[field], lw=1.2, color="#1f77b4")
            if field != "temp":
                ax.set_ylim(0, 105)
            steady = trace["steady_start_s"]
            if steady is not None:
                ax.axvspan(trace["time_s"][0], steady, color="0.9", lw=0, label="warm-up")
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
            if row == 0:
                ax.set_title(name)
        axes[-1][col].set_xlabel("time (s)")
    plots.save(fig, out, dpi=120)
    return True


def profile_section(table: RunTable, ctx: Context) -> Section | None:
    path = ctx.suite_dir / PROFILE_RUN
    if not (path / store.SUMMARY).exists():
        return None
    summary = store.read_json(path / store.SUMMARY)
    figure_path, figure = ctx.figure(
        "fig8_profile.png",
        "Fig. 8: profiling traces, benign vs ADMO (warm-up shaded); sensors this machine does "
        "not have are left out",
    )
    figures = [figure] if plot_profile(path, CONTROLLERS, figure_path) else []
    rows = []
    for name in CONTROLLERS:
        run = summary[name]
        lat = run["latency_ms"]
        rows.append(
            [
                name,
                f"{lat['p50']:.3f} / {lat['p95']:.3f} / {lat['p99']:.3f}",
                f"{run['decisions_per_s']:.0f}",
                f"{run['update_ms']['p50']:.2f}",
            ]
            + [fmt(run[k], 1) for k in ("mean_cpu_percent", "mean_gpu_percent", "mean_power_w")]
            + [fmt(run["energy_j"], 1), fmt(run["peak_temp_c"], 1)]
        )
    amortized = summary["comparison"]["update_per_decision_ms"]["percent_of_decision"]
    admo = summary["admo"]
    cpu = admo["mean_cpu_percent"]
    gpu = admo["mean_gpu_percent"]
    ok = amortized <= 25.0 and (cpu is None or cpu < 90.0) and (gpu is None or gpu < 90.0)
    claim = Claim(
        "C8",
        "ADMO adds modest, mostly CPU-side, bursty overhead; no sustained saturation",
        "ADMO's extra update cost amortized over decisions ≤ 25 % of a benign decision, and "
        "mean CPU and GPU utilization under ADMO < 90 %",
        f"amortized ADMO update cost {amortized:+.1f} % of a benign decision; update p50 "
        f"{summary['comparison']['update_p50_ms']['percent']:+.0f} %; mean CPU under ADMO "
        f"{fmt(cpu, 1)} %, GPU {fmt(gpu, 1)} %",
        verdict(ok),
        f"amortized update {amortized:+.1f} % of a decision; CPU {fmt(cpu, 1)} %, "
        f"GPU {fmt(gpu, 1)} % under ADMO",
    )
    header = ["controller", "latency p50/p95/p99 (ms)", "decisions/s", "update p50 (ms)"]
    header += ["CPU %", "GPU %", "power (W)", "energy (J)", "peak temp (°C)"]
    return Section(
        "On-device profile: benign vs ADMO (C8)",
        text=[
            f"Decision loop of LIO on ER(2,1) on the profiling machine "
            f"({admo['config']['duration_s']:g} s steady state per controller); sensors that "
            "are not present read '–' and have no panel in Fig. 8."
        ],
        tables=[Table(header, rows, name="profile")],
        figures=figures,
        claims=[claim],
    )


def _estimate(entry: dict) -> Estimate:
    return Estimate(entry["mean"], *entry["ci95"], digits=2)


def robot_section(table: RunTable, ctx: Context) -> Section | None:
    """One row per trained run driven by robots, labelled like the trained run itself."""
    summaries = [store.read_json(p) for p in sorted(ctx.suite_dir.glob("robot/*/summary.json"))]
    if not summaries:
        return None
    trained = {r.name: r for r in table.records}
    results = []
    for s in summaries:
        run = trained.get(s.get("spec", {}).get("run"))
        if run is not None:
            results.append((run.env, run.condition, s))
        else:  # the trained run is not in this suite directory: its label says what it was
            _, env, condition = (s["label"].split(" ", 2) + ["?", "?"])[:3]
            results.append((env, condition, s))
    results.sort(key=lambda r: (natural_key(r[0]), condition_key(r[1])))
    rows = [
        [env, condition, len(s["seeds"]), s["episodes_per_seed"]]
        + [_estimate(s["physics"]), _estimate(s["abstract"]), f"{s['arrived']:.2f}"]
        + [f"{s['physics_steps_per_s']:,.0f}"]
        for env, condition, s in results
    ]
    path, figure = ctx.figure(
        "fig9_robot.png",
        "Fig. 9: success in physics vs the abstract env (solid: physics, hatched: abstract; "
        f"mean over {count_text((len(s['seeds']) for _, _, s in results), 'seeds')}, 95 % "
        "bootstrap CI)",
    )
    colors = condition_colors([r.condition for r in table.records] + [c for _, c, _ in results])
    plot_robot(results, path, colors)
    header = ["env", "condition", "seeds", "episodes/seed", "physics success [CI]"]
    header += ["abstract success [CI]", "arrived", "physics steps/s"]
    return Section(
        "Robot case study: trained policies in MuJoCo physics (Fig. 9)",
        text=[
            "Each trained Escape Room run of the attack group drives TurtleBot3-sized robots in "
            "MuJoCo (go-to-goal controller, odometry and actuation noise); success in physics "
            "next to success of the same policies in the abstract environment, same episodes "
            "per seed, mean and 95 % bootstrap CI over seeds. 'arrived' = fraction of driving "
            "decisions whose robot reached its zone in time."
        ],
        tables=[Table(header, rows, name="robot")],
        figures=[figure],
    )


def plot_robot(results: list[tuple[str, str, dict]], path, colors: dict) -> None:
    """Physics (solid) and abstract (hatched) success per condition, in its colour."""
    envs = sorted({env for env, _, _ in results}, key=natural_key)
    fig, axes = plots.plt.subplots(1, len(envs), figsize=(4.2 * len(envs), 3.4), squeeze=False)
    for ax, env in zip(axes[0], envs, strict=True):
        mine = [(c, s) for e, c, s in results if e == env]
        x = np.arange(len(mine))
        shades = [colors.get(c, "0.5") for c, _ in mine]
        for offset, key, style in (
            (-0.2, "physics", {}),
            (0.2, "abstract", {"hatch": "///", "alpha": 0.45, "edgecolor": "white"}),
        ):
            means = [s[key]["mean"] for _, s in mine]
            lo = [s[key]["mean"] - s[key]["ci95"][0] for _, s in mine]
            hi = [s[key]["ci95"][1] - s[key]["mean"] for _, s in mine]
            ax.bar(x + offset, means, 0.4, yerr=[lo, hi], color=shades, capsize=2, **style)
            plots.mark_zero_bars(ax, x + offset, means, "0.3")
        ax.set_xticks(x, [c for c, _ in mine], rotation=45, ha="right", fontsize=8)
        ax.set_ylim(0, 1.05)
        ax.set_title(env)
        ax.set_ylabel("success")
        ax.grid(axis="y", alpha=0.3)
    handles = [
        plots.plt.Rectangle((0, 0), 1, 1, facecolor="0.35", label="physics"),
        plots.plt.Rectangle(
            (0, 0), 1, 1, facecolor="0.35", alpha=0.45, hatch="///", ec="white", label="abstract"
        ),
    ]
    axes[0][0].legend(handles=handles, fontsize=8)
    plots.save(fig, path)
