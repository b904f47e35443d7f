"""The on-device sections: the paired profile (claim C8, Fig. 8) and the robot case study
(Fig. 9). Their job directories hold a summary.json of their own kind, not training runs.

C8 is judged at LIO's training cadence (profiling.cadence), the other cadences shown."""

from __future__ import annotations

import numpy as np

from pimbot import statistics
from pimbot.analysis import plots, verdicts
from pimbot.analysis.claims import Claim, Comparison, deciding_part, summarized
from pimbot.analysis.document import Context, Section, count_text
from pimbot.analysis.runs import (
    PROFILE_RUN,
    RunTable,
    condition_colors,
    condition_key,
    natural_key,
    read_profile,
)
from pimbot.analysis.tables import INTERVAL, Estimate, Table, estimate, fmt
from pimbot.analysis.verdicts import Verdict
from pimbot.profiling import decision_loop
from pimbot.profiling import report as profile_files

CONTROLLERS = decision_loop.CONTROLLERS
"""benign, the paper's ADMO, the published code's ADMO (a profile may lack the last)."""
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
            if field == "cpu":
                process = profile_files.with_breaks(trace["time_s"], trace["process_cpu"])
                ax.plot(
                    *process, ".-", lw=1.2, ms=3, color="#d62728", label="process (of its cores)"
                )
            series = profile_files.with_breaks(trace["time_s"], trace[field])
            ax.plot(
                *series,
                ".-",
                lw=1.2,
                ms=3,
                color="#1f77b4",
                label="system" if field == "cpu" else None,
            )
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
    plots.legend_below(fig, fig.axes)
    plots.save(fig, out, dpi=120)
    return True


SATURATED_PERCENT = 90.0
"""Mean utilization (% of the cores the process may use; % of the GPU) that is saturation."""
MIN_UPDATES = 10
"""Update steps per controller at the judged cadence below which C8 is inconclusive."""


def _overhead_estimate(per_round: list[float]) -> Estimate | None:
    return estimate(np.asarray(per_round), digits=1, signed=True) if per_round else None


def _overhead_text(est: Estimate | None, at_slowest: float | None, slowest: int, context) -> str:
    """ADMO's amortized overhead, a measurement with its interval over the paired rounds
    (the paper gives no size for "modest"), with what explains it: the update step's cost
    against a benign one, the slowest cadence, and the published code's ADMO beside it."""
    if est is None:
        return "amortized overhead: no paired rounds at the training cadence"
    code = context.get("code")
    return (
        f"amortized overhead ({context['basis']}) {est} % over {context['rounds']} rounds, "
        f'a measurement (the paper gives no size for "modest"): an ADMO update step costs '
        f"{context['update_ratio']:.1f}x a benign one on this machine ({context['machine']}), "
        f"ADMO's decisions {context['latency_percent']:+.1f} % against benign ones; "
        f"{fmt(at_slowest, 1)} % at {slowest} decisions per update"
        + (f"; the published code's ADMO {code} % at the training cadence" if code else "")
    )


def _bursty(share: float | None, update: list[float], what: str) -> Verdict:
    """Bursty: the extra time arrives in the update steps rather than spread over the
    decisions, i.e. the update steps carry more of it than the decisions do."""
    text = (
        f"update step ADMO {update[0]:.2f} ms vs benign {update[1]:.2f} ms ({what}), update "
        f"steps {fmt(share, 0)} % of ADMO's extra time"
    )
    if share is None:
        return verdicts.inconclusive(f"{text}: ADMO took no extra time to split")
    if share > 50.0:
        return verdicts.reproduced(text)
    return verdicts.inconclusive(
        f"{text}: the decisions carry most of it; no profile of the published code's "
        "burstiness to name a cause"
    )


WALL = {
    "basis": "wall-clock time",
    "per_round": "per_round_percent",
    "amortized": "amortized_ms",
    "update": ("update_ms", "mean"),
    "decision": ("latency_ms", "mean"),
}
CPU_TIME = {
    "basis": "the process's CPU time: the machine was shared",
    "per_round": "per_round_cpu_percent",
    "amortized": "amortized_cpu_ms",
    "update": ("update_cpu_ms",),
    "decision": ("decision_cpu_ms",),
}
SHARED_CORES = 0.5
"""Other work on the machine (mean cores busy besides this process) from which wall-clock
times no longer show the controller's own cost: its decisions wait for the CPU, and waits
lengthen short decisions far more than updates. C8 is then judged on the process's CPU
time (where no GPU works for it; with a GPU that time misses the GPU's work)."""


def _basis(summary: dict, key: str) -> tuple[dict | None, str, bool]:
    """What the overhead at cadence `key` is judged on (None: nothing fits), the words that
    say why, and whether the machine was shared: other work at that cadence, or over the
    whole steady state where its segments were too short for a sample."""
    runs = [summary[c] for c in ("benign", "admo")]
    loads = [r["cadences"][key].get("other_load_cores") for r in runs]
    if all(v is None for v in loads):
        loads = [r.get("other_load_cores") for r in runs]
    loads = [v for v in loads if v is not None]
    if not loads:
        return WALL, "other load on the machine not measured", False
    other = max(loads)
    words = f"{other:.1f} cores of other work on the machine"
    if other < SHARED_CORES:
        return WALL, words, False
    if runs[1]["cadences"][key]["mean_gpu_percent"] is not None:
        return None, words, True
    return CPU_TIME, words, True


def _value(entry: dict, path: tuple[str, ...]):
    for key in path:
        entry = entry[key]
    return entry


def _unsaturated(admo: dict, benign: dict, cores: int, shared: bool) -> Verdict:
    """No sustained saturation: ADMO's mean process CPU (and mean GPU, where measured)
    below the bound. A saturated ADMO run is our setting where the benign run saturates
    too (the machine), inconclusive where only ADMO does (no profile of the published
    code's saturation to name a cause). Unsaturated on a
    `shared` machine is inconclusive: other work held the process's share down."""
    cpu, gpu = admo["process_cpu"], admo["mean_gpu_percent"]
    text = (
        f"process CPU under ADMO mean {fmt(cpu['mean'], 1)} / p95 {fmt(cpu['p95'], 1)} / max "
        f"{fmt(cpu['max'], 1)} % of its {cores} usable cores (benign mean "
        f"{fmt(benign['process_cpu']['mean'], 1)} %); GPU "
        + (f"{gpu:.1f} %" if gpu is not None else "not measured (no GPU sensor)")
    )
    if cpu["mean"] is None:
        return verdicts.inconclusive("no process CPU windows at the training cadence")
    saturated = cpu["mean"] >= SATURATED_PERCENT or (gpu is not None and gpu >= SATURATED_PERCENT)
    if not saturated and shared:
        return verdicts.inconclusive(
            f"{text}; the machine was shared, which holds the process's CPU below what it "
            "would use alone"
        )
    if not saturated:
        return verdicts.reproduced(text)
    b_gpu = benign["mean_gpu_percent"]
    benign_saturated = (benign["process_cpu"]["mean"] or 0.0) >= SATURATED_PERCENT or (
        b_gpu is not None and b_gpu >= SATURATED_PERCENT
    )
    if benign_saturated:  # measured: the benign run saturates this machine too
        return verdicts.refuted(verdicts.BUDGET, f"{text}: saturated, and so is the benign run")
    return verdicts.inconclusive(
        f"{text}: saturated under ADMO only; the published code's ADMO not profiled for "
        "saturation: no cause can be named"
    )


def judge_c8(summary: dict) -> tuple[Verdict, str, str, list[Comparison]]:
    """C8 judged at LIO's training cadence (`comparison.judged_cadence`) from a paired
    profile's summary: (verdict, every number judged on, its short form, paper | original
    | pimbot rows). Measured on wall-clock time, or on the process's CPU time where the
    machine was shared (`SHARED_CORES`).
    The parts, in the paper's words: bursty (the update steps carry more of ADMO's extra
    time than the decisions do) and no sustained saturation of the process's CPU or the
    GPU under ADMO. The amortized overhead is a measurement with its interval, not judged:
    the paper gives no size for "modest"."""
    comp = summary["comparison"]
    training = comp["training_cadence"]
    judged = comp["judged_cadence"]
    if judged is None:
        reason = (
            f"the training cadence ({training['decisions_per_update']} decisions per update) "
            "was not profiled"
        )
        return verdicts.inconclusive(reason), reason, reason, []
    key = str(judged)
    benign, admo = summary["benign"]["cadences"][key], summary["admo"]["cadences"][key]
    updates = min(benign["updates"], admo["updates"])
    if updates < MIN_UPDATES:
        reason = f"only {updates} update steps at the training cadence ({judged} decisions)"
        return verdicts.inconclusive(reason), reason, reason, []
    basis, load, shared = _basis(summary, key)
    overhead, fits = _overhead(summary, key, basis, load)
    basis = basis or WALL
    what = basis["basis"].split(":")[0]
    share, update = _update_share(summary, key, basis)
    bursty = (
        _bursty(share, update, what)
        if fits
        else verdicts.inconclusive(f"{load}: wall-clock times are distorted ({overhead})")
    )
    cores = summary["admo"]["usable_cores"]
    parts = {"bursty": bursty, "saturation": _unsaturated(admo, benign, cores, shared)}
    measured = _c8_measured(summary, key, basis, load, overhead, parts)
    per_round = comp["cadences"][key].get(basis["per_round"], [])
    cpu = admo["process_cpu"]
    numbers = _c8_numbers(f"{judged} decisions/update (training)", what, per_round, share, cpu)
    short = (
        f"{judged} decisions/update: overhead ({what}) {_overhead_estimate(per_round)} % "
        f"(measured); update steps {fmt(share, 0)} % of the extra time; ADMO process CPU "
        f"{fmt(cpu['mean'], 1)} % of its cores"
    )
    return verdicts.combine(parts), measured, short, numbers


def _c8_numbers(cadence: str, what: str, per_round, share, cpu: dict) -> list[Comparison]:
    """C8's paper | original | pimbot rows: the overhead (a measurement), burstiness and
    the process's CPU under ADMO."""
    return [
        Comparison(
            f"ADMO amortized overhead per decision ({what}; a measurement)",
            cadence,
            "modest (no size given)",
            None,
            f"{_overhead_estimate(per_round)} %",
        ),
        Comparison(
            "update steps' share of ADMO's extra time",
            cadence,
            "bursty",
            None,
            f"{fmt(share, 0)} %",
        ),
        Comparison(
            "process CPU under ADMO (of usable cores)",
            cadence,
            "no sustained saturation",
            None,
            f"mean {fmt(cpu['mean'], 1)} %, p95 {fmt(cpu['p95'], 1)} %",
        ),
    ]


def _overhead(summary: dict, key: str, basis: dict | None, load: str) -> tuple[str, bool]:
    """C8's overhead at cadence `key` on `basis` (`_basis`; None: nothing fits), as a
    measurement; and whether the basis fits the machine."""
    comp = summary["comparison"]
    at = comp["cadences"][key]
    benign, admo = summary["benign"]["cadences"][key], summary["admo"]["cadences"][key]
    if basis is None:
        return (
            f"{load}: wall-clock times are distorted and the process's CPU time misses the "
            f"GPU's work (wall-clock overhead {_overhead_estimate(at['per_round_percent'])} %)"
        ), False
    est = _overhead_estimate(at.get(basis["per_round"], []))
    slowest = max(int(k) for k in comp["cadences"])
    at_slowest = comp["cadences"][str(slowest)].get(basis["amortized"])
    decision = [_value(c, basis["decision"]) for c in (admo, benign)]
    code = summary.get("comparison_admo_code", {}).get("cadences", {}).get(key, {})
    context = {
        "code": _overhead_estimate(code.get(basis["per_round"], [])),
        "basis": basis["basis"],
        "rounds": len(at.get(basis["per_round"], [])),
        "update_ratio": _value(admo, basis["update"]) / _value(benign, basis["update"]),
        "latency_percent": 100.0 * (decision[0] - decision[1]) / decision[1],
        "machine": f"{summary['admo']['usable_cores']} usable cores, GPU "
        + ("present" if admo["mean_gpu_percent"] is not None else "absent")
        + f", {load}",
    }
    slowest_percent = None if at_slowest is None else at_slowest["percent"]
    return _overhead_text(est, slowest_percent, slowest, context), True


def _update_share(summary: dict, key: str, basis: dict) -> tuple[float | None, list[float]]:
    """(% of ADMO's extra amortized time that its update steps carry, None where it took
    none; [ADMO, benign] update step time) at cadence `key` on `basis`."""
    judged = int(key)
    benign, admo = summary["benign"]["cadences"][key], summary["admo"]["cadences"][key]
    update = [_value(c, basis["update"]) for c in (admo, benign)]
    extra = admo[basis["amortized"]] - benign[basis["amortized"]]
    share = 100.0 * (update[0] - update[1]) / judged / extra if extra > 0 else None
    return share, update


def _c8_measured(
    summary: dict, key: str, basis: dict, load: str, overhead: str, parts: dict
) -> str:
    """Every number C8 is judged on, and the overhead and other cadences beside them."""
    comp = summary["comparison"]
    training, judged, at = comp["training_cadence"], comp["judged_cadence"], comp["cadences"][key]
    others = ", ".join(
        f"{k}: {fmt(c.get(basis['amortized']) and c[basis['amortized']]['percent'], 1)} %"
        for k, c in sorted(comp["cadences"].items(), key=lambda kv: int(kv[0]))
        if k != key
    )
    wall, cpu = at["amortized_ms"], at.get("amortized_cpu_ms")
    what = basis["basis"].split(":")[0]
    return (
        f"training cadence {judged} decisions per update ({training['episodes_per_update']} "
        f"episodes × {training['max_steps']}-step horizon); {load}; bursty: "
        f"{parts['bursty'].reason}; {parts['saturation'].reason}; {overhead}; amortized "
        f"overhead by wall clock {fmt(wall and wall['percent'], 1)} %, by CPU time "
        f"{fmt(cpu and cpu['percent'], 1)} %, from medians (decision p50 + update p50 / "
        f"cadence) {fmt(at['amortized_p50_ms'] and at['amortized_p50_ms']['percent'], 1)} %; "
        f"other cadences ({what}) {others}"
    )


def _cpu_cell(cpu: dict) -> str:
    return " / ".join(fmt(cpu[k], 1) for k in ("mean", "p95", "max"))


CLAIM_TEXT = "ADMO adds modest, mostly CPU-side, bursty overhead; no sustained saturation"
SECTION = "On-device profile: benign vs ADMO (C8)"


def profile_section(table: RunTable | None, ctx: Context) -> Section | None:
    """The paired profile (`RunTable.profile`; without a table, read from the suite
    directory): Fig. 8, its tables and C8."""
    summary = table.profile if table is not None else read_profile(ctx.suite_dir)
    if summary is None:
        return None
    figure_path, figure = ctx.figure(
        "fig8_profile.png",
        "Fig. 8: profiling traces, benign vs ADMO and the published code's ADMO (warm-up "
        "shaded; CPU: the process's own, "
        "of the cores it may use, and the system's); the controllers' segments are "
        "interleaved, so each column has gaps; sensors this machine does not have are left out",
    )
    path = ctx.suite_dir / PROFILE_RUN
    figures = [figure] if plot_profile(path, CONTROLLERS, figure_path) else []  # those present
    if "cadences" not in summary.get("comparison", {}):
        reason = "the profile predates the per-cadence measurement; rerun its job (--restart)"
        claim = Claim("C8", CLAIM_TEXT, "–", reason, verdicts.inconclusive(reason))
        return Section(SECTION, claims=[claim])
    return Section(
        SECTION,
        text=profile_text(summary),
        tables=profile_tables(summary),
        figures=figures,
        claims=[c8(summary)],
    )


def c8(summary: dict) -> Claim:
    verdict, measured, short, numbers = judge_c8(summary)
    return Claim(
        "C8",
        CLAIM_TEXT,
        "at LIO's training cadence (decisions per update = episodes per update × the "
        "horizon): bursty, i.e. ADMO's update steps carry more of its extra time per decision "
        "than its decisions do; and no sustained saturation: under ADMO the process's mean "
        f"CPU (of the cores it may use) and the mean GPU < {SATURATED_PERCENT:g} %. ADMO's "
        "amortized overhead per decision (decision latency + update time / cadence, against "
        "benign; interval over the paired rounds; by wall clock, or by the process's CPU time "
        f"where other work kept ≥ {SHARED_CORES:g} cores busy) is a measurement, not judged: "
        'the paper gives no size for "modest"; "mostly CPU-side" is shown (the GPU\'s '
        "presence and use), not judged; the other cadences shown",
        measured,
        verdict,
        short,
        numbers=numbers,
        **summarized(
            verdict,
            _c8_headlines(numbers),
            agreed="ADMO's extra time arrives in its update steps and it saturates neither the "
            "CPU nor the GPU",
            why=_c8_why(verdict),
        ),
    )


def _c8_headlines(numbers: list[Comparison]) -> dict[str, str]:
    """The number of each C8 part, from its paper | original | pimbot rows (overhead, update
    steps' share, process CPU)."""
    if len(numbers) < 3:
        return {}
    return {
        "bursty": f"update steps {numbers[1].pimbot} of ADMO's extra time",
        "saturation": f"ADMO process CPU {numbers[2].pimbot} of its cores",
    }


def _c8_why(verdict: Verdict) -> str:
    """Why C8's deciding part is not reproduced: its reason after the numbers."""
    found = deciding_part(verdict)
    if found is None or found[1].kind == verdicts.REPRODUCED:
        return ""
    name, part = found
    if ": " in part.reason:  # "numbers: why"
        return part.reason.split(": ", 1)[1]
    return "; ".join(part.reason.split("; ")[1:])


def profile_tables(summary: dict) -> list[Table]:
    """Every cadence of every controller (speed, latency, overhead, CPU, GPU), and power."""
    comp = summary["comparison"]
    judged = comp["judged_cadence"]
    controllers = [name for name in CONTROLLERS if name in summary]
    comparisons = {"admo": comp, "admo_code": summary.get("comparison_admo_code", {})}
    rows = []
    for key in sorted(summary["benign"]["cadences"], key=int):
        for name in controllers:
            run = summary[name]["cadences"].get(key)
            if run is None:
                continue
            lat = run["latency_ms"]
            paired = comparisons.get(name, {}).get("cadences", {}).get(key, {})
            rows.append(
                [
                    key + (" (training)" if judged is not None and key == str(judged) else ""),
                    name,
                    fmt(run["decisions_per_s"], 0),
                    f"{lat['p50']:.3f} / {lat['p95']:.3f} / {lat['p99']:.3f}",
                    fmt(run["update_ms"]["mean"], 2),
                    f"{fmt(run['amortized_ms'], 3)} / {fmt(run.get('amortized_cpu_ms'), 3)}",
                    _overhead_estimate(paired.get("per_round_percent", [])),
                    _overhead_estimate(paired.get("per_round_cpu_percent", [])),
                    _cpu_cell(run["process_cpu"]),
                    fmt(run["mean_system_cpu_percent"], 1),
                    fmt(run.get("other_load_cores"), 2),
                    fmt(run["mean_gpu_percent"], 1),
                ]
            )
    header = ["decisions/update", "controller", "decisions/s", "latency p50/p95/p99 (ms)"]
    header += ["update mean (ms)", "amortized ms/decision wall / CPU"]
    header += [f"overhead % wall {INTERVAL}", f"overhead % CPU time {INTERVAL}"]
    header += ["process CPU % mean/p95/max", "system CPU %", "other load (cores)", "GPU %"]
    power = [
        [name] + [fmt(summary[name][k], 1) for k in ("mean_power_w", "energy_j", "peak_temp_c")]
        for name in controllers
    ]
    power_header = ["controller", "power (W)", "energy (J)", "peak temp (°C)"]
    return [Table(header, rows, name="profile"), Table(power_header, power, name="profile_power")]


def profile_text(summary: dict) -> list[str]:
    """What was profiled, the training cadence, and what each column measures."""
    training = summary["comparison"]["training_cadence"]
    played = training["played_per_update"]
    config = summary["admo"]["config"]
    return [
        f"Decision loop of LIO on ER(2,1) on the profiling machine "
        f"({config['duration_s']:g} s steady state per controller over "
        f"{len(config['cadences'])} cadences, the controllers interleaved in "
        f"{config['rounds']} rounds): benign LIO, the paper's ADMO on agent 0 (`admo`, "
        "judged) and the published code's ADMO (`admo_code`, a scheduler of extra "
        "ordinary steps, shown beside it); sensors that are not present read '–' and have "
        "no panel in Fig. 8.",
        f"The training cadence: one LIO update is one iteration, which plays "
        f"{training['episodes_per_update']} episodes (counted from a trace of the "
        f"learner's update) of up to {training['max_steps']} decisions each, so its "
        f"training takes {training['decisions_per_update']} decisions per update (its "
        "rollouts compute every step of the horizon). Episodes that end early play fewer: "
        f"the profiled learners played {played['benign']:.1f} (benign) and "
        f"{played['admo']:.1f} (ADMO) per update, and a converged ER(2,1) policy plays "
        "2 (one step per episode). C8 is judged at the training cadence.",
        "Amortized ms/decision = (decision latencies + update times) / decisions at that "
        "cadence, by wall clock and by the process's CPU time over each; the environment "
        "runs off the timed path. Process CPU = this process's CPU time (all threads) in "
        f"% of the {summary['admo']['usable_cores']} cores it may use, in windows of "
        f"{config['cpu_window_s']:g} s; system CPU = the whole machine's (sampled); other "
        "load = the cores the rest of the machine kept busy meanwhile. Where that is "
        f"≥ {SHARED_CORES:g} cores, short decisions wait for the CPU far more than "
        "updates do and wall-clock overheads understate ADMO's; C8 is then judged on "
        "CPU time.",
    ]


def _estimate(entry: dict) -> Estimate:
    """A robot summary's success with its interval over seeds, from its per-seed values."""
    return estimate(np.asarray(entry["per_seed"], dtype=float), digits=2)


def robot_section(table: RunTable, ctx: Context) -> Section | None:
    """One row per trained run driven by robots (`RunTable.robot`), labelled like the
    trained run itself."""
    summaries = table.robot
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
        f"mean over {count_text((len(s['seeds']) for _, _, s in results), 'seeds')}; "
        f"{statistics.interval_text(len(s['seeds']) for _, _, s in results)})",
    )
    colors = condition_colors([r.condition for r in table.records] + [c for _, c, _ in results])
    plot_robot(results, path, colors)
    header = ["env", "condition", "seeds", "episodes/seed", f"physics success {INTERVAL}"]
    header += [f"abstract success {INTERVAL}", "arrived", "physics steps/s"]
    return Section(
        "Robot case study: trained policies in MuJoCo physics (Fig. 9)",
        text=[
            "Each trained Escape Room run of the attack group drives TurtleBot3-sized robots in "
            "MuJoCo (go-to-goal controller, odometry and actuation noise); success in physics "
            "next to success of the same policies in the abstract environment, same episodes "
            "per seed, mean over seeds with its interval: "
            + statistics.interval_text(len(s["seeds"]) for _, _, s in results)
            + ". 'arrived' = fraction of driving decisions whose robot reached its zone in time."
        ],
        tables=[Table(header, rows, name="robot")],
        figures=[figure],
    )


def plot_robot(results: list[tuple[str, str, dict]], path, colors: dict) -> None:
    """Physics (solid) and abstract (hatched) success per condition, in its colour, with
    their intervals over seeds; the legend under the panels says what the error bars are."""
    envs = sorted({env for env, _, _ in results}, key=natural_key)
    fig, axes = plots.plt.subplots(1, len(envs), figsize=(4.2 * len(envs), 3.4), squeeze=False)
    drawn = []
    for ax, env in zip(axes[0], envs, strict=True):
        mine = [(c, s) for e, c, s in results if e == env]
        x = np.arange(len(mine))
        shades = [colors.get(c, "0.5") for c, _ in mine]
        for offset, key, style in (
            (-0.2, "physics", {}),
            (0.2, "abstract", {"hatch": "///", "alpha": 0.45, "edgecolor": "white"}),
        ):
            means = [s[key]["mean"] for _, s in mine]
            intervals = [statistics.mean_interval(s[key]["per_seed"]) for _, s in mine]
            drawn += [(i.kind, i.n) for i in intervals]
            lo = [m - i.lo for m, i in zip(means, intervals, strict=True)]
            hi = [i.hi - m for m, i in zip(means, intervals, strict=True)]
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
        plots.Line2D(
            [], [], color="black", marker="|", ls="", label=plots.band_text(drawn, "error bar")
        ),
    ]
    plots.legend_below(fig, [], handles)
    plots.save(fig, path)
