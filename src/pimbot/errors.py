"""The ground floor of every check: `InvalidParameter` and the one integer check.

Every layer raises `InvalidParameter` for a value a user gave that cannot be used; the
command line turns it into one line (the message names the field and what is allowed)
and exit code 2.
"""

from __future__ import annotations

from collections.abc import Collection
from typing import Any


class InvalidParameter(ValueError):
    """A bad environment (or other) parameter; the message names the field and what is allowed."""


def check_choice(name: str, value: Any, allowed: Collection[str]) -> None:
    """Raises InvalidParameter unless `value` is one of `allowed` (the message lists them)."""
    if value not in allowed:
        raise InvalidParameter(f"{name}: must be one of {', '.join(allowed)}, got {value!r}")


def check_int(name: str, value: Any, low: int, high: int | None = None) -> None:
    """Raises InvalidParameter unless `value` is an int (not a bool) in [low, high]
    (no upper bound where `high` is None)."""
    allowed = f"≥ {low}" if high is None else f"in [{low}, {high}]"
    out_of_range = not isinstance(value, int) or value < low or (high is not None and value > high)
    if isinstance(value, bool) or out_of_range:
        raise InvalidParameter(f"{name}: must be an integer {allowed}, got {value!r}")
