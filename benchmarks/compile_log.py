"""Where the test suite's compile time goes: every XLA compile of each test, by test.

    COMPILE_LOG_DIR=DIR PYTHONPATH=benchmarks python -m pytest -p compile_log   # record
    python benchmarks/compile_log.py DIR                                          # read

As a pytest plugin (`-p compile_log`, loaded by every xdist worker too) it turns on
`jax_log_compiles` and appends one JSON line per test to DIR/<worker>.jsonl: the test,
its wall time, and each compile JAX logged in that process (the program's name, its
argument shapes, XLA's seconds). Compiles in subprocesses a test starts (the CLI,
sweep workers) are not seen. As a script it prints, per test file, the wall time, the
XLA seconds and the compile count; the tests whose many small compiles (below 1.5 s:
mostly eager `jnp` ops outside `jit`, each op and shape its own program) add up; and
the largest programs. Not part of CI: the suite runs without it.
"""

from __future__ import annotations

import json
import logging
import os
import re
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

import pytest

FINISHED = re.compile(r"Finished XLA compilation of (.*) in ([\d.e-]+) sec")
SMALL_S = 1.5
_records: list[tuple[str, str, float]] = []


class _CompileHandler(logging.Handler):
    def emit(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        if message.startswith("Compiling "):
            _records.append(("compiling", message[:2000], 0.0))
        elif match := FINISHED.match(message):
            _records.append(("xla", match[1], float(match[2])))


def pytest_configure(config) -> None:
    import jax

    jax.config.update("jax_log_compiles", True)
    handler = _CompileHandler(level=logging.DEBUG)
    for name in ("jax._src.dispatch", "jax._src.interpreters.pxla"):
        logger = logging.getLogger(name)
        logger.addHandler(handler)
        logger.setLevel(logging.DEBUG)
        logger.propagate = False  # the suite's output stays as it is


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):  # noqa: ARG001  (pytest's hook signature)
    start, began = len(_records), time.time()
    yield
    out = Path(os.environ.get("COMPILE_LOG_DIR", "compile-log"))
    out.mkdir(parents=True, exist_ok=True)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    line = {"test": item.nodeid, "wall": time.time() - began, "records": _records[start:]}
    with open(out / f"{worker}.jsonl", "a") as f:
        f.write(json.dumps(line) + "\n")


def report(directory: Path) -> None:
    tests = [
        json.loads(line)
        for f in sorted(directory.glob("*.jsonl"))
        for line in f.read_text().splitlines()
    ]
    compiles = [(t, r) for t in tests for r in t["records"] if r[0] == "xla"]
    print(
        f"{len(tests)} tests, {len(compiles)} XLA compiles in the test processes, "
        f"{sum(r[2] for _, r in compiles):.0f} s of {sum(t['wall'] for t in tests):.0f} s"
    )
    by_file: dict[str, list[float]] = defaultdict(lambda: [0.0, 0.0, 0])
    for t in tests:
        row = by_file[t["test"].split("::")[0]]
        row[0] += t["wall"]
        for r in t["records"]:
            if r[0] == "xla":
                row[1] += r[2]
                row[2] += 1
    print("\n   wall s    xla s  compiles  file")
    for name, (wall, xla, count) in sorted(by_file.items(), key=lambda kv: -kv[1][0]):
        print(f"  {wall:7.1f}  {xla:7.1f}  {count:8d}  {name}")
    print(f"\nmany small compiles (< {SMALL_S} s each; eager ops): s, count, test")
    small = []
    for t in tests:
        times = [r[2] for r in t["records"] if r[0] == "xla" and r[2] < SMALL_S]
        if len(times) >= 25:
            small.append((sum(times), len(times), t["test"]))
    for seconds, count, name in sorted(small, reverse=True)[:20]:
        print(f"  {seconds:6.1f}  {count:4d}  {name}")
    print("\nlargest programs: s, program, test")
    for t, r in sorted(compiles, key=lambda tr: -tr[1][2])[:20]:
        print(f"  {r[2]:6.1f}  {r[1][:28]:28s}  {t['test']}")
    names = Counter(r[1] for _, r in compiles if r[2] >= SMALL_S)
    print("\nprograms compiled more than once (by name; shapes or structure differ):")
    print("  " + ", ".join(f"{n} ×{c}" for n, c in names.most_common(8) if c > 1))


if __name__ == "__main__":
    if len(sys.argv) != 2 or not Path(sys.argv[1]).is_dir():
        sys.exit("usage: python benchmarks/compile_log.py DIR (a directory -p compile_log wrote)")
    report(Path(sys.argv[1]))
