"""Wigner d/D of brdfscale.so3 against mpmath, the seed's formula, `spherical` and group theory."""

import math

import jax
import jax.numpy as jnp
import mpmath as mp
import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings, strategies as st

import brdfscale.so3 as so3
from brdfscale import InvalidInputError


def d_mpmath(J, Mp, M, beta, dps=None):
    """Wigner's explicit sum for d^J_{M'M}(β) (Wikipedia's convention) at high precision."""
    with mp.workdps(dps or int(0.7 * J) + 40):
        b = mp.mpf(beta)
        c, s = mp.cos(b / 2), mp.sin(b / 2)
        fact = mp.factorial
        pre = mp.sqrt(fact(J + Mp) * fact(J - Mp) * fact(J + M) * fact(J - M))
        total = mp.mpf(0)
        for k in range(max(0, M - Mp), min(J + M, J - Mp) + 1):
            den = fact(J + M - k) * fact(k) * fact(Mp - M + k) * fact(J - Mp - k)
            total += (-1) ** (Mp - M + k) * pre / den * c ** (2 * J + M - Mp - 2 * k) * s ** (Mp - M + 2 * k)
        return total


def d_seed_formula(J, M, Mp, beta, arith):
    """The seed's Rodrigues formula (§5), derivative expanded by Leibniz' rule, in `arith`.

    d^J_{MM'}(t) = (−1)^{J−M'} 2^{−J} √((J+M)!/((J+M')!(J−M')!(J−M)!)) (1−t)^{−(M−M')/2}
                   (1+t)^{−(M+M')/2} d^{J−M}/dt^{J−M} [(1−t)^{J−M'} (1+t)^{J+M'}],  t = cos β.
    """
    fact, power, sqrt, cos = arith
    t = cos(beta)
    n, a, b = J - M, J - Mp, J + Mp
    deriv = 0
    for k in range(0, n + 1):
        if k > a or n - k > b:
            continue
        term = (fact(n) / (fact(k) * fact(n - k))) * (-1) ** k * fact(a) / fact(a - k) * power(1 - t, a - k)
        deriv = deriv + term * fact(b) / fact(b - n + k) * power(1 + t, b - n + k)
    pre = (-1) ** (J - Mp) * 2.0 ** (-J) * sqrt(fact(J + M) / (fact(J + Mp) * fact(J - Mp) * fact(J - M)))
    return pre * power(1 - t, -(M - Mp) / 2) * power(1 + t, -(M + Mp) / 2) * deriv


FLOAT64 = (lambda k: float(math.factorial(k)), lambda x, p: x**p, math.sqrt, math.cos)
MPMATH = (mp.factorial, lambda x, p: x ** mp.mpf(p), mp.sqrt, lambda b: mp.cos(mp.mpf(b)))


def test_d1_10_explicit():
    beta = np.linspace(0.0, np.pi, 7)
    d = np.asarray(so3.wigner_d(1, beta))
    np.testing.assert_allclose(d[:, 2, 1], -np.sin(beta) / np.sqrt(2), atol=1e-15)  # d¹_{1,0}
    np.testing.assert_allclose(d[:, 1, 2], np.sin(beta) / np.sqrt(2), atol=1e-15)  # d¹_{0,1}
    np.testing.assert_allclose(d[:, 2, 2], (1 + np.cos(beta)) / 2, atol=1e-15)


@pytest.mark.parametrize("J", [0, 1, 2, 5, 12, 25])
def test_small_J_against_mpmath_all_entries(J):
    beta = 1.234
    d = np.asarray(so3.wigner_d(J, beta))
    ref = np.array([[float(d_mpmath(J, Mp, M, beta)) for M in range(-J, J + 1)] for Mp in range(-J, J + 1)])
    assert np.max(np.abs(d - ref)) <= 1e-14


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_large_J_entries_and_unitarity():
    J = 1024
    beta = 1.1
    d = np.asarray(so3.wigner_d(J, beta))
    for M, Mp in [(0, 0), (1, 0), (500, -3), (1024, 1000), (-700, 700), (17, -900), (-1024, -1024)]:
        assert abs(d[M + J, Mp + J] - float(d_mpmath(J, M, Mp, beta))) <= 1e-12, (M, Mp)
    assert np.max(np.abs(d @ d.T - np.eye(2 * J + 1))) <= 1e-12


def test_seed_formula_agrees_at_high_precision_and_fails_in_float64():
    beta = math.pi / 2
    # (a) in exact-enough arithmetic the seed's formula is our d (same sign convention)
    with mp.workdps(80):
        for J, M, Mp in [(1, 1, 0), (2, -1, 2), (5, 3, -2), (7, 0, 0)]:
            seed = float(d_seed_formula(J, M, Mp, 0.77, MPMATH))
            assert abs(seed - float(so3.wigner_d(J, 0.77)[M + J, Mp + J])) < 1e-14
    # (b) in float64 it loses accuracy as J grows (factorials, cancellation)
    errors = {}
    for J in (5, 20, 40, 60):
        ours = np.asarray(so3.wigner_d(J, beta))
        errors[J] = max(
            abs(d_seed_formula(J, M, Mp, beta, FLOAT64) - ours[M + J, Mp + J])
            for M in range(-J, J + 1, max(1, J // 6))
            for Mp in range(-J, J + 1, max(1, J // 6))
        )
    assert errors[5] < 1e-13
    assert errors[40] > 1e-6 and errors[60] > errors[20] * 1e3
    # while ours stays at rounding level against mpmath
    assert abs(float(so3.wigner_d(60, beta)[60 + 7, 60 - 30]) - float(d_mpmath(60, 7, -30, beta))) < 1e-14


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
@settings(max_examples=8, deadline=None)
@given(st.integers(0, 6), st.tuples(*[st.floats(0, 2 * np.pi)] * 3), st.tuples(*[st.floats(0, 2 * np.pi)] * 3))
def test_representation_property(J, e1, e2):
    R = np.asarray(so3.euler_to_matrix(*e1)) @ np.asarray(so3.euler_to_matrix(*e2))
    a, b, g = so3.matrix_to_euler(R)
    left = np.asarray(so3.wigner_D(J, a, b, g))
    right = np.asarray(so3.wigner_D(J, *e1)) @ np.asarray(so3.wigner_D(J, *e2))
    assert np.max(np.abs(left - right)) < 1e-12


@settings(max_examples=15, deadline=None)
@given(st.tuples(st.floats(0, 2 * np.pi), st.floats(0, np.pi), st.floats(0, 2 * np.pi)))
def test_euler_round_trip(e):
    R = np.asarray(so3.euler_to_matrix(*e))
    back = np.asarray(so3.euler_to_matrix(*so3.matrix_to_euler(R)))
    assert np.max(np.abs(R - back)) < 1e-12


# ~70 s in a fresh environment (spherical's numba compile): run in .ci/run's second step, outside the default
# suite's 6-minute budget
@pytest.mark.slow
def test_against_spherical_package():
    import quaternionic
    import spherical

    ell_max = 8
    wigner = spherical.Wigner(ell_max)
    alpha, beta, gamma = 0.4, 2.1, 5.3
    R = quaternionic.array.from_euler_angles(alpha, beta, gamma)
    Dsph = wigner.D(R)
    for J in (1, 4, 8):
        ours = np.asarray(so3.wigner_D(J, alpha, beta, gamma))
        theirs = np.array([[Dsph[wigner.Dindex(J, M, Mp)] for Mp in range(-J, J + 1)] for M in range(-J, J + 1)])
        # `spherical`'s D is the complex conjugate of the seed's (docs/dependencies.md)
        assert np.max(np.abs(ours - np.conj(theirs))) < 1e-13


def test_generator_convention():
    for J in (1, 3, 6):
        Jx, Jy, Jz = so3.angular_momentum(J)
        np.testing.assert_allclose(scipy.linalg.expm(-1j * 0.8 * Jy), np.asarray(so3.wigner_d(J, 0.8)), atol=1e-14)
        # a rotation by θ about x is exp(−iθ J_x)
        a, b, g = so3.matrix_to_euler(
            np.array([[1, 0, 0], [0, np.cos(0.6), -np.sin(0.6)], [0, np.sin(0.6), np.cos(0.6)]])
        )
        np.testing.assert_allclose(scipy.linalg.expm(-1j * 0.6 * Jx), np.asarray(so3.wigner_D(J, a, b, g)), atol=1e-13)
        np.testing.assert_allclose(Jx @ Jy - Jy @ Jx, 1j * Jz, atol=1e-13)


def test_vectorised_differentiable_and_float32():
    beta = jnp.linspace(0.1, 3.0, 5)
    d = so3.wigner_d(7, beta)
    assert d.shape == (5, 15, 15)
    grad = jax.grad(lambda b: so3.wigner_d(7, b)[3, 9])(0.7)
    fd = (so3.wigner_d(7, 0.7 + 1e-6)[3, 9] - so3.wigner_d(7, 0.7 - 1e-6)[3, 9]) / 2e-6
    assert abs(grad - fd) < 1e-8
    d32 = so3.wigner_d(40, jnp.float32(1.3))
    assert d32.dtype == jnp.float32
    assert np.max(np.abs(np.asarray(d32, float) - np.asarray(so3.wigner_d(40, 1.3)))) < 2e-6


@pytest.mark.parametrize(
    "bad", [-1, pytest.param(1.5, marks=pytest.mark.wrong_types), True, so3.MAX_DEGREE + 1]
)  # 1.5: J is annotated int (True is one)
def test_bad_degree(bad):
    with pytest.raises(InvalidInputError, match="J must be an integer"):
        so3.wigner_d(bad, 0.3)


def test_bad_angles_and_rotations():
    with pytest.raises(InvalidInputError, match="finite"):
        so3.wigner_d(2, np.nan)
    with pytest.raises(InvalidInputError, match="proper rotation"):
        so3.matrix_to_euler(np.diag([1.0, 1.0, -1.0]))


@pytest.mark.parametrize("J", [0, 1, 2, 7, 40, 255])
def test_flip_symmetry_of_the_fourier_rows(J):
    """X^J_{m,−M} = (−1)^{J+m} X^J_{mM}: the symmetry the transforms' contraction relies on
    (four sign quadrants of (M, M') share one kernel). Equivalent, through the Fourier form, to
    d^J_{M,−M'}(β) = (−1)^{J+M} d^J_{MM'}(π − β), checked on wigner_d too."""
    from brdfscale.so3._wigner import fourier_rows

    X = fourier_rows(J)
    eta = (-1.0) ** (J + np.arange(J + 1))
    assert np.max(np.abs(X[:, ::-1] - eta[:, None] * X)) < 1e-13 * max(1, J)
    d = np.asarray(so3.wigner_d(J, 0.7))
    d_reflected = np.asarray(so3.wigner_d(J, np.pi - 0.7))
    M = np.arange(-J, J + 1)
    np.testing.assert_allclose(d[:, ::-1], ((-1.0) ** (J + M))[:, None] * d_reflected, atol=1e-12)


@pytest.mark.wrong_types  # the angles are annotated as broadcasting to one shape ("*#batch")
def test_euler_angles_that_do_not_broadcast_are_named():
    with pytest.raises(InvalidInputError, match="broadcast"):
        so3.wigner_D(2, jnp.zeros(3), jnp.zeros(2), jnp.zeros(3))
    with pytest.raises(InvalidInputError, match="broadcast"):
        so3.analyse_points(jnp.zeros(3), jnp.zeros(2), jnp.zeros(3), 4)
