"""Checked numeric parameters of attacks and defenses (one line naming the field)."""

from __future__ import annotations

import math
from typing import Any

from pimbot.envs.core import InvalidParameter


def is_number(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | float)


def check_number(
    name: str,
    value: Any,
    low: float | None = None,
    high: float | None = None,
    *,
    strict_low: bool = False,
) -> None:
    """Raises InvalidParameter unless `value` is a finite number in the range."""
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
