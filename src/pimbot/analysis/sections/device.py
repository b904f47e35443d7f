"""The on-device sections: the paired profile (claim C8, Fig. 8) and the robot case study
(Fig. 9). Their job directories hold a summary.json of their own kind, not training runs."""

from __future__ import annotations

import numpy as np

from pimbot.analysis import plots
from pimbot.analysis.document import Claim, Context, Section, verdict
from pimbot.analysis.runs import RunTable, condition_key, natural_key
from pimbot.analysis.tables import Estimate, Table, fmt
from pimbot.experiment import store

PROFILE_RUN = "profile/er21_paired"


def profile_section(table: RunTable, ctx: Context) -> Section | None:
    path = ctx.suite_dir / PROFILE_RUN
    if not (path / store.SUMMARY).exists():
        return None
    summary = store.read_json(path / store.SUMMARY)
    figure_path, figure = ctx.figure("fig8_profile.png", "Fig. 8: profiling traces, benign vs ADMO")
    figure_path.write_bytes((path / "profile.png").read_bytes())
    rows = []
    for name in ("benign", "admo"):
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
    )
    header = ["controller", "latency p50/p95/p99 (ms)", "decisions/s", "update p50 (ms)"]
    header += ["CPU %", "GPU %", "power (W)", "energy (J)", "peak temp (°C)"]
    return Section(
        "On-device profile: benign vs ADMO (C8)",
        text=[
            f"Decision loop of LIO on ER(2,1) on this machine ({admo['config']['duration_s']:g} s "
            "steady state per controller); sensors that are not present read '–'."
        ],
        tables=[Table(header, rows, name="profile")],
        figures=[figure],
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
    path, figure = ctx.figure("fig9_robot.png", "Fig. 9: success in physics vs abstract")
    plot_robot(results, path)
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


def plot_robot(results: list[tuple[str, str, dict]], path) -> None:
    envs = sorted({env for env, _, _ in results}, key=natural_key)
    fig, axes = plots.plt.subplots(1, len(envs), figsize=(4.2 * len(envs), 3.4), squeeze=False)
    for ax, env in zip(axes[0], envs, strict=True):
        mine = [(c, s) for e, c, s in results if e == env]
        x = np.arange(len(mine))
        for offset, key, color in ((-0.2, "physics", "tab:blue"), (0.2, "abstract", "tab:gray")):
            means = [s[key]["mean"] for _, s in mine]
            lo = [s[key]["mean"] - s[key]["ci95"][0] for _, s in mine]
            hi = [s[key]["ci95"][1] - s[key]["mean"] for _, s in mine]
            ax.bar(x + offset, means, 0.4, yerr=[lo, hi], color=color, label=key, capsize=2)
        ax.set_xticks(x, [c for c, _ in mine], rotation=45, ha="right", fontsize=8)
        ax.set_ylim(0, 1.05)
        ax.set_title(env)
        ax.set_ylabel("success")
    axes[0][0].legend(fontsize=8)
    plots.save(fig, path)
