"""One profile: the decision loop under the samplers, written to a run directory.

`profile(config, out)` runs one controller; with `paired=True` benign and ADMO
run back to back with everything else identical (out/benign, out/admo), and
the top-level summary compares them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from pimbot.experiment import store
from pimbot.profiling import decision_loop, report, samplers
from pimbot.profiling.decision_loop import ProfileConfig


def profile_one(
    config: ProfileConfig,
    run_dir: Path,
    sample_hz: float = 1.0,
    sensors_factory: Callable[[float], list] = samplers.default_sensors,
) -> dict:
    """Profiles one controller; writes trace.csv, latency.csv, updates.csv, summary.json."""
    sampler = samplers.Sampler(sensors_factory(sample_hz), sample_hz)

    def on_phase(phase: str) -> None:
        sampler.phase = phase

    with sampler:
        loop = decision_loop.run(config, on_phase)
        sampler.phase = "done"
    summary = report.summarize(
        dataclasses.asdict(config), loop, sampler.rows, sampler.availability()
    )
    report.write_run(Path(run_dir), loop, sampler.rows, summary)
    return summary


def profile(
    config: ProfileConfig,
    out: Path,
    paired: bool = False,
    sample_hz: float = 1.0,
    truncate_idle_gpu: bool = False,
    sensors_factory: Callable[[float], list] = samplers.default_sensors,
) -> dict:
    """Profiles `config` (or benign and ADMO, paired) into `out`; returns the summary."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if not paired:
        summary = profile_one(config, out, sample_hz, sensors_factory)
        report.plot_profiles({config.controller: out}, out / report.FIGURE, truncate_idle_gpu)
        return summary
    runs = {}
    for controller in decision_loop.CONTROLLERS:
        run_config = dataclasses.replace(config, controller=controller)
        runs[controller] = profile_one(run_config, out / controller, sample_hz, sensors_factory)
    summary = {**runs, "comparison": report.compare(runs["benign"], runs["admo"])}
    store.write_json(out / report.SUMMARY, summary)
    report.plot_profiles(
        {c: out / c for c in decision_loop.CONTROLLERS}, out / report.FIGURE, truncate_idle_gpu
    )
    return summary
