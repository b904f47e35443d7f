"""Hardware sensors sampled in a background thread.

Each sensor is a small object with `name`, `available` and `read() -> dict`.
A sensor that is absent or unreadable is unavailable: its columns are None
(null in JSON, empty in CSV), never 0. `Sampler` polls all sensors at a fixed
rate and keeps one flat row per sample.
"""

from __future__ import annotations

import contextlib
import glob
import os
import queue
import shutil
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

from pimbot.profiling import process_cpu, tegrastats

RAPL_GLOB = "/sys/class/powercap/intel-rapl*"


def counter_delta(previous: int, current: int, max_range: int | None) -> int:
    """Increase of a wrapping energy counter between two reads.

    A counter that went down wrapped once at `max_range` (RAPL's
    max_energy_range_uj); without a known range the delta is taken as 0.
    """
    if current >= previous:
        return current - previous
    if max_range is None:
        return 0
    return max_range - previous + current


class PsutilSensor:
    """System-wide total and per-core CPU %, the process's own CPU % (all its threads;
    100 = one core), process RSS, CPU frequency (psutil)."""

    name = "psutil"

    def __init__(self):
        try:
            import psutil
        except ImportError:
            self._psutil = None
            self.available = False
            return
        self._psutil = psutil
        self._process = psutil.Process()
        self.cores = psutil.cpu_count() or 0
        psutil.cpu_percent(percpu=True)  # the first call only sets the reference point
        self._process.cpu_percent()  # likewise
        self._last_cpu_read = time.monotonic()
        self.available = True

    def read(self) -> dict[str, Any]:
        if not self.available:
            return {
                "cpu_percent": None,
                "process_cpu_percent": None,
                "rss_mb": None,
                "cpu_freq_mhz": None,
            }
        per_core = self._psutil.cpu_percent(percpu=True)
        process = self._process.cpu_percent()
        now = time.monotonic()
        since = now - self._last_cpu_read
        self._last_cpu_read = now
        if since < 0.05:  # too short an interval to measure: unknown, not 0
            per_core, process = [None] * len(per_core), None
        freq = None
        try:
            f = self._psutil.cpu_freq()
            freq = float(f.current) if f is not None and f.current else None
        except (OSError, NotImplementedError, AttributeError):
            freq = None
        row: dict[str, Any] = {
            "cpu_percent": sum(per_core) / len(per_core)
            if per_core and None not in per_core
            else None,
            "process_cpu_percent": process,
            "rss_mb": self._process.memory_info().rss / 2**20,
            "cpu_freq_mhz": freq,
        }
        for i, value in enumerate(per_core):
            row[f"cpu{i}_percent"] = value
        return row


class NvmlSensor:
    """GPU util %, memory, power, temperature, energy (NVML via nvidia-ml-py), GPU 0."""

    name = "nvml"
    _EMPTY = {
        "gpu_util_percent": None,
        "gpu_mem_used_mb": None,
        "gpu_power_w": None,
        "gpu_temp_c": None,
        "gpu_energy_j": None,
    }

    def __init__(self, index: int = 0):
        self.available = False
        self._last_energy_mj = None
        try:
            import pynvml

            pynvml.nvmlInit()
            self._nvml = pynvml
            self._handle = pynvml.nvmlDeviceGetHandleByIndex(index)
            self.available = True
        except Exception:  # no library, no driver or no GPU: unavailable
            return
        self._last_energy_mj = self._energy_mj()

    def _try(self, fn, *args):
        try:
            return fn(self._handle, *args)
        except Exception:  # a field the device does not support
            return None

    def _energy_mj(self):
        return self._try(self._nvml.nvmlDeviceGetTotalEnergyConsumption)

    def read(self) -> dict[str, Any]:
        if not self.available:
            return dict(self._EMPTY)
        util = self._try(self._nvml.nvmlDeviceGetUtilizationRates)
        mem = self._try(self._nvml.nvmlDeviceGetMemoryInfo)
        power = self._try(self._nvml.nvmlDeviceGetPowerUsage)
        temp = self._try(self._nvml.nvmlDeviceGetTemperature, self._nvml.NVML_TEMPERATURE_GPU)
        energy = self._energy_mj()
        delta = None
        if energy is not None and self._last_energy_mj is not None:
            delta = counter_delta(self._last_energy_mj, energy, None) / 1000.0
        self._last_energy_mj = energy
        return {
            "gpu_util_percent": float(util.gpu) if util is not None else None,
            "gpu_mem_used_mb": mem.used / 2**20 if mem is not None else None,
            "gpu_power_w": power / 1000.0 if power is not None else None,
            "gpu_temp_c": float(temp) if temp is not None else None,
            "gpu_energy_j": delta,
        }

    def close(self) -> None:
        if self.available:
            with contextlib.suppress(Exception):
                self._nvml.nvmlShutdown()


class RaplSensor:
    """CPU package energy from /sys/class/powercap/intel-rapl*/energy_uj (top-level zones)."""

    name = "rapl"

    def __init__(self, pattern: str = RAPL_GLOB):
        self._zones: list[tuple[Path, int | None]] = []
        self._last: dict[Path, int] = {}
        for zone in sorted(glob.glob(pattern)):
            path = Path(zone)
            if path.name.count(":") != 1:  # packages only; subzones are counted in them
                continue
            value = _read_int(path / "energy_uj")
            if value is None:
                continue
            self._zones.append((path, _read_int(path / "max_energy_range_uj")))
            self._last[path] = value
        self._last_time = time.monotonic()
        self.available = bool(self._zones)

    def read(self) -> dict[str, Any]:
        if not self.available:
            return {"rapl_energy_j": None, "rapl_power_w": None}
        now = time.monotonic()
        total_uj = 0
        for path, max_range in self._zones:
            value = _read_int(path / "energy_uj")
            if value is None:
                return {"rapl_energy_j": None, "rapl_power_w": None}
            total_uj += counter_delta(self._last[path], value, max_range)
            self._last[path] = value
        elapsed, self._last_time = now - self._last_time, now
        energy = total_uj / 1e6
        return {"rapl_energy_j": energy, "rapl_power_w": energy / elapsed if elapsed > 0 else None}


class ThermalSensor:
    """Highest temperature over psutil.sensors_temperatures / thermal zones."""

    name = "thermal"

    def __init__(self, zone_glob: str = "/sys/class/thermal/thermal_zone*/temp"):
        self._zone_glob = zone_glob
        self.available = self._max_temp() is not None

    def _max_temp(self) -> float | None:
        temps: list[float] = []
        try:
            import psutil

            for entries in (getattr(psutil, "sensors_temperatures", dict)() or {}).values():
                temps += [e.current for e in entries if e.current is not None and e.current > -256]
        except Exception:
            pass
        if not temps:
            for path in glob.glob(self._zone_glob):
                value = _read_int(Path(path))
                if value is not None and value > -256000:
                    temps.append(value / 1000.0)
        return max(temps) if temps else None

    def read(self) -> dict[str, Any]:
        return {"temp_max_c": self._max_temp() if self.available else None}


class TegrastatsSensor:
    """A live `tegrastats --interval MS` subprocess, parsed line by line."""

    name = "tegrastats"
    _EMPTY = {k: None for k in tegrastats.summarize(tegrastats.parse_line(""))}

    def __init__(self, interval_ms: int = 1000, binary: str = "tegrastats"):
        path = shutil.which(binary)
        self.available = False
        self._lines: queue.Queue[str] = queue.Queue()
        self._latest: dict[str, Any] = dict(self._EMPTY)
        self._proc = None
        if path is None:
            return
        try:
            self._proc = subprocess.Popen(
                [path, "--interval", str(interval_ms)],
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
                text=True,
            )
        except OSError:
            return
        self.available = True
        threading.Thread(target=self._pump, daemon=True).start()

    def _pump(self) -> None:
        for line in self._proc.stdout:
            self._lines.put(line)

    def read(self) -> dict[str, Any]:
        while True:
            try:
                line = self._lines.get_nowait()
            except queue.Empty:
                break
            self._latest = tegrastats.summarize(tegrastats.parse_line(line))
        return dict(self._latest)

    def close(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(timeout=2)
            except subprocess.TimeoutExpired:
                self._proc.kill()


def _read_int(path: Path) -> int | None:
    try:
        return int(path.read_text().strip())
    except (OSError, ValueError):
        return None


def default_sensors(sample_hz: float) -> list:
    """Every sensor kind; absent ones come back unavailable."""
    return [
        PsutilSensor(),
        NvmlSensor(),
        RaplSensor(),
        ThermalSensor(),
        TegrastatsSensor(interval_ms=max(int(1000 / sample_hz), 10)),
    ]


def combined(row: dict[str, Any]) -> dict[str, Any]:
    """Source-independent columns for the figure and summary: cpu % (system-wide), process
    cpu % (this process, of the cores it may use), gpu %, temp, power."""

    def first(*names):
        return next((row[n] for n in names if row.get(n) is not None), None)

    temps = [row[n] for n in ("temp_max_c", "gpu_temp_c", "tegra_temp_max_c") if row.get(n)]
    power = row.get("tegra_power_w")
    if power is None:
        parts = [row[n] for n in ("gpu_power_w", "rapl_power_w") if row.get(n) is not None]
        power = sum(parts) if parts else None
    process = row.get("process_cpu_percent")
    return {
        "cpu": first("tegra_cpu_percent", "cpu_percent"),
        "process_cpu": None if process is None else process / process_cpu.usable_cores(),
        "gpu": first("tegra_gpu_percent", "gpu_util_percent"),
        "temp": max(temps) if temps else None,
        "power": power,
    }


class Sampler:
    """Polls `sensors` every 1/`sample_hz` s in a daemon thread; rows in `self.rows`.

    Each row carries `self.tags` as they are when it is taken (the phase, and the
    controller and cadence running); a sensor's interval value (CPU %) covers the time
    since the previous sample, so a row just after a change of tags partly describes
    the part before."""

    def __init__(self, sensors: list, sample_hz: float = 1.0):
        self.sensors = sensors
        self.period = 1.0 / sample_hz
        self.rows: list[dict[str, Any]] = []
        self.tags: dict[str, Any] = {"phase": "warmup"}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._t0 = time.monotonic()

    def availability(self) -> dict[str, bool]:
        return {s.name: bool(s.available) for s in self.sensors}

    def sample(self) -> dict[str, Any]:
        row: dict[str, Any] = {"time_s": time.monotonic() - self._t0, **self.tags}
        for sensor in self.sensors:
            row.update(sensor.read())
        row.update(combined(row))
        return row

    def _run(self) -> None:
        next_time = time.monotonic()
        while not self._stop.is_set():
            self.rows.append(self.sample())
            next_time += self.period
            self._stop.wait(max(next_time - time.monotonic(), 0.0))

    def __enter__(self) -> Sampler:
        self._t0 = time.monotonic()
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self.rows.append(self.sample())  # one closing sample, so short runs have ≥ 2
        for sensor in self.sensors:
            if hasattr(sensor, "close"):
                sensor.close()


def pin_cpus(cpus: list[int]) -> None:
    """Pins this process to `cpus` (os.sched_setaffinity), where supported."""
    if not hasattr(os, "sched_setaffinity"):
        raise OSError("CPU pinning is not supported on this platform")
    os.sched_setaffinity(0, set(cpus))
