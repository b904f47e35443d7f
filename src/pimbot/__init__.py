"""pimbot: stress-testing incentive-based multi-agent RL against manipulation."""

from __future__ import annotations

import importlib

from pimbot import moved

__version__ = "0.2.0"

_LAZY = {
    "train": "pimbot.cli.api",
    "sweep": "pimbot.cli.api",
    "report": "pimbot.cli.api",
    "load_run": "pimbot.cli.api",
    "Run": "pimbot.cli.api",
    "Policy": "pimbot.cli.api",
    "Incentive": "pimbot.cli.api",
    "Suite": "pimbot.cli.api",
    "make": "pimbot.envs",
}
"""The Python API (docs/usage.md, "Python API"): name -> the module that defines it. They
load on first use, so `import pimbot` stays light (no JAX: `pimbot --help` answers at
once). The package root is the door to the top layer here: nothing inside pimbot uses
these names (tests/test_layers.py)."""

__all__ = ["__version__", *_LAZY]

moved.install()


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module 'pimbot' has no attribute {name!r}")
    value = getattr(importlib.import_module(_LAZY[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
