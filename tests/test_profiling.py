"""On-device profiling: tegrastats parsing, sensor fallbacks, RAPL wrap-around, the process's
own CPU, the training cadence, C8's verdict rules, end to end."""

import csv
import json
import os

import numpy as np
import pytest

from pimbot import cli
from pimbot.analysis import verdicts
from pimbot.envs import InvalidParameter
from pimbot.profiling import ProfileConfig, cadence, process_cpu, report, samplers, tegrastats

ORIN_JP6 = (
    "RAM 2456/7620MB (lfb 2x4MB) SWAP 0/3810MB (cached 0MB) "
    "CPU [2%@1510,1%@1510,0%@1510,0%@1510,off,off] GR3D_FREQ 12%@[1300,1300] "
    "cpu@47.5C soc2@45.9C soc0@46.2C gpu@46.9C tj@47.5C soc1@46.5C "
    "VDD_IN 4787mW/4787mW VDD_CPU_GPU_CV 598mW/598mW VDD_SOC 1435mW/1435mW"
)
JP7 = (
    "11-20-2025 10:00:01 RAM 5120/125772MB (lfb 10x4MB) SWAP 0/0MB (cached 0MB) "
    "CPU [3%@2601,1%@2601,off] GR3D_FREQ 5%@[1575,1575] "
    "cpu@45.2C/46.8C gpu@44.1C/45.0C tj@46.8C/48.0C "
    "VDD_GPU 1200mW/1300mW VDD_CPU_SOC_MSS 4500mW/4600mW VIN_SYS_5V0 9000mW/9100mW"
)
ORIN_OLD = (
    "12-23-2024 22:54:11 RAM 3162/7620MB (lfb 4x2MB) SWAP 0/3810MB (cached 0MB) "
    "CPU [1%@729,0%@729,0%@729,0%@729,off,off] GR3D_FREQ 47% cpu@62.843C soc2@61.968C "
    "soc0@60.625C gpu@61.687C tj@41.468C soc1@61.687C "
    "VDD_IN 3913mW/3922mW VDD_CPU_GPU_CV 598mW/598mW VDD_SOC 1238mW/1237mW"
)
XAVIER = (
    "RAM 3504/31927MB (lfb 6327x4MB) SWAP 0/15963MB (cached 0MB) "
    "CPU [1%@1190,0%@1190,off,off,off,off,off,off] EMC_FREQ 0%@2133 GR3D_FREQ 0%@318 "
    "APE 150 MTS fg 0% bg 0% AO@36.5C GPU@36C Tdiode@38.5C PMIC@100C AUX@35.5C CPU@37C "
    "thermal@36.6C Tboard@36C GPU 1155/1155 CPU 311/311 SOC 1554/1554 CV 0/0 "
    "VDDRQ 155/155 SYS5V 1283/1283"
)
NANO = (
    "RAM 1766/3964MB (lfb 197x4MB) SWAP 0/2048MB (cached 0MB) IRAM 0/252kB(lfb 252kB) "
    "CPU [24%@1224,15%@1224,13%@1224,10%@1224] EMC_FREQ 0%@1600 GR3D_FREQ 0%@76 APE 25 "
    "PLL@21C CPU@25C PMIC@100C GPU@23.5C AO@33.5C iwlwifi@-256C thermal@24.5C "
    "POM_5V_IN 933/933 POM_5V_GPU 0/0 POM_5V_CPU 118/118"
)
TX2 = (
    "RAM 2196/7855MB (lfb 1x4MB) SWAP 0/3927MB (cached 0MB) CPU [35%@2035,off,off,"
    "30%@2035,28%@2035,33%@2035] EMC_FREQ 9%@1866 GR3D_FREQ 99%@1300 APE 150 "
    "PLL@46.5C MCPU@46.5C PMIC@100C Tboard@42C GPU@44C BCPU@46.5C thermal@45.4C "
    "Tdiode@45.25C VDD_SYS_GPU 5036/5184 VDD_SYS_SOC 1068/1082 VDD_4V0_WIFI 0/0 "
    "VDD_IN 14025/14416 VDD_SYS_CPU 1294/1312 VDD_SYS_DDR 1525/1590"
)


def test_orin_jetpack6():
    p = tegrastats.parse_line(ORIN_JP6)
    assert (p["ram_used_mb"], p["ram_total_mb"]) == (2456, 7620)
    assert (p["swap_used_mb"], p["swap_total_mb"]) == (0, 3810)
    assert p["cpu_percent"] == [2.0, 1.0, 0.0, 0.0, None, None]
    assert p["cpu_mhz"] == [1510] * 4 + [None, None]
    assert p["gpu_percent"] == 12.0 and p["gpu_mhz"] == [1300, 1300]
    assert p["temps_c"]["tj"] == 47.5 and p["temps_c"]["gpu"] == 46.9
    assert len(p["temps_c"]) == 6
    assert p["rails_mw"] == {"VDD_IN": 4787.0, "VDD_CPU_GPU_CV": 598.0, "VDD_SOC": 1435.0}
    assert p["power_mw"] == 4787.0  # VDD_IN is the total, not the sum


def test_jetpack7_temperature_pairs():
    p = tegrastats.parse_line(JP7)
    assert p["temps_c"] == {"cpu": 45.2, "gpu": 44.1, "tj": 46.8}
    assert p["temps_max_c"] == {"cpu": 46.8, "gpu": 45.0, "tj": 48.0}
    assert p["cpu_percent"] == [3.0, 1.0, None]
    assert p["gpu_percent"] == 5.0
    assert p["power_mw"] == 1200.0 + 4500.0 + 9000.0  # no VDD_IN: sum of the rails


def test_older_orin_plain_gr3d():
    p = tegrastats.parse_line(ORIN_OLD)
    assert p["gpu_percent"] == 47.0 and p["gpu_mhz"] is None
    assert p["temps_c"]["tj"] == 41.468
    assert p["power_mw"] == 3913.0


def test_xavier_rails_without_unit():
    p = tegrastats.parse_line(XAVIER)
    assert p["rails_mw"]["GPU"] == 1155.0 and p["rails_mw"]["CPU"] == 311.0
    assert p["power_mw"] == 1155 + 311 + 1554 + 0 + 155 + 1283
    assert p["cpu_percent"][:2] == [1.0, 0.0] and p["cpu_percent"][2:] == [None] * 6
    assert p["gpu_percent"] == 0.0 and p["gpu_mhz"] == [318]
    assert p["temps_c"]["Tdiode"] == 38.5
    assert "APE" not in p["rails_mw"] and "RAM" not in p["rails_mw"]


def test_nano_pom_total_and_off_sensor():
    p = tegrastats.parse_line(NANO)
    assert p["power_mw"] == 933.0
    assert p["temps_c"]["iwlwifi"] is None  # −256 C means off
    assert p["temps_c"]["GPU"] == 23.5
    assert "IRAM" not in p["rails_mw"]
    s = tegrastats.summarize(p)
    assert s["tegra_power_w"] == pytest.approx(0.933)
    assert s["tegra_temp_max_c"] == 100.0
    assert s["tegra_cpu_percent"] == pytest.approx((24 + 15 + 13 + 10) / 4)


def test_tx2_vdd_in_total():
    p = tegrastats.parse_line(TX2)
    assert p["power_mw"] == 14025.0
    assert p["rails_mw"]["VDD_SYS_GPU"] == 5036.0
    assert p["cpu_percent"] == [35.0, None, None, 30.0, 28.0, 33.0]
    assert p["gpu_percent"] == 99.0


def test_empty_line_reports_nothing():
    p = tegrastats.parse_line("")
    assert p["power_mw"] is None and p["gpu_percent"] is None and p["cpu_percent"] is None
    assert all(v is None for v in tegrastats.summarize(p).values())


def test_rapl_counter_wraps():
    assert samplers.counter_delta(100, 250, 1000) == 150
    assert samplers.counter_delta(900, 50, 1000) == 150  # wrapped at max_energy_range_uj
    assert samplers.counter_delta(900, 50, None) == 0


def test_rapl_sensor_reads_fake_sysfs_with_wrap(tmp_path):
    zone = tmp_path / "intel-rapl:0"
    zone.mkdir()
    (zone / "max_energy_range_uj").write_text("1000000\n")
    (zone / "energy_uj").write_text("900000\n")
    sub = tmp_path / "intel-rapl:0:0"  # a subzone: already counted in the package
    sub.mkdir()
    (sub / "energy_uj").write_text("5\n")
    sensor = samplers.RaplSensor(str(tmp_path / "intel-rapl*"))
    assert sensor.available
    (zone / "energy_uj").write_text("100000\n")
    assert sensor.read()["rapl_energy_j"] == pytest.approx(0.2)


def test_absent_sensors_are_none_never_zero(tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "pynvml", None)  # import fails: no NVML
    monkeypatch.setattr(samplers.shutil, "which", lambda name: None)  # no tegrastats
    sensors = [
        samplers.NvmlSensor(),
        samplers.RaplSensor(str(tmp_path / "intel-rapl*")),  # no RAPL
        samplers.ThermalSensor(str(tmp_path / "thermal_zone*/temp")),
        samplers.TegrastatsSensor(),
    ]
    assert not any(s.available for s in sensors[:2]) and not sensors[3].available
    sampler = samplers.Sampler(sensors)
    row = sampler.sample()
    for column in (
        "gpu_util_percent",
        "gpu_power_w",
        "gpu_energy_j",
        "rapl_energy_j",
        "rapl_power_w",
        "tegra_gpu_percent",
        "tegra_power_w",
        "gpu",
        "power",
    ):
        assert row[column] is None, column
    assert sampler.availability()["nvml"] is False
    assert report.energy_j([{**row, "phase": "steady"}] * 3) is None
    path = tmp_path / "trace.csv"
    report.write_csv(path, [row])
    written = next(csv.DictReader(path.read_text().splitlines()))
    assert written["gpu_util_percent"] == "" and written["rapl_energy_j"] == ""


def test_combined_prefers_tegrastats_total_power():
    row = {"tegra_power_w": 5.0, "gpu_power_w": 100.0, "rapl_power_w": 20.0}
    assert samplers.combined(row)["power"] == 5.0
    assert samplers.combined({"gpu_power_w": 100.0, "rapl_power_w": 20.0})["power"] == 120.0


def test_truncate_idle_gpu_cuts_long_zero_stretches():
    t = np.arange(20.0)
    gpu = np.array([50.0] * 2 + [0.0] * 15 + [60.0] * 3)
    trace = {"time_s": t, "gpu": gpu, "cpu": gpu, "temp": gpu}
    cut = report.truncate_idle(trace, min_idle_s=3.0)
    assert cut["time_s"].size < t.size
    assert np.all(np.diff(cut["time_s"]) > 0)
    assert cut["gpu"][-1] == 60.0


def test_profile_bad_input_is_one_line(tmp_path, capsys):
    argv = ["profile", "--env", "escape_room-v0", "--controller", "evil", "--out", str(tmp_path)]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert (
        err.count("\n") == 1
        and "controller: unknown value 'evil'; allowed: benign, admo, admo_code" in err
    )
    assert cli.main(["profile", "--env", "escape_room-v0", "--duration", "0", "--out", "x"]) == 2


def test_paired_profile_end_to_end(tmp_path, capsys):
    out = tmp_path / "prof"
    argv = [
        "profile",
        "--env",
        "escape_room-v0",
        "n_agents=2",
        "min_at_lever=1",
        "--paired",
        "--duration",
        "1.5",
        "--hidden",
        "16",
        "8",
        "--update-every",
        "10",
        "--sample-hz",
        "4",
        "--out",
        str(out),
    ]
    assert cli.main(argv) == 0
    printed = capsys.readouterr().out
    assert "ADMO overhead" in printed and "decisions/s" in printed
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary) == {"benign", "admo", "admo_code", "comparison", "comparison_admo_code"}
    assert (out / "profile.png").stat().st_size > 0
    for controller in ("benign", "admo", "admo_code"):
        run = out / controller
        for name in ("trace.csv", "latency.csv", "updates.csv", "segments.csv", "summary.json"):
            assert (run / name).exists(), name
        s = summary[controller]
        assert s["config"]["controller"] == controller
        assert s["config"]["hidden"] == [16, 8] and s["config"]["cadences"] == [10]
        assert s["latency_ms"]["count"] > 0
        assert s["latency_ms"]["p50"] <= s["latency_ms"]["p99"] <= s["latency_ms"]["max"]
        assert s["decisions_per_s"] > 0
        assert s["update_ms"]["count"] > 0
        assert set(s["compile_s"]) == {"env_reset", "env_step", "decision", "update"}
        for key in ("warmup_s", "mean_power_w", "energy_j", "peak_temp_c", "sensors"):
            assert key in s
        assert s["sensors"]["psutil"] is True
        rows = list(csv.DictReader((run / "trace.csv").read_text().splitlines()))
        assert len(rows) >= 2 and {"cpu", "process_cpu", "gpu", "temp", "power"} <= set(rows[0])
        assert {r["controller"] for r in rows} <= {controller, ""}  # its own samples only
        lat = list(csv.DictReader((run / "latency.csv").read_text().splitlines()))
        assert len(lat) == s["latency_ms"]["count"]
        # every segment is whole cycles: `cadence` decisions, then one update
        segments = list(csv.DictReader((run / "segments.csv").read_text().splitlines()))
        assert len(segments) == s["config"]["rounds"]
        for seg in segments:
            assert int(seg["decisions"]) == 10 * int(seg["updates"]) > 0
        at = s["cadences"]["10"]
        assert at["decisions"] == 10 * at["updates"] == s["latency_ms"]["count"]
        lat_s = sum(float(r["latency_s"]) for r in lat)
        updates = csv.DictReader((run / "updates.csv").read_text().splitlines())
        upd_s = sum(float(r["time_s"]) for r in updates)
        assert at["amortized_ms"] == pytest.approx(1e3 * (lat_s + upd_s) / at["decisions"])
        cpus = sum(float(r["cpu_s"]) for r in segments)
        assert 0 < at["amortized_cpu_ms"] * at["decisions"] / 1e3 <= cpus  # inside segments
        assert "other_load_cores" in at
        cpu = at["process_cpu"]
        assert cpu["windows"] >= len(segments) and 0 < cpu["mean"] <= cpu["max"] <= 100.0
        assert cpu["one_core_mean"] == pytest.approx(cpu["mean"] * s["usable_cores"])
    # Only the controller differs between the paired runs.
    b = summary["benign"]["config"]
    for attacked in ("admo", "admo_code"):
        a = summary[attacked]["config"]
        assert {k for k in b if b[k] != a[k]} == {"controller"}
    comp = summary["comparison"]
    assert comp["latency_p50_ms"]["benign"] > 0
    assert "percent_of_decision" in comp["update_per_decision_ms"]
    # LIO's ER(2,1) training: 2 episodes per update of a 5-step horizon = the cadence run
    training = comp["training_cadence"]
    assert (training["episodes_per_update"], training["decisions_per_update"]) == (2, 10)
    assert 2 <= training["played_per_update"]["benign"] <= 10
    assert comp["judged_cadence"] == 10
    assert len(comp["cadences"]["10"]["per_round_percent"]) == b["rounds"]
    assert len(comp["cadences"]["10"]["per_round_cpu_percent"]) == b["rounds"]
    code = summary["comparison_admo_code"]
    assert code["judged_cadence"] == 10 and len(code["cadences"]["10"]["per_round_percent"])
    amortized = comp["cadences"]["10"]["amortized_ms"]
    assert amortized["percent"] == pytest.approx(
        100 * (amortized["admo"] - amortized["benign"]) / amortized["benign"]
    )
    # the report section judges it in the verdict vocabulary
    from pimbot.analysis.document import Context
    from pimbot.analysis.sections import device

    suite = tmp_path / "suite" / device.PROFILE_RUN
    suite.parent.mkdir(parents=True)
    out.rename(suite)
    section = device.profile_section(None, Context(tmp_path / "suite", tmp_path / "rep", {}))
    (claim,) = section.claims
    assert claim.judged.kind in verdicts.KINDS and claim.judged.kind != verdicts.NOT_RUN
    assert "10 decisions per update" in claim.measured
    assert any("10 (training)" in str(row[0]) for row in section.tables[0].rows)


def test_training_cadence_follows_the_horizon():
    """Derived from the learner and env, not a constant: a 7-step horizon makes 14."""
    config = ProfileConfig(hidden=(8,), env_params=(("max_steps", 7),))
    assert cadence.of_profile(config) == {
        "episodes_per_update": 2,
        "max_steps": 7,
        "decisions_per_update": 14,
    }


def test_process_cpu_is_the_process_not_the_machine():
    """A sleeping process reads ~0 % whatever else the machine runs; a busy one > 0."""
    import time

    start_wall, start_cpu = time.perf_counter(), process_cpu.seconds()
    time.sleep(0.3)
    idle = process_cpu.seconds() - start_cpu, time.perf_counter() - start_wall
    start_wall, start_cpu = time.perf_counter(), process_cpu.seconds()
    while time.perf_counter() - start_wall < 0.3:
        pass
    busy = process_cpu.seconds() - start_cpu, time.perf_counter() - start_wall
    assert idle[0] / idle[1] < 0.1
    assert busy[0] / busy[1] > 0.1
    assert 1 <= process_cpu.usable_cores() <= (os.cpu_count() or 1)


def test_process_cpu_stats_weight_windows_by_time_and_count_cores():
    windows = [(1.0, 1.0), (1.0, 0.0), (2.0, 1.0)]  # (wall s, CPU s)
    s = process_cpu.stats(windows, cores=2)
    assert s["mean"] == pytest.approx(100 * 2.0 / 4.0 / 2)  # time-weighted, of 2 cores
    assert s["max"] == pytest.approx(50.0) and s["one_core_mean"] == pytest.approx(50.0)
    assert s["windows"] == 3 and 25.0 < s["p95"] <= 50.0
    assert process_cpu.stats([], cores=2)["mean"] is None


def test_sampler_rows_carry_their_segment_and_breaks_span_gaps():
    sampler = samplers.Sampler([])
    sampler.tags = {"phase": "steady", "controller": "admo", "cadence": 10}
    row = sampler.sample()
    assert (row["phase"], row["controller"], row["cadence"]) == ("steady", "admo", 10)
    t, y = report.with_breaks(np.array([0.0, 1.0, 2.0, 6.0, 7.0]), np.arange(5.0))
    assert t.size == 6 and np.isnan(y[3]) and 2.0 < t[3] < 6.0


def test_config_refuses_bad_cadences():
    for bad in ((), (0,), (2, -1), (1.5,)):
        with pytest.raises(InvalidParameter, match="cadences"):
            ProfileConfig(cadences=bad)
    with pytest.raises(InvalidParameter, match="rounds"):
        ProfileConfig(rounds=0)


def _summary(
    per_round,
    cpu_mean=40.0,
    benign_cpu=40.0,
    judged=10,
    slowest_percent=5.0,
    other_load=0.1,
    per_round_cpu=None,
    gpu=None,
):
    """A paired profile's summary with what judge_c8 reads: overheads per round at the
    judged cadence (by wall clock and by CPU time), a 100-decision cadence at
    `slowest_percent`, `other_load` cores of other work on the machine."""

    def run(update_ms, cpu):
        entry = {
            "updates": 50,
            "update_ms": {"mean": update_ms},
            "latency_ms": {"mean": 1.0},
            "update_cpu_ms": update_ms,
            "decision_cpu_ms": 1.0,
            "amortized_ms": 1.0 + update_ms / judged,
            "amortized_cpu_ms": 1.0 + update_ms / judged,
            "amortized_p50_ms": 1.0 + update_ms / judged,
            "process_cpu": {"mean": cpu, "p95": cpu, "max": cpu},
            "other_load_cores": other_load,
            "mean_gpu_percent": gpu,
        }
        return {"usable_cores": 2, "process_cpu": entry["process_cpu"], "mean_gpu_percent": gpu,
                "other_load_cores": other_load, "cadences": {str(judged): entry}}  # fmt: skip

    def percent(values):
        return {"percent": float(np.mean(values))}

    cpu_rounds = list(per_round if per_round_cpu is None else per_round_cpu)
    cadences = {
        str(judged): {
            "per_round_percent": list(per_round),
            "per_round_cpu_percent": cpu_rounds,
            "amortized_ms": percent(per_round),
            "amortized_cpu_ms": percent(cpu_rounds),
            "amortized_p50_ms": percent(per_round),
        },
        "100": {
            "amortized_ms": {"percent": slowest_percent},
            "amortized_cpu_ms": {"percent": slowest_percent},
        },
    }
    return {
        "benign": run(2.0, benign_cpu),
        "admo": run(4.0, cpu_mean),
        "comparison": {
            "training_cadence": {
                "episodes_per_update": 2,
                "max_steps": 5,
                "decisions_per_update": 10,
            },  # fmt: skip
            "judged_cadence": judged,
            "cadences": cadences,
        },
    }


LOW = [5, 8, 6, 7, 9, 4]
HIGH = [60, 62, 58, 61, 59, 63]


def test_c8_verdicts_from_the_numbers():
    """C8 is judged on "bursty" and "no sustained saturation"; the overhead is a
    measurement with its interval whatever its size (the paper gives none)."""
    from pimbot.analysis.sections.device import judge_c8

    assert judge_c8(_summary(LOW))[0].kind == verdicts.REPRODUCED
    dear, measured, short, numbers = judge_c8(_summary(HIGH))
    assert dear.kind == verdicts.REPRODUCED  # ADMO's update 4 ms vs 2 ms: bursty
    assert "2.0x a benign" in measured and "+60.5" in measured and "(measured)" in short
    assert numbers[0].paper == "modest (no size given)" and numbers[1].pimbot == "100 %"
    spread = _summary(HIGH)  # ADMO's decisions, not its updates, carry the extra time
    spread["admo"]["cadences"]["10"]["amortized_ms"] = 3.0
    smooth = judge_c8(spread)[0]
    assert smooth.kind == verdicts.INCONCLUSIVE and "decisions carry most" in smooth.reason
    saturated = judge_c8(_summary(LOW, cpu_mean=95.0))[0]
    assert saturated.kind == verdicts.INCONCLUSIVE  # ADMO alone saturates: no cause shown
    assert "saturated under ADMO only" in saturated.reason and "no cause" in saturated.reason
    machine = judge_c8(_summary(LOW, cpu_mean=95.0, benign_cpu=95.0))[0]
    assert machine.causes == (verdicts.BUDGET,)
    summary = _summary(LOW)
    summary["comparison"]["judged_cadence"] = None
    missing = judge_c8(summary)[0]
    assert missing.kind == verdicts.INCONCLUSIVE and "not profiled" in missing.reason


def test_c8_shows_the_published_codes_admo_beside_ours():
    from pimbot.analysis.sections.device import judge_c8

    summary = _summary(HIGH)
    summary["comparison_admo_code"] = {
        "cadences": {"10": {"per_round_percent": LOW, "per_round_cpu_percent": LOW}}
    }
    verdict, measured, _, _ = judge_c8(summary)
    assert not verdict.causes and "the published code's ADMO +6.5" in measured


def test_c8_on_a_shared_machine_is_judged_on_cpu_time():
    """Other work on the machine lengthens short decisions more than updates: the
    wall-clock overhead (LOW) is not the controller's; its CPU time (HIGH) is judged."""
    from pimbot.analysis.sections.device import judge_c8

    verdict, measured, short, _ = judge_c8(_summary(LOW, other_load=1.5, per_round_cpu=HIGH))
    assert verdict.kind == verdicts.INCONCLUSIVE and "machine was shared" in verdict.reason
    assert "+60.5" in measured and "CPU time" in measured  # the CPU-time overhead shown
    assert "1.5 cores of other work" in measured and "CPU time" in short
    quiet = judge_c8(_summary(LOW, other_load=0.2, per_round_cpu=HIGH))[0]
    assert quiet.kind == verdicts.REPRODUCED
    _, measured, _, _ = judge_c8(_summary(LOW, other_load=0.2, per_round_cpu=HIGH))
    assert "wall-clock time) +6.5" in measured
    unsampled = _summary(LOW, other_load=1.5, per_round_cpu=HIGH)  # segments under a sample
    for name in ("benign", "admo"):
        unsampled[name]["cadences"]["10"]["other_load_cores"] = None
    assert "CPU time" in judge_c8(unsampled)[1]  # the whole steady state's load
    with_gpu = judge_c8(_summary(LOW, other_load=1.5, per_round_cpu=HIGH, gpu=10.0))[0]
    assert with_gpu.kind == verdicts.INCONCLUSIVE and "GPU" in with_gpu.reason
