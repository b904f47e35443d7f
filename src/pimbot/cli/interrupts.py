"""SIGTERM handled like Ctrl-C: `Terminated`, the KeyboardInterrupt the `pimbot` process
raises on SIGTERM (`raise_terminated`, the handler `pimbot.cli.main` installs), so that
every command stops as it stops on Ctrl-C and says which of the two stopped it."""

from __future__ import annotations


class Terminated(KeyboardInterrupt):
    """SIGTERM, handled like Ctrl-C: the checkpoint and metrics already written stay
    consistent (each chunk's are written atomically), so the same command resumes."""


def raise_terminated(signum, frame) -> None:
    """The SIGTERM handler: raises `Terminated` where the process is."""
    raise Terminated
