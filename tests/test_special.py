"""Bessel functions against SciPy (values) and SciPy/analytic identities (derivatives)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.special as sp

from brdfscale._special import j0, j1, jinc, k0, xk1


X_J = np.concatenate([-np.logspace(-8, 4, 400), [0.0], np.logspace(-8, 4, 2000)])
X_K = np.logspace(-12, np.log10(700), 2000)


@pytest.mark.parametrize("ours, order", [(j0, 0), (j1, 1)])
def test_bessel_j_absolute_error(ours, order):
    """Against 30-digit mpmath on both sides of the series/modulus–phase switch at |x| = 8 and
    out to 1e4 (SciPy itself is off by up to 5e-15 near x = 1e4, where it rounds x − π/4)."""
    mpmath = pytest.importorskip("mpmath")
    mpmath.mp.dps = 30
    x = np.concatenate([X_J[::5], np.linspace(7.9, 8.1, 41), -np.linspace(7.9, 8.1, 11), np.linspace(24, 26, 21)])
    ref = np.array([float(mpmath.besselj(order, v)) for v in x])
    assert np.max(np.abs(np.asarray(ours(jnp.asarray(x))) - ref)) < 2e-15


@pytest.mark.parametrize("ours, ref", [(j0, sp.j0), (j1, sp.j1)])
def test_bessel_j_against_scipy(ours, ref):
    """Every point of X_J against SciPy, within SciPy's own error (above)."""
    err = np.abs(np.asarray(ours(jnp.asarray(X_J))) - ref(X_J))
    assert err.max() < 6e-15


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_jinc_against_scipy():
    x = X_J[X_J != 0]
    err = np.abs(np.asarray(jinc(jnp.asarray(x))) - 2 * sp.j1(x) / x)
    assert err.max() < 1e-14
    assert float(jinc(0.0)) == 1.0


def test_bessel_k_relative_error():
    assert np.max(np.abs(np.asarray(k0(jnp.asarray(X_K))) / sp.k0(X_K) - 1)) < 1e-13
    assert np.max(np.abs(np.asarray(xk1(jnp.asarray(X_K))) / (X_K * sp.k1(X_K)) - 1)) < 1e-13
    assert float(xk1(0.0)) == 1.0


def test_bessel_k_against_mpmath_to_a_few_ulp():
    """30-digit mpmath values (independent of SciPy) on both sides of the series/Chebyshev switch
    at x = 2 and out to the underflow of e^{−x}: x·K1 to 2e-15 and K0 to 1e-14 relative (K0's
    series loses a digit to cancellation just below x = 2)."""
    mpmath = pytest.importorskip("mpmath")
    mpmath.mp.dps = 30
    x = np.concatenate([np.logspace(-10, np.log10(700), 300), np.linspace(1.9, 2.1, 41)])
    ref_xk1 = np.array([float(v * mpmath.besselk(1, v)) for v in x])
    ref_k0 = np.array([float(mpmath.besselk(0, v)) for v in x])
    assert np.max(np.abs(np.asarray(xk1(jnp.asarray(x))) / ref_xk1 - 1)) < 2e-15
    assert np.max(np.abs(np.asarray(k0(jnp.asarray(x))) / ref_k0 - 1)) < 1e-14


@pytest.mark.slow  # 5–60 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_derivatives():
    x = np.array([1e-6, 0.3, 2.0, 17.0, 40.0, 300.0])
    for f, ref in [(j0, -sp.j1(x)), (j1, sp.jvp(1, x)), (k0, -sp.k1(x)), (xk1, -x * sp.k0(x))]:
        d = np.asarray(jax.vmap(jax.grad(f))(jnp.asarray(x)))
        np.testing.assert_allclose(d, ref, rtol=1e-11, atol=1e-15)
    djinc = np.asarray(jax.vmap(jax.grad(jinc))(jnp.asarray(x)))
    np.testing.assert_allclose(djinc, -2 * sp.jv(2, x) / x, rtol=1e-10, atol=1e-15)
    # finite at the origin, where naive formulas divide 0 by 0
    for f in (j1, jinc, xk1):
        assert np.isfinite(float(jax.grad(f)(0.0)))


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_float32_matches_float64():
    x = np.linspace(0.01, 60.0, 500)
    for f in (j0, j1, jinc):
        np.testing.assert_allclose(np.asarray(f(jnp.asarray(x, jnp.float32))), np.asarray(f(jnp.asarray(x))), atol=2e-6)
    xs = np.logspace(-4, np.log10(60), 200)  # x K1(x) ≥ 1e-25: inside float32's normal range
    np.testing.assert_allclose(np.asarray(xk1(jnp.asarray(xs, jnp.float32))), xs * sp.k1(xs), rtol=2e-6, atol=1e-30)
    np.testing.assert_allclose(np.asarray(k0(jnp.asarray(xs, jnp.float32))), sp.k0(xs), rtol=2e-6, atol=1e-30)
    assert k0(jnp.asarray(xs, jnp.float32)).dtype == jnp.float32
