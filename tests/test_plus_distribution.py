"""Plus-distributions as slope statistics: action on test functions, nearly-specular statistics,
the instrument view, and their use in evolve and Mixture (docs/conventions.md §4)."""

import jax
import jax.numpy as jnp
import mpmath as mp
import numpy as np
import pytest

from brdfscale import evolve, InvalidInputError, lobes, NoBRDFAtScaleError, plus, SingularDensityError, stats


def _action_reference(n, x0, angular_mean, points):
    """∫_0^{x0} (logⁿ(x/x0)/x)(ψ̄(x) − ψ̄(0)) dx (the definition, docs/conventions.md §4) by mpmath quadrature
    in v = ln(x0/x) on unit panels, split at the images of ``points``; beyond v = 40 the
    integrand is below e^{−80} (ψ̄(x) − ψ̄(0) = O(x²)) and is dropped (there 1 − ψ̄/ψ̄(0) is
    below the working precision)."""
    with mp.workdps(40):
        x0 = mp.mpf(x0)
        centre = angular_mean(mp.mpf(0))
        f = lambda v: (-v) ** n * (angular_mean(x0 * mp.exp(-v)) - centre)
        breaks = {mp.log(x0 / mp.mpf(p)) for p in points if 0 < p < x0}
        return float(mp.quad(f, sorted(breaks | set(mp.linspace(0, 40, 41)))))


def _gaussian_angular_mean(rho, s):
    """Mean of exp(−|m − m1|²/2s²) over the circle |m| = x, |m1| = ρ (closed form with I₀)."""
    rho, s = mp.mpf(rho), mp.mpf(s)
    return lambda x: mp.exp(-(x * x + rho * rho) / (2 * s * s)) * mp.besseli(0, x * rho / (s * s))


@pytest.mark.parametrize("n", [0, 1, 3, 6])
def test_apply_against_definition(n):
    """⟨h_n, ψ⟩ for an off-centre Gaussian bump (not radially symmetric about the centre)."""
    x0, m1, s = 0.2, np.array([0.05, -0.03]), 0.04
    psi = lambda m: jnp.exp(-jnp.sum((m - m1) ** 2, axis=-1) / (2 * s**2))
    got = float(plus.PlusDistribution(n, x0).apply(psi, scale=s))
    rho = float(np.linalg.norm(m1))
    want = _action_reference(n, x0, _gaussian_angular_mean(rho, s), [rho - 3 * s, rho, rho + 3 * s])
    # rounding of ψ̄ − ψ̄(0) (about 1e-16) is weighted by vⁿ: the bound grows with n
    assert abs(got - want) <= 1e-11 * (n + 1) * abs(want)


def test_apply_shifted_is_translation():
    x0, offset = 0.1, jnp.array([0.02, 0.01])
    psi = lambda m: jnp.exp(-jnp.sum((m - 0.03) ** 2, axis=-1) / 0.002) * (1 + m[..., 0])
    h = plus.PlusDistribution(2, x0)
    moved = h.shifted(offset).apply(psi)
    direct = h.apply(lambda m: psi(m + offset))
    assert abs(float(moved - direct)) <= 1e-13 * abs(float(direct))


@pytest.mark.parametrize("n", [0, 4])
def test_apply_plane_wave_is_transform(n):
    """ψ(m) = cos(W·m) gives H_n(|W|): the action and the transform agree."""
    x0 = 0.3
    for k in (10.0, 70.0):  # z = 3 (series branch) and z = 21 (expansion branch)
        W = jnp.array([0.6, 0.8]) * k
        got = plus.PlusDistribution(n, x0).apply(lambda m: jnp.cos(m @ W), scale=x0 / 40, angles=128)
        want = plus.plus_transform(k * x0, n)
        assert abs(float(got - want)) <= 1e-11 * abs(float(want))


def test_distribution_interface():
    h = plus.PlusDistribution(1, 0.05)
    with pytest.raises(SingularDensityError, match="apply"):
        h.density(jnp.zeros(2))
    assert float(h.cf(jnp.zeros(2)).real) == 0.0  # no mass
    W = jnp.array([[30.0, -40.0]])
    offset = jnp.array([0.01, 0.02])
    np.testing.assert_allclose(
        np.asarray(h.shifted(offset).cf(W)), np.asarray(h.cf(W) * jnp.exp(-1j * W @ offset)), rtol=1e-15
    )
    assert float(h.support_radius(1e-9)) == pytest.approx(0.05)
    with pytest.raises(InvalidInputError, match="x0"):
        plus.PlusDistribution(1, -0.1)
    with pytest.raises(InvalidInputError, match="psi"):
        h.apply(3.0)


def test_nearly_specular_is_the_sum_of_its_terms_and_mixture_refuses_h_n():
    """S = (a·1 + c_1 H_1 + w S_smooth)/(a + w): the terms' transforms, normalised by the mass a + w
    (the h_n have none). A Mixture of probability densities cannot take an h_n: its weights
    would be normalised by a sum that is not the mass."""
    x0, smooth = 0.05, stats.Beckmann(0.1)
    h1 = plus.PlusDistribution(1, x0)
    nearly = plus.NearlySpecular(0.6, [0.0, 0.1], x0, smooth=smooth, smooth_weight=0.3)
    W = jnp.array([[0.0, 0.0], [10.0, 5.0], [200.0, -100.0]])
    terms = 0.6 * stats.Delta().cf(W) + 0.1 * h1.cf(W) + 0.3 * smooth.cf(W)
    np.testing.assert_allclose(np.asarray(nearly.cf(W)), np.asarray(terms) / 0.9, rtol=1e-14)
    with pytest.raises(SingularDensityError):
        nearly.density(jnp.zeros(2))
    with pytest.raises(
        InvalidInputError, match=r"components must be probability densities.*PlusDistribution.*NearlySpecular"
    ):
        stats.Mixture([0.6, 0.1, 0.3], [stats.Delta(), h1, smooth])


def test_nearly_specular_normalisation_and_validation():
    s = plus.NearlySpecular(3.0, [0.6, -0.3], 0.1, smooth=stats.Beckmann(0.2), smooth_weight=1.0)
    assert float(s.specular) == pytest.approx(0.75) and float(s.smooth_weight) == pytest.approx(0.25)
    np.testing.assert_allclose(np.asarray(s.strengths), [0.15, -0.075])
    assert complex(s.cf(jnp.zeros(2))) == pytest.approx(1.0)
    for bad in (dict(specular=-1.0), dict(strengths=np.zeros(8)), dict(smooth_weight=0.5)):
        kwargs = dict(specular=1.0, strengths=[0.1], x0=0.1) | bad
        with pytest.raises(InvalidInputError):
            plus.NearlySpecular(**kwargs)


def _observed_reference(a, c, x0, sigma, r):
    """a K(r) + Σ c_n ∫ (logⁿ(x/x0)/x)(K̄(x; r) − K(r)) dx, K̄ the kernel's circular mean."""
    mean = lambda x: _gaussian_angular_mean(r, sigma)(x) / (2 * mp.pi * mp.mpf(sigma) ** 2)
    total = a * float(mean(mp.mpf(0)))
    for n, cn in enumerate(c):
        total += cn * _action_reference(n, x0, mean, [r - 3 * sigma, r, r + 3 * sigma, sigma])
    return total


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_observed_density_against_mpmath():
    a, c, x0, sigma = 1.0, [0.25, 0.08, -0.01], 0.06, 0.008
    seen = plus.observe(plus.NearlySpecular(a, c, x0), stats.Gaussian(sigma=sigma))
    r = np.array([0.0, 0.059])
    got = np.asarray(seen.density(jnp.stack([r, np.zeros_like(r)], -1)))
    want = np.array([_observed_reference(a, c, x0, sigma, v) for v in r])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-11 * want.max())


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
@pytest.mark.parametrize("method", ["radial", "grid"])
def test_evolve_agrees_with_slope_space_view(method):
    """brdfscale.evolve (spectral, from S(W) = a + Σ c_n H_n + w S_smooth) sees the same lobe as the
    slope-space action: the statistic works in evolve's paths."""
    s = plus.NearlySpecular(0.7, [0.2, 0.05], 0.05, smooth=stats.Beckmann(0.04), smooth_weight=0.3)
    kernel = stats.Gaussian(sigma=0.006)
    u = jnp.array([[0.0, 0.0], [0.004, 0.003], [0.02, 0.0], [0.0, -0.045], [0.07, 0.02]])
    direct = np.asarray(plus.observe(s, kernel).density(u))
    spectral = np.asarray(
        evolve(
            lobes.Lobe(kernel), s, stats.Delta(), method=method, **({"size": 256} if method == "grid" else {})
        ).density(u)
    )
    tol = 1e-8 if method == "radial" else 1e-6
    np.testing.assert_allclose(spectral, direct, rtol=0, atol=tol * direct.max())


def test_observed_gradients_against_finite_differences():
    kernel = stats.Gaussian(sigma=0.01)
    u = jnp.array([[0.0, 0.0], [0.015, 0.01], [0.05, 0.0]])

    def total(params):
        c, x0 = params[:2], params[2]
        return jnp.sum(plus.ObservedDensity(plus.NearlySpecular(1.0, c, x0), kernel).density(u))

    p = jnp.array([0.2, 0.05, 0.06])
    grad = np.asarray(jax.grad(total)(p))
    assert np.all(np.isfinite(grad))
    for i in range(3):
        h = 1e-6 * max(abs(float(p[i])), 1e-2)
        e = jnp.zeros(3).at[i].set(h)
        fd = float(total(p + e) - total(p - e)) / (2 * h)
        assert grad[i] == pytest.approx(fd, rel=1e-6)


def test_negative_observation_is_reported():
    """c_0 > 0 removes ~c_0 ln(x0/σ) of the δ's weight at the centre; c_0 < 0 puts negative mass
    on the disk. Both are physical at a coarse resolution only."""
    fine, coarse = stats.Gaussian(sigma=1e-4), stats.Gaussian(sigma=0.05)
    too_strong = plus.NearlySpecular(1.0, [0.5], 0.2)
    with pytest.raises(NoBRDFAtScaleError, match="negative"):
        plus.observe(too_strong, fine)
    plus.observe(too_strong, coarse)  # fine when blurred enough
    negative = plus.NearlySpecular(1.0, [-0.1], 0.2)
    with pytest.raises(NoBRDFAtScaleError, match=r"u = \[0\.[01]"):
        plus.observe(negative, stats.Gaussian(sigma=0.005))
    low, high, where = plus.ObservedDensity(negative, stats.Gaussian(sigma=0.005)).minimum()
    assert float(low) < 0 < float(high) and 0 < float(jnp.linalg.norm(where)) < 0.2


@pytest.mark.wrong_types
def test_observe_refuses_a_kernel_that_is_no_gaussian():
    with pytest.raises(InvalidInputError, match="kernel"):
        plus.observe(plus.NearlySpecular(1.0, [0.5], 0.2), stats.Disk(0.01))


# --- input handling -------------------------------------------------------------------------------


@pytest.mark.wrong_types
def test_observe_refuses_a_string_rtol_and_fractional_points():
    s, kernel = plus.NearlySpecular(1.0, [0.1], 0.1), stats.Gaussian(sigma=0.01)
    with pytest.raises(InvalidInputError, match="rtol must be a finite number ≥ 0"):
        plus.observe(s, kernel, rtol="1e-9")
    with pytest.raises(InvalidInputError, match=r"points must be an integer in \[16, 65536\]"):
        plus.observe(s, kernel, points=100.5)


def test_observe_validates_rtol_and_points():
    s, kernel = plus.NearlySpecular(1.0, [0.1], 0.1), stats.Gaussian(sigma=0.01)
    for bad in (-1, float("nan"), float("inf")):
        with pytest.raises(InvalidInputError, match="rtol must be a finite number ≥ 0"):
            plus.observe(s, kernel, rtol=bad)
    plus.observe(s, kernel, rtol=0)
    for bad in (10**9, 8):
        with pytest.raises(InvalidInputError, match=r"points must be an integer in \[16, 65536\]"):
            plus.observe(s, kernel, points=bad)
    # above one batch of samples the minimum is found batch by batch, same values
    shifted = plus.NearlySpecular(1.0, [-0.1], 0.2, mean=[0.01, 0.0])
    seen = plus.ObservedDensity(shifted, stats.Gaussian(sigma=0.005))
    low, high, where = seen.minimum(600)  # 8 rays × 600 radii > 4096
    radii = np.linspace(0.0, 1.0, 600) * float(seen.support_radius(1e-12))
    phi = np.arange(8) * np.pi / 4
    u = (np.array([0.01, 0.0]) + radii[:, None, None] * np.stack([np.cos(phi), np.sin(phi)], -1)[None]).reshape(-1, 2)
    direct = np.asarray(seen.density(u))
    assert float(low) == direct.min() and float(high) == direct.max()
    np.testing.assert_array_equal(np.asarray(where), u[np.argmin(direct)])


def test_kernel_variance_must_be_representable():
    s = plus.NearlySpecular(1.0, [0.1], 0.1)
    with pytest.raises(InvalidInputError, match="σ²|variances"):
        plus.observe(s, stats.Gaussian(sigma=1e-200))  # σ² underflows to 0


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_transforms_stay_finite_for_huge_arguments():
    """Far out H_n = P_n(ℓ), ℓ = ln(z e^γ/2): P_0 = −ℓ, P_1 = ℓ²/2; needs ln z only, so z² may
    overflow (z > 1.3e154), and x0² too at W = 0."""
    for z in (1e160, 1e300):
        ell = np.log(z) + np.euler_gamma - np.log(2)
        assert float(plus.plus_transform(z, 0)) == pytest.approx(-ell, rel=1e-15)
        assert float(plus.plus_transform(z, 1)) == pytest.approx(ell**2 / 2, rel=1e-15)
    assert np.isfinite(float(plus.plus_transform(1e160, 6)))
    # continuous where the decaying terms are dropped and where z² overflows
    for z in (1e15, 1.3e154):
        below, above = (float(plus.plus_transform(z * f, 2)) for f in (1 - 1e-9, 1 + 1e-9))
        assert abs(above - below) < 1e-6 * abs(below)
    h = plus.PlusDistribution(0, 1e200)
    W = jnp.array([[0.0, 0.0], [3.0, 4.0]])
    ell = np.log(5.0 * 1e200) + np.euler_gamma - np.log(2)
    np.testing.assert_allclose(np.asarray(h.cf(W)), [0.0, -ell], rtol=1e-15)
    assert np.all(np.isfinite(np.asarray(plus.NearlySpecular(1.0, [0.1, 0.01], 1e200).cf(W))))


def test_plus_distribution_is_a_generalised_density_not_a_probability_density():
    """A plus-distribution has mass 0 and no pointwise density: its type says so
    (AbstractGeneralisedDensity, sharing only the transform interface AbstractDistribution with
    the probability densities), and it is refused as a nearly-specular smooth part."""
    h = plus.PlusDistribution(1, 0.1)
    assert issubclass(plus.PlusDistribution, stats.AbstractGeneralisedDensity)
    assert isinstance(h, stats.AbstractGeneralisedDensity) and isinstance(h, stats.AbstractDistribution)
    assert not isinstance(h, stats.AbstractSlopeDensity)
    assert not hasattr(plus.PlusDistribution, "is_probability_density")
    assert complex(h.cf(jnp.zeros(2))) == 0  # mass 0
    with pytest.raises(SingularDensityError, match="no pointwise density"):
        h.density(jnp.zeros(2))
    for density in (
        stats.Beckmann(0.1),
        stats.Delta(),
        plus.NearlySpecular(0.5, [0.1], 0.1),
        stats.Tabulated(np.ones((3, 3)), extent=0.1),
    ):
        assert isinstance(density, stats.AbstractSlopeDensity) and isinstance(density, stats.AbstractDistribution)
        assert not isinstance(density, stats.AbstractGeneralisedDensity)
    assert not issubclass(stats.AbstractSlopeDensity, stats.AbstractGeneralisedDensity)
    assert not issubclass(stats.AbstractGeneralisedDensity, stats.AbstractSlopeDensity)
    with pytest.raises(InvalidInputError, match="smooth must be a probability density"):
        plus.NearlySpecular(0.5, [0.1], 0.1, smooth=plus.PlusDistribution(0, 0.1), smooth_weight=0.5)


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
@pytest.mark.parametrize("n", [0, 2])
def test_transform_depends_on_w_x0_only_against_mpmath(n):
    """Regression (issue 16): ``PlusDistribution(2, x0).cf(W)`` was NaN for |W| ≳ 1.3e154 even
    where W·x0 = 1 — the norm was formed as |W|² x0², which overflows before x0 scales it.
    H_n depends on z = |W| x0 alone: against mpmath's series at the same z, wherever |W| and
    x0 sit in float64's range (and with |W| tiny, x0 huge), on the vector and radial paths and
    in the nearly-specular statistic."""
    from tests.references.plus_transform import polynomial, reference

    cases = []
    wanted = {z: reference(n, z) for z in (1e-3, 1.0, 7.5, 30.0, 400.0)}
    for z in wanted:
        for w in (1e-200, 1e-20, 1.3e154, 1e155, 1e200, 1e300):
            x0 = z / w
            if 1e-300 < x0 < 1e300:
                cases.append((w, x0, z))
    for w, x0, z in cases:
        want = wanted[z]
        h = plus.PlusDistribution(n, x0)
        along = complex(h.cf(jnp.array([w, 0.0])))
        diagonal = complex(h.cf(jnp.array([w, w]) / np.sqrt(2)))
        radial = float(h.cf_radial(w))
        for got in (along.real, diagonal.real, radial):
            assert np.isfinite(got) and abs(got - want) <= 2e-13 * abs(want), (w, x0, z, got, want)
        assert along.imag == 0
    # far out (z > 1e15 drops the decaying terms): z² overflows as well; H_n = P_n(ln z + γ − ln 2)
    with mp.workdps(30):
        want = float(polynomial(n, mp.mpf(10) ** 200))
    for w, x0 in ((1e300, 1e-100), (1e250, 1e-50), (1e-100, 1e300)):
        got = complex(plus.PlusDistribution(n, x0).cf(jnp.array([w, 0.0]))).real
        assert abs(got - want) <= 1e-14 * abs(want), (w, x0)
    s = plus.NearlySpecular(1.0, [0.1, 0.2], 1e-200)
    W = jnp.array([[1e200, 0.0], [0.0, 0.0], [1e300, 1e300]])
    value = np.asarray(s.cf(W))
    assert np.all(np.isfinite(value)) and value[1] == 1
    assert abs(value[0].real - (1 + (0.1 * reference(0, 1.0) + 0.2 * reference(1, 1.0)) / 1.0)) < 1e-14
    # gradients stay finite at W = 0 and where |W|² overflows
    grad = jax.grad(lambda t: plus.PlusDistribution(n, 1e-200).cf(jnp.array([t, 0.0])).real)
    assert np.isfinite(float(grad(1e200))) and float(grad(0.0)) == 0
