"""The CPU threefry lowering `jax_setup.unroll_cpu_threefry` installs (conftest applies it
through `enable_compilation_cache`) computes the same bits as JAX's rolled-loop one."""

import jax
import jax.numpy as jnp
import numpy as np

from pimbot import jax_setup


def test_unrolled_threefry_gives_the_rolled_loops_bits():
    from jax._src.random import threefry2x32

    assert jax_setup.unroll_cpu_threefry()
    key = jax.random.PRNGKey(12345)
    k1, k2 = jax.random.key_data(key).astype(jnp.uint32)
    count = jnp.arange(2 * 37, dtype=jnp.uint32)
    x1, x2 = count[::2], count[1::2]

    def rolled(k1, k2, x1, x2):  # JAX's CPU rule, traced as plain lax ops
        return threefry2x32._threefry2x32_lowering(k1, k2, x1, x2, use_rolled_loops=True)

    expected = jax.jit(rolled)(k1, k2, x1, x2)
    got = jax.jit(lambda *a: threefry2x32.threefry2x32_p.bind(*a))(k1, k2, x1, x2)
    for a, b in zip(got, expected, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_the_cache_directory_is_keyed_by_the_plugin_files(tmp_path):
    one = jax_setup.cache_dir(tmp_path, ["aa", "bb"])
    assert one == jax_setup.cache_dir(tmp_path, ["bb", "aa"])  # the order loaded is no key
    assert one != jax_setup.cache_dir(tmp_path, ["aa", "bc"])  # one plugin file changed
    assert one != jax_setup.cache_dir(tmp_path, ["aa"])
    assert one.parent == tmp_path and one.name.startswith(jax_setup.CACHE_PREFIX)


def test_the_cache_directory_is_keyed_by_pimbot_version_and_sources(tmp_path, monkeypatch):
    import pimbot

    before = jax_setup.cache_dir(tmp_path, [])
    assert pimbot.__version__ in before.name
    monkeypatch.setattr(jax_setup, "source_digest", lambda: "another version")
    assert jax_setup.cache_dir(tmp_path, []) != before


def test_the_source_digest_covers_the_version():
    import pimbot

    digest = jax_setup.source_digest()
    jax_setup.source_digest.cache_clear()
    try:
        original = pimbot.__version__
        pimbot.__version__ = f"{original}+edited"
        assert jax_setup.source_digest() != digest
    finally:
        pimbot.__version__ = original
        jax_setup.source_digest.cache_clear()
    assert jax_setup.source_digest() == digest


def test_the_cache_keeps_every_program_however_small():
    """conftest enabled it: a key directory under $PIMBOT_CACHE_DIR, no time or size floor."""
    path = jax_setup.active_cache_dir()
    assert path is not None and path.parent == jax_setup.cache_root()
    assert jax.config.jax_persistent_cache_min_compile_time_secs == 0
    assert jax.config.jax_persistent_cache_min_entry_size_bytes == -1


def test_a_marker_is_kept_in_the_active_cache_directory():
    first = jax_setup.marker("preflight", "a run's structure")
    assert first is not None and first.parent == jax_setup.active_cache_dir() / "preflight"
    assert first == jax_setup.marker("preflight", "a run's structure")
    assert first != jax_setup.marker("preflight", "another structure")


def test_old_cache_directories_are_pruned_beyond_the_recent_ones(tmp_path):
    import os
    import time

    now = time.time()
    ages_days = [0, 0.5, 2, 3, 4, 5, 6]  # the newest first
    dirs = [tmp_path / f"{jax_setup.CACHE_PREFIX}v{i}" for i in range(len(ages_days))]
    for path, age in zip(dirs, ages_days, strict=True):
        path.mkdir()
        os.utime(path, (now - age * 86400, now - age * 86400))
    other = tmp_path / "not-ours"
    other.mkdir()
    os.utime(other, (now - 30 * 86400, now - 30 * 86400))
    removed = jax_setup.prune_cache_dirs(tmp_path, keep=dirs[-1], versions=2)
    assert sorted(removed) == sorted(dirs[2:-1])  # unused for over a day, beyond the 2 newest
    assert all(p.exists() for p in [*dirs[:2], dirs[-1], other])
