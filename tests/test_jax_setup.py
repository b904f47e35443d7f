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
