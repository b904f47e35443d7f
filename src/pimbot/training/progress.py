"""Progress display for long runs: a live bar on a terminal, periodic lines elsewhere."""

from __future__ import annotations

import sys
import time


class Progress:
    """Shows iterations done, iterations/s, ETA and the current success."""

    def __init__(self, title: str, total: int, done: int = 0, enabled: bool = True):
        self.title, self.total, self.start_done = title, total, done
        self.done = done
        self.enabled = enabled
        self.t0 = time.perf_counter()
        self.last_line = 0.0
        self._bar = None
        if enabled and sys.stderr.isatty():
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                TextColumn,
                TimeRemainingColumn,
            )
            from rich.progress import Progress as RichProgress

            self._bar = RichProgress(
                TextColumn("{task.description}"),
                BarColumn(bar_width=12),
                MofNCompleteColumn(),
                TextColumn("{task.fields[rate]} it/s  success {task.fields[success]}"),
                TimeRemainingColumn(),
                transient=False,
            )
            self._task = self._bar.add_task(
                title, total=total, completed=done, rate="-", success="-"
            )
            self._bar.start()

    def rate(self) -> float:
        elapsed = time.perf_counter() - self.t0
        return (self.done - self.start_done) / elapsed if elapsed > 0 else 0.0

    def update(self, done: int, success: float) -> None:
        self.done = done
        if not self.enabled:
            return
        rate = self.rate()
        if self._bar is not None:
            self._bar.update(
                self._task, completed=done, rate=f"{rate:,.0f}", success=f"{success:.2f}"
            )
            return
        now = time.perf_counter()
        if now - self.last_line >= 5.0 or done >= self.total:
            self.last_line = now
            eta = (self.total - done) / rate if rate > 0 else float("nan")
            print(
                f"{self.title}: {done}/{self.total} iterations, {rate:,.0f} it/s, "
                f"success {success:.2f}, ETA {eta:,.0f} s",
                file=sys.stderr,
                flush=True,
            )

    def close(self) -> None:
        if self._bar is not None:
            self._bar.stop()


class CompileNotice:
    """`compiling TITLE … N s` on stderr while a program compiles, then how long it took.

    On a terminal the line counts the seconds (rich redraws it from its own thread,
    which runs while XLA compiles); elsewhere one line before and one after.
    """

    def __init__(self, title: str, enabled: bool = True):
        self.title, self.enabled = title, enabled
        self.seconds = 0.0
        self._live = None

    def __enter__(self) -> CompileNotice:
        self.t0 = time.perf_counter()
        if not self.enabled:
            return self
        if sys.stderr.isatty():
            from rich.progress import Progress as RichProgress
            from rich.progress import SpinnerColumn, TextColumn

            self._live = RichProgress(
                SpinnerColumn(),
                TextColumn("compiling {task.description} … {task.elapsed:.0f} s"),
                transient=True,
            )
            self._live.add_task(self.title, total=None)
            self._live.start()
        else:
            print(f"compiling {self.title} …", file=sys.stderr, flush=True)
        return self

    def __exit__(self, *exc) -> None:
        self.seconds = time.perf_counter() - self.t0
        if self._live is not None:
            self._live.stop()
        if self.enabled and exc[0] is None:
            print(f"compiled {self.title} in {self.seconds:.1f} s", file=sys.stderr, flush=True)
