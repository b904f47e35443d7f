"""The marks the command classes (`pimbot.cli.commands`) put on their options, and the
defaults their code shares: what the modules below the command classes read of them.

`parsing` reads the marks (`PAIRS`, `Registered`, `Spelling`, `FromRun`) to turn a
command line, a --config file or a saved run into a command object; the code of
`pimbot check` reads `CHECK_ENV`. Neither imports the command classes, which import the
code of every command (`run`): so the command classes sit on top, and this module, which
imports nothing of pimbot, at the bottom.
"""

import dataclasses
from collections.abc import Callable
from typing import Any, Literal

PAIRS = "pimbot:name=value"
"""Marks a field holding `name=value` strings; a --config file may give it a table."""


@dataclasses.dataclass(frozen=True)
class Registered:
    """Marks an option whose values are names in one of pimbot's registries."""

    registry: Literal["envs", "learners", "attacks", "defenses"]
    """The registry (`pimbot.envs`, ...); `pimbot <registry>` lists its names."""


@dataclasses.dataclass(frozen=True)
class Spelling:
    """An option's flag when it is not `--field-name`, and its aliases (as given to tyro)."""

    name: str | None = None
    aliases: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class FromRun:
    """Marks a train option that `--from RUN_DIR` takes from the saved `RunConfig` field
    `field` (through `convert`); an option named like a RunConfig field needs no mark."""

    field: str
    convert: Callable[[Any], Any] = dict


CHECK_ENV = "escape_room-v0"
"""The env `pimbot check` runs attacks, defenses and learners on where the file has none."""
