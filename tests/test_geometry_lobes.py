"""Geometry (directions, slopes, Jacobians) and lobe evaluation."""

import math

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.integrate as si
from hypothesis import given, settings, strategies as st

import brdfscale as bs
from brdfscale import geometry, lobes, stats


@settings(max_examples=30, deadline=None)
@given(mx=st.floats(-3, 3), my=st.floats(-3, 3), tx=st.floats(-0.6, 0.6), ty=st.floats(-0.6, 0.6))
def test_mirror_reflection_half_slope_is_the_facet_slope(mx, my, tx, ty):
    n = geometry.slope_to_direction(jnp.array([mx, my]))
    i = geometry.slope_to_direction(jnp.array([tx, ty]))  # any upward unit vector
    o = geometry.reflect(i, n)
    if float(o[2]) <= 1e-3:  # reflected below the horizon: no half vector in the upper hemisphere
        return
    np.testing.assert_allclose(geometry.half_slope(i, o), [mx, my], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(geometry.direction_to_slope(n), [mx, my], rtol=1e-12, atol=1e-15)


def test_slope_area_jacobian_against_quadrature():
    """∫_{|m|<R} cos³θ d²m is the solid angle of the cap θ < atan R: 2π(1 − cos θ_max)."""
    R = 1.7
    val, _ = si.quad(lambda r: 2 * math.pi * r * float(geometry.solid_angle_per_slope_area(jnp.array([r, 0.0]))), 0, R)
    assert abs(val - 2 * math.pi * (1 - math.cos(math.atan(R)))) < 1e-12


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_microfacet_factor_energy_at_normal_incidence():
    """∫ ρ dω_o for a Beckmann lobe at normal incidence, against an independent 1D integral.

    With ρ = A D(h)/(4 cosθ_o), dω_o = 4 (h·o) dω_h, h·o = cosθ_h and cosθ_o = 2cos²θ_h − 1
    (i = z), the integral is A·E[(1 + x)/(1 − x)] over the Beckmann slope density, whose
    x = |m|² is exponential with mean α²."""
    alpha, amplitude = 0.05, 0.7
    lobe = lobes.Beckmann(alpha, amplitude=amplitude)
    i = jnp.array([0.0, 0.0, 1.0])

    def integrand(phi, theta):
        o = jnp.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])
        return float(lobe.evaluate(i, o)) * math.sin(theta)

    val, _ = si.dblquad(integrand, 0, 0.6, 0, 2 * math.pi, epsabs=1e-11, epsrel=1e-9)
    x_max = math.tan(0.3) ** 2  # θ_o < 0.6 ⇔ θ_h < 0.3
    ref, _ = si.quad(lambda x: (1 + x) / (1 - x) * math.exp(-x / alpha**2) / alpha**2, 0, x_max, epsabs=1e-14)
    assert abs(val / amplitude - ref) < 1e-8


def test_evaluate_batches_over_directions():
    lobe = lobes.GGX(alpha_x=0.1, alpha_y=0.2)
    rng = np.random.default_rng(0)
    i = np.asarray(geometry.slope_to_direction(jnp.asarray(rng.normal(scale=0.2, size=(7, 5, 2)))))
    o = np.asarray(geometry.slope_to_direction(jnp.asarray(rng.normal(scale=0.2, size=(7, 5, 2)))))
    vals = lobe.evaluate(i, o)
    assert vals.shape == (7, 5)
    one = lobe.evaluate(i[3, 2], o[3, 2])
    assert float(one) == pytest.approx(float(vals[3, 2]), rel=1e-14)
    h = (i[3, 2] + o[3, 2]) / np.linalg.norm(i[3, 2] + o[3, 2])
    m = h[:2] / h[2]
    D = float(stats.GGX(alpha_x=0.1, alpha_y=0.2).density(jnp.asarray(m))) / h[2] ** 4
    assert float(one) == pytest.approx(D / (4 * o[3, 2, 2]), rel=1e-12)


def test_tabulated_lobe_amplitude_is_its_integral():
    x = np.linspace(-0.5, 0.5, 101)
    X, Y = np.meshgrid(x, x)
    vals = 3.0 * np.exp(-(X**2 + Y**2) / 0.01) / (np.pi * 0.01)
    lobe = lobes.Tabulated(vals, extent=0.5)
    assert float(lobe.amplitude) == pytest.approx(3.0, rel=1e-6)
    assert float(lobe.density(jnp.array([0.0, 0.0]))) == pytest.approx(vals[50, 50], rel=1e-12)


@pytest.mark.parametrize(
    "args, match",
    [
        ((jnp.array([0.0, 0.0, 2.0]), jnp.array([0.0, 0.0, 1.0])), "unit vectors"),
        ((jnp.array([0.0, 0.6, -0.8]), jnp.array([0.0, 0.0, 1.0])), "upper hemisphere"),
        pytest.param(
            (jnp.array([0.0, 1.0]), jnp.array([0.0, 0.0, 1.0])), r"shape \(\.\.\., 3\)", marks=pytest.mark.wrong_types
        ),
    ],
)
def test_direction_validation(args, match):
    with pytest.raises(bs.InvalidInputError, match=match):
        lobes.Beckmann(0.1).evaluate(*args)


def test_mirror_lobe_has_no_pointwise_value():
    with pytest.raises(bs.SingularDensityError):
        lobes.Mirror().density(jnp.zeros(2))


@pytest.mark.parametrize(
    "call",
    [
        lambda: lobes.GGX(0.1, amplitude=-1.0),
        lambda: lobes.Mirror(-2.0),
        lambda: geometry.direction_to_slope(jnp.array([0.0, 0.6, -0.8])),
        pytest.param(lambda: geometry.slope_to_direction(jnp.array([1.0, 0.0, 0.0])), marks=pytest.mark.wrong_types),
        lambda: geometry.half_vector(jnp.array([0.0, 0.0, 1.0]), jnp.array([0.0, 0.6, -0.8])),
        pytest.param(
            lambda: geometry.half_slope(jnp.array([0.0, 0.0, 1.0 + 0j]), jnp.array([0.0, 0.0, 1.0])),
            marks=pytest.mark.wrong_types,
        ),
    ],
    ids=[
        "negative amplitude",
        "negative mirror amplitude",
        "lower-hemisphere direction",
        "3-vector slope",
        "lower-hemisphere o",
        "complex i",
    ],
)
def test_geometry_and_lobes_refuse_what_has_no_meaning(call):
    with pytest.raises(bs.InvalidInputError):
        call()


@pytest.mark.wrong_types
def test_plus_distributions_are_not_accepted_as_densities():
    """A plus-distribution h_n has mass 0 and no pointwise density: as statistics it gave a
    negative lobe (−38.6 at the origin), as a lobe shape it was accepted."""
    from brdfscale import plus

    with pytest.raises(bs.InvalidInputError, match="probability density"):
        bs.evolve(lobes.GGX(0.08), plus.PlusDistribution(0, 0.1), stats.Delta())
    with pytest.raises(bs.InvalidInputError, match="probability density"):
        lobes.Lobe(plus.PlusDistribution(0, 0.1))
