"""Tests of brdfscale.scene: planner choices, accuracy against independent references
(closed forms, SciPy Hankel quadrature, a NumPy 2D quadrature, a SciPy-rotation group
integral for the SO(3) path: tests/references/planner.py), camera geometry, jit/differentiability
and input validation (the smoke run of experiments/bench_planner.py is in test_experiments_smoke.py)."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import brdfscale as bs
from brdfscale import lobes, scene, so3, stats
from brdfscale._interpolate import interpolate
from brdfscale.geometry import microfacet_factor, slope_to_direction
from tests.references import planner as oracle  # the independent references (shared with experiments/bench_planner.py)


TOL = 1e-4


def queries_at(u, mu):
    """Queries whose half-vector slope is u (i = o = the direction of slope u), flat m∞."""
    d = np.asarray(slope_to_direction(jnp.asarray(u)))
    return scene.Queries(d, d, mu), np.asarray(microfacet_factor(jnp.asarray(d), jnp.asarray(d)))


def spiral(n, reach=0.15):
    r = np.linspace(0, reach, n)
    phi = 7.3 * np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.stack([r * np.cos(phi), r * np.sin(phi)], -1)


def test_closed_form_chosen_and_exact():
    mat = oracle.material("closed_form")
    u = spiral(40)
    mu = np.geomspace(1e-3, 10, 40)
    q, F = queries_at(u, mu)
    plan = scene.plan(scene.Scene((mat,), q, TOL))
    assert plan.parts[0].path == "closed_form"
    got = np.asarray(plan.evaluate()) / F
    want = np.array([oracle.gaussian_reference(m, x[None])[0] for m, x in zip(mu, u)])
    np.testing.assert_allclose(got, want, rtol=1e-12)


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_radial_log_mu_binning_meets_target_against_scipy_hankel():
    """Many distinct scales over four decades: log-μ nodes with interpolation; max error
    relative to each scale's peak within the target (SciPy Hankel reference)."""
    mat = oracle.material("beckmann_ggx")
    rng = np.random.default_rng(1)
    n = 200
    u = rng.uniform(-0.12, 0.12, (n, 2))
    mu = np.exp(rng.uniform(np.log(2e-3), np.log(20), n))
    q, F = queries_at(u, mu)
    plan = scene.plan(scene.Scene((mat,), q, TOL))
    part = plan.parts[0]
    assert part.path == "radial" and "log-μ nodes" in part.details
    got = np.asarray(plan.evaluate()) / F
    want = oracle._hankel_rows(mu, np.linalg.norm(u, axis=-1))
    peak = oracle._hankel_rows(mu, np.zeros(n))
    err = np.max(np.abs(got - want) / peak)
    assert err <= TOL
    assert err <= plan.predicted_error * 4  # the prediction is not wildly optimistic


@pytest.mark.slow
def test_scipy_hankel_reference_matches_mpmath():
    r = 0.05
    assert oracle.hankel_reference("beckmann_ggx", 0.01, [r])[0] == pytest.approx(
        oracle.mpmath_check("beckmann_ggx", 0.01, r), rel=1e-10
    )


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_grid_for_skewed_statistics_against_2d_quadrature():
    mat = oracle.material("skewed_mixture")
    g = np.linspace(-0.12, 0.12, 9)
    u = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    mu = np.full(len(u), 0.01)
    q, F = queries_at(u, mu)
    plan = scene.plan(scene.Scene((mat,), q, TOL))
    assert plan.parts[0].path == "grid"
    got = np.asarray(plan.evaluate()) / F
    want = oracle.skewed_reference(0.01, u)
    assert np.max(np.abs(got - want)) / np.max(want) <= TOL
    # the skew is resolved: the lobe is not symmetric under u_x → −u_x (the grid is)
    mirrored = want.reshape(9, 9)[:, ::-1].ravel()
    assert np.max(np.abs(want - mirrored)) > 100 * TOL * np.max(want)


def test_nearly_specular_statistics_against_series_reference():
    """Plus-distribution statistics (seed §6): radial path against SciPy quadrature with H_0
    from its power series, which itself matches mpmath."""
    mat = oracle.material("plus")
    u = spiral(40)
    mu = np.full(40, 0.01)
    q, F = queries_at(u, mu)
    plan = scene.plan(scene.Scene((mat,), q, TOL))
    assert plan.parts[0].path == "radial"
    want = oracle.hankel_reference("plus", 0.01, np.linalg.norm(u, axis=-1))
    got = np.asarray(plan.evaluate()) / F
    assert np.max(np.abs(got - want)) / np.max(want) <= TOL
    np.testing.assert_allclose(oracle.plus_h0(np.array([2.0])), [-0.44191940220810094], rtol=1e-12)  # mpmath value


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_grid_table_mode_matches_direct_mode():
    """Many queries → FFT tables + cubic interpolation; few → direct DFT sums. Same answer."""
    mat = oracle.material("skewed_mixture")
    rng = np.random.default_rng(2)
    u = rng.uniform(-0.1, 0.1, (2000, 2))
    mu = np.exp(rng.uniform(np.log(8e-3), np.log(1.2e-2), len(u)))
    q, F = queries_at(u, mu)
    table = scene.plan(scene.Scene((mat,), q, 1e-3))
    assert "FFT grid" in table.parts[0].details
    few = np.arange(0, len(u), 500)
    q_few, F_few = queries_at(u[few], mu[few])
    direct = scene.plan(scene.Scene((mat,), q_few, 1e-6))
    assert "summed at the" in direct.parts[0].details
    a = np.asarray(table.evaluate())[few] / F[few]
    b = np.asarray(direct.evaluate()) / F_few
    assert np.max(np.abs(a - b)) / np.max(b) <= 1e-3


def test_duplicate_queries_are_computed_once():
    mat = oracle.material("beckmann_ggx")
    u = np.repeat(spiral(5), 4, axis=0)
    q, F = queries_at(u, np.full(len(u), 0.05))
    plan = scene.plan(scene.Scene((mat,), q, TOL))
    assert plan.parts[0].inverse.max() == 4
    v = np.asarray(plan.evaluate()).reshape(5, 4)
    np.testing.assert_array_equal(v, v[:, :1].repeat(4, 1))
    assert "5 distinct (u, μ)" in plan.explain()


def test_camera_scene_geometry_and_image():
    cam = scene.Camera(height=2.0, pitch=0.3, fov=0.8, resolution=(20, 30))
    light = np.array([0.6, 0.0, 0.8])
    sc = scene.camera_scene([oracle.material("closed_form")], cam, light, TOL)
    rays = cam.rays().reshape(-1, 3)
    hit = rays[:, 2] < 0
    assert len(sc.queries) == hit.sum() < 600  # the sky above the horizon gives no queries
    # independent check of one pixel: distance to the plane and footprint
    j = int(np.asarray(sc.pixels)[7])
    d = rays[j]
    t = 2.0 / -d[2]
    np.testing.assert_allclose(np.asarray(sc.queries.o)[7], -d, atol=1e-12)
    np.testing.assert_allclose(float(sc.queries.mu[7]), t * (0.8 / 20) / math.sqrt(-d[2]), rtol=1e-12)
    plan = scene.plan(sc)
    img = np.asarray(plan.image())
    assert img.shape == (20, 30) and np.all(img.ravel()[~hit] == 0) and np.all(img.ravel()[hit] > 0)


@pytest.mark.slow  # 7 s on 2 cores: the default suite measured 372 s in a clean clone at fc7a33e (budget 360)
def test_plan_is_jitted_and_differentiable():
    mat = oracle.material("beckmann_ggx")
    u = spiral(12)
    mu = np.geomspace(5e-3, 0.5, 12)
    q, F = queries_at(u, mu)
    plan = scene.plan(scene.Scene((mat,), q, 1e-4))

    def loss(alpha):
        m = eqx.tree_at(lambda m: m.lobe, mat, lobes.Beckmann(alpha))
        return jnp.sum(plan.evaluate((m,)) ** 2)

    a = 0.05
    grad = jax.grad(loss)(jnp.asarray(a))
    h = 1e-6
    fd = (loss(jnp.asarray(a + h)) - loss(jnp.asarray(a - h))) / (2 * h)
    assert float(grad) == pytest.approx(float(fd), rel=1e-5)


def test_explain_reports_choices_costs_and_errors():
    mats = (oracle.material("beckmann_ggx"), oracle.material("closed_form"))
    u = spiral(10)
    q, _ = queries_at(u, np.full(10, 0.02))
    q = scene.Queries(q.i, q.o, q.mu, material=np.arange(10) % 2)
    text = scene.plan(scene.Scene(mats, q, TOL)).explain()
    assert "path: radial" in text and "path: closed_form" in text
    assert "predicted error" in text and "units" in text and "Gauss–Legendre" in text


def test_forced_method_that_does_not_apply():
    mat = oracle.material("skewed_mixture")
    q, _ = queries_at(spiral(4), np.full(4, 0.01))
    with pytest.raises(bs.MethodNotApplicableError):
        scene.plan(scene.Scene((mat,), q, TOL), method="radial")
    with pytest.raises(bs.MethodNotApplicableError):
        scene.plan(scene.Scene((mat,), q, TOL), method="closed_form")


def test_no_brdf_at_a_finer_scale_is_reported_at_planning():
    coarse = scene.Material(lobes.Beckmann(0.01), 10.0, stats.ScaledFamily(stats.Beckmann, oracle.WIDTH))
    q, _ = queries_at(spiral(3), np.full(3, 1e-4))
    with pytest.raises(bs.NoBRDFAtScaleError):
        scene.plan(scene.Scene((coarse,), q, TOL))


def test_bad_input():
    mat = oracle.material("closed_form")
    q, _ = queries_at(spiral(3), np.full(3, 0.1))
    with pytest.raises(bs.InvalidInputError, match="tol"):
        scene.Scene((mat,), q, 2.0)
    with pytest.raises(bs.InvalidInputError, match="material indices"):
        scene.Scene((mat,), scene.Queries(q.i, q.o, q.mu, material=[0, 1, 0]), TOL)
    with pytest.raises(bs.InvalidInputError, match="shape"):
        scene.Queries(q.i, q.o[:2], q.mu)
    with pytest.raises(bs.InvalidInputError, match="positive"):
        scene.Queries(q.i, q.o, [0.1, -1.0, 0.1])
    with pytest.raises(bs.InvalidInputError, match="method"):
        scene.plan(scene.Scene((mat,), q, TOL), method="fast")
    with pytest.raises(bs.InvalidInputError, match="fov"):
        scene.Camera(height=1.0, pitch=0.1, fov=4.0, resolution=(4, 4))


@pytest.mark.wrong_types
def test_a_density_is_no_scale_law():
    with pytest.raises(bs.InvalidInputError, match="scale law"):
        scene.Material(lobes.Beckmann(0.1), 1.0, stats.Beckmann(0.1))


@settings(max_examples=15, deadline=None)
@given(st.lists(st.floats(-2, 2), min_size=4, max_size=4), st.lists(st.floats(-2, 2), min_size=4, max_size=4))
def test_cubic_interpolation_is_exact_for_cubics(cx, cy):
    """Tensor cubic Lagrange interpolation reproduces bicubic polynomials (clamped stencils too)."""
    px, py = np.polynomial.Polynomial(cx), np.polynomial.Polynomial(cy)
    x, y = np.linspace(-1, 1, 9), np.linspace(0, 2, 7)
    table = px(x)[:, None] * py(y)[None, :]
    rng = np.random.default_rng(0)
    qx, qy = rng.uniform(-1, 1, 50), rng.uniform(0, 2, 50)
    pos = np.stack([(qx + 1) / 0.25, qy / (2 / 6)], -1)
    got = np.asarray(interpolate(jnp.asarray(table), jnp.asarray(pos)))
    want = px(qx) * py(qy)
    np.testing.assert_allclose(got, want, atol=1e-10 * (1 + np.max(np.abs(table))))
    # the NumPy form the planner uses on concrete tables is the same interpolation
    np.testing.assert_allclose(interpolate(table, pos, xp=np), got, rtol=1e-14, atol=1e-14 * np.max(np.abs(table)))


# -- SO(3) path -------------------------------------------------------------------------------------
def test_so3_reference_parts_are_sound():
    """The benchmark's independent pieces: its NumPy facet lobe is the library's model, and the
    heat kernel (character sum) times the Haar density integrates to 1 on its quadrature."""
    i, o = oracle._unit(0.3, 0.0), oracle._unit(0.4, math.pi)
    rot = np.asarray(
        so3.euler_to_matrix(np.array([0.1, 2.0, 4.0]), np.array([0.2, 0.3, 0.1]), np.array([0.0, 1.0, 5.0]))
    )
    np.testing.assert_allclose(
        oracle.so3_lobe(i, o, rot), np.asarray(oracle.so3_material().lobe.evaluate(i, o, rot)), rtol=1e-12
    )
    _, total = oracle.so3_reference(0.01, i, o, np.zeros((1, 3)), nodes=32)
    assert total == pytest.approx(1.0, abs=1e-8)


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_so3_material_is_planned_on_so3_and_meets_target_against_group_integral():
    queries, ref, peak, _ = oracle.so3_problem(np.array([0.01]), 6, nodes=32)
    plan = scene.plan(scene.Scene((oracle.so3_material(),), queries, 1e-3))
    part = plan.parts[0]
    assert part.path == "so3"
    B = int(part.details.split("band limit B = ")[1].split(" ")[0])
    # a priori from the lobe's width and the least damping (not the largest band limit allowed)
    assert (
        B
        == so3.band_limit(
            lambda J: (
                np.asarray(oracle.so3_material().lobe.spectrum(J))
                * np.exp(-(oracle.so3_material().tau(oracle.MU0) - oracle.so3_material().tau(0.01)) * J * (J + 1))
            ),
            2.5e-4,
        )[0]
    )
    assert part.step.rows == B - 1 and part.step.columns == B - 1  # tilted Γ∞, twist-dependent lobe
    err = np.max(np.abs(np.asarray(plan.evaluate()) - ref) / peak)
    assert err <= 1e-3
    assert err <= 4 * plan.predicted_error + 1e-4  # the prediction is not wildly optimistic
    text = plan.explain()
    assert "path: so3" in text and "band limit B =" in text and "twist columns" in text and "units" in text


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_so3_twist_free_lobe_on_a_flat_plane_needs_one_order():
    """An isotropic facet lobe depends on the facet normal only (M' = 0); at flat global
    orientations D^J is diagonal, so only M = M' = 0 is computed — and the result is still
    right (group-integral reference), independent of the twist, and differentiable."""
    alpha = (0.2, 0.2)
    mat = oracle.so3_material(alpha)
    i, o = oracle._unit(0.3, 0.0), oracle._unit(0.4, math.pi)
    # three twists at one scale, and 30 more scales: log-μ nodes with cubic interpolation
    twist = np.array([0.0, 0.7, 2.0] + [0.5] * 30)
    mu = np.concatenate([np.full(3, 0.01), np.geomspace(2e-3, 0.5, 30)])
    n = len(mu)
    q = scene.Queries(np.tile(i, (n, 1)), np.tile(o, (n, 1)), mu, m_inf=np.zeros((n, 2)), twist=twist)
    plan = scene.plan(scene.Scene((mat,), q, 1e-3))
    step = plan.parts[0].step
    assert (step.rows, step.lobe_columns, step.columns) == (0, 0, 0)
    assert "log-μ nodes" in plan.parts[0].details
    got = np.asarray(plan.evaluate())
    np.testing.assert_allclose(got[:3], got[0], rtol=1e-12)
    check = np.arange(2, n, 4)  # one twist at 0.01 and every fourth further scale, between nodes or on them
    angles = np.asarray(q.euler_angles())
    want = np.array([oracle.so3_reference(mu[k], i, o, angles[k][None], nodes=32, alpha=alpha)[0][0] for k in check])
    assert np.max(np.abs(got[check] - want) / want) <= 1e-3  # each query is at its (flat) peak orientation

    def loss(a):  # through the lobe's samples, the transform, the propagator and the synthesis
        m = eqx.tree_at(lambda m: m.lobe, mat, so3.AnisotropicMicrofacetLobe(a, a))
        return jnp.sum(plan.evaluate((m,)))

    a, h = jnp.asarray(0.2), 1e-5
    fd = (loss(a + h) - loss(a - h)) / (2 * h)
    assert float(jax.grad(loss)(a)) == pytest.approx(float(fd), rel=1e-5)


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_so3_anisotropic_diffusion_matches_the_public_pipeline():
    """D_x ≠ D_y mixes twist orders: the plan keeps them all and agrees with so3.forward →
    so3.evolve_diffusion (matrix exponentials) → so3.synthesize at the same band limit."""
    mat = oracle.so3_material((0.5, 0.5), D=(1.0, 0.4, 0.2))
    i, o = oracle._unit(0.3, 0.0), oracle._unit(0.4, math.pi)
    m = np.array([[0.15, 0.0], [0.1, 0.05], [0.2, -0.05]])
    twist = np.array([0.0, 1.0, 2.5])
    q = scene.Queries(np.tile(i, (3, 1)), np.tile(o, (3, 1)), np.full(3, 0.01), m_inf=m, twist=twist)
    plan = scene.plan(scene.Scene((mat,), q, 1e-2))
    step = plan.parts[0].step
    assert step.lobe_columns == 0 and step.columns == step.band_limit - 1 and not step.diagonal
    assert "mixes twist orders" in plan.parts[0].details
    a = np.asarray(q.euler_angles())
    B = step.band_limit
    R0 = so3.forward(mat.lobe.samples(i, o, step.sample_band_limit), m_max=B - 1, n_max=B - 1)[:B]
    R = so3.evolve_diffusion(R0, mat.law.D, mat.tau(mat.mu0), mat.tau(0.01))
    want = np.real(np.asarray(so3.synthesize(R, a[:, 0], a[:, 1], a[:, 2])))
    np.testing.assert_allclose(np.asarray(plan.evaluate()), want, rtol=1e-9, atol=1e-9 * np.max(np.abs(want)))


def test_so3_bad_requests():
    mat = oracle.so3_material()
    i, o = oracle._unit(0.3, 0.0), oracle._unit(0.4, math.pi)
    q = scene.Queries(i[None], o[None], [1e-5])  # finer than μ0 = 1e-4: a deconvolution
    with pytest.raises(bs.NoBRDFAtScaleError, match="finer"):
        scene.plan(scene.Scene((mat,), q, TOL))
    q = scene.Queries(i[None], o[None], [0.01])
    with pytest.raises(bs.MethodNotApplicableError, match="so3"):
        scene.plan(scene.Scene((mat,), q, TOL), method="grid")
    with pytest.raises(bs.MethodNotApplicableError, match="AnisotropicMaterial"):
        scene.plan(scene.Scene((oracle.material("closed_form"),), q, TOL), method="so3")
    with pytest.raises(bs.InvalidInputError, match="twist"):
        scene.Queries(i[None], o[None], [0.01], twist=[0.0, 1.0])


@pytest.mark.wrong_types
def test_an_anisotropic_material_refuses_an_isotropic_lobe_or_law():
    mat = oracle.so3_material()
    with pytest.raises(bs.InvalidInputError, match="AnisotropicMicrofacetLobe"):
        scene.AnisotropicMaterial(lobes.Beckmann(0.1), 1.0, mat.law)
    with pytest.raises(bs.InvalidInputError, match="DiffusionLaw"):
        scene.AnisotropicMaterial(mat.lobe, 1.0, oracle.WIDTH)


def test_midpoint_error_uses_the_evaluations_interpolation():
    """The planner's interpolation check (NumPy) equals the jit-compiled interpolation of the
    evaluation at the midpoints between nodes, ends of the grid included."""
    from brdfscale.scene._scales import midpoint_error

    rng = np.random.default_rng(0)
    at_nodes = rng.random((9, 5))
    exact = np.asarray(jax.jit(interpolate)(jnp.asarray(at_nodes), jnp.arange(8)[:, None] + 0.5))
    assert midpoint_error(at_nodes, exact) < 1e-15
    perturbed = exact.copy()
    perturbed[0, 0] += 1e-3 * np.max(np.abs(exact[0]))
    assert midpoint_error(at_nodes, perturbed) == pytest.approx(
        1e-3 * np.max(np.abs(exact[0])) / np.max(np.abs(perturbed[0]))
    )


def test_no_brdf_from_a_spectral_path_reads_as_one_message():
    """The run-time check's equinox error is turned into NoBRDFAtScaleError with the library's
    message first, not JAX's traceback text around it."""
    finer = scene.Material(lobes.GGX(0.05), 10.0, stats.ScaledFamily(stats.GGX, oracle.WIDTH))
    q, _ = queries_at(spiral(3), np.full(3, 1e-3))
    with pytest.raises(bs.NoBRDFAtScaleError) as err:
        scene.plan(scene.Scene((finer,), q, TOL))
    assert str(err.value).startswith("no BRDF exists") and "stack" not in str(err.value)


def test_material_regularisation_must_be_non_negative():
    with pytest.raises(bs.InvalidInputError, match="regularisation must be ≥ 0"):
        scene.Material(lobes.GGX(0.05), 10.0, stats.ScaledFamily(stats.GGX, oracle.WIDTH), regularisation=-1.0)


def test_no_queries_is_refused_by_name():
    with pytest.raises(bs.InvalidInputError, match="at least one"):
        scene.Queries(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
