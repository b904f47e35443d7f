"""Parsing `tegrastats` lines (Jetson) into flat dicts.

One pure function, `parse_line`, accepts the known formats: Orin (JetPack 6)
`GR3D_FREQ 12%@[1300,1300]`, JetPack 7 `name@T/maxC` temperature pairs, older
Orin `GR3D_FREQ 47%`, Xavier rails without a unit (`GPU 1155/1155`), Nano
`POM_5V_IN 933/933`, TX2 `VDD_IN 14025/14416`, and disabled cores `off`.
Sensors reporting −256 C are off and become None.
"""

from __future__ import annotations

import re
from typing import Any

_RAM = re.compile(r"\bRAM (\d+)/(\d+)MB")
_SWAP = re.compile(r"\bSWAP (\d+)/(\d+)MB")
_CPU = re.compile(r"\bCPU \[([^\]]*)\]")
_CORE = re.compile(r"^(\d+)%(?:@(\d+))?$")
_GR3D = re.compile(r"\bGR3D_FREQ (\d+)%(?:@\[?([\d,]+)\]?)?")
_TEMP = re.compile(r"(?<![\w@])([A-Za-z][\w-]*)@(-?\d+(?:\.\d+)?)C?(?:/(-?\d+(?:\.\d+)?))?C\b")
_RAIL = re.compile(r"(?<![\w/])([A-Z][A-Z0-9_]*) (\d+)(?:mW)?/(\d+)(?:mW)?(?![\w/])")
_TOTAL_RAILS = ("VDD_IN", "POM_5V_IN")
_OFF_TEMP = -256.0


def parse_line(line: str) -> dict[str, Any]:
    """Parses one tegrastats line.

    Returns:
        dict with keys (each None when the line does not report it):
        ram_used_mb, ram_total_mb, swap_used_mb, swap_total_mb,
        cpu_percent (list, None per disabled core), cpu_mhz (list),
        gpu_percent, gpu_mhz (list), temps_c ({name: °C or None if off}),
        temps_max_c ({name: °C} where a max is printed), rails_mw
        ({name: current mW}), power_mw (VDD_IN / POM_5V_IN if present,
        else the sum of the rails).
    """
    out: dict[str, Any] = {
        "ram_used_mb": None,
        "ram_total_mb": None,
        "swap_used_mb": None,
        "swap_total_mb": None,
        "cpu_percent": None,
        "cpu_mhz": None,
        "gpu_percent": None,
        "gpu_mhz": None,
        "temps_c": {},
        "temps_max_c": {},
        "rails_mw": {},
        "power_mw": None,
    }
    if m := _RAM.search(line):
        out["ram_used_mb"], out["ram_total_mb"] = int(m[1]), int(m[2])
    if m := _SWAP.search(line):
        out["swap_used_mb"], out["swap_total_mb"] = int(m[1]), int(m[2])
    if m := _CPU.search(line):
        percents, mhz = [], []
        for core in m[1].split(","):
            c = _CORE.match(core.strip())
            percents.append(float(c[1]) if c else None)
            mhz.append(int(c[2]) if c and c[2] else None)
        out["cpu_percent"], out["cpu_mhz"] = percents, mhz
    if m := _GR3D.search(line):
        out["gpu_percent"] = float(m[1])
        out["gpu_mhz"] = [int(f) for f in m[2].split(",") if f] if m[2] else None
    for m in _TEMP.finditer(line):
        value = float(m[2])
        out["temps_c"][m[1]] = None if value <= _OFF_TEMP else value
        if m[3] is not None:
            out["temps_max_c"][m[1]] = None if float(m[3]) <= _OFF_TEMP else float(m[3])
    for m in _RAIL.finditer(line):
        out["rails_mw"][m[1]] = float(m[2])
    rails = out["rails_mw"]
    total = next((rails[name] for name in _TOTAL_RAILS if name in rails), None)
    if total is None and rails:
        total = sum(rails.values())
    out["power_mw"] = total
    return out


def summarize(parsed: dict[str, Any]) -> dict[str, float | None]:
    """The trace columns of one parsed line (None where not reported)."""
    cores = [c for c in parsed["cpu_percent"] or [] if c is not None]
    temps = [t for t in parsed["temps_c"].values() if t is not None]
    power = parsed["power_mw"]
    return {
        "tegra_cpu_percent": sum(cores) / len(cores) if cores else None,
        "tegra_gpu_percent": parsed["gpu_percent"],
        "tegra_ram_used_mb": parsed["ram_used_mb"],
        "tegra_temp_max_c": max(temps) if temps else None,
        "tegra_power_w": power / 1000.0 if power is not None else None,
    }
