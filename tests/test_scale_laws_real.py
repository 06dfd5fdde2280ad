"""Scale laws for real surfaces (issue 31, item 3): a measured topography as a scale law
(brdfscale.stats.MeasuredScaleLaw) against the facet statistics of a real field, against an
analytic GaussianSurface it interpolates, as a density (SciPy quadrature), positive definite and
monotone over hypothesis-drawn measurements, under jit/grad/vmap, and in evolve."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
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
