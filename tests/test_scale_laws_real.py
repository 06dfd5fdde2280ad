"""Scale laws for real surfaces (issue 31, item 3): a measured topography as a scale law
(brdfscale.stats.MeasuredScaleLaw) against the facet statistics of a real field, against an
analytic GaussianSurface it interpolates, as a density (SciPy quadrature), positive definite and
monotone over hypothesis-drawn measurements, under jit/grad/vmap, and in evolve."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.integrate
import scipy.special
from hypothesis import given, settings, strategies as st

import brdfscale as bs
from brdfscale import lobes, stats


jax.config.update("jax_enable_x64", True)

DATA = Path(__file__).parent / "data" / "topographies"


def _surface():
    return stats.GaussianSurface(stats.GaussianCorrelation(1.0, (2.0, 5.0)))


def _sampled(surface, mus):
    return stats.MeasuredScaleLaw(mus, np.stack([np.asarray(surface.slope_covariance(m)) for m in mus]))


@pytest.mark.slow  # ~10 s on 2 cores (a real file's facet statistics)
def test_the_measured_law_reproduces_the_fields_facet_statistics():
    from brdfscale import synth, topography

    field = topography.read(DATA / "di-3.di", detrend="curvature")
    facets = synth.facet_statistics(field, field.scales(4), bins=17)
    law = stats.MeasuredScaleLaw.from_facets(facets[::-1])  # any order: sorted by μ
    for s in facets:
        np.testing.assert_allclose(np.asarray(law.slope_covariance(s.mu)), s.covariance, rtol=1e-12)
        np.testing.assert_allclose(np.asarray(law.slope_covariance_error(s.mu)), s.covariance_error, rtol=1e-9)
        np.testing.assert_allclose(np.asarray(law.at(s.mu).cov), s.covariance, rtol=1e-12)
    np.testing.assert_array_equal(np.asarray(law.mu), sorted(s.mu for s in facets))
    with pytest.raises(bs.InvalidInputError, match="not in"):
        law.at(facets[-1].mu * 2)
    with pytest.raises(bs.InvalidInputError, match="at 2 scales or more"):
        stats.MeasuredScaleLaw.from_facets(facets[:1])


@pytest.mark.slow  # ~13 s on 2 cores
def test_the_measured_law_interpolates_an_analytic_surface_within_its_stated_error():
    surface = _surface()
    stated = []
    for count in (10, 28):  # 2 decades of μ, then 3× denser
        mus = np.geomspace(0.5, 50.0, count)
        law = _sampled(surface, mus)
        t = np.linspace(0.1, 0.9, 5)[:, None]  # inside each interval, in ln μ
        worst = 0.0
        for mu in np.exp((1 - t) * np.log(mus[:-1]) + t * np.log(mus[1:])).ravel():
            truth = np.asarray(surface.slope_covariance(mu))
            got, err = np.asarray(law.slope_covariance(mu)), np.asarray(law.slope_covariance_error(mu))
            assert np.all(np.abs(got - truth) <= err + 1e-15 * np.abs(truth).max())
            worst = max(worst, float(np.max(err / np.abs(truth).max())))
        stated.append(worst)
    # not vacuous: second order in the spacing (3× denser: about 9× smaller)
    assert stated[1] < stated[0] / 5


def _ordered(draw_values):
    """Covariances decreasing in the Loewner order: Σ_{i+1} = Σ_i − a_i v vᵀ − b_i I with small steps."""
    theta, ratio, steps = draw_values
    rot = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    cov = rot @ np.diag([1.0, ratio]) @ rot.T
    out = [cov]
    for a, b in steps:
        step = a * out[-1] + b * np.eye(2) * min(np.linalg.eigvalsh(out[-1])[0], 1.0)
        out.append(out[-1] - 0.5 * step)
    return np.stack(out)


@pytest.mark.slow  # ~13 s on 2 cores
@settings(max_examples=15, deadline=None)
@given(
    st.tuples(
        st.floats(0.0, np.pi),
        st.floats(0.02, 50.0),
        st.lists(st.tuples(st.floats(0.0, 0.9), st.floats(0.0, 0.9)), min_size=2, max_size=6),
    ),
    st.floats(0.0, 1.0),
)
def test_measured_laws_are_positive_definite_and_monotone(values, where):
    cov = _ordered(values)
    mus = np.geomspace(1.0, 100.0, len(cov))
    law = stats.MeasuredScaleLaw(mus, cov)
    grid = np.geomspace(mus[0], mus[-1], 40)
    sigmas = np.stack([np.asarray(law.slope_covariance(m)) for m in grid])
    assert np.all(np.linalg.eigvalsh(sigmas)[:, 0] > 0)
    steps = np.linalg.eigvalsh(sigmas[:-1] - sigmas[1:])  # Σ(μ) − Σ(μ') ⪰ 0 for μ < μ'
    assert np.all(steps >= -1e-12 * np.abs(sigmas).max())
    mu = float(np.exp(np.log(mus[0]) + where * (np.log(mus[-1]) - np.log(mus[0]))))
    assert np.all(np.linalg.eigvalsh(np.asarray(law.at(mu).cov)) > 0)


def test_s_at_mu_is_a_density_of_mass_one():
    law = _sampled(_surface(), np.geomspace(0.5, 50.0, 6))
    s = law.at(3.7)
    c = np.asarray(s.cov)
    r = 10 * np.sqrt(np.linalg.eigvalsh(c).max())
    x, w = scipy.special.roots_legendre(240)  # SciPy's Gauss–Legendre product rule on [−r, r]²
    x, w = r * x, r * w
    grid = np.stack(np.meshgrid(x, x, indexing="ij"), axis=-1)
    values = np.asarray(s.density(jnp.asarray(grid)))
    weights = np.outer(w, w)
    assert float(np.sum(weights * values)) == pytest.approx(1.0, abs=1e-10)
    # its second moments are Σ(μ)
    xx = float(np.sum(weights * values * grid[..., 0] ** 2))
    xy = float(np.sum(weights * values * grid[..., 0] * grid[..., 1]))
    np.testing.assert_allclose([xx, xy], [c[0, 0], c[0, 1]], rtol=1e-9, atol=1e-12 * c[0, 0])


@pytest.mark.slow  # ~13 s on 2 cores
def test_jit_grad_vmap_equal_eager():
    surface = _surface()
    law = _sampled(surface, np.geomspace(0.5, 50.0, 8))
    law = stats.MeasuredScaleLaw(law.mu, law.covariance, 0.01 * jnp.abs(law.covariance))
    mus = jnp.array([0.6, 1.3, 7.0, 44.0])
    eager = np.stack([np.asarray(law.slope_covariance(m)) for m in mus])
    eager_err = np.stack([np.asarray(law.slope_covariance_error(m)) for m in mus])
    np.testing.assert_allclose(np.asarray(jax.vmap(law.slope_covariance)(mus)), eager, rtol=1e-14)
    np.testing.assert_allclose(np.asarray(jax.jit(jax.vmap(law.slope_covariance_error))(mus)), eager_err, rtol=1e-14)
    f = lambda m: law.at(m).cov[0, 0]
    for m in mus:
        g, gj = float(jax.grad(f)(m)), float(jax.jit(jax.grad(f))(m))
        h = 1e-6 * float(m)
        numeric = (float(f(m + h)) - float(f(m - h))) / (2 * h)
        assert g == pytest.approx(gj, rel=1e-13) and g == pytest.approx(numeric, rel=1e-6)
    # the data themselves: differentiable (a fit's parameters)
    dcov = jax.grad(lambda c: stats.MeasuredScaleLaw(law.mu, c).slope_covariance(2.0)[1, 1])(law.covariance)
    assert float(jnp.sum(dcov)) == pytest.approx(1.0)  # weights (1 − t) and t of a convex combination
    with pytest.raises(Exception, match="outside the measured scales"):
        jax.block_until_ready(jax.jit(lambda m: law.slope_covariance(m))(100.0))


def test_evolve_with_a_measured_law():
    law = _sampled(_surface(), np.geomspace(0.5, 50.0, 8))
    lobe = lobes.Lobe(stats.Gaussian(cov=jnp.array([[0.01, 0.002], [0.002, 0.02]])))
    mu0, mu = 1.0, 12.0
    evolved = bs.evolve(lobe, law.at(mu0), law.at(mu))
    # Gaussian algebra (seed Eq. 4.4): covariances add — Σ_lobe + Σ(μ0) − Σ(μ)
    expected = np.asarray(lobe.shape.cov) + np.asarray(law.slope_covariance(mu0)) - np.asarray(law.slope_covariance(mu))
    np.testing.assert_allclose(np.asarray(evolved.shape.cov), expected, rtol=1e-12)
    with pytest.raises(bs.NoBRDFAtScaleError, match="negative variance"):
        bs.evolve(
            lobes.Lobe(stats.Gaussian(cov=1e-6 * jnp.eye(2))), law.at(mu), law.at(mu0)
        )  # far finer than the lobe allows


def test_bad_measurements_are_refused_by_name():
    mus, cov = np.array([1.0, 2.0]), np.stack([np.eye(2), 0.5 * np.eye(2)])
    with pytest.raises(bs.InvalidInputError, match="increasing"):
        stats.MeasuredScaleLaw(mus[::-1], cov)
    with pytest.raises(bs.InvalidInputError, match="positive definite"):
        stats.MeasuredScaleLaw(mus, np.stack([np.eye(2), -np.eye(2)]))
    with pytest.raises(bs.InvalidInputError, match="shape"):
        stats.MeasuredScaleLaw(mus, cov[:1])
    with pytest.raises(bs.InvalidInputError, match="standard errors"):
        stats.MeasuredScaleLaw(mus, cov, -cov)


# -- heavy tails: StudentT and StudentTLaw; a learned law: MonotoneSplineLaw -------------------------
@pytest.mark.slow  # ~14 s on 2 cores
def test_student_t_transform_matches_scipys_bessel_k_and_nu_2_is_ggx():
    import scipy.special as sp

    cov = np.array([[0.02, 0.006], [0.006, 0.01]])
    W = np.array([[0.0, 0.0], [3.0, -1.0], [20.0, 7.0], [60.0, 45.0], [-200.0, 10.0]])
    q = np.einsum("...i,ij,...j->...", W, cov, W)
    for nu in (0.7, 2.0, 3.3, 9.0, 60.0):
        s = stats.StudentT(cov, nu=nu)
        a, x = nu / 2, np.sqrt(nu * q)
        with np.errstate(invalid="ignore"):
            ref = np.where(x > 0, x**a * sp.kv(a, x) / (sp.gamma(a) * 2 ** (a - 1)), 1.0)
        np.testing.assert_allclose(np.asarray(s.cf(jnp.asarray(W))).real, ref, rtol=1e-11, atol=1e-14)
    # ν = 2 is GGX with α = √2 σ (its own closed form, x K₁(x))
    t, g = stats.StudentT(sigma=(0.05, 0.08), nu=2.0), stats.GGX(alpha_x=0.05 * np.sqrt(2), alpha_y=0.08 * np.sqrt(2))
    m = jnp.array([[0.0, 0.0], [0.1, -0.3], [1.0, 2.0]])
    np.testing.assert_allclose(np.asarray(t.density(m)), np.asarray(g.density(m)), rtol=1e-13)
    np.testing.assert_allclose(
        np.asarray(t.cf(jnp.asarray(W))), np.asarray(g.cf(jnp.asarray(W))), rtol=1e-11, atol=1e-14
    )


@pytest.mark.slow  # ~10 s on 2 cores
@settings(max_examples=8, deadline=None)
@given(st.floats(0.8, 30.0), st.floats(0.01, 0.3), st.floats(0.2, 5.0), st.floats(0.0, np.pi))
def test_student_t_is_a_density_of_mass_one_and_its_transform_is_the_gaussian_scale_mixture(nu, sigma, ratio, angle):
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    cov = rot @ np.diag([sigma**2, (ratio * sigma) ** 2]) @ rot.T
    s = stats.StudentT(cov, nu=nu)
    # mass: in whitened coordinates m = L z (Σ = L Lᵀ) the density is radial; SciPy quadrature
    # of 2π r s(L r e) det L to r = ∞ along two directions e (equal: the level sets are ellipses)
    L = np.linalg.cholesky(cov)
    f = jax.jit(lambda r, e: s.density(jnp.asarray(L) @ (r * e)))
    for e in (np.array([1.0, 0.0]), np.array([0.6, 0.8])):
        mass = scipy.integrate.quad(
            lambda r: 2 * np.pi * r * float(f(r, e)) * np.linalg.det(L),
            0,
            np.inf,
            epsabs=1e-13,
            epsrel=1e-11,
            limit=200,
        )[0]
        assert mass == pytest.approx(1.0, abs=1e-8)
    # the transform is E_τ[exp(−WᵀΣW/(2τ))], τ ~ Gamma(ν/2, rate ν/2): SciPy quadrature of that definition
    import scipy.stats as sps

    for w in (np.array([0.7, -0.4]) / sigma, np.array([5.0, 2.0]) / sigma):
        q = float(w @ cov @ w)
        value = scipy.integrate.quad(
            lambda t: sps.gamma.pdf(t, nu / 2, scale=2 / nu) * np.exp(-q / (2 * t)), 0, np.inf, epsabs=1e-14, limit=200
        )[0]
        assert float(s.cf(jnp.asarray(w)).real) == pytest.approx(value, rel=1e-9, abs=1e-13)


@pytest.mark.slow  # ~10 s on 2 cores
@settings(max_examples=20, deadline=None)
@given(
    st.tuples(st.floats(0.01, 1.0), st.floats(0.01, 1.0)),
    st.lists(st.tuples(st.floats(0.0, 2.0), st.floats(0.0, 2.0)), min_size=2, max_size=6),
    st.floats(-np.pi, np.pi),
)
def test_monotone_spline_laws_are_positive_definite_monotone_and_have_the_stated_slopes(sigma, rates, angle):
    r = np.array(rates).T
    law = stats.MonotoneSplineLaw(0.1, 100.0, sigma, r, angle=angle)
    grid = np.geomspace(0.01, 1e3, 60)
    sigmas = np.stack([np.asarray(law.slope_covariance(m)) for m in grid])
    assert np.all(np.linalg.eigvalsh(sigmas)[:, 0] > 0)
    steps = np.linalg.eigvalsh(sigmas[:-1] - sigmas[1:])
    assert np.all(steps >= -1e-12 * np.abs(sigmas).max(axis=(1, 2))[:-1, None])
    # d ln σ_a / d ln μ = −r_{a,k} at the knots (forward-mode derivative of the closed form)
    f = lambda x: jnp.log(law.principal_sigmas(jnp.exp(x)))
    for k, x in enumerate(np.asarray(law.knots)):
        np.testing.assert_allclose(np.asarray(jax.jacfwd(f)(x)), -r[:, k], atol=1e-12)


@pytest.mark.slow  # ~60 s on 2 cores (compilations)
def test_heavy_tailed_and_learned_laws_under_jit_grad_vmap_equal_eager():
    spline = stats.MonotoneSplineLaw(0.5, 50.0, (0.2, 0.1), [[0.1, 0.6, 1.0], [0.3, 0.4, 1.2]], angle=0.3, nu=3.0)
    heavy = stats.StudentTLaw(stats.WidthLaw(0.2, 1.0, 0.8), 2.5, nu_exponent=0.3)
    mus = jnp.array([0.3, 1.0, 7.0, 80.0])
    W = jnp.array([[5.0, -2.0], [30.0, 11.0]])
    for law in (spline, heavy):
        cf = lambda mu: law.at(mu).cf(W).real
        eager = np.stack([np.asarray(cf(m)) for m in mus])
        np.testing.assert_allclose(np.asarray(jax.vmap(cf)(mus)), eager, rtol=1e-13)
        np.testing.assert_allclose(np.asarray(jax.jit(jax.vmap(cf))(mus)), eager, rtol=1e-13)
        g = lambda mu: law.at(mu).cf(W).real.sum()
        for m in mus:
            h = 1e-6 * float(m)
            numeric = (float(g(m + h)) - float(g(m - h))) / (2 * h)
            assert float(jax.grad(g)(m)) == pytest.approx(float(jax.jit(jax.grad(g))(m)), rel=1e-12)
            assert float(jax.grad(g)(m)) == pytest.approx(numeric, rel=1e-5, abs=1e-10)
    # the tail index is a differentiable parameter: d S/d ν against central differences
    s_of = lambda nu: stats.StudentT(jnp.eye(2) * 0.01, nu=nu).cf(W).real.sum()
    numeric = (float(s_of(3.0 + 1e-6)) - float(s_of(3.0 - 1e-6))) / 2e-6
    assert float(jax.grad(s_of)(3.0)) == pytest.approx(numeric, rel=1e-6)


@pytest.mark.slow  # ~15 s on 2 cores
def test_evolve_with_a_heavy_tailed_law():
    heavy = stats.StudentTLaw(stats.WidthLaw(0.2, 1.0, 0.8), 2.5)
    s0, s1 = heavy.at(1.0), heavy.at(10.0)
    lobe = lobes.GGX(0.1)
    evolved = bs.evolve(lobe, s0, s1, tol=1e-6)  # towards coarser facets: the radial path
    assert evolved.shape.discretisation.path == "radial"
    k = jnp.array([0.0, 3.0, 15.0, 40.0])
    W = jnp.stack([k, jnp.zeros_like(k)], -1)
    # seed Eq. 4.3: G(W, μ) S(W, μ) = G(W, μ0) S(W, μ0)
    np.testing.assert_allclose(
        np.asarray(evolved.cf(W) * s1.cf(W)).real, np.asarray(lobe.cf(W) * s0.cf(W)).real, rtol=1e-10, atol=1e-14
    )
    values = np.asarray(evolved.density(jnp.array([[0.0, 0.0], [0.05, 0.0], [0.3, 0.1]])))
    assert np.all(values > 0)


def test_the_planner_takes_a_measured_law():
    """brdfscale.scene accepts any AbstractScaleLaw: a material whose statistics are measured
    evaluates, at every query's scale, what evolve gives with the law's statistics there."""
    from brdfscale import scene
    from brdfscale.geometry import microfacet_factor, slope_to_direction

    law = _sampled(_surface(), np.geomspace(0.5, 50.0, 8))
    lobe = lobes.Lobe(stats.Gaussian(cov=jnp.array([[0.01, 0.002], [0.002, 0.02]])), amplitude=0.8)
    mu0 = 1.0
    material = scene.Material(lobe, mu0, law)
    u = np.array([[0.0, 0.0], [0.05, -0.02], [-0.1, 0.07], [0.02, 0.15]])
    mu = np.array([1.0, 3.0, 12.0, 45.0])
    d = np.asarray(slope_to_direction(jnp.asarray(u)))
    plan = scene.plan(scene.Scene((material,), scene.Queries(d, d, mu), 1e-6))
    got = np.asarray(plan.evaluate()) / np.asarray(microfacet_factor(jnp.asarray(d), jnp.asarray(d)))
    want = [float(bs.evolve(lobe, law.at(mu0), law.at(m)).density(jnp.asarray(x)[None])[0]) for x, m in zip(u, mu)]
    np.testing.assert_allclose(got, want, rtol=1e-10)  # both A·g (the amplitude 0.8 included)
