"""Test configuration, applied before jax is imported.

Two XLA host devices, so seed sharding is exercised as in `pimbot train`, and
one persistent compilation cache for the whole session (shared with the CLI
subprocesses some tests start), so identical programs compile once; a directory this
session made is removed when it ends.

With pytest-xdist (the `addopts` of pyproject.toml) this module runs first in the
controller, whose environment every worker inherits: the workers see the same
XLA_FLAGS (two host devices each) and the same cache directory, so a program one
worker compiled is a cache hit in the other (JAX writes each entry once and a torn
read is a warning and a recompile, as between the workers of `pimbot reproduce`).
"""

import os
import shutil
import tempfile

import pytest

flags = os.environ.get("XLA_FLAGS", "")
if "xla_force_host_platform_device_count" not in flags:
    os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count=2".strip()
SESSION_CACHE = None
"""The cache directory this process made (the controller, or a run without xdist), removed
when its session ends; None where PIMBOT_CACHE_DIR was given (a worker inherits it)."""
if "PIMBOT_CACHE_DIR" not in os.environ:  # the controller's, inherited by the workers
    SESSION_CACHE = tempfile.mkdtemp(prefix="pimbot-jax-cache-")
    os.environ["PIMBOT_CACHE_DIR"] = SESSION_CACHE

from pimbot import jax_setup  # noqa: E402

jax_setup.enable_compilation_cache()

MAX_WORKERS = 4
"""The cap of `--numprocesses=auto`. Every worker is a JAX process that compiles and keeps
its programs (2.7 and 4.3 GB resident at most in a 2-worker run of the suite, plus the
sweep and CLI subprocesses some tests start), and the suite is a few compile-bound
files handed out whole: past four workers a many-core laptop gains little and risks its
memory."""


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_auto_num_workers(config: pytest.Config) -> int | None:
    """`--numprocesses=auto`: one worker per CPU this process may run on (2 in CI), at most
    `MAX_WORKERS` and at most one per test file named on the command line (a directory
    counts as many); 0 (the tests run in this process, no workers) where that leaves one,
    so `pytest tests/test_x.py -k name` runs as it would without xdist. xdist's own count
    is physical cores of the whole machine: 1 on a 2-vCPU runner, too many in a container
    pinned to a few CPUs of a big host. PYTEST_XDIST_AUTO_NUM_WORKERS still overrides it
    (None: xdist's hook reads it)."""
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None
    affinity = getattr(os, "sched_getaffinity", None)  # Linux; elsewhere every CPU
    cpus = len(affinity(0)) if affinity else os.cpu_count() or 1
    paths = {arg.split("::")[0] for arg in config.args}
    files = len(paths) if paths and all(p.endswith(".py") for p in paths) else MAX_WORKERS
    workers = min(cpus, MAX_WORKERS, files)
    return workers if workers > 1 else 0


def pytest_addoption(parser: pytest.Parser, pluginmanager: pytest.PytestPluginManager) -> None:
    """Without xdist (`-p no:xdist`, or an install from before it joined the test extra)
    its options in `addopts` are accepted and ignored: the tests run in this process."""
    if pluginmanager.has_plugin("xdist"):
        return
    group = parser.getgroup("xdist", "pytest-xdist is not active: these options do nothing")
    group.addoption("--numprocesses", action="store", help="ignored without pytest-xdist")
    group.addoption("--dist", action="store", help="ignored without pytest-xdist")
    group.addoption("--no-loadscope-reorder", action="store_true", help="ignored too")


def pytest_unconfigure(config: pytest.Config) -> None:
    """Removes the session's compilation cache (about 25 MB) once every worker is done:
    the process that made it ends its session last."""
    if SESSION_CACHE is not None:
        shutil.rmtree(SESSION_CACHE, ignore_errors=True)
