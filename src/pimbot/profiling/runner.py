"""One profile: the decision loop under the samplers, written to a run directory.

`profile(config, out)` runs one controller; with `paired=True` every controller
(benign, the paper's ADMO, the published code's ADMO) runs in one process, their
segments interleaved, with everything else identical (out/benign, out/admo,
out/admo_code), and the top-level summary compares each attack with benign per
cadence and at LIO's training cadence (`cadence.of_profile`): "comparison" (ADMO)
and "comparison_admo_code".
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from pimbot.profiling import cadence, decision_loop, process_cpu, report, samplers
from pimbot.profiling.decision_loop import ProfileConfig
from pimbot.training import store


def _summaries(config, controllers, sample_hz, sensors_factory):
    """{controller: (summary, loop, its sampler rows)} of one profiling process."""
    sampler = samplers.Sampler(sensors_factory(sample_hz), sample_hz)

    def on_segment(tags: dict) -> None:
        sampler.tags = dict(tags)

    with sampler:
        loops = decision_loop.run(config, controllers, on_segment)
    cores = process_cpu.usable_cores()
    out = {}
    for name, loop in loops.items():
        rows = [r for r in sampler.rows if r.get("controller") in (name, None)]
        run_config = dataclasses.asdict(dataclasses.replace(config, controller=name))
        summary = report.summarize(run_config, loop, rows, sampler.availability(), cores)
        out[name] = (summary, loop, rows)
    return out


def profile_one(
    config: ProfileConfig,
    run_dir: Path,
    sample_hz: float = 1.0,
    sensors_factory: Callable[[float], list] = samplers.default_sensors,
) -> dict:
    """Profiles one controller; writes its run directory (`report.write_run`)."""
    ((summary, loop, rows),) = _summaries(
        config, (config.controller,), sample_hz, sensors_factory
    ).values()
    report.write_run(Path(run_dir), loop, rows, summary)
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
    runs = _summaries(config, decision_loop.CONTROLLERS, sample_hz, sensors_factory)
    for name, (summary, loop, rows) in runs.items():
        report.write_run(out / name, loop, rows, summary)
    training = cadence.of_profile(config)
    summaries = {name: run[0] for name, run in runs.items()}
    summary = {
        **summaries,
        "comparison": report.compare(summaries["benign"], summaries["admo"], training),
        "comparison_admo_code": report.compare(
            summaries["benign"], summaries["admo_code"], training
        ),
    }
    store.write_json(out / report.SUMMARY, summary)
    report.plot_profiles(
        {c: out / c for c in decision_loop.CONTROLLERS}, out / report.FIGURE, truncate_idle_gpu
    )
    return summary
