"""H_n(W): the transforms of the regularised plus-distributions against mpmath (docs/conventions.md §4)."""

import math

import jax
import jax.numpy as jnp
import mpmath as mp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from brdfscale import InvalidInputError, plus, stats
from brdfscale.plus import _transform
from tests.references.plus_transform import decaying, polynomial, reference


ORDERS = range(plus.MAX_ORDER + 1)
Z_SERIES_REF = [1e-6, 3e-4, 0.05, 0.7, 2.0, 5.0, 7.9, 8.1, 11.0, 19.0, 47.0, 150.0, 999.0]


@pytest.mark.parametrize("n", ORDERS)
def test_against_mpmath_series(n):
    """Both branches (series z ≤ 8, polynomial − decaying beyond) to 1e-13 relative."""
    z = np.array(Z_SERIES_REF)
    got = np.asarray(plus.plus_transform(z, n))
    want = np.array([reference(n, v) for v in z])
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=0)


@pytest.mark.parametrize("n,z", [(0, 1e5), (0, 1e8), (2, 3e6)])
def test_large_argument_against_mpmath_quadrature(n, z):
    """Beyond the reach of the series: mpmath's Gamma-function Taylor coefficients and its
    Hankel-function quadrature of the decaying part."""
    with mp.workdps(20):
        want = float(polynomial(n, z) - decaying(n, z))
    got = float(plus.plus_transform(z, n))
    assert abs(got - want) <= 1e-13 * abs(want)


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_decaying_terms_against_mpmath():
    """The Gauss–Laguerre form of T_n against mpmath quadrature with mpmath's H₀⁽¹⁾ at the switch
    (n = 0, where T_n is largest relative to H_n)."""
    n, z = 0, 8.0
    got = float(_transform._decaying(jnp.asarray(z), n)[n])
    with mp.workdps(20):
        want = float(decaying(n, z))
        scale = float(abs(polynomial(n, z)))
    assert abs(got - want) <= 1e-15 * scale


@pytest.mark.parametrize("n", ORDERS)
def test_polynomial_coefficients_against_mpmath(n):
    """P_n(ℓ) from the ζ-series equals mpmath's Taylor coefficient of (2/z)^s Γ(1+s/2)/Γ(1−s/2)."""
    for z in (10.0, 1e3, 1e7):
        ell = math.log(z) + float(mp.euler) - math.log(2)
        got = float(_transform._polynomial(jnp.asarray(ell), n)[n])
        with mp.workdps(30):
            want = float(polynomial(n, z))
        assert abs(got - want) <= 2e-15 * max(1.0, abs(want))


@pytest.mark.parametrize("n", ORDERS)
def test_expansion_agrees_with_series_in_overlap(n):
    """Where both converge cleanly (6 ≤ z ≤ 9: the Laguerre rule needs z ≳ 6, the series'
    cancellation exceeds 1e-13 beyond z ≈ 9 for n = 0) the two branches agree to 1e-13."""
    z = jnp.linspace(6.0, 9.0, 31)
    series = _transform._series(z**2 / 4, n)[..., n]
    ell = jnp.log(z) + (_transform._EULER_GAMMA - math.log(2))
    expansion = _transform._polynomial(ell, n)[..., n] - _transform._decaying(z, n)[..., n]
    np.testing.assert_allclose(np.asarray(expansion), np.asarray(series), rtol=1e-13)


def _all_orders(z):
    return _transform.transforms_from_square(z * z, plus.MAX_ORDER)


def test_seamless_and_differentiable_at_switch():
    s = _transform.SWITCH
    below, above = jnp.asarray(s * (1 - 1e-12)), jnp.asarray(s * (1 + 1e-12))
    g_below, g_above = (np.asarray(jax.jacfwd(_all_orders)(v)) for v in (below, above))
    jump = np.asarray(_all_orders(above) - _all_orders(below)) - g_above * float(above - below)
    assert np.all(np.abs(jump) <= 1e-13 * np.abs(np.asarray(_all_orders(jnp.asarray(s)))))
    assert np.all(np.isfinite(g_below))
    np.testing.assert_allclose(g_below, g_above, rtol=1e-11)


def _derivative_reference(n, z):
    """z H_n'(z) = J₀(z) − 1 (n = 0) or −n H_{n−1}(z), from differentiating the definition."""
    if n == 0:
        with mp.workdps(30):
            return float((mp.besselj(0, z) - 1) / z)
    return -n * reference(n - 1, z) / z


def test_gradient_against_recurrence():
    z = jnp.array([1e-3, 0.5, 3.0, 7.99, 8.01, 20.0, 300.0, 2500.0])
    grad = np.asarray(jax.vmap(jax.jacfwd(_all_orders))(z))  # (z, n)
    for n in ORDERS:
        want = np.array([_derivative_reference(n, float(v)) for v in z])
        np.testing.assert_allclose(grad[:, n], want, rtol=1e-11, err_msg=f"n = {n}")


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_gradient_finite_at_zero_frequency():
    """cf is written in |W|², so ∂/∂W and ∂/∂x0 are 0, not NaN, at W = 0."""
    h = plus.PlusDistribution(2, 0.1)
    grad_W = jax.grad(lambda W: jnp.real(h.cf(W)))(jnp.zeros(2))
    assert np.array_equal(np.asarray(grad_W), np.zeros(2))
    grad_x0 = jax.grad(lambda x0: plus.PlusDistribution(2, x0).cf_radial(0.0))(0.1)
    assert float(grad_x0) == 0.0
    nearly = plus.NearlySpecular(0.5, [0.1, -0.2], 0.1, smooth=stats.Beckmann(0.2), smooth_weight=0.5)
    grad_W = jax.grad(lambda W: jnp.real(nearly.cf(W)))(jnp.zeros(2))
    assert np.array_equal(np.asarray(grad_W), np.zeros(2))


def test_jit_matches_eager():
    z = jnp.logspace(-6, 8, 57)
    for n in (0, 4):
        eager = plus.plus_transform(z, n)
        jitted = jax.jit(lambda v: plus.plus_transform(v, n))(z)
        np.testing.assert_allclose(np.asarray(jitted), np.asarray(eager), rtol=1e-15)


def test_float32_against_float64():
    """float32 (rounding 6e-8): measured ≤ 5e-7 relative (experiments/plus_transform_accuracy.py)."""
    z = np.logspace(-6, 8, 141)
    f64 = np.asarray(_all_orders(jnp.asarray(z, jnp.float64)))
    f32 = _all_orders(jnp.asarray(z, jnp.float32))
    assert f32.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(f32, np.float64), f64, rtol=1e-6)


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
@settings(max_examples=40, deadline=None)
@given(n=st.integers(0, plus.MAX_ORDER), a=st.floats(1e-5, 1e7), ratio=st.floats(1.0001, 10.0))
def test_sign_and_monotone_modulus(n, a, ratio):
    """(−1)^{n+1} H_n > 0 and |H_n| increases with z: (logⁿt)(J₀ − 1) has one sign, and
    z H_n' = −n H_{n−1} (n ≥ 1), z H_0' = J₀ − 1 ≤ 0."""
    lo, hi = (float((-1) ** (n + 1) * plus.plus_transform(v, n)) for v in (a, a * ratio))
    assert 0 < lo < hi


@pytest.mark.parametrize(
    "order",
    [
        -1,
        7,
        pytest.param(1.0, marks=pytest.mark.wrong_types),
        True,
        pytest.param("2", marks=pytest.mark.wrong_types),
    ],
)
def test_bad_order(order):
    with pytest.raises(InvalidInputError, match="order"):
        plus.plus_transform(1.0, order)
