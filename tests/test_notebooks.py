"""The example notebooks run from top to bottom, as a reader runs them: nbmake executes
each in a fresh Jupyter kernel (a pytest of its own, without this suite's options), with
the session's compilation cache and XLA flags inherited; their runs go to this test's
temporary folder (TMPDIR)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "examples" / "notebooks").glob("*.ipynb"))


def test_every_example_notebook_runs(tmp_path):
    assert NOTEBOOKS, "no notebook in examples/notebooks"
    command = [sys.executable, "-m", "pytest", "--nbmake", "--nbmake-timeout=600", "-q"]
    command += ["-p", "no:xdist", "-p", "no:cacheprovider", "-o", "addopts="]
    done = subprocess.run(
        [*command, *map(str, NOTEBOOKS)],
        cwd=ROOT,
        env={**os.environ, "TMPDIR": str(tmp_path)},
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, done.stdout[-6000:] + done.stderr[-2000:]
    assert f"{len(NOTEBOOKS)} passed" in done.stdout
