"""Checked numeric parameters of attacks and defenses (one line naming the field)."""

from __future__ import annotations

import math
from typing import Any

from pimbot.errors import InvalidParameter


def is_number(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | float)


MAX_MAGNITUDE = 1e6
"""A parameter without a declared bound must still lie in [−1e6, 1e6]: beyond, float32
training overflows or stalls, so a value like 1e30 is a typo, not an experiment."""


def check_number(
    name: str,
    value: Any,
    low: float | None = None,
    high: float | None = None,
    *,
    strict_low: bool = False,
) -> None:
    """Raises InvalidParameter unless `value` is a finite number in the range (an absent
    bound is ±`MAX_MAGNITUDE`)."""
    low = -MAX_MAGNITUDE if low is None else low
    high = MAX_MAGNITUDE if high is None else high
    lower = "" if low is None else (f"> {low:g}" if strict_low else f"≥ {low:g}")
    upper = "" if high is None else f"≤ {high:g}"
    bound = " and ".join(b for b in (lower, upper) if b)
    what = f"a finite number{' ' + bound if bound else ''}"
    if not is_number(value) or not math.isfinite(value):
        raise InvalidParameter(f"{name}: must be {what}, got {value!r}")
    too_low = low is not None and (value < low or (strict_low and value == low))
    if too_low or (high is not None and value > high):
        raise InvalidParameter(f"{name}: must be {bound}, got {value!r}")


def check_int(name: str, value: Any, low: int) -> None:
    """Raises InvalidParameter unless `value` is an integer ≥ `low`."""
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise InvalidParameter(f"{name}: must be an integer ≥ {low}, got {value!r}")


def describe_range(bounds: tuple[float | None, float | None]) -> str:
    """ "in [0, 1]" / "≥ 0" / "≤ 1" / "" for (low, high) bounds (None: unbounded)."""
    low, high = bounds
    if low is not None and high is not None:
        return f"in [{low:g}, {high:g}]"
    if low is not None:
        return f"≥ {low:g}"
    return f"≤ {high:g}" if high is not None else ""


def field_ranges(config: Any, default_low: float | None = 0.0) -> dict[str, tuple]:
    """name -> (low, high) of every numeric field of a frozen config: its class's `RANGES`
    where declared, else ≥ 1 for a tuple (layer widths) and ≥ `default_low` for a number
    (hyperparameters are rates, weights and counts)."""
    import dataclasses

    declared = getattr(type(config), "RANGES", {})
    ranges = {}
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        if not (is_number(value) or isinstance(value, tuple)):
            continue
        default = (1, None) if isinstance(value, tuple) else (default_low, None)
        ranges[field.name] = declared.get(field.name, default)
    return ranges


def check_fields(config: Any, default_low: float | None = 0.0) -> None:
    """Checks every numeric field of a frozen config against `field_ranges` (for a tuple
    field, each element), finite and within ±`MAX_MAGNITUDE` where no bound is declared.
    Raises InvalidParameter naming the field and its range."""
    import dataclasses

    ranges = field_ranges(config, default_low)
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        items = value if isinstance(value, tuple) else (value,)
        for index, item in enumerate(items):
            name = field.name if not isinstance(value, tuple) else f"{field.name}[{index}]"
            if not is_number(item):
                continue
            low, high = ranges[field.name]
            if isinstance(item, int) and isinstance(field.default, int | tuple):
                if low is not None and item < low or high is not None and item > high:
                    raise InvalidParameter(
                        f"{name}: must be an integer {describe_range((low, high))}, got {item!r}"
                    )
                continue
            check_number(name, item, low, high)
