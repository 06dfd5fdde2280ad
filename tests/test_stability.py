"""Regressions for the failures the stability sweep (experiments/stability.py) found, each
against a closed form; the sweep's own smoke test is in tests/test_experiments_smoke.py."""

import warnings

import jax.numpy as jnp
import numpy as np
import pytest

import brdfscale as bs
from brdfscale import lobes, stats


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
@pytest.mark.parametrize("method", ["radial", "grid"])
def test_gaussian_lobe_between_gaussian_statistics_towards_finer_is_one_exponential(method):
    """A Beckmann lobe of √(0.05² + 3) ≈ 1.73 between Beckmann statistics 1 → 2 (finer) is
    Beckmann 0.05: its transform is one exponential. The lobe's own transform
    underflowed at |W| ≈ 31 while the growing quotient was still huge, so the forced spectral
    paths saw a truncated transform and refused the lobe as negative."""
    aL, a0, a1 = np.sqrt(0.05**2 + 3.0), 1.0, 2.0
    width = np.sqrt(aL**2 + a0**2 - a1**2)
    r = np.array([0.0, 0.5, 2.0]) * width
    u = jnp.asarray(np.stack([r, 0 * r], -1))
    got = np.asarray(
        bs.evolve(lobes.Beckmann(aL), stats.Beckmann(a0), stats.Beckmann(a1), method=method, tol=1e-8).density(u)
    )
    want = np.exp(-((r / width) ** 2)) / (np.pi * width**2)
    assert np.max(np.abs(got - want)) <= 1e-8 * want[0]


@pytest.mark.slow  # 5–60 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_float32_grid_path_keeps_its_precision():
    """The grid path's inverse FFT scattered a float64 sign pattern into a complex64 spectrum
    (JAX: 'cannot safely cast', an error in future releases): float32 in, float32 out, no warning."""
    f32 = lambda x: jnp.asarray(x, jnp.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lobe = bs.evolve(lobes.Beckmann(f32(0.05)), stats.GGX(f32(0.2)), stats.GGX(f32(0.1)), method="grid", tol=1e-4)
        values = lobe.density(jnp.zeros((4000, 2), jnp.float32))  # many queries: the FFT table
    assert values.dtype == jnp.float32 and np.all(np.isfinite(np.asarray(values)))
