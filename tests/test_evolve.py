"""The evolution operator (seed Eq. 4.4): closed forms, spectral paths, physics, errors."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.integrate as si
import scipy.special as sp
from hypothesis import given, settings, strategies as st

import brdfscale as bs
from brdfscale import geometry, lobes, stats


RNG = np.random.default_rng(42)
U = jnp.asarray(RNG.normal(scale=0.12, size=(40, 2)))


def _max_rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


# -- closed forms ------------------------------------------------------------------------
def test_beckmann_alpha_squared_adds():
    a0, af, at = 0.1, 0.2, 0.05
    out = bs.evolve(lobes.Beckmann(a0, amplitude=0.8), stats.Beckmann(af), stats.Beckmann(at))
    alpha = math.sqrt(a0**2 + af**2 - at**2)
    u = np.asarray(U)
    ref = 0.8 * np.exp(-np.sum(u**2, -1) / alpha**2) / (np.pi * alpha**2)
    assert _max_rel(out.density(U), ref) < 1e-13


def test_closed_form_keeps_isotropy_for_later_radial_evolution():
    out = bs.evolve(lobes.Beckmann(0.1), stats.Beckmann(0.2), stats.Beckmann(0.05))
    assert out.shape.isotropic
    assert not bs.evolve(lobes.Beckmann(alpha_x=0.1, alpha_y=0.2), stats.Beckmann(0.2), stats.Delta()).shape.isotropic
    assert bs.evolve(out, stats.GGX(0.1), stats.GGX(0.05)).shape.method == "radial"


def test_mirror_with_ggx_statistics_is_the_ggx_lobe():
    """Harvey's relation (seed Eq. 6.1): mirror facets at μ0, flat at μ: the lobe is s(μ0)."""
    s = stats.GGX(alpha_x=0.1, alpha_y=0.2)
    out = bs.evolve(lobes.Mirror(2.0), s, stats.Delta())
    u = np.asarray(U)
    x2 = (u[:, 0] / 0.1) ** 2 + (u[:, 1] / 0.2) ** 2
    ref = 2.0 / (np.pi * 0.1 * 0.2 * (1 + x2) ** 2)
    assert _max_rel(out.density(U), ref) < 1e-14


def test_closed_form_refuses_what_it_cannot_do():
    with pytest.raises(bs.MethodNotApplicableError, match="no closed form"):
        bs.evolve(lobes.Beckmann(0.1), stats.GGX(0.1), stats.Beckmann(0.01), method="closed_form")
    with pytest.raises(bs.MethodNotApplicableError, match="radial"):
        bs.evolve(lobes.Beckmann(0.1), stats.GGX(alpha_x=0.1, alpha_y=0.2), stats.Delta(), method="radial")


# -- spectral paths against closed forms and direct convolution ------------------------------
@pytest.mark.parametrize("method", ["radial", "grid"])
def test_spectral_paths_match_closed_form(method):
    args = (lobes.Beckmann(0.1), stats.Beckmann(0.2), stats.Beckmann(0.05))
    exact = bs.evolve(*args).density(U)
    assert _max_rel(bs.evolve(*args, method=method).density(U), exact) < 1e-8


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_grid_path_matches_closed_form_for_skewed_anisotropic_mixture():
    s_from = stats.Mixture(
        [0.7, 0.3],
        [stats.Beckmann(alpha_x=0.05, alpha_y=0.08, mean=[0.03, 0.0]), stats.Beckmann(0.08, mean=[-0.07, 0.01])],
    )
    args = (lobes.Beckmann(alpha_x=0.1, alpha_y=0.06), s_from, stats.Beckmann(0.02))
    exact = bs.evolve(*args).density(U)
    assert _max_rel(bs.evolve(*args, method="grid").density(U), exact) < 1e-8
    u, values = bs.evolve(*args, method="grid").shape.on_grid()
    grid_points = jnp.stack(jnp.meshgrid(u, u, indexing="xy"), -1)
    assert _max_rel(values, bs.evolve(*args).density(grid_points)) < 1e-8


def _beckmann(alpha):
    return lambda x, y: math.exp(-(x * x + y * y) / alpha**2) / (math.pi * alpha**2)


def _ggx(alpha):
    return lambda x, y: 1.0 / (math.pi * alpha**2 * (1 + (x * x + y * y) / alpha**2) ** 2)


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_too_small_explicit_grid_warns():
    with pytest.warns(UserWarning, match="below the"):
        bs.evolve(lobes.Beckmann(0.1), stats.GGX(0.08), stats.Delta(), method="grid", size=64)


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_grid_extent_and_size_can_be_forced():
    args = (lobes.Beckmann(0.1), stats.Beckmann(0.2), stats.Beckmann(0.05))
    out = bs.evolve(*args, method="grid", size=128, extent=1.5)
    u, values = out.shape.on_grid()
    assert values.shape == (128, 128) and float(u[0]) == pytest.approx(-1.5)
    assert _max_rel(out.density(U), bs.evolve(*args).density(U)) < 1e-8
    with pytest.raises(bs.InvalidInputError, match="extent"):
        bs.evolve(*args, method="grid", extent=-1.0)


def _direct_convolution(g0, s, u, s_radius=1.2):
    """∫ g0(u − m) s(m) d²m by adaptive 2D quadrature (SciPy) in polar coordinates about the
    origin of s, with g0 and s written out independently of the library (plain math)."""

    def integrand(phi, rho):
        mx, my = rho * math.cos(phi), rho * math.sin(phi)
        return rho * g0(u[0] - mx, u[1] - my) * s(mx, my)

    val, _ = si.dblquad(integrand, 0, s_radius, 0, 2 * math.pi, epsabs=1e-13, epsrel=1e-11)
    return val


@pytest.mark.parametrize("method", ["radial", "grid"])
def test_ggx_statistics_against_direct_convolution(method):
    """Beckmann lobe at μ0 with GGX facet statistics, evolved to μ = ∞ (flat): g0 ∗ s."""
    out = bs.evolve(lobes.Beckmann(0.1), stats.GGX(0.08), stats.Delta(), method=method)
    pts = np.array([[0.0, 0.0], [0.07, 0.02], [0.15, -0.1]])
    ref = np.array([_direct_convolution(_beckmann(0.1), _ggx(0.08), p) for p in pts])
    # GGX's |m|⁻⁴ tail beyond the quadrature's 1.2 radius holds < 1e-8 of the mass; the capped
    # grid honours a looser tolerance than the radial path, and says so (out.shape.tol)
    values = np.asarray(out.density(jnp.asarray(pts)))
    if method == "radial":
        np.testing.assert_allclose(values, ref, rtol=2e-8)
    else:
        assert out.shape.tol <= 1e-8 and np.max(np.abs(values - ref)) <= out.shape.tol * ref[0]


def test_disk_statistics_radial_against_direct_convolution():
    out = bs.evolve(lobes.Beckmann(0.05), stats.Disk(0.1), stats.Delta(), method="radial")
    pts = np.array([[0.0, 0.0], [0.09, 0.0], [0.0, 0.16]])
    disk = lambda x, y: 1 / (math.pi * 0.01)
    ref = np.array([_direct_convolution(_beckmann(0.05), disk, p, s_radius=0.1) for p in pts])
    np.testing.assert_allclose(np.asarray(out.density(jnp.asarray(pts))), ref, rtol=1e-8)


@pytest.mark.slow  # 5–60 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_fine_coarse_fine_round_trip_radial():
    lobe = lobes.Beckmann(0.1)
    s0, s1 = stats.GGX(0.15), stats.GGX(0.05)
    coarse = bs.evolve(lobe, s0, s1)
    assert coarse.shape.method == "radial"
    back = bs.evolve(coarse, s1, s0)
    assert _max_rel(back.density(U), lobe.density(U)) < 1e-8


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_fine_coarse_fine_round_trip_grid_honours_its_stated_tolerance():
    """Anisotropic GGX statistics (|m|⁻⁴ tails): the capped grid states the accuracy it can
    reach in ``shape.tol``; the round trip must be within it."""
    lobe = lobes.Beckmann(alpha_x=0.1, alpha_y=0.07)
    s0, s1 = stats.GGX(alpha_x=0.12, alpha_y=0.08), stats.GGX(alpha_x=0.04, alpha_y=0.03)
    coarse = bs.evolve(lobe, s0, s1)
    back = bs.evolve(coarse, s1, s0)
    assert back.shape.method == "grid" and back.shape.tol <= 1e-6
    assert _max_rel(back.density(U), lobe.density(U)) < back.shape.tol


# -- physics: the sign of skewed statistics (docs/conventions.md §2) --------------------------------------
def test_skewed_statistics_sign_against_brute_force_reflection():
    """70 % of the mirror facets have slope +0.03 (30 % −0.07): the coarse lobe peaks at +0.03.

    Brute force: reflect the incident ray on each facet's normal and histogram the half-vector
    slope of the reflected direction; the evolution must put its peak at the same place.
    """
    rng = np.random.default_rng(0)
    slopes = np.where(rng.random(20000) < 0.7, 0.03, -0.07)
    m = np.stack([slopes, np.zeros_like(slopes)], -1) + rng.normal(scale=0.01, size=(20000, 2))
    n = np.asarray(geometry.slope_to_direction(jnp.asarray(m)))
    i = np.array([0.3, 0.1, 1.0]) / np.linalg.norm([0.3, 0.1, 1.0])
    o = np.asarray(geometry.reflect(jnp.asarray(i), jnp.asarray(n)))
    u_brute = np.asarray(geometry.half_slope(jnp.asarray(i), jnp.asarray(o)))
    hist, edges = np.histogram(u_brute[:, 0], bins=np.linspace(-0.12, 0.08, 41))
    brute_peak = 0.5 * (edges[hist.argmax()] + edges[hist.argmax() + 1])

    s = stats.Mixture([0.7, 0.3], [stats.Delta(mean=[0.03, 0.0]), stats.Delta(mean=[-0.07, 0.0])])
    out = bs.evolve(lobes.Beckmann(0.01 * math.sqrt(2)), s, stats.Delta())
    x = jnp.linspace(-0.12, 0.08, 401)
    prof = out.density(jnp.stack([x, jnp.zeros_like(x)], -1))
    model_peak = float(x[jnp.argmax(prof)])
    assert abs(model_peak - 0.03) < 1e-3 and abs(brute_peak - 0.03) < 5e-3
    # the reflection identity behind it, to rounding
    np.testing.assert_allclose(u_brute, m, atol=1e-12)


# -- errors ---------------------------------------------------------------------------------
def test_no_brdf_at_finer_scale_closed_form():
    with pytest.raises(bs.NoBRDFAtScaleError, match="negative variance"):
        bs.evolve(lobes.Beckmann(0.1), stats.Beckmann(0.05), stats.Beckmann(0.2))


def test_no_brdf_at_finer_scale_spectral_and_under_jit():
    with pytest.raises(bs.NoBRDFAtScaleError, match="exceeds 1"):
        bs.evolve(lobes.Beckmann(0.05), stats.GGX(0.02), stats.GGX(0.2), method="grid").density(U)

    @jax.jit
    def f(alpha_to):
        return bs.evolve(lobes.Beckmann(0.1), stats.Beckmann(0.05), stats.Beckmann(alpha_to)).density(U)

    assert np.all(np.isfinite(f(0.02)))
    with pytest.raises(Exception, match="negative variance"):
        f(0.3).block_until_ready()


@pytest.mark.parametrize("method", ["closed_form", "radial", "grid"])
def test_check_false_leaves_out_only_the_run_time_check(method):
    """Where a BRDF exists, check=False gives the checked values bit for bit; where none
    exists it no longer raises (the caller has taken that responsibility)."""
    lobe = lobes.Beckmann(0.1)

    def evaluate(alpha_to, check):
        return bs.evolve(
            lobe, stats.Beckmann(0.05), stats.Beckmann(alpha_to), method=method, size=64, check=check
        ).density(U)

    checked = jax.jit(lambda a: evaluate(a, True))
    unchecked = jax.jit(lambda a: evaluate(a, False))
    np.testing.assert_array_equal(np.asarray(checked(0.02)), np.asarray(unchecked(0.02)))
    with pytest.raises(Exception, match="negative variance|exceeds 1"):
        checked(0.3).block_until_ready()
    unchecked(0.3).block_until_ready()  # no error: undefined values, by request


def test_no_brdf_found_beyond_the_grids_nyquist_frequency():
    """Mirror lobe from GGX(α) to GGX(α + δ): G = xK₁(αW)/xK₁((α+δ)W) grows like e^{δW}. With
    δ = 5e-9 it stays within 1e-6 of 1 on the 64² grid (|W| ≤ √2·π·64/1.6, checked with
    SciPy's K₁) but not three decades above: the grid path still refuses — when it is built
    from concrete parameters (the probe), and at run time when they are traced."""
    alpha, delta = 0.01, 5e-9
    ratio = lambda w: (sp.k1e(alpha * w) / sp.k1e((alpha + delta) * w)) * np.exp(delta * w) * alpha / (alpha + delta)
    nyquist = math.pi * 64 / 1.6
    assert np.max(ratio(np.linspace(1.0, math.sqrt(2) * nyquist, 200))) < 1 + 1e-6 < ratio(100 * nyquist)

    def evolved(a):
        return bs.evolve(lobes.Mirror(), stats.GGX(a), stats.GGX(a + delta), method="grid", size=64, extent=0.8)

    with pytest.raises(bs.NoBRDFAtScaleError, match="exceeds 1"):
        evolved(alpha)
    # inside a user's jit equinox raises from its run-time callback (the type depends on the JAX version)
    with pytest.raises((eqx.EquinoxRuntimeError, jax.errors.JaxRuntimeError), match="exceeds 1"):
        jax.jit(lambda a: evolved(a).shape.on_grid()[1])(alpha)
    with pytest.raises((eqx.EquinoxRuntimeError, jax.errors.JaxRuntimeError), match="exceeds 1"):
        jax.jit(lambda a: evolved(a).density(U))(alpha)


def test_bad_arguments():
    with pytest.raises(bs.InvalidInputError, match="regularisation"):
        bs.evolve(lobes.Beckmann(0.1), stats.GGX(0.1), stats.Delta(), regularisation=-1.0)


@pytest.mark.wrong_types
def test_a_density_as_lobe_and_an_unknown_method_name_are_named():
    with pytest.raises(bs.InvalidInputError, match="lobe must be"):
        bs.evolve(stats.Beckmann(0.1), stats.Delta(), stats.Delta())
    with pytest.raises(bs.InvalidInputError, match="method must be"):
        bs.evolve(lobes.Beckmann(0.1), stats.Delta(), stats.Delta(), method="fft")


# -- differentiability, compilation, batching, precision ------------------------------------
def test_gradients_match_finite_differences():
    law = stats.ScaledFamily(stats.GGX, stats.WidthLaw(alpha_max=0.2, mu_c=1.0, exponent=1.0))
    u = jnp.array([[0.05, 0.02]])

    def f(params):
        alpha0, mu = params
        return bs.evolve(lobes.Beckmann(alpha0), law.at(1.0), law.at(mu), method="radial", size=384).density(u)[0]

    p = jnp.array([0.1, 3.0])
    g = jax.jit(jax.grad(f))(p)  # compiled once: the eager gradient costs seconds of dispatch
    eps = 1e-6
    f = jax.jit(f)
    fd = np.array([(f(p.at[k].add(eps)) - f(p.at[k].add(-eps))) / (2 * eps) for k in range(2)])
    np.testing.assert_allclose(g, fd, rtol=1e-6)


def test_no_recompilation_when_only_values_change():
    traces = []

    @eqx.filter_jit
    def f(lobe, s0, s1, u):
        traces.append(1)
        return bs.evolve(lobe, s0, s1, method="grid", size=128).density(u)

    for a in (0.1, 0.12, 0.15):
        f(lobes.Beckmann(a), stats.GGX(a / 2), stats.GGX(a / 4), U)
    assert len(traces) == 1


def test_batched_over_scales_with_vmap():
    law = stats.ScaledFamily(stats.Beckmann, stats.WidthLaw(alpha_max=0.2, mu_c=1.0, exponent=1.0))
    mus = jnp.array([2.0, 5.0, 20.0])
    lobe = lobes.Beckmann(0.05)
    batched = jax.vmap(lambda mu: bs.evolve(lobe, law.at(1.0), law.at(mu)).density(U))(mus)
    for k, mu in enumerate(mus):
        np.testing.assert_allclose(batched[k], bs.evolve(lobe, law.at(1.0), law.at(mu)).density(U), rtol=1e-14)


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
@pytest.mark.parametrize("method", ["radial", "grid"])
def test_float32_matches_float64(method):
    def run(dtype):
        lobe = lobes.Beckmann(jnp.asarray(0.1, dtype))
        out = bs.evolve(
            lobe,
            stats.GGX(jnp.asarray(0.08, dtype)),
            stats.GGX(jnp.asarray(0.03, dtype)),
            method=method,
            size=256,
            tol=1e-6,
        )
        return out.density(jnp.asarray(U, dtype))

    v32, v64 = run(jnp.float32), run(jnp.float64)
    assert v32.dtype == jnp.float32
    assert _max_rel(v32, v64) < 1e-5  # float32: ~1e-7 per operation, a few hundred summed terms


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
@settings(max_examples=15, deadline=None)
@given(a0=st.floats(0.02, 0.3), af=st.floats(0.02, 0.3), frac=st.floats(0.05, 0.95))
def test_radial_path_agrees_with_closed_form_over_parameters(a0, af, frac):
    at = frac * math.hypot(a0, af)
    args = (lobes.Beckmann(a0), stats.Beckmann(af), stats.Beckmann(at))
    pts = jnp.asarray(np.array([[0.0, 0.0], [0.5, 0.3]]) * math.hypot(a0, af))
    assert _max_rel(bs.evolve(*args, method="radial").density(pts), bs.evolve(*args).density(pts)) < 1e-8


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_tight_tolerances_resolve_heavy_tailed_lobes_against_scipy_quadrature():
    """GGX lobe and statistics (|m|⁻⁴ tails): at tight tol the support radius is large, and the
    frequency window that finds the cut-off must stay on the lobe's core (it once slid down to
    frequencies below the lobe's bandwidth and truncated it: 44 % off at tol = 1e-18, then
    accepted). Reference: SciPy's adaptive quadrature of g(0) = (2π)⁻¹ ∫ G(k) k dk with
    SciPy's exponentially scaled K1. The error stays within tol: the cut-off bounds the
    k-weighted tail of a transform that decays only like e^{−0.13 k} (a pointwise |G| < tol
    cut-off had left up to 14 tol), and the rule's nodes grow as tol tightens."""

    def xk1e(x):  # x K1(x) eˣ, finite where K1 underflows
        return x * sp.k1e(x) if x > 0 else 1.0

    def G(k):
        return xk1e(0.08 * k) * xk1e(0.1 * k) / xk1e(0.05 * k) * np.exp(-(0.08 + 0.1 - 0.05) * k)

    reference = si.quad(lambda k: G(k) * k, 0, np.inf, epsabs=0, epsrel=1e-13, limit=500)[0] / (2 * np.pi)
    errors = []
    for tol in (1e-8, 1e-10, 1e-12):  # the reference's own accuracy (1e-13) cannot judge 1e-14
        value = float(bs.evolve(lobes.GGX(0.08), stats.GGX(0.1), stats.GGX(0.05), tol=tol).density(jnp.zeros(2)))
        errors.append(abs(value - reference) / reference)
        assert errors[-1] <= tol, (tol, value, reference)
    assert errors[0] > errors[1] > errors[2]


@pytest.mark.parametrize(
    "tol",
    [
        1e-15,
        0.0,
        1.0,
        float("nan"),
        *(pytest.param(tol, marks=pytest.mark.wrong_types) for tol in ("1e-3", None, np.array([1e-3]))),
    ],
)
def test_tol_outside_what_float64_can_meet_is_refused(tol):
    with pytest.raises(bs.InvalidInputError, match="tol must be a number in"):
        bs.evolve(lobes.GGX(0.08), stats.GGX(0.1), stats.GGX(0.05), tol=tol)


def test_radial_queries_beyond_the_lobes_nodes_warn():
    lobe = bs.evolve(lobes.GGX(0.08), stats.GGX(0.1), stats.GGX(0.05), method="radial", size=64, tol=1e-10)
    with pytest.warns(UserWarning, match="Gauss–Legendre nodes"):
        lobe.density(jnp.array([[30.0, 0.0]]))


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_radial_queries_at_the_centre_resolve_an_oscillating_transform():
    """Narrow Beckmann lobe (α = 1e-3) with uniform-disk statistics (radius 0.1): g(0) is
    (πr²)⁻¹ (1 − e^{−r²/α²}) = 1/(π · 0.01) exactly in float64. G oscillates over the disk's
    extent, so a query at the centre alone needs the nodes for that extent too (it once got
    64 nodes and returned 41.2)."""
    exact = 1 / (math.pi * 0.1**2)
    for tol in (1e-3, 1e-6):
        lobe = bs.evolve(lobes.Beckmann(1e-3), stats.Disk(0.1), stats.Delta(), method="radial", tol=tol)
        alone = float(lobe.density(jnp.zeros(2)))
        together = float(lobe.density(jnp.array([[0.0, 0.0], [0.05, 0.0]]))[0])
        assert abs(alone - exact) <= tol * exact and abs(together - exact) <= tol * exact, (tol, alone, together)


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_grid_path_refuses_a_lobe_it_cannot_resolve():
    """Aspect ratio 5·10⁴: no grid within the size cap spans the wide axis and resolves the
    narrow one; the grid path once returned a lobe 100 times too low at its centre."""
    with pytest.raises(bs.InvalidInputError, match="cannot resolve this lobe even to 1e-2"):
        bs.evolve(lobes.Beckmann(alpha_x=1.0, alpha_y=2e-5), stats.GGX(1e-6), stats.Delta(), method="grid")
