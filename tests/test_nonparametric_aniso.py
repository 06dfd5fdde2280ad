"""fitting.AnisotropicNonParametricModel (issue 31, item 1): R_k(W) over the W plane.

The oracles are hand-written NumPy Gaussians and Gaussian mixtures (covariances add under
convolution), not brdfscale's evolution; ΔΣ is checked against a finite-difference Hessian of
the model's own log R_k and against the Gaussian closed form."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from brdfscale import InvalidInputError, LobeImage, MeasurementSet


jax.config.update("jax_enable_x64", True)

from brdfscale import fitting  # noqa: E402
from brdfscale.fitting._derived import covariance_differences  # noqa: E402
from brdfscale.fitting._nonparametric_aniso import _fast_length, _noise_frequency, evolve_on_grid  # noqa: E402


SCALES = (1.0, 2.0, 4.0)
SIZE, EXTENT = 17, 0.5


def rotation(phi):
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, -s], [s, c]])


def gaussian(u, mean, cov, amplitude=1.0):
    """``A exp(−½ dᵀC⁻¹d)/(2π √det C)``, by hand."""
    d = u - mean
    q = np.einsum("...i,ij,...j->...", d, np.linalg.inv(cov), d)
    return amplitude * np.exp(-q / 2) / (2 * np.pi * np.sqrt(np.linalg.det(cov)))


def grid(size=SIZE, extent=EXTENT):
    x = np.linspace(-extent, extent, size)
    return np.stack(np.meshgrid(x, x), axis=-1)  # rows u_y, columns u_x (brdfscale.LobeImage)


C0 = rotation(0.5) @ np.diag([0.03, 0.008]) @ rotation(0.5).T
MEAN = np.array([0.04, -0.03])
STEPS = [
    rotation(0.3) @ np.diag([0.012, 0.003]) @ rotation(0.3).T,
    rotation(-0.2) @ np.diag([0.010, 0.004]) @ rotation(-0.2).T,
]
DIFFERENCES = np.cumsum([np.zeros((2, 2)), *STEPS], axis=0)


def dataset(lobes, seed=0, noise=0.01, floor=1e-3, size=SIZE, extent=EXTENT):
    """A Dataset of the lobes (functions of u) at SCALES with Gaussian noise of known σ."""
    rng, u = np.random.default_rng(seed), grid(size, extent)
    images = []
    for mu, lobe in zip(SCALES, lobes):
        v = lobe(u)
        sigma = noise * v.max() + floor
        images.append(
            LobeImage(
                mu=mu,
                incident=[0.0, 0.0, 1.0],
                extent=extent,
                values=v + sigma * rng.standard_normal(v.shape),
                sigma=np.full(v.shape, sigma),
            )
        )
    return fitting.Dataset.from_measurements(MeasurementSet(tuple(images)))


def gaussian_set(seed=0, **kw):
    return dataset([lambda u, d=d: gaussian(u, MEAN, C0 + d, 2.0) for d in DIFFERENCES], seed, **kw)


def test_the_last_knot_stops_where_the_lobe_s_transform_meets_the_noise():
    """``_noise_frequency``: for μ0 images of known flux F (the sum of the valid pixels) and σ, ``√(2 ln(F/N))/σ_min``
    with N = (Σ σ²)^{1/2} over the valid pixels only (a masked pixel counts in neither), replicate images adding
    their F/N in quadrature, ln(F/N) floored at 2 (also for a flux ≤ 0); the model's default ``w_max`` is the least
    of that, 6/σ_min and π/h."""

    def image(mu, value, sigma, mask=None):
        v = np.full((SIZE, SIZE), value)
        return LobeImage(
            mu=mu, incident=[0.0, 0.0, 1.0], extent=EXTENT, values=v, sigma=np.full(v.shape, sigma), mask=mask
        )

    coarser = [image(mu, 1.0, 0.1) for mu in SCALES[1:]]
    mask = np.ones((SIZE, SIZE), bool)
    mask[:5] = False  # 5 of 17 rows masked
    cases = [
        ([image(1.0, 1.0, 0.01)], SIZE * SIZE / (0.01 * SIZE)),  # F = 289, N = 0.17
        ([image(1.0, 1.0, 0.01, mask)], 12 * SIZE / (0.01 * math.sqrt(12 * SIZE))),
        ([image(1.0, 1.0, 0.01), image(1.0, 1.0, 0.02)], math.hypot(SIZE / 0.01, SIZE / 0.02)),
        ([image(1.0, 1e-4, 0.01)], math.exp(2.0)),  # F/N = 0.17: the floor
        ([image(1.0, -1.0, 0.01)], math.exp(2.0)),
    ]
    for first, ratio in cases:
        data = fitting.Dataset.from_measurements(MeasurementSet((*first, *coarser)))
        assert _noise_frequency(data, 0.02) == pytest.approx(math.sqrt(2 * math.log(ratio)) / 0.02, rel=1e-12)
    data = gaussian_set()
    model = fitting.AnisotropicNonParametricModel(data)
    centre, cov = fitting._anisotropic.image_moments(data)
    h = 2 * EXTENT / (SIZE - 1)
    sd = math.sqrt(max(float(np.linalg.eigvalsh(cov[0])[0]), h * h / 12))
    assert model.knots[-1] == pytest.approx(min(6 / sd, math.pi / h, _noise_frequency(data, sd)), rel=1e-12)


def gaussian_theta(model, differences, base_theta):
    """θ with the given base part and constant profiles for Gaussian statistics of ΔΣ_k:
    a = (xx + yy)/4, b = (xx − yy)/4, c = xy/2 (per reference variance), no higher harmonics, no odd part."""
    rows, J1, v = [], len(model.knots), model.reference_variance
    for d in differences[1:]:
        d = np.asarray(d) / v
        row = [np.full(J1, (d[0, 0] + d[1, 1]) / 4)]
        if model.harmonics:
            row += [np.full(J1, (d[0, 0] - d[1, 1]) / 4), np.full(J1, d[0, 1] / 2)]
            row += [np.zeros(J1 - 1)] * (2 * (model.harmonics - 1))
        rows.append(np.concatenate(row))
    theta = np.concatenate([np.asarray(base_theta), *rows])
    return jnp.asarray(np.concatenate([theta, np.zeros(len(model.names) - theta.size)]))  # no odd part


def model_grid(model):
    x = model.origin + model.pitch * np.arange(model.grid_points)
    return np.stack(np.meshgrid(x, x), axis=-1)


@pytest.fixture(scope="module")
def data():
    return gaussian_set()


@pytest.fixture(scope="module")
def model(data):
    return fitting.AnisotropicNonParametricModel(data, base_nodes=9, n_knots=3, harmonics=2)


# --- the discretisation against the closed-form Gaussian evolution ---------------------------------


def check_gaussian_evolution(phi, ratio, phi_d, ratio_d):
    """Base N(m, C0), Gaussian statistics of ΔΣ: the evolved grid equals N(m, C0 + ΔΣ) sampled."""
    h, g = 0.02, 81
    x = h * (np.arange(g) - g // 2)
    u = np.stack(np.meshgrid(x, x), axis=-1)
    c0 = rotation(phi) @ np.diag([0.01, 0.01 / ratio]) @ rotation(phi).T
    dd = rotation(phi_d) @ np.diag([0.006, 0.006 / ratio_d]) @ rotation(phi_d).T
    mean = np.array([0.05, -0.03])

    def log_ratio(W):
        return -0.5 * jnp.einsum("...i,ij,...j->...", W, jnp.asarray(dd), W)[None]

    out = np.asarray(evolve_on_grid(jnp.asarray(gaussian(u, mean, c0)), log_ratio, h, 2 * g))[0]
    truth = gaussian(u, mean, c0 + dd)
    np.testing.assert_allclose(out, truth, atol=1e-6 * truth.max())


def test_fft_evolution_is_the_closed_form_gaussian():
    check_gaussian_evolution(0.4, 3.0, -0.7, 2.0)


@settings(max_examples=15, deadline=None)
@given(
    phi=st.floats(0.0, math.pi),
    ratio=st.floats(1.0, 4.0),
    phi_d=st.floats(0.0, math.pi),
    ratio_d=st.floats(1.0, 6.0),
)
def test_fft_evolution_over_orientation_and_anisotropy(phi, ratio, phi_d, ratio_d):
    check_gaussian_evolution(phi, ratio, phi_d, ratio_d)


@settings(max_examples=15, deadline=None)
@given(phi=st.floats(0.0, math.pi), ratio=st.floats(1.0, 8.0), scale=st.floats(1e-3, 3e-2))
def test_gaussian_statistics_are_exact_in_the_family(model, phi, ratio, scale):
    """Constant profiles give R_k = exp(−½ Wᵀ ΔΣ_k W) over the whole plane, any orientation and
    anisotropy, and covariance_differences returns that ΔΣ_k."""
    d1 = rotation(phi) @ np.diag([scale, scale / ratio]) @ rotation(phi).T
    differences = np.stack([np.zeros((2, 2)), d1, 2 * d1])
    theta = gaussian_theta(model, differences, np.zeros(model.base_nodes**2))
    W = np.random.default_rng(1).normal(size=(50, 2)) * 20
    got = np.asarray(model.relative_statistics_plane(theta, jnp.asarray(W), jnp.asarray(SCALES)))
    want = np.exp(-0.5 * np.einsum("wi,kij,wj->kw", W, differences, W))
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-300)
    got_d = np.asarray(model.covariance_differences(theta, jnp.asarray(SCALES)))
    np.testing.assert_allclose(got_d, differences, rtol=1e-12, atol=1e-14 * scale)


def test_predicted_images_are_the_gaussian_evolution():
    """The whole forward map (spline base lobe, FFT, reading at the pixels) against N(m, C0 + ΔΣ_k):
    the base lobe exactly (the spline of a quadratic log), the evolved ones to 1e-7 of the peak on
    images that hold the base lobe's mass (on the 17² px, ±0.5 set, whose edge cuts the base lobe at
    about 3 standard deviations, the evolved lobes miss the cut-off mass: 1.2e-3 of the peak)."""
    data = gaussian_set(size=33, extent=1.0)
    model = fitting.AnisotropicNonParametricModel(data, base_nodes=9, n_knots=3, harmonics=2)
    nodes = np.stack(np.meshgrid(model.node_x, model.node_y), axis=-1)
    base = np.log(gaussian(nodes, MEAN, C0, 2.0)).ravel()
    theta = gaussian_theta(model, DIFFERENCES, base)
    pred = np.asarray(model.predict(theta, data))
    offsets = np.asarray(data.offsets)
    for i, k in enumerate(data.scale_of_image):
        truth = gaussian(offsets[i], MEAN, C0 + DIFFERENCES[k], 2.0)
        assert np.max(np.abs(pred[i] - truth)) < (1e-12 if k == 0 else 1e-7) * truth.max()


def test_covariance_differences_are_the_hessian_of_log_R(model):
    """ΔΣ_k = −∇² log R_k(0), by central differences of the model's own log R_k along e_x, e_y,
    e_x + e_y, with every profile non-constant and every harmonic non-zero."""
    rng = np.random.default_rng(3)
    theta = jnp.asarray(rng.normal(size=len(model.names)) * 0.3)
    exact = np.asarray(model.covariance_differences(theta, jnp.asarray(SCALES)))
    eps = 1e-4

    def second(direction):
        W = eps * np.asarray(direction, float)
        f = np.asarray(model.log_relative(theta, jnp.asarray(np.stack([W, -W]))))
        return -(f[:, 0] + f[:, 1]) / eps**2  # log R(0) = 0; −(f(h) + f(−h))/h² → wᵀΔΣw

    xx, yy, both = second([1, 0]), second([0, 1]), second([1, 1])
    fd = np.stack([np.stack([xx, (both - xx - yy) / 2], -1), np.stack([(both - xx - yy) / 2, yy], -1)], -2)
    np.testing.assert_allclose(fd, exact, rtol=1e-3, atol=1e-3 * np.abs(exact).max())
    generic = np.asarray(covariance_differences(model, theta, jnp.asarray(SCALES)))
    np.testing.assert_array_equal(generic, exact)


def test_isotropic_special_case(data):
    """harmonics=0 (and no odd part, the default): R_k depends on |W| only, equals the radial
    relative_statistics, and a Gaussian base lobe evolves to the Gaussian of covariance C0 + d I."""
    model = fitting.AnisotropicNonParametricModel(data, base_nodes=9, n_knots=3, harmonics=0)
    assert all("cos" not in n and "sin" not in n for n in model.names)
    rng = np.random.default_rng(2)
    theta = jnp.asarray(rng.normal(size=len(model.names)) * 0.3)
    r = rng.uniform(0, 30, 40)
    phi = rng.uniform(0, 2 * np.pi, 40)
    W = np.stack([r * np.cos(phi), r * np.sin(phi)], -1)
    plane = np.asarray(model.relative_statistics_plane(theta, jnp.asarray(W), jnp.asarray(SCALES)))
    radial = np.asarray(model.relative_statistics(theta, jnp.asarray(r), jnp.asarray(SCALES)))
    np.testing.assert_allclose(plane, radial, rtol=1e-12)
    d = np.asarray(model.covariance_differences(theta, jnp.asarray(SCALES)))
    np.testing.assert_allclose(d[:, 0, 1], 0.0, atol=0)
    np.testing.assert_allclose(d[:, 0, 0], d[:, 1, 1])
    iso = [np.zeros((2, 2)), 0.01 * np.eye(2), 0.02 * np.eye(2)]
    c0 = 0.02 * np.eye(2)
    nodes = np.stack(np.meshgrid(model.node_x, model.node_y), axis=-1)
    theta = gaussian_theta(model, iso, np.log(gaussian(nodes, np.zeros(2), c0)).ravel())
    grids = np.asarray(model.evolved_grids(theta))
    u = model_grid(model)
    for k in range(3):
        truth = gaussian(u, np.zeros(2), c0 + iso[k])
        assert np.max(np.abs(grids[k] - truth)) < 2e-3 * truth.max()


# --- transformations ---------------------------------------------------------------------------


@pytest.mark.slow
def test_jit_grad_vmap_equal_eager():
    """About 20 s on 2 cores: eager JAX dispatches every operation separately."""
    data = gaussian_set(size=9)  # small: eager JAX dispatches op by op
    model = fitting.AnisotropicNonParametricModel(data, base_nodes=5, n_knots=2, harmonics=2)
    theta = jnp.asarray(model.initial(data))
    eager = model.predict(theta, data)
    # an FFT's rounding is relative to the largest value it transforms, not to each output: XLA's
    # fused program differs from op-by-op dispatch at ~1e-18 of the peak on pixels 1e6 below it
    # (measured 7.6e-11 absolute on a peak of 1.9e7), so the bound is relative to the peak (here and under vmap)
    peak_bound = 1e-15 * float(jnp.max(jnp.abs(eager)))
    np.testing.assert_allclose(eqx.filter_jit(model.predict)(theta, data), eager, rtol=1e-12, atol=peak_bound)

    def loss(t):
        return jnp.sum(model.predict(t, data) ** 2)

    g = eqx.filter_jit(jax.grad(loss))(theta)
    # the gradient against central differences along a random direction (the eager gradient: the slow test below)
    v = jnp.asarray(np.random.default_rng(0).normal(size=theta.shape))
    eps, jitted_loss = 1e-6, eqx.filter_jit(loss)
    fd = (jitted_loss(theta + eps * v) - jitted_loss(theta - eps * v)) / (2 * eps)
    np.testing.assert_allclose(float(g @ v), float(fd), rtol=1e-5)
    stack = jnp.stack([theta, theta + 0.01 * v])
    batched = jax.vmap(lambda t: model.predict(t, data))(stack)
    np.testing.assert_allclose(batched[0], eager, rtol=1e-12, atol=peak_bound)
    np.testing.assert_allclose(batched[1], eqx.filter_jit(model.predict)(stack[1], data), rtol=1e-12, atol=peak_bound)


@pytest.mark.slow  # ≈ 8 s on 2 cores (the eager pass compiles op by op): the default suite is near its 360 s budget
def test_odd_part_jit_grad_vmap_equal_eager():
    """The model with an odd part (complex log R_k = −D_k + iΨ_k; every odd coordinate non-zero) under jax.jit,
    jax.grad and jax.vmap: the jitted prediction equals the eager one, the jitted gradient of the sum of squared
    residuals (data and prior rows) equals central differences of that sum along a random direction, a jitted
    vmap over two θ equals a loop of eager calls. Harmonics 4φ and 5φ: both parts' profiles without a
    coordinate at ρ = 0. Tolerances: rtol 1e-12 plus 1e-15 of the peak for the predictions (an FFT's rounding
    is relative to its largest input: test_jit_grad_vmap_equal_eager; measured 1e-16 of it), rtol 1e-7 for the
    differences at ε = 1e-6 (measured 4e-10). About 8 s on 2 cores, most of it eager JAX compiling op by op; the
    eager gradient (9 s more) is compared in test_eager_gradient_equals_jitted (slow)."""
    data = gaussian_set(size=9)  # small: eager JAX dispatches (and compiles) op by op
    model = fitting.AnisotropicNonParametricModel(data, base_nodes=5, n_knots=2, harmonics=2, odd_harmonics=3)
    n_odd = sum(name.startswith("Q") for name in model.names)
    assert n_odd == 2 * (4 * 3 + 2 * 2)  # 2 scales × (cos φ … sin 3φ from ρ_0, cos 5φ and sin 5φ from ρ_1)
    rng = np.random.default_rng(5)
    theta = jnp.asarray(model.initial(data) + 0.1 * rng.normal(size=len(model.names)))
    values, weight = jnp.asarray(data.values), jnp.asarray(data.weight)

    def loss(t):
        residuals = (model.predict(t, data) - values) * weight
        return jnp.sum(residuals**2) + jnp.sum(model.penalty(t) ** 2)

    eager = model.predict(theta, data)
    peak_bound = 1e-15 * float(jnp.max(jnp.abs(eager)))
    np.testing.assert_allclose(jax.jit(lambda t: model.predict(t, data))(theta), eager, rtol=1e-12, atol=peak_bound)
    value_and_grad = jax.jit(jax.value_and_grad(loss))
    g = value_and_grad(theta)[1]
    assert np.all(np.asarray(g)[-n_odd:] != 0)  # every odd coordinate moves the loss
    v = jnp.asarray(rng.normal(size=theta.shape))
    eps = 1e-6
    fd = (value_and_grad(theta + eps * v)[0] - value_and_grad(theta - eps * v)[0]) / (2 * eps)
    np.testing.assert_allclose(float(g @ v), float(fd), rtol=1e-7)
    stack = jnp.stack([theta, theta + 0.05 * v])
    batched = jax.jit(jax.vmap(lambda t: model.predict(t, data)))(stack)
    for b, t in zip(batched, stack):
        np.testing.assert_allclose(b, model.predict(t, data), rtol=1e-12, atol=peak_bound)


# --- options and refusals -------------------------------------------------------------------------


def test_bad_options_are_refused(data):
    with pytest.raises(InvalidInputError, match="odd"):
        fitting.AnisotropicNonParametricModel(data, base_nodes=8)
    with pytest.raises(InvalidInputError, match="harmonics"):
        fitting.AnisotropicNonParametricModel(data, harmonics=-1)
    with pytest.raises(InvalidInputError, match="odd_harmonics"):
        fitting.AnisotropicNonParametricModel(data, odd_harmonics=-1)
    with pytest.raises(InvalidInputError, match="regularisation"):
        fitting.AnisotropicNonParametricModel(data, regularisation=-1.0)


@pytest.mark.wrong_types
def test_not_a_dataset_is_refused():
    with pytest.raises(InvalidInputError, match="Dataset"):
        fitting.AnisotropicNonParametricModel("data")  # type: ignore[arg-type]


def test_other_number_of_scales_refused(model):
    two = dataset([lambda u: gaussian(u, MEAN, C0, 2.0)] * 2)
    with pytest.raises(InvalidInputError, match="3 scales"):
        model.check_data(two)


# --- fits ----------------------------------------------------------------------------------------


@pytest.mark.slow
def test_gaussian_fit_recovers_delta_sigma(data, model):
    """Synthetic anisotropic Gaussian data: every ΔΣ component within 3 standard errors (about 3
    minutes on 2 cores: the solve runs its 256 steps)."""
    result = fitting.fit(model, data, starts=1)
    assert result.chi2 / result.dof < 1.5
    for entry, truth in zip(result.covariance_differences, DIFFERENCES[1:]):
        value, std = np.asarray(entry["value"]), np.asarray(entry["std"], float)
        assert np.all(np.isfinite(std))
        assert np.all(np.abs(value - truth) <= 3 * std), (value, truth, std)


def mixture_set(seed=0):
    """A heavy-tailed anisotropic set: base lobe and relative statistics are both two-Gaussian
    mixtures of different covariances (a narrow core, a wide rotated tail), so every scale's lobe
    is a four-Gaussian mixture (covariances add)."""
    tail = rotation(1.0) @ np.diag([0.08, 0.02]) @ rotation(1.0).T
    core = rotation(0.2) @ np.diag([0.015, 0.004]) @ rotation(0.2).T
    stats = [
        [(1.0, np.zeros((2, 2)))],
        [(0.7, 0.3 * STEPS[0]), (0.3, 3 * STEPS[0])],
        [(0.6, 0.4 * DIFFERENCES[2]), (0.4, 3 * DIFFERENCES[2])],
    ]

    def lobe(k):
        def f(u):
            return sum(
                2.0 * wb * ws * gaussian(u, MEAN, cb + cs, 1.0)
                for wb, cb in ((0.8, core), (0.2, tail))
                for ws, cs in stats[k]
            )

        return f

    return dataset([lobe(k) for k in range(3)], seed, noise=0.005, size=25)


@pytest.mark.slow
def test_heavy_tailed_set_is_fitted_where_the_gaussian_model_is_not():
    data = mixture_set()
    model = fitting.AnisotropicNonParametricModel(data, base_nodes=13, n_knots=4, harmonics=2)
    result = fitting.fit(model, data, starts=1)
    gaussian_fit = fitting.fit(fitting.AnisotropicModel(3), data, starts=2)
    assert result.chi2 / result.dof <= 1.5, result.chi2 / result.dof
    assert gaussian_fit.chi2 / gaussian_fit.dof > 3.0, gaussian_fit.chi2 / gaussian_fit.dof


@pytest.mark.slow
@pytest.mark.parametrize("odd_harmonics", [0, 3])
def test_eager_gradient_equals_jitted(odd_harmonics):
    """About 20 s each: the eager gradient dispatches every operation separately. With an odd part, its
    coordinates non-zero (a phase on every scale)."""
    data = gaussian_set(size=9)
    model = fitting.AnisotropicNonParametricModel(
        data, base_nodes=5, n_knots=2, harmonics=2, odd_harmonics=odd_harmonics
    )
    theta = model.initial(data)
    n_odd = sum(name.startswith("Q") for name in model.names)
    theta[theta.size - n_odd :] = 0.1 * np.random.default_rng(5).normal(size=n_odd)
    theta = jnp.asarray(theta)

    def loss(t):
        return jnp.sum(model.predict(t, data) ** 2)

    g = jax.grad(loss)(theta)
    g_jit = eqx.filter_jit(jax.grad(loss))(theta)
    np.testing.assert_allclose(g_jit, g, rtol=1e-10, atol=1e-14 * float(jnp.abs(g).max()))


def test_fft_length_is_the_smallest_5_smooth_number():
    def smooth(m):
        for p in (2, 3, 5):
            while m % p == 0:
                m //= p
        return m == 1

    for n in range(1, 600):
        assert _fast_length(n) == next(m for m in range(n, 4 * n) if smooth(m))


def test_start_of_a_noisy_set_does_not_ring():
    """The data-driven start of a noisy set: the base lobe's spline through log g0 at the nodes stays
    near the measured peak (the noise read at the outer nodes, or its floor where negative, made the
    spline ring: 6.4 × the peak on this set, 1.5e17 × on experiments/bench_anisotropic.py's)."""
    from helpers import anisotropic_dataset

    data = anisotropic_dataset(0)
    model = fitting.AnisotropicNonParametricModel(data)
    base = np.asarray(model.base_grid(jnp.asarray(model.initial(data))))
    peak = float(np.max(np.asarray(data.values[0])))
    assert 0.5 * peak < base.max() < 1.5 * peak, base.max() / peak
    assert np.all(base > 0)


def test_the_odd_part_adds_the_third_cumulants_it_states():
    """The odd part (R_k's phase Ψ_k = ρ³ Σ Q B(φ)): the evolved lobes' third central moments on the model grid,
    less the Gaussian base lobe's, equal third_cumulant_differences (cumulants add under convolution; the
    grid's moments are the oracle, the closed form of the cumulants from Ψ's cubic term is the method's);
    their means and covariances are the Gaussian evolution's, the odd part changing neither."""
    data = gaussian_set(size=49, extent=1.5)
    model = fitting.AnisotropicNonParametricModel(data, base_nodes=9, n_knots=3, harmonics=1, odd_harmonics=2)
    assert [n for n in model.names if n.startswith("Q1[")][::4] == [
        "Q1[cosφ](W=0) [v^1.5]",
        "Q1[sinφ](W=0) [v^1.5]",
        "Q1[cos3φ](W=0) [v^1.5]",
        "Q1[sin3φ](W=0) [v^1.5]",
    ]
    x = model_grid(model)
    base = np.log(gaussian(np.stack(np.meshgrid(model.node_x, model.node_y), -1), MEAN, C0, 2.0)).ravel()
    theta = np.array(gaussian_theta(model, DIFFERENCES, base))
    odd = np.array([[0.05, -0.03, 0.02, 0.01], [-0.02, 0.04, -0.01, 0.03]])  # (k, g) in units of v^1.5
    J1 = len(model.knots)
    theta[-2 * 4 * J1 :] = np.repeat(odd[:, :, None], J1, axis=2).ravel()  # constant profiles
    grids = np.asarray(model.evolved_grids(jnp.asarray(theta)))
    stated = np.asarray(model.third_cumulant_differences(jnp.asarray(theta)))
    assert np.all(stated[0] == 0)

    def moments(g):
        w = g / g.sum()
        mean = np.einsum("ij,ijk->k", w, x)
        d = x - mean
        cov = np.einsum("ij,ijk,ijl->kl", w, d, d)
        k3 = [np.sum(w * d[..., 0] ** (3 - n) * d[..., 1] ** n) for n in range(4)]
        return mean, cov, np.array(k3)

    m0, c0, k0 = moments(grids[0])
    np.testing.assert_allclose(k0, 0.0, atol=1e-9)  # the Gaussian base lobe
    for k in (1, 2):
        mean, cov, k3 = moments(grids[k])
        np.testing.assert_allclose(mean, m0, atol=1e-9)
        np.testing.assert_allclose(cov, C0 + DIFFERENCES[k], atol=1e-8)
        np.testing.assert_allclose(k3 - k0, stated[k], rtol=1e-6, atol=1e-9)
        assert np.max(np.abs(stated[k])) > 1e-4  # not vanishingly small: the check has teeth


@pytest.mark.parametrize(("harmonics", "odd"), [(2, 0), (2, 1), (2, 2), (1, 3)])
def test_every_odd_coordinate_sets_the_profile_value_its_name_states(data, harmonics, odd):
    """θ's layout: each coordinate named ``Q{k}[{g}](W=ρ_j)`` moves the odd profile Q_{k,g}(ρ_j) alone (by
    v^1.5), none of the even ones; the harmonics 5φ and above have no coordinate at ρ = 0; with no odd part the
    third cumulants are 0."""
    model = fitting.AnisotropicNonParametricModel(data, base_nodes=5, n_knots=3, harmonics=harmonics, odd_harmonics=odd)
    functions = ["cosφ", "sinφ", "cos3φ", "sin3φ", "cos5φ", "sin5φ"][: 2 * odd]
    names = [n for n in model.names if n.startswith("Q")]
    assert len(names) == (len(SCALES) - 1) * (min(2 * odd, 4) * 4 + max(2 * odd - 4, 0) * 3)
    v = model.reference_variance
    for name in names:
        k, g = int(name[1]), functions.index(name[name.index("[") + 1 : name.index("]")])
        j = model.knots.index(min(model.knots, key=lambda w, t=float(name.split("W=")[1].split(")")[0]): abs(w - t)))
        theta = np.zeros(len(model.names))
        theta[model.names.index(name)] = 1.0
        Q = np.asarray(model.odd_profiles(jnp.asarray(theta)))
        expected = np.zeros_like(Q)
        expected[k, g, j] = v**1.5
        np.testing.assert_allclose(Q, expected, rtol=1e-12)
        assert not np.any(np.asarray(model.profiles(jnp.asarray(theta))))
        assert g < 4 or j > 0
    stated = np.asarray(model.third_cumulant_differences(jnp.zeros(len(model.names))))
    assert stated.shape == (len(SCALES), 4) and not np.any(stated)
