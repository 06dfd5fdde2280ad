"""Smith masking–shadowing (issue 32 item 4; docs/masking.md): stats.smith_lambda against closed
forms and quadrature of its definition computed here with SciPy/mpmath, the masking choices'
G₁/G₂ properties, the lobe's evaluate switch, jit/grad/vmap and float32, bad input, and
Mitsuba's roughconductor G."""

import math

import jax
import jax.numpy as jnp
import mpmath
import numpy as np
import pytest
import scipy.integrate as si
import scipy.stats as ss
from hypothesis import example, given, settings, strategies as st

from brdfscale import choices, InvalidInputError, lobes, stats


def _direction(theta, phi=0.0):
    return np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])


def _beckmann_lambda(mu, alpha):
    """Beckmann (Walter et al. 2007): a = μ/α, Λ = (erf a − 1)/2 + e^(−a²)/(2a√π), in mpmath with
    erf a − 1 = −erfc a (50 digits; the two terms cancel to about 1/(2a²) of each)."""
    with mpmath.workdps(50):
        a = mpmath.mpf(mu) / mpmath.mpf(alpha)
        return float(-mpmath.erfc(a) / 2 + mpmath.exp(-(a**2)) / (2 * a * mpmath.sqrt(mpmath.pi)))


def _ggx_lambda(mu, alpha):
    """GGX (Walter et al. 2007): a = μ/α, Λ = (−1 + √(1 + 1/a²))/2, in mpmath."""
    with mpmath.workdps(50):
        a = mpmath.mpf(mu) / mpmath.mpf(alpha)
        return float((-1 + mpmath.sqrt(1 + 1 / a**2)) / 2)


# -- closed forms ---------------------------------------------------------------------------------


@pytest.mark.parametrize("alpha", [0.05, 0.3, 1.0])
def test_beckmann_and_ggx_against_their_closed_forms(alpha):
    thetas = np.radians([0.5, 10, 30, 50, 70, 80, 85, 89, 89.9])
    w = np.stack([_direction(t, phi) for t, phi in zip(thetas, np.linspace(0, 5, len(thetas)))])
    mu = 1 / np.tan(thetas)
    for family, closed in ((stats.Beckmann, _beckmann_lambda), (stats.GGX, _ggx_lambda)):
        ours = np.asarray(stats.smith_lambda(family(alpha), w))
        ref = np.array([closed(m, alpha) for m in mu])
        np.testing.assert_allclose(ours, ref, rtol=1e-12, atol=1e-300)


def test_normal_incidence_is_zero_and_grazing_is_finite_and_grows():
    for density in (stats.Beckmann(0.3), stats.GGX(0.3), stats.StudentT(sigma=0.2, nu=3.0)):
        lam = np.asarray(stats.smith_lambda(density, np.array([_direction(0.0), _direction(1e-9), _direction(1.5707)])))
        assert lam[0] == 0 and np.all(np.isfinite(lam)) and lam[1] < 1e-12 and lam[2] > 100


@settings(max_examples=15, deadline=None)
@given(
    alpha=st.floats(0.05, 1.0),
    ratio=st.floats(0.2, 1.0),
    orientation=st.floats(0, math.pi),
    theta=st.floats(0.05, 1.55),
    phi=st.floats(0, 2 * math.pi),
)
def test_anisotropic_against_the_rotated_closed_forms(alpha, ratio, orientation, theta, phi):
    """A Gaussian of any orientation: the closed form with the projected width α_φ = √(2 eᵀΣe); GGX
    (axis-aligned α_x, α_y): with α_φ = √(α_x² cos²φ + α_y² sin²φ)."""
    c, s = math.cos(orientation), math.sin(orientation)
    R = np.array([[c, -s], [s, c]])
    cov = R @ np.diag([alpha**2 / 2, (ratio * alpha) ** 2 / 2]) @ R.T
    w = _direction(theta, phi)
    e = np.array([math.cos(phi), math.sin(phi)])
    mu = 1 / math.tan(theta)
    ours = float(stats.smith_lambda(stats.Gaussian(cov=cov), w))
    assert ours == pytest.approx(_beckmann_lambda(mu, math.sqrt(2 * e @ cov @ e)), rel=1e-10, abs=1e-300)
    ggx = stats.GGX(alpha_x=alpha, alpha_y=ratio * alpha)
    projected = math.hypot(alpha * e[0], ratio * alpha * e[1])
    assert float(stats.smith_lambda(ggx, w)) == pytest.approx(_ggx_lambda(mu, projected), rel=1e-10)


def test_off_centre_densities_are_centred_by_their_mean():
    w = _direction(1.2, 0.4)
    for centred, shifted in (
        (stats.Beckmann(0.3), stats.Beckmann(0.3, mean=[0.2, -0.1])),
        (stats.GGX(0.3), stats.GGX(0.3, mean=[0.2, -0.1])),
    ):
        assert float(stats.smith_lambda(shifted, w)) == pytest.approx(float(stats.smith_lambda(centred, w)), rel=1e-14)
    # a point mass is a flat (tilted) plane: no masking; a blazed mixture of two facet slopes is exact:
    # Λ = Σ w_k (v·(m_k − c) − 1)₊, c the mixture's mean
    assert float(stats.smith_lambda(stats.Delta([0.3, 0.1]), w)) == 0.0
    blazed = stats.Mixture([0.7, 0.3], [stats.Delta([0.9, 0.0]), stats.Delta([-2.1, 0.0])])
    v = w[:2] / w[2]
    expected = 0.7 * max(v[0] * 0.9 - 1, 0) + 0.3 * max(v[0] * -2.1 - 1, 0)  # mean 0.7·0.9 − 0.3·2.1 = 0
    assert float(stats.smith_lambda(blazed, w)) == pytest.approx(expected, rel=1e-14)
    assert expected > 0


# -- the generic path -----------------------------------------------------------------------------


def _bilinear(values, extent):
    """The tent sum of a table (stats.Tabulated's meaning), written here: bilinear interpolation on the
    table bordered by a ring of zeros one spacing beyond it, normalised to mass 1."""
    ny, nx = values.shape
    hx, hy = 2 * extent / (nx - 1), 2 * extent / (ny - 1)
    v = np.pad(values / (hx * hy * values.sum()), 1)

    def s(x, y):
        gx, gy = (x + extent + hx) / hx, (y + extent + hy) / hy
        if not (0 <= gx <= nx + 1 and 0 <= gy <= ny + 1):
            return 0.0
        i, j = min(int(gx), nx), min(int(gy), ny)
        fx, fy = gx - i, gy - j
        return (v[j, i] * (1 - fx) * (1 - fy) + v[j, i + 1] * fx * (1 - fy) + v[j + 1, i] * (1 - fx) * fy) + v[
            j + 1, i + 1
        ] * fx * fy

    return s, (hx, hy)


def _quadrature_lambda(values, extent, theta, phi):
    """Λ = (1/μ) ∫_μ^∞ (q − μ) P₂(q + c_e) dq by SciPy: P₂(q) = ∫ s(q e + t e⊥) dt (the 2-D density
    marginalised numerically, break points where the line crosses the table's grid lines), its
    mean c_e and the hinge integral by adaptive quadrature over q."""
    s, (hx, hy) = _bilinear(values, extent)
    e, n = np.array([math.cos(phi), math.sin(phi)]), np.array([-math.sin(phi), math.cos(phi)])
    reach = math.hypot(extent + hx, extent + hy)
    xs = np.linspace(-extent - hx, extent + hx, values.shape[1] + 2)
    ys = np.linspace(-extent - hy, extent + hy, values.shape[0] + 2)

    def marginal(q):
        breaks = []
        for grid, a, b in ((xs, q * e[0], n[0]), (ys, q * e[1], n[1])):
            if abs(b) > 1e-12:
                breaks += [(g - a) / b for g in grid]
        breaks = sorted(t for t in breaks if -reach < t < reach)
        return si.quad(lambda t: s(*(q * e + t * n)), -reach, reach, points=breaks or None, limit=200, epsabs=1e-13)[0]

    # P₂ has kinks where the line crosses a node, q = e·node: break points of the outer integrals (without them
    # SciPy's quad missed Λ by 5e-7 of itself on an axis-aligned azimuth, where whole columns of nodes align)
    kinks = sorted({float(q) for q in (xs[None, :] * e[0] + ys[:, None] * e[1]).ravel()})
    mean = si.quad(lambda q: q * marginal(q), -reach, reach, points=kinks, limit=400, epsabs=1e-12)[0]
    mu = 1 / math.tan(theta)
    if mu + mean >= reach:
        return 0.0
    inside = [q for q in kinks if mu + mean < q < reach] or None
    hinge = si.quad(lambda q: (q - mu - mean) * marginal(q), mu + mean, reach, points=inside, limit=400, epsabs=1e-12)
    return hinge[0] / mu


@pytest.mark.slow  # SciPy's nested adaptive quadrature: ~10 s per example
@settings(max_examples=6, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    n=st.integers(3, 6),
    extent=st.floats(0.1, 1.0),
    theta=st.floats(0.3, 1.5),
    phi=st.floats(0, 2 * math.pi),
)
@example(seed=2_147_483_648, n=3, extent=1.0, theta=1.4375, phi=0.0)  # axis-aligned: Λ = 1.61662642743513784 (mpmath)
def test_generic_path_against_quadrature_of_the_definition_for_random_tables(seed, n, extent, theta, phi):
    """Random non-negative tables (off-centre in general): the table's exact tent-sum path against SciPy's
    adaptive quadrature of Λ's definition. Both are accurate to ~1e-10 here; 1e-8 of Λ + 1e-10 holds."""
    values = np.random.default_rng(seed).uniform(0, 1, size=(n, n + 1))
    ours = float(stats.smith_lambda(stats.Tabulated(values, extent=extent), _direction(theta, phi)))
    ref = _quadrature_lambda(values, extent, theta, phi)
    assert ours == pytest.approx(ref, rel=1e-8, abs=1e-10)


@pytest.mark.slow  # SciPy's nested adaptive quadrature
def test_generic_path_against_quadrature_of_the_definition_for_one_table():
    """The default suite's example of the random-table property (below, slow)."""
    values = np.random.default_rng(11).uniform(0, 1, size=(3, 4))
    ours = float(stats.smith_lambda(stats.Tabulated(values, extent=0.6), _direction(1.1, 0.7)))
    assert ours == pytest.approx(_quadrature_lambda(values, 0.6, 1.1, 0.7), rel=1e-8, abs=1e-10)


@pytest.mark.parametrize(
    "shape, extent, centre",
    [
        ((7, 5), (0.3, 0.8), [0.05, -0.1]),
        pytest.param((3, 4), 0.6, None, marks=pytest.mark.slow),
        pytest.param((17, 17), 1.0, [0.2, 0.0], marks=pytest.mark.slow),
    ],
)
def test_tabulated_path_equals_the_transform_quadrature(shape, extent, centre):
    """The table's exact path (a sum over rows of cubic splines, stats/_masking.py) against the transform
    quadrature that serves densities without one (written independently: the tent sum's transform S(k e)),
    for random tables of several shapes, extents and centres and directions of every azimuth — axis-aligned
    ones included, where one tent's projection collapses — within the quadrature's own accuracy (1e-7 of Λ +
    1e-10); and the table's exact mean against the transform's difference quotient (1e-10)."""
    import equinox as eqx

    from brdfscale.stats import _masking

    rng = np.random.default_rng(3)
    density = stats.Tabulated(rng.uniform(0, 1, size=shape), extent=extent, center=centre)
    theta = np.concatenate([rng.uniform(0.05, 1.5, 40), [1.0, 1.2, 0.9, 1.3]])
    phi = np.concatenate([rng.uniform(0, 2 * math.pi, 40), [0.0, math.pi / 2, math.pi, 1.5 * math.pi]])
    w = np.stack([_direction(t, p) for t, p in zip(theta, phi)])
    ours = np.asarray(stats.smith_lambda(density, w))
    mean = eqx.filter_jit(_masking._mean)(density)  # compiled: eagerly, op by op, these take seconds
    np.testing.assert_allclose(
        np.asarray(mean), np.asarray(eqx.filter_jit(_masking._transform_mean)(density)), atol=1e-10
    )
    fourier = np.asarray(eqx.filter_jit(_masking._generic_hinge)(density, jnp.asarray(w[:, :2] / w[:, 2:]), mean))
    np.testing.assert_allclose(ours, fourier, rtol=1e-7, atol=1e-10)
    assert np.count_nonzero(ours > 1e-6) > 20 and ours.max() > 0.1  # masking happens: the check can fail


@pytest.mark.parametrize(
    "nu, rtol",
    [pytest.param(3.0, 1e-3, marks=pytest.mark.slow), pytest.param(6.0, 1e-7, marks=pytest.mark.slow), (12.0, 1e-10)],
)
def test_generic_path_for_a_rotated_student_t_against_its_marginal(nu, rtol):
    """A Student-t of full scale matrix Σ: its marginal along e is the 1-D Student-t of scale √(eᵀΣe)
    (SciPy), Λ by quad. Tails falling as |m|^−(ν+2) alias into the Fourier sum's period (about 4 support
    radii at 1e-9 of the peak) as ~R^−(ν−1): the accuracy the module docstring states."""
    cov = np.array([[0.04, 0.015], [0.015, 0.02]])
    density = stats.StudentT(cov, nu=nu)
    for theta, phi in ((0.6, 0.3), (1.2, 2.0), (1.45, 4.0)):
        e = np.array([math.cos(phi), math.sin(phi)])
        mu, scale = 1 / math.tan(theta), math.sqrt(e @ cov @ e)
        ref = si.quad(lambda q: (q - mu) * ss.t.pdf(q, nu, scale=scale), mu, np.inf, epsabs=1e-14, epsrel=1e-12)[0]
        ours = float(stats.smith_lambda(density, _direction(theta, phi)))
        assert ours == pytest.approx(ref / mu, rel=rtol)


def test_generic_path_reproduces_the_closed_forms_through_an_evolved_shape():
    """A Beckmann lobe evolved to a coarser scale is a Gaussian lobe (docs/conventions.md §1); evolved on the
    radial path its shape is an EvolvedDensity, so Λ goes through the generic path: equal to the closed
    form of α² = α0² + α_f² − α_t²."""
    import brdfscale

    lobe = brdfscale.evolve(lobes.Beckmann(0.2), stats.Beckmann(0.3), stats.Beckmann(0.1), method="radial")
    assert not isinstance(lobe.shape, stats.Gaussian)
    alpha = math.sqrt(0.2**2 + 0.3**2 - 0.1**2)
    for theta in (0.5, 1.2, 1.5):
        ours = float(stats.smith_lambda(lobe.shape, _direction(theta, 0.7)))
        assert ours == pytest.approx(_beckmann_lambda(1 / math.tan(theta), alpha), rel=1e-9)


# -- the masking choices --------------------------------------------------------------------------


def _directions(rng, count):
    theta = rng.uniform(0, 1.55, count)
    phi = rng.uniform(0, 2 * np.pi, count)
    return np.stack([_direction(t, p) for t, p in zip(theta, phi)])


@pytest.mark.parametrize("correlated", [True, False])
def test_g2_is_at_most_one_reciprocal_and_one_at_normal_incidence(correlated):
    rng = np.random.default_rng(3)
    i, o = _directions(rng, 200), _directions(rng, 200)
    masking = lobes.SmithMasking(correlated=correlated)
    for density in (stats.Beckmann(0.4), stats.GGX(alpha_x=0.2, alpha_y=0.5)):
        g = np.asarray(masking.g2(density, i, o))
        assert np.all((g > 0) & (g <= 1))
        np.testing.assert_array_equal(g, np.asarray(masking.g2(density, o, i)))  # exactly: Λ(i) + Λ(o) commutes
        z = np.array([0.0, 0.0, 1.0])
        assert float(masking.g2(density, z, z)) == 1.0
        g1 = np.asarray(masking.g1(density, i))
        expected = (
            1 / (1 / g1 + 1 / np.asarray(masking.g1(density, o)) - 1) if correlated else g1 * masking.g1(density, o)
        )
        np.testing.assert_allclose(g, expected, rtol=1e-14)
    # height correlation lets a facet seen from i and o be so more often: G₂ ≥ G₁ G₁
    d = stats.Beckmann(0.4)
    correlated, separable = (np.asarray(lobes.SmithMasking(correlated=c).g2(d, i, o)) for c in (True, False))
    assert np.all(correlated >= separable * (1 - 2e-16)) and np.any(correlated > 1.01 * separable)


def test_a_tilted_patch_rotates_the_directions_and_is_dark_below_its_plane():
    d, masking = stats.Beckmann(0.3), lobes.SmithMasking()
    tilt = np.array([0.4, -0.2])
    n = np.append(tilt, 1.0) / math.sqrt(1 + tilt @ tilt)
    # the patch's own normal is its normal incidence: G₂ = 1
    assert float(masking.g2(d, n, n, tilt)) == pytest.approx(1.0, abs=1e-15)
    # a direction below the tilted plane: G₂ = 0
    below = _direction(1.4, math.atan2(-tilt[1], -tilt[0]))
    assert float(masking.g2(d, n, below, tilt)) == 0.0
    # rotating the whole configuration about z leaves G₂ unchanged
    i, o = _direction(0.9, 0.3), _direction(0.5, 2.5)
    a = 0.8
    Rz = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    g = float(masking.g2(d, i, o, tilt))
    assert float(masking.g2(d, Rz @ i, Rz @ o, Rz[:2, :2] @ tilt)) == pytest.approx(g, rel=1e-12)


def test_evaluate_switch_default_none_and_smith():
    lobe = lobes.GGX(0.3, amplitude=0.8)
    i = _directions(np.random.default_rng(5), 50)
    o = _directions(np.random.default_rng(6), 50)
    plain = np.asarray(lobe.evaluate(i, o))
    assert choices.MASKING.default == "none" and isinstance(lobes.as_masking(None), lobes.NoMasking)
    np.testing.assert_array_equal(np.asarray(lobe.evaluate(i, o, masking="none")), plain)
    np.testing.assert_array_equal(np.asarray(lobe.evaluate(i, o, masking=lobes.NoMasking())), plain)
    masked = np.asarray(lobe.evaluate(i, o, masking="smith"))
    np.testing.assert_allclose(masked, plain * np.asarray(lobes.SmithMasking().g2(lobe.shape, i, o)), rtol=1e-15)
    assert np.all(masked <= plain) and np.any(masked < 0.9 * plain)
    # a mirror (shape δ) is never masked
    mirror = lobes.Lobe(stats.Beckmann(1e-3))
    assert float(lobes.Mirror().shape.support_radius(1e-3)) == 0.0
    assert np.all(np.asarray(mirror.evaluate(i, o, masking="smith")) <= np.asarray(mirror.evaluate(i, o)))


# -- transformations and precision -----------------------------------------------------------------


_SLOW = pytest.mark.slow  # generic-path compilations: 5–30 s on 2 cores, run in .ci/run's second step


@pytest.mark.parametrize(
    "make",
    [
        lambda a: stats.Beckmann(a),
        lambda a: stats.GGX(alpha_x=a, alpha_y=0.5 * a),
        pytest.param(lambda a: stats.StudentT(sigma=a, nu=8.0), marks=_SLOW),
        pytest.param(
            lambda a: stats.Tabulated(
                np.exp(-(np.linspace(-2, 2, 9)[:, None] ** 2 + np.linspace(-2, 2, 9) ** 2)), extent=4 * a
            ),
            marks=_SLOW,
        ),
    ],
    ids=["beckmann", "ggx", "student_t", "tabulated"],
)
def test_jit_grad_vmap_equal_eager(make):
    w = np.stack([_direction(0.3, 0.2), _direction(1.0, 2.0), _direction(1.4, 4.0)])

    def lam(a, w):
        return stats.smith_lambda(make(a), w)

    """Jit and vmap equal eager to rounding (the generic path sums 1024 terms of size ≤ 1 in another
    order: 1e-13 absolute); the gradient equals a central difference (step 1e-5: truncation 1e-10
    relative, round-off 1e-11/1e-5)."""
    eager = np.asarray(lam(0.3, w))
    assert np.all(eager[1:] > 1e-5)
    np.testing.assert_allclose(np.asarray(jax.jit(lam)(0.3, w)), eager, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(np.asarray(jax.vmap(lam, in_axes=(None, 0))(0.3, w)), eager, rtol=1e-12, atol=1e-13)
    grad = np.asarray(jax.vmap(jax.grad(lam), in_axes=(None, 0))(0.3, w))
    step = 1e-5
    central = (np.asarray(lam(0.3 + step, w)) - np.asarray(lam(0.3 - step, w))) / (2 * step)
    assert np.all(np.isfinite(grad))
    np.testing.assert_allclose(grad, central, rtol=1e-6, atol=1e-8)
    # normal incidence: Λ = 0 with a finite gradient
    assert float(jax.grad(lam)(0.3, np.array([0.0, 0.0, 1.0]))) == 0.0


@pytest.mark.parametrize("generic", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_float32_against_float64(generic):
    """float32 within 2e-6 of Λ + 1e-6 (closed forms) and 5e-5 of Λ + 1e-5 (the generic path's sum of
    1024 terms, on an evolved lobe's shape) of float64."""
    import brdfscale

    w = np.stack([_direction(t, 0.5 * t) for t in np.linspace(0.1, 1.55, 12)])

    def lam(dtype):
        if generic:
            lobe = lobes.Beckmann(jnp.asarray(0.1, dtype))
            s_from, s_to = stats.GGX(jnp.asarray(0.08, dtype)), stats.GGX(jnp.asarray(0.03, dtype))
            density = brdfscale.evolve(lobe, s_from, s_to, method="radial", size=64, tol=1e-6).shape
        else:
            density = stats.GGX(alpha_x=jnp.asarray(0.25, dtype), alpha_y=jnp.asarray(0.4, dtype))
        return np.asarray(stats.smith_lambda(density, jnp.asarray(w, dtype)))

    low, high = lam(jnp.float32), lam(jnp.float64)
    assert low.dtype == np.float32 and np.all(np.isfinite(low))
    rtol, atol = (5e-5, 1e-5) if generic else (2e-6, 1e-6)
    np.testing.assert_allclose(low, high, rtol=rtol, atol=atol)


# -- bad input --------------------------------------------------------------------------------------


@pytest.mark.wrong_types
def test_bad_input_is_refused_with_the_library_error():
    d = stats.Beckmann(0.3)
    with pytest.raises(InvalidInputError, match="upper hemisphere"):
        stats.smith_lambda(d, np.array([0.0, 0.6, -0.8]))
    with pytest.raises(InvalidInputError, match="unit vectors"):
        stats.smith_lambda(d, np.array([0.0, 0.0, 2.0]))
    with pytest.raises(InvalidInputError, match="density"):
        stats.smith_lambda("beckmann", np.array([0.0, 0.0, 1.0]))
    with pytest.raises(InvalidInputError, match="no first moment"):
        stats.smith_lambda(stats.StudentT(sigma=0.2, nu=0.8), np.array([0.0, 0.0, 1.0]))
    with pytest.raises(InvalidInputError, match="masking must be one of"):
        lobes.as_masking("smyth")
    with pytest.raises(InvalidInputError, match="masking must be None"):
        lobes.GGX(0.3).evaluate(_direction(0.2), _direction(0.3), masking=3)
    with pytest.raises(InvalidInputError, match="correlated must be True or False"):
        lobes.SmithMasking(correlated="yes")
    with pytest.raises(InvalidInputError, match="does not decay"):
        from brdfscale import plus

        stats.smith_lambda(
            plus.NearlySpecular(0.5, [0.1], 0.05, smooth=stats.Beckmann(0.1), smooth_weight=0.5), _direction(0.5)
        )


# -- Mitsuba ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["Beckmann", "GGX"])
def test_separable_g2_against_mitsuba_roughconductor(kind):
    """Mitsuba's microfacet G is G₁(i)G₁(o) (its roughconductor): GGX's Λ exact (float32 rounding); Beckmann's
    G₁ a rational approximation within 0.35 %."""
    from brdfscale import _mitsuba

    mi = _mitsuba.mitsuba(variant=None)
    alpha = 0.3
    dist = mi.MicrofacetDistribution(getattr(mi.MicrofacetType, kind), alpha, alpha, False)
    ours_density = stats.Beckmann(alpha) if kind == "Beckmann" else stats.GGX(alpha)
    masking = lobes.SmithMasking(correlated=False)
    for ti, to, phi in ((0.3, 0.5, 1.0), (1.1, 0.2, 2.5), (1.3, 1.35, 0.4)):
        i, o = _direction(ti, 0.0), _direction(to, phi)
        h = (i + o) / np.linalg.norm(i + o)
        g = dist.G(*(mi.Vector3f(*(float(c) for c in v)) for v in (i, o, h)))
        theirs = float(np.ravel(np.asarray(g))[0])
        ours = float(masking.g2(ours_density, i, o))
        assert ours == pytest.approx(theirs, rel=3.5e-3 if kind == "Beckmann" else 1e-5)


# -- the measurement-set forward model, the fits, the command line -------------------------------------


def _masked_beckmann_set(n=41, extent=1.2):
    """Two scales (Beckmann lobes α 0.3 and 0.25) at incidences 17° and 69°: images of the masked lobe
    G₂(i, o(u)) · g(u) with the closed-form Λ, and the unmasked lobes and factors."""
    from brdfscale import geometry, LobeImage, MeasurementSet

    x = np.linspace(-extent, extent, n)
    u = np.stack(np.meshgrid(x, x, indexing="xy"), axis=-1)
    h = np.asarray(geometry.slope_to_direction(u))
    images, truth = [], []
    for mu, alpha in ((1.0, 0.3), (2.0, 0.25)):
        for theta in (0.3, 1.2):
            i = _direction(theta)
            o = np.asarray(geometry.reflect(np.broadcast_to(i, h.shape), h))
            leaves = o[..., 2] > 0
            o = np.where(leaves[..., None], o, [0.0, 0.0, 1.0])
            lobe = lobes.Beckmann(alpha)
            plain = np.asarray(lobe.density(u))
            g = np.where(leaves, np.asarray(lobes.SmithMasking().g2(lobe.shape, np.broadcast_to(i, o.shape), o)), 0.0)
            images.append(LobeImage(mu=mu, incident=i, extent=extent, values=plain * g, sigma=np.full((n, n), 1e-3)))
            truth.append((plain, g))
    return MeasurementSet(tuple(images)), truth


def test_dataset_masking_none_is_unchanged_and_smith_removes_the_masking():
    """masking none (the default) gives the seed's dataset exactly; smith divides value and σ by G₂ of
    each scale's lobe (taken from the image nearest normal incidence, unmasked by fixed point), so the
    unmasked lobe times G₂ — the masked forward model, ≤ the unmasked one — fits the masked images.
    Against the closed-form Beckmann G₂: the 41-px images (pitch 0.06, truncated at 4–5 α) recover the
    unmasked lobe within 1.5 % (0.95 % measured) wherever G₂ > 0.01, at 17° and at 69° incidence."""
    from brdfscale import fitting

    mset, truth = _masked_beckmann_set()
    default, none = fitting.Dataset.from_measurements(mset), fitting.Dataset.from_measurements(mset, masking="none")
    for a, b in ((default.values, none.values), (default.weight, none.weight), (default.offsets, none.offsets)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert none.masking == "none"
    smith = fitting.Dataset.from_measurements(mset, masking=lobes.SmithMasking())
    assert smith.masking == "smith"
    n = mset.images[0].size
    for k, (plain, g) in enumerate(truth):
        values, weight = (np.asarray(x[k][: n * n]).reshape(n, n) for x in (smith.values, smith.weight))
        valid = weight > 0
        raw = np.asarray(default.values[k][: n * n]).reshape(n, n)
        assert np.all(values[valid] >= raw[valid])  # the model's prediction times G₂ ≤ 1 is the masked one
        # σ is divided as the value is: each pixel's signal-to-noise ratio is kept
        np.testing.assert_allclose(
            (values * weight)[valid], (raw * np.asarray(default.weight[k][: n * n]).reshape(n, n))[valid], rtol=1e-12
        )
        seen = valid & (g > 0.01)
        assert np.count_nonzero(seen) > n * n / 4
        np.testing.assert_allclose(values[seen], plain[seen], rtol=1.5e-2)
        assert not np.any(valid & (g == 0))  # pixels whose light leaves below the horizon are masked out


def test_masking_option_of_the_fit_command_and_the_library():
    from brdfscale import library
    from brdfscale._cli import build_parser
    from brdfscale._cli._fit import spec_of

    parse = build_parser().parse_args
    assert parse(["fit", "m.exr", "--out", "d"]).masking == choices.MASKING.default == "none"
    assert spec_of(parse(["fit", "m.exr", "--out", "d", "--masking", "smith"])).masking == "smith"
    with pytest.raises(SystemExit) as exit_:
        parse(["fit", "m.exr", "--out", "d", "--masking", "smyth"])
    assert exit_.value.code == 2
    assert library.FitSpec(masking="smith").to_json()["masking"] == "smith"
    with pytest.raises(InvalidInputError, match="masking must be one of"):
        library.FitSpec(masking="smyth")


@pytest.mark.wrong_types
def test_dataset_refuses_a_masking_that_is_not_one():
    from brdfscale import fitting

    with pytest.raises(InvalidInputError, match="masking must be None"):
        fitting.Dataset.from_measurements(_masked_beckmann_set(n=5)[0], masking=1.0)


# -- multiple scattering (smith_ms) ------------------------------------------------------------------


def _albedo_by_quadrature(incident, alpha, kind):
    """``E(i) = ∫ s(m) (i·h)/(i_z h_z) G₂(i, o(m)) d²m`` of an isotropic Beckmann or GGX density by SciPy's
    adaptive quadrature in polar slopes, with Λ in closed form (mpmath above): the definition, written here."""
    lam = _beckmann_lambda if kind == "beckmann" else _ggx_lambda

    def lam_of(w):
        t = math.hypot(w[0], w[1]) / w[2]
        return 0.0 if t == 0 else lam(1 / t, alpha)

    lam_i = lam_of(incident)

    def integrand(r, phi):
        if kind == "beckmann":
            p = math.exp(-(r**2) / alpha**2) / (math.pi * alpha**2)
        else:
            p = 1 / (math.pi * alpha**2 * (1 + r**2 / alpha**2) ** 2)
        h = np.array([r * math.cos(phi), r * math.sin(phi), 1.0]) / math.sqrt(1 + r**2)
        lit = float(incident @ h) / (incident[2] * h[2])
        o = 2 * float(incident @ h) * h - incident
        if o[2] <= 0 or lit <= 0:
            return 0.0
        return p * lit / (1 + lam_i + lam_of(o)) * r

    return si.dblquad(integrand, 0, 2 * math.pi, 0, np.inf, epsabs=1e-9, epsrel=1e-7)[0]


@pytest.mark.parametrize(
    "kind, alpha, theta",
    [
        pytest.param("beckmann", 0.3, 45.0, marks=_SLOW),  # SciPy's dblquad: 2–4 s each
        pytest.param("beckmann", 0.6, 80.0, marks=_SLOW),
        ("ggx", 0.3, 0.0),
        pytest.param("ggx", 0.1, 85.0, marks=_SLOW),
    ],
)
def test_albedo_against_quadrature_of_its_definition(kind, alpha, theta):
    """SmithMasking.albedo (its polar rule, 96 × 128 nodes) within 5e-4 of SciPy's adaptive quadrature of the
    definition (measured ≤ 4.1e-4 over α 0.1–0.6 and θ 0–85°, largest at normal incidence where the integrand has a
    kink on the circle |m| = 1 beyond which the mirror direction points into the surface)."""
    i = _direction(math.radians(theta))
    density = stats.Beckmann(alpha) if kind == "beckmann" else stats.GGX(alpha)
    got = float(lobes.SmithMasking().albedo(density, i))
    assert 0.5 < got < 1.0
    assert got == pytest.approx(_albedo_by_quadrature(i, alpha, kind), abs=5e-4)


def _hemisphere_albedo(lobe, i, masking, n=400, n_phi=800):
    """``(1/i_z) ∫ ρ(i, o) cosθ_o dω_o`` over the hemisphere of outgoing directions (Gauss–Legendre in cosθ_o,
    midpoints in φ): the directional albedo of the lobe's BRDF ``ρ/cosθ_i`` (seed §2), in directions, not slopes."""
    x, w = np.polynomial.legendre.leggauss(n)
    c, wc = (x + 1) / 2, w / 2
    phi = (np.arange(n_phi) + 0.5) * 2 * math.pi / n_phi
    s = np.sqrt(1 - c**2)
    o = np.stack([s[:, None] * np.cos(phi), s[:, None] * np.sin(phi), np.broadcast_to(c[:, None], (n, n_phi))], -1)
    rho = np.asarray(lobe.evaluate(i, o.reshape(-1, 3), masking=masking)).reshape(n, n_phi)
    return float(np.sum(rho * (c * wc)[:, None]) * 2 * math.pi / n_phi) / i[2]


@pytest.mark.parametrize("shape", ["beckmann", "ggx_anisotropic"])
def test_lossless_facets_with_multiple_scattering_reflect_all_light(shape):
    """Integrated over the hemisphere of outgoing directions: the Smith-masked lobe of lossless mirror facets (A = 1)
    reflects E(i) (SmithMasking.albedo, computed over slopes) within 5e-4 — two changes of variables, one number —
    and with the multiply scattered light (``"smith_ms"``) all of it, 1 within 5e-4 (measured ≤ 2e-4), where the
    seed's unmasked lobe reflects up to 16 % more than it receives at 80°."""
    density = stats.Beckmann(0.3) if shape == "beckmann" else stats.GGX(alpha_x=0.2, alpha_y=0.4)
    lobe = lobes.Lobe(density)
    for theta in (0.0, 60.0, 80.0):
        i = _direction(math.radians(theta), 0.3)
        e = float(lobes.SmithMasking().albedo(density, i))
        assert _hemisphere_albedo(lobe, i, "smith") == pytest.approx(e, abs=5e-4)
        assert _hemisphere_albedo(lobe, i, "smith_ms") == pytest.approx(1.0, abs=5e-4)
        if theta == 80.0:
            assert e < 0.93 and _hemisphere_albedo(lobe, i, "none") > 1.09


def test_multiple_scattering_choice_factor_name_and_where_it_is_refused():
    from brdfscale import fitting, render

    ms = lobes.as_masking("smith_ms")
    assert isinstance(ms, lobes.SmithMasking) and ms.multiple_scattering and ms.correlated
    assert ms.name == "smith_ms" and lobes.SmithMasking().name == "smith" and "smith_ms" in choices.MASKING.names
    density = stats.GGX(0.3)
    i = _direction(1.2, 0.4)
    o = _directions(np.random.default_rng(7), 40)
    e = float(ms.albedo(density, i))
    np.testing.assert_allclose(
        np.asarray(ms.factor(density, i, o)), np.asarray(lobes.SmithMasking().g2(density, i, o)) / e, rtol=1e-14
    )
    # the factor of a tilted patch takes E of the incident direction in the patch's frame; dark below its plane
    m_inf = np.array([0.4, -0.2])
    tilted = np.asarray(ms.factor(density, i, o, m_inf))
    plain = np.asarray(lobes.SmithMasking().g2(density, i, o, m_inf))
    lit = plain > 0
    ratio = tilted[lit] / plain[lit]
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-13)
    assert ratio[0] > 1 and np.all(tilted[~lit] == 0)
    # a measurement set's masking record names it; the Mitsuba plugin refuses it (not reciprocal)
    mset, _ = _masked_beckmann_set(n=9)
    with_ms = fitting.Dataset.from_measurements(mset, masking="smith_ms")
    single = fitting.Dataset.from_measurements(mset, masking="smith")
    assert with_ms.masking == "smith_ms"
    # the same unmasked density, so each image's values are smith's times that image's E(i): a per-incidence
    # constant, which a fit of one incidence puts into the lobe's amplitude (its ΔΣ and C0 are smith's)
    for k, img in enumerate(mset.images):
        valid = np.asarray(single.weight[k]) > 0
        ratio = np.asarray(with_ms.values[k])[valid] / np.asarray(single.values[k])[valid]
        np.testing.assert_allclose(ratio, ratio[0], rtol=1e-12)
        assert 0.5 < ratio[0] <= 1.0 and (ratio[0] < 0.999 or img.incident[2] > 0.9)
    with pytest.raises(InvalidInputError, match="not reciprocal"):
        render.bsdf(lobes.Beckmann(0.2), stats.WidthLaw(0.1, 1.0, 0.5), mu0=1.0, masking="smith_ms")


def _albedo_of_alpha(a, i=_direction(1.1, 0.7)):
    return lobes.SmithMasking().albedo(stats.Beckmann(a), i)


@_SLOW
def test_albedo_gradient_against_the_definitions_derivative():
    """dE/dα by autodiff (the rule's nodes held, stop_gradient on its scale) within 1e-3 relative of the central
    difference (step 1e-3) of SciPy's quadrature of the definition (measured 3e-4). The central difference of the
    rule itself is 1 % off: its nodes move with α."""
    i = _direction(1.1, 0.7)
    h = 1e-3
    reference = (_albedo_by_quadrature(i, 0.35 + h, "beckmann") - _albedo_by_quadrature(i, 0.35 - h, "beckmann")) / (
        2 * h
    )
    assert float(jax.grad(_albedo_of_alpha)(0.35)) == pytest.approx(reference, rel=1e-3)


@_SLOW  # eager dispatch of the rule's 12288-node program op by op: 7 s
def test_albedo_jit_vmap_and_pixel_rule():
    """E(α) under jit and vmap equals eager to rounding; a PixelGaussians image of the Beckmann density (its own
    nodes, 41² over ±4.5σ) gives the closed-form density's E within 2e-3."""
    i = _direction(1.1, 0.7)
    eager = float(_albedo_of_alpha(0.35))
    assert float(jax.jit(_albedo_of_alpha)(0.35)) == pytest.approx(eager, rel=1e-12)
    batched = np.asarray(jax.vmap(_albedo_of_alpha)(jnp.array([0.2, 0.35])))
    assert batched[1] == pytest.approx(eager, rel=1e-12) and batched[0] == pytest.approx(
        float(_albedo_of_alpha(0.2)), rel=1e-12
    )
    sigma = 0.35 / math.sqrt(2)
    x = np.linspace(-4.5 * sigma, 4.5 * sigma, 41)
    values = np.exp(-(x[None, :] ** 2 + x[:, None] ** 2) / (2 * sigma**2))
    pixels = stats.PixelGaussians(values, extent=4.5 * sigma)
    assert float(lobes.SmithMasking().albedo(pixels, i)) == pytest.approx(eager, abs=2e-3)


def test_albedo_of_many_directions_is_computed_in_blocks_of_bounded_memory():
    """Deterministic: the compiled albedo's temporary buffers (XLA's memory analysis) at 10⁴ directions stay within
    the library's budget plus a few bytes per direction (unblocked, 10⁴ directions × 12,288 nodes of the polar rule
    asked for tens of GB); the values of a block equal those computed one direction at a time."""
    from brdfscale._blocks import DEFAULT_BUDGET

    density = stats.Beckmann(alpha_x=0.3, alpha_y=0.2, mean=[0.05, 0.0])
    smith = lobes.SmithMasking()
    q = 10**4
    compiled = jax.jit(lambda i: smith.albedo(density, i)).lower(jax.ShapeDtypeStruct((q, 3), jnp.float64)).compile()
    temporaries = compiled.memory_analysis().temp_size_in_bytes
    assert temporaries <= DEFAULT_BUDGET + 64 * q, temporaries
    rng = np.random.default_rng(7)
    i = rng.normal(size=(5, 3))
    i[:, 2] = np.abs(i[:, 2]) + 0.2
    i /= np.linalg.norm(i, axis=1, keepdims=True)
    together = np.asarray(smith.albedo(density, i))
    apart = np.array([float(smith.albedo(density, w)) for w in i])
    np.testing.assert_allclose(together, apart, rtol=1e-13)


def test_mean_slope_against_the_mean_of_the_density_on_a_grid():
    """stats.mean_slope (closed forms, node centroids, mixtures, the transform's difference quotient for a Student-t)
    against ∫ m s(m) d²m summed on a fine grid of the density itself (1e-6 absolute; the origin for a centred one)."""
    x = np.linspace(-6.0, 6.0, 1201)
    grid = np.stack(np.meshgrid(x, x, indexing="xy"), axis=-1)
    cell = (x[1] - x[0]) ** 2
    table = np.exp(-((np.linspace(-1, 1, 21)[None, :] - 0.3) ** 2 + np.linspace(-1, 1, 21)[:, None] ** 2) / 0.1)
    for density in (
        stats.Beckmann(0.3, mean=[0.2, -0.1]),
        stats.StudentT(sigma=0.2, nu=6.0).shifted(np.array([-0.15, 0.05])),
        stats.Mixture([0.6, 0.4], [stats.Beckmann(0.2, mean=[0.3, 0.0]), stats.Beckmann(0.4, mean=[-0.2, 0.1])]),
        stats.Tabulated(table, extent=1.0, center=[0.1, 0.2]),
        stats.Beckmann(0.3),
    ):
        s = np.asarray(density.density(grid))
        expected = np.einsum("yx,yxk->k", s, grid) * cell / (s.sum() * cell)
        np.testing.assert_allclose(np.asarray(stats.mean_slope(density)), expected, atol=1e-6, err_msg=repr(density))
