"""Test configuration, applied before jax is imported.

Two XLA host devices, so seed sharding is exercised as in `pimbot train`, and
one persistent compilation cache for the whole session (shared with the CLI
subprocesses some tests start), so identical programs compile once.
"""

import os
import tempfile

flags = os.environ.get("XLA_FLAGS", "")
if "xla_force_host_platform_device_count" not in flags:
    os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count=2".strip()
os.environ.setdefault("PIMBOT_CACHE_DIR", tempfile.mkdtemp(prefix="pimbot-jax-cache-"))

from pimbot import jax_setup  # noqa: E402

jax_setup.enable_compilation_cache()
