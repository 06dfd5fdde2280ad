"""SO(3) transforms of brdfscale.so3 against closed forms, `spherical`, s2fft and brute force."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdfscale.so3 as so3
from brdfscale import InvalidInputError


def random_coefficients(B, rng, batch=(), L=None, N=None):
    L = B - 1 if L is None else L
    N = B - 1 if N is None else N
    c = rng.normal(size=batch + (B, 2 * L + 1, 2 * N + 1)) + 1j * rng.normal(size=batch + (B, 2 * L + 1, 2 * N + 1))
    M = np.arange(-L, L + 1)[:, None]
    Mp = np.arange(-N, N + 1)[None, :]
    J = np.arange(B)[:, None, None]
    return np.where((np.abs(M) <= J) & (np.abs(Mp) <= J), c, 0.0)


def direct_sum(c, alpha, beta, gamma):
    B, L, N = c.shape[-3], (c.shape[-2] - 1) // 2, (c.shape[-1] - 1) // 2
    total = 0
    for J in range(B):
        D = np.asarray(so3.wigner_D(J, alpha, beta, gamma))
        l, n = min(J, L), min(J, N)
        total = total + np.sum(c[J, L - l : L + l + 1, N - n : N + n + 1] * D[J - l : J + l + 1, J - n : J + n + 1])
    return total


def test_quadrature_weights_exact_for_legendre():
    for B in (3, 8, 16):
        _, beta, _ = so3.grid(B)
        w = so3.quadrature_weights(B)
        assert abs(w.sum() - 2) < 1e-14
        for l in range(2 * B):  # ∫ P_l(cos β) sin β dβ = 2 δ_l0, exact for l < 2B
            P = np.polynomial.legendre.legval(np.cos(beta), np.eye(2 * B)[l])
            assert abs(w @ P - (2.0 if l == 0 else 0.0)) < 1e-13


@pytest.mark.parametrize("B", [1, 4, 11])
def test_round_trip(B):
    rng = np.random.default_rng(B)
    c = random_coefficients(B, rng)
    f = so3.inverse(c)
    assert f.shape == (2 * B, 2 * B, 2 * B)
    assert np.max(np.abs(np.asarray(so3.forward(f)) - c)) < 1e-12 * max(1, np.abs(c).max())
    np.testing.assert_allclose(np.asarray(so3.inverse(so3.forward(f))), np.asarray(f), atol=1e-12)


@pytest.mark.slow
def test_round_trip_B64():
    rng = np.random.default_rng(64)
    c = random_coefficients(64, rng)
    assert np.max(np.abs(np.asarray(so3.forward(so3.inverse(c))) - c)) <= 1e-11


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
@pytest.mark.parametrize("B, L, N, tile_entries", [(9, 8, 8, 64), (9, 3, 6, 256), (12, 11, 0, 64), (16, 15, 9, 256)])
def test_blocked_contraction_against_direct_sums(B, L, N, tile_entries, monkeypatch):
    """The inverse at grid points against Σ f^J D^J summed with wigner_D, and the round trip,
    with kernel tiles forced small so that several degree slabs, column tiles and padded
    columns occur (the default tiles cover these sizes in one piece)."""
    from brdfscale.so3 import _contraction

    monkeypatch.setattr(_contraction, "_TILE_ENTRIES", tile_entries)
    _contraction.plan.cache_clear()
    try:
        p = _contraction.plan(B, L, N)
        assert len(p.edges) > 2 and (p.tile < N + 1 or N == 0)
        rng = np.random.default_rng(B + L + N)
        c = random_coefficients(B, rng, L=L, N=N)
        f = np.asarray(so3.inverse(c))
        a, b, g = so3.grid(B)
        for i, k, j in rng.integers(0, 2 * B, size=(4, 3)):
            assert abs(f[i, k, j] - direct_sum(c, a[i], b[k], g[j])) < 1e-13 * np.sqrt(np.sum(np.abs(c) ** 2))
        back = np.asarray(so3.forward(f, m_max=L, n_max=N))
        assert np.max(np.abs(back - c)) < 1e-12 * np.abs(c).max()
    finally:
        _contraction.plan.cache_clear()


@pytest.mark.slow  # 5–60 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_forward_of_a_single_D_from_spherical():
    """Samples of the seed's D^2_{1,−1} taken from `spherical` (conjugate convention) transform
    to the single coefficient 1 at (J, M, M') = (2, 1, −1)."""
    import quaternionic
    import spherical

    B = 4
    a, b, g = so3.grid(B)
    A, Bt, G = np.meshgrid(a, b, g, indexing="ij")
    wigner = spherical.Wigner(3)
    D = wigner.D(quaternionic.array.from_euler_angles(A, Bt, G))
    samples = np.conj(D[..., wigner.Dindex(2, 1, -1)])
    c = np.asarray(so3.forward(samples))
    expected = np.zeros_like(c)
    expected[2, B - 1 + 1, B - 1 - 1] = 1.0
    assert np.max(np.abs(c - expected)) < 1e-13


def test_synthesis_matches_s2fft_inverse():
    """s2fft's exact precomputed inverse, with the index map of docs/dependencies.md:
    f^J_{MM'} = (2J+1)/(8π²) (−1)^{M−M'} flmn[N−1−M', J, L−1−M]."""
    from s2fft.precompute_transforms import construct, wigner
    from s2fft.sampling import s2_samples

    L = N = B = 5
    c = random_coefficients(B, np.random.default_rng(7))
    flmn = np.zeros((2 * N - 1, L, 2 * L - 1), complex)
    for J in range(B):
        for M in range(-J, J + 1):
            for Mp in range(-J, J + 1):
                flmn[N - 1 - Mp, J, L - 1 - M] = (
                    c[J, B - 1 + M, B - 1 + Mp] * 8 * np.pi**2 / (2 * J + 1) * (-1) ** (M - Mp)
                )
    kernel = construct.wigner_kernel_jax(L, N, sampling="mw", forward=False)
    theirs = np.asarray(wigner.inverse(flmn, L, N, kernel, sampling="mw", method="jax"))  # [γ, β, α]
    gam = 2 * np.pi * np.arange(2 * N - 1) / (2 * N - 1)
    G, Bt, A = np.meshgrid(gam, s2_samples.thetas(L, "mw"), s2_samples.phis_equiang(L, "mw"), indexing="ij")
    ours = np.asarray(so3.synthesize(c, A, Bt, G))
    assert np.max(np.abs(ours - theirs)) < 1e-12 * np.abs(theirs).max()


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_synthesis_at_arbitrary_rotations_and_on_the_grid():
    B = 4
    c = random_coefficients(B, np.random.default_rng(3))
    rng = np.random.default_rng(4)
    a, b, g = rng.uniform(0, 2 * np.pi, 6), rng.uniform(0, np.pi, 6), rng.uniform(0, 2 * np.pi, 6)
    ours = np.asarray(so3.synthesize(c, a, b, g, chunk=4))
    ref = np.array([direct_sum(c, *x) for x in zip(a, b, g)])
    np.testing.assert_allclose(ours, ref, atol=1e-12)
    ga, gb, gg = so3.grid(B)
    on_grid = np.asarray(so3.inverse(c))
    np.testing.assert_allclose(
        np.asarray(so3.synthesize(c, ga[3], gb[[0, 7]], gg[5])), on_grid[3, [0, 7], 5], atol=1e-12
    )


def test_orders_restricted_to_what_a_query_needs():
    B = 4
    c = random_coefficients(B, np.random.default_rng(5), L=2, N=0)
    f = so3.inverse(c)
    full = np.asarray(so3.forward(f))
    part = np.asarray(so3.forward(f, m_max=2, n_max=0))
    np.testing.assert_allclose(part, c, atol=1e-12)
    np.testing.assert_allclose(full[:, B - 3 : B + 2, B - 1 : B], c, atol=1e-12)
    assert np.max(np.abs(np.delete(full, B - 1, axis=2))) < 1e-12


def test_batched_equals_individual():
    B = 4
    c = random_coefficients(B, np.random.default_rng(6), batch=(2, 3))
    f = np.asarray(so3.inverse(c))
    assert f.shape == (2, 3, 2 * B, 2 * B, 2 * B)
    np.testing.assert_allclose(f[1, 2], np.asarray(so3.inverse(c[1, 2])), atol=1e-13)
    np.testing.assert_allclose(np.asarray(so3.forward(f)), c, atol=1e-12)
    q = np.asarray(so3.synthesize(c, 0.3, 1.0, 2.0))
    assert q.shape == (2, 3)


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_differentiable_through_the_transforms():
    B = 4
    c0 = jnp.asarray(random_coefficients(B, np.random.default_rng(8)))
    f0 = so3.inverse(c0).real

    def loss(t):
        c = so3.forward(f0 * t)
        return jnp.sum(jnp.abs(c) ** 2) + jnp.real(so3.synthesize(c, 0.2, 0.9, 1.7))

    t = 1.3
    fd = (loss(t + 1e-5) - loss(t - 1e-5)) / 2e-5
    assert abs(jax.grad(loss)(t) - fd) < 1e-6 * abs(fd)


def test_float32_against_float64():
    B = 4
    c = random_coefficients(B, np.random.default_rng(9))
    f64 = np.asarray(so3.inverse(c))
    f32 = so3.inverse(jnp.asarray(c, jnp.complex64))
    assert f32.dtype == jnp.complex64
    assert np.max(np.abs(np.asarray(f32) - f64)) < 1e-5 * np.abs(f64).max()
    c32 = so3.forward(f32)
    assert c32.dtype == jnp.complex64
    assert np.max(np.abs(np.asarray(c32) - c)) < 1e-5 * np.abs(c).max()


def test_analyse_points_is_the_adjoint_of_synthesis():
    rng = np.random.default_rng(10)
    a, b, g = rng.uniform(0, 2 * np.pi, 7), rng.uniform(0, np.pi, 7), rng.uniform(0, 2 * np.pi, 7)
    w = rng.uniform(0.1, 1.0, 7)
    B = 4
    c = np.asarray(so3.analyse_points(a, b, g, B, weights=w))
    for J in range(B):
        ref = (
            (2 * J + 1)
            / (8 * np.pi**2)
            * sum(wk * np.conj(np.asarray(so3.wigner_D(J, *x))) for wk, x in zip(w, zip(a, b, g)))
        )
        np.testing.assert_allclose(c[J, B - 1 - J : B + J, B - 1 - J : B + J], ref, atol=1e-13)


@pytest.mark.parametrize(
    "call, match",
    [
        pytest.param(  # samples are annotated as a cube of grid samples ("*batch n n n")
            lambda: so3.forward(np.zeros((4, 4, 6))), "2B, 2B, 2B", marks=pytest.mark.wrong_types
        ),
        (lambda: so3.forward(np.zeros((3, 3, 3))), "2B, 2B, 2B"),
        (lambda: so3.forward(np.zeros((4, 4, 4)), m_max=2), "m_max"),
        (lambda: so3.inverse(np.zeros((3, 4, 5))), "2L\\+1"),
        (lambda: so3.inverse(np.zeros((2, 5, 5))), "L, N ≤ B − 1"),
        (lambda: so3.synthesize(np.zeros((2, 3, 3)), np.nan, 0.0, 0.0), "finite"),
        (lambda: so3.grid(0), "band limit"),
        pytest.param(  # lists: the angles are annotated as arrays (ArrayLike)
            lambda: so3.analyse_points([], [], [], 3), "at least one", marks=pytest.mark.wrong_types
        ),
    ],
)
def test_bad_inputs(call, match):
    with pytest.raises(InvalidInputError, match=match):
        call()
