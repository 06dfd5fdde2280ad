"""Tests of brdfscale.synth: height fields, facet statistics, the synthetic gonioreflectometer.

References used: the analytic Σ(μ) of stats.GaussianSurface (quadrature of the spectrum,
written independently of the synthesis), the spectrum's own P(k) via the periodogram,
Tabulated.from_samples, brute-force pixel averages and mirror reflection computed with
brdfscale.geometry from normals built by a cross product, closed-form densities.
"""

import math
import re

import jax
import numpy as np
import pytest
from scipy.integrate import quad

from brdfscale import geometry, InvalidInputError, stats, synth, topography
from brdfscale.stats._histogram import SlopeHistogram


GAUSS_ISO = stats.GaussianCorrelation(1.0, 8.0)
GAUSS_ANISO = stats.GaussianCorrelation(1.0, (6.0, 16.0))


@pytest.mark.parametrize("spectrum", [GAUSS_ISO, GAUSS_ANISO], ids=["isotropic", "anisotropic"])
def test_facet_slope_covariance_matches_box_law(spectrum):
    """The ensemble mean of the facet-slope covariance equals GaussianSurface(window='box').Σ(μ)
    within 4.5 standard errors of the ensemble (24 independent 256² fields)."""
    scales = (1.0, 4.0, 16.0)
    covs = np.array(
        [
            [
                np.cov(synth.facet_slopes(synth.spectral_field(spectrum, size=256, seed=s), mu).reshape(-1, 2).T)
                for mu in scales
            ]
            for s in range(24)
        ]
    )
    mean = covs.mean(axis=0)
    stderr = covs.std(axis=0, ddof=1) / math.sqrt(len(covs))
    law = stats.GaussianSurface(spectrum, window="box", n_k=256)
    for j, mu in enumerate(scales):
        expected = np.asarray(law.slope_covariance(mu))
        assert np.all(np.abs(mean[j] - expected) <= 4.5 * stderr[j]), (mu, mean[j], expected, stderr[j])
        # and the statistical error is small enough for the comparison to mean something
        assert np.all(stderr[j].diagonal() < 0.03 * expected.diagonal())


def test_kcorrelation_field_has_the_spectrum():
    """Periodogram / P(k) averages to 1 in radial bands (each mode: an Exp(1) variable)."""
    spectrum = stats.KCorrelation(A=30.0, B=16.0, C=3.5)
    n, spacing, fields = 128, 0.5, 8
    k = 2 * np.pi * np.fft.fftfreq(n, spacing)
    kv = np.stack(np.meshgrid(k, k, indexing="xy"), axis=-1)
    power = np.asarray(spectrum(kv))
    ratio = np.zeros((n, n))
    for s in range(fields):
        h = synth.spectral_field(spectrum, size=n, spacing=spacing, seed=s).heights
        ratio += np.abs(np.fft.fft2(h)) ** 2 * spacing**2 / n**2 / power
    ratio /= fields
    kmag = np.linalg.norm(kv, axis=-1)
    edges = np.geomspace(kmag[kmag > 0].min(), kmag.max() * 1.0001, 8)
    for lo, hi in zip(edges[:-1], edges[1:]):
        band = (kmag >= lo) & (kmag < hi)
        independent = fields * band.sum() / 2  # ±k modes are complex conjugates
        assert abs(ratio[band].mean() - 1) < 5 / math.sqrt(independent), (lo, hi, ratio[band].mean())
    assert ratio[0, 0] < 1e-20  # the mean height is removed (round-off only)


def test_seed_determinism():
    a = synth.spectral_field(GAUSS_ISO, size=32, seed=7).heights
    assert np.array_equal(a, synth.spectral_field(GAUSS_ISO, size=32, seed=7).heights)
    assert not np.array_equal(a, synth.spectral_field(GAUSS_ISO, size=32, seed=8).heights)
    key = jax.random.key(3)
    b = synth.spectral_field(GAUSS_ISO, size=32, seed=key).heights
    assert np.array_equal(b, synth.spectral_field(GAUSS_ISO, size=32, seed=jax.random.key(3)).heights)
    assert np.array_equal(b, synth.spectral_field(GAUSS_ISO, size=32, seed=jax.random.PRNGKey(3)).heights)
    assert not np.array_equal(b, synth.spectral_field(GAUSS_ISO, size=32, seed=jax.random.key(4)).heights)
    rng = np.random.default_rng(5)
    c1 = synth.spectral_field(GAUSS_ISO, size=32, seed=rng).heights
    c2 = synth.spectral_field(GAUSS_ISO, size=32, seed=rng).heights
    assert not np.array_equal(c1, c2)  # a Generator is consumed, not reset
    s1 = synth.scratches(size=64, count=3, depth=1.0, width=4.0, length=20.0, seed=2).heights
    assert np.array_equal(s1, synth.scratches(size=64, count=3, depth=1.0, width=4.0, length=20.0, seed=2).heights)


@pytest.mark.parametrize("seed", [None, 1.5, "x", -1, True])
def test_bad_seeds(seed):
    with pytest.raises(InvalidInputError, match="seed"):
        synth.spectral_field(GAUSS_ISO, size=16, seed=seed)


def _cloud_in_cell_reference(samples, weights, extent, bins):
    """Direct bilinear deposition with np.add.at, written independently of SlopeHistogram."""
    h = 2 * extent / (bins - 1)
    g = (samples + extent) / h
    keep = np.all((g >= 0) & (g <= bins - 1), axis=1)
    g, w = g[keep], (np.ones(len(samples)) if weights is None else weights)[keep]
    i0 = np.minimum(np.floor(g).astype(int), bins - 2)
    f = g - i0
    out = np.zeros((bins, bins))
    for dx, wx in ((0, 1 - f[:, 0]), (1, f[:, 0])):
        for dy, wy in ((0, 1 - f[:, 1]), (1, f[:, 1])):
            np.add.at(out, (i0[:, 1] + dy, i0[:, 0] + dx), w * wx * wy)
    return out


def test_histogram_equals_direct_cloud_in_cell():
    rng = np.random.default_rng(0)
    samples = rng.standard_normal((30000, 2)) * 0.4
    weights = rng.uniform(0, 2, len(samples))
    for w in (None, weights):
        ref_counts = _cloud_in_cell_reference(samples, w, 1.0, 41)
        reference = stats.Tabulated(ref_counts, extent=1.0)
        np.testing.assert_allclose(
            np.asarray(stats.Tabulated.from_samples(samples, extent=1.0, bins=41, weights=w).values),
            np.asarray(reference.values),
            rtol=1e-12,
            atol=1e-15,
        )
        hist = SlopeHistogram(1.0, 41)
        for chunk in np.array_split(np.arange(len(samples)), 3):
            hist.add(samples[chunk, 0], samples[chunk, 1], None if w is None else w[chunk])
        np.testing.assert_allclose(
            np.asarray(stats.Tabulated.from_histogram(hist).values),
            np.asarray(reference.values),
            rtol=1e-12,
            atol=1e-15,
        )
    inside = np.all(np.abs(samples) <= 1.0, axis=1).mean()
    h = 2.0 / 40
    assert math.isclose(
        hist.density().sum() * h * h,
        np.sum(weights[np.all(np.abs(samples) <= 1.0, axis=1)]) / len(samples),
        rel_tol=1e-12,
    )
    assert inside < 1  # the grid cuts some samples, so the per-sample normalisation was exercised


@pytest.mark.parametrize("size,mu", [(48, 4.0), (50, 8.0), (32, 1.0), (32, 32.0)])
def test_facet_slopes_are_block_means_of_pixel_normals(size, mu):
    field = synth.spectral_field(GAUSS_ISO, size=size, spacing=1.0, seed=1)
    h = field.heights
    nx = -(np.roll(h, -1, axis=1) - h)  # normal slope m = −∇h by forward differences
    ny = -(np.roll(h, -1, axis=0) - h)
    b = int(mu)
    nb = size // b
    expected_x = nx[: nb * b, : nb * b].reshape(nb, b, nb, b).mean(axis=(1, 3))
    expected_y = ny[: nb * b, : nb * b].reshape(nb, b, nb, b).mean(axis=(1, 3))
    got = synth.facet_slopes(field, mu)
    np.testing.assert_allclose(got[..., 0], expected_x, atol=1e-14)
    np.testing.assert_allclose(got[..., 1], expected_y, atol=1e-14)


def test_scale_must_be_whole_pixels():
    field = synth.spectral_field(GAUSS_ISO, size=16, spacing=0.5, seed=0)
    assert field.block(2.0) == (4, 4)
    for mu in (0.75, 0.25, 9.0, -1.0):
        with pytest.raises(InvalidInputError, match="whole number of pixels"):
            synth.facet_slopes(field, mu)


def _blazed(**kw):
    return synth.blazed(size=160, period=20, **kw)  # 70 % of facets at +0.03, 30 % at −0.07


def test_blazed_mirror_facets_reflect_into_their_slope():
    """Mirror reflection computed independently (normals by a cross product of the tangents,
    geometry.reflect, geometry.half_slope) lands where the gonioreflectometer puts the lobe:
    70 % of the light at half-vector slope +0.03 (docs/conventions.md §2's sign test)."""
    field = _blazed()
    h = field.heights
    tx = np.stack([np.ones_like(h), np.zeros_like(h), np.roll(h, -1, axis=1) - h], axis=-1)
    ty = np.stack([np.zeros_like(h), np.ones_like(h), np.roll(h, -1, axis=0) - h], axis=-1)
    normal = np.cross(tx, ty)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    i = np.array([math.sin(0.3), 0.0, math.cos(0.3)])
    o = np.asarray(geometry.reflect(i, normal))
    ms = np.asarray(geometry.half_slope(np.broadcast_to(i, o.shape), o)).reshape(-1, 2)
    frac_plus = np.mean(np.isclose(ms[:, 0], 0.03, atol=1e-9))
    frac_minus = np.mean(np.isclose(ms[:, 0], -0.07, atol=1e-9))
    assert frac_plus == pytest.approx(0.7, abs=1e-12) and frac_minus == pytest.approx(0.3, abs=1e-12)

    mset = synth.gonioreflectometer(field, [160.0], i, extent=0.1, pixels=21)  # nodes every 0.01
    image = mset.images[0]
    x = np.linspace(-0.1, 0.1, 21)
    h2 = (x[1] - x[0]) ** 2
    centre = 10
    assert image.values[centre, np.argmin(np.abs(x - 0.03))] * h2 == pytest.approx(0.7, rel=1e-9)
    assert image.values[centre, np.argmin(np.abs(x + 0.07))] * h2 == pytest.approx(0.3, rel=1e-9)
    assert image.values.sum() * h2 == pytest.approx(1.0, rel=1e-12)


def test_blazed_facet_statistics_by_scale():
    field = _blazed()
    fine, period = synth.facet_statistics(field, [1.0, 20.0], bins=17, extent=0.08)  # nodes every 0.01
    assert fine.mean == pytest.approx([0.0, 0.0], abs=1e-15)
    # pixel facets: variance of the two-point distribution 0.7·0.03² + 0.3·0.07²
    assert fine.covariance[0, 0] * (fine.count - 1) / fine.count == pytest.approx(
        0.7 * 0.03**2 + 0.3 * 0.07**2, rel=1e-9
    )
    assert float(fine.slopes.cf(np.array([50.0, 0.0])).real) == pytest.approx(
        (0.7 * math.cos(50 * 0.03) + 0.3 * math.cos(50 * 0.07)) * math.sin(0.25) ** 2 / 0.25**2, rel=1e-9
    )  # × hat transform sinc²(W h/2)
    np.testing.assert_allclose(period.covariance, 0.0, atol=1e-25)  # a whole period is flat
    # skewness: the within-facet lobe at the period is the pixel distribution itself
    mean_cube = 0.7 * 0.03**3 + 0.3 * (-0.07) ** 3
    assert mean_cube < 0
    u = np.stack(np.meshgrid(*period.lobe.nodes(), indexing="xy"), axis=-1)
    w = np.asarray(period.lobe.values) * float(np.prod(np.asarray(period.lobe.spacing)))
    assert np.sum(w * u[..., 0] ** 3) == pytest.approx(mean_cube, rel=1e-9)


def test_projected_area_weighting_of_blazed_facets():
    field = _blazed()
    theta = 0.5
    i = np.array([math.sin(theta), 0.0, math.cos(theta)])
    image = synth.gonioreflectometer(field, [160.0], i, extent=0.1, pixels=21, weighting="projected_area").images[0]
    h2 = 0.01**2
    w_plus, w_minus = 1 + 0.03 * math.tan(theta), 1 - 0.07 * math.tan(theta)
    assert image.values[10, 13] * h2 == pytest.approx(0.7 * w_plus, rel=1e-9)
    assert image.values[10, 3] * h2 == pytest.approx(0.3 * w_minus, rel=1e-9)
    flat = synth.gonioreflectometer(field, [160.0], i, extent=0.1, pixels=21).images[0]
    assert flat.values[10, 13] * h2 == pytest.approx(0.7, rel=1e-9)


def _flat(micro=None, size=16):
    return synth.HeightField(np.zeros((size, size)), 1.0, micro=stats.Delta() if micro is None else micro)


def test_rough_micro_facets_and_instrument_blur_give_closed_form_lobes():
    x = np.linspace(-0.1, 0.1, 81)
    u = np.stack(np.meshgrid(x, x, indexing="xy"), axis=-1)
    micro = stats.Gaussian(sigma=(0.015, 0.01), mean=[0.02, -0.01])  # shifted: tests the sign
    image = synth.gonioreflectometer(_flat(micro), [4.0], [0, 0, 1.0], extent=0.1, pixels=81).images[0]
    expected = np.asarray(micro.density(u))
    assert np.max(np.abs(image.values - expected)) < 1e-9 * expected.max()
    # mirror facets seen by an instrument of resolution r: a Gaussian of std r per axis
    r = 0.012
    blurred = synth.gonioreflectometer(_flat(), [4.0], [0, 0, 1.0], extent=0.1, pixels=81, resolution=r).images[0]
    expected = np.asarray(stats.Gaussian(sigma=r).density(u))
    assert np.max(np.abs(blurred.values - expected)) < 1e-6 * expected.max()
    # within-facet lobe of facet_statistics: the micro lobe itself on a flat field
    (st,) = synth.facet_statistics(_flat(stats.GGX(0.01)), [4.0], bins=65, extent=0.05)
    h = 0.1 / 64
    probe = np.array([[0.0, 0.0], [8 * h, 2 * h], [-13 * h, 7 * h]])  # grid nodes
    np.testing.assert_allclose(
        np.asarray(st.lobe.density(probe)), np.asarray(stats.GGX(0.01).density(probe)), rtol=1e-4
    )


def test_noise_models():
    field = synth.spectral_field(GAUSS_ISO, size=64, seed=0)
    args = dict(extent=0.5, pixels=33)
    clean = synth.gonioreflectometer(field, [4.0], [0, 0, 1.0], **args).images[0]
    assert clean.sigma is None
    noisy = synth.gonioreflectometer(
        field, [4.0], [0, 0, 1.0], noise=synth.GaussianNoise(floor=0.05, relative=0.1), seed=3, **args
    )
    again = synth.gonioreflectometer(
        field, [4.0], [0, 0, 1.0], noise=synth.GaussianNoise(floor=0.05, relative=0.1), seed=3, **args
    )
    assert np.array_equal(noisy.images[0].values, again.images[0].values)
    im = noisy.images[0]
    np.testing.assert_allclose(im.sigma, np.sqrt((0.1 * clean.values) ** 2 + 0.05**2))
    z = (im.values - clean.values) / im.sigma
    assert abs(z.mean()) < 4 / math.sqrt(z.size) and abs(z.std() - 1) < 4 / math.sqrt(2 * z.size)
    exposure = 50.0
    pois = synth.gonioreflectometer(
        field, [4.0], [0, 0, 1.0], noise=synth.PoissonNoise(exposure), seed=4, **args
    ).images[0]
    counts = pois.values * exposure
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)
    np.testing.assert_allclose(pois.sigma, np.sqrt(np.maximum(clean.values * exposure, 1)) / exposure)
    bright = clean.values * exposure > 20
    zp = (pois.values - clean.values)[bright] / pois.sigma[bright]
    assert abs(zp.mean()) < 4 / math.sqrt(zp.size) and abs(zp.std() - 1) < 0.15


def test_poisson_read_noise_gives_chi2_one_in_dark_and_bright_pixels():
    """σ of PoissonNoise(exposure, read_noise) is the reading's true spread: ⟨z²⟩ = 1 at every
    expected count, down to counts ≪ 1 where the one-count floor of read_noise = 0 gives ⟨z²⟩ ≪ 1
    (the demo's former χ²/dof of 0.31)."""
    rng = np.random.default_rng(7)
    exposure, n = 2.0, 200_000
    for counts in (0.0, 0.01, 0.3, 5.0, 400.0):
        values = np.full(n, counts / exposure)
        reading, sigma = synth.PoissonNoise(exposure, read_noise=1.5).sample(values, rng)
        z2 = np.mean(((reading - values) / sigma) ** 2)
        assert abs(z2 - 1) < 5 * math.sqrt(2 / n) * 3, (counts, z2)  # var(z²) ≤ ~3·2 for these mixtures
        np.testing.assert_allclose(sigma, np.sqrt(counts + 1.5**2) / exposure)
    reading, sigma = synth.PoissonNoise(exposure).sample(np.full(n, 0.01 / exposure), rng)
    assert np.mean(((reading - 0.01 / exposure) / sigma) ** 2) < 0.05  # the floor overstates σ of dark pixels
    assert synth.PoissonNoise(3.0, 2.0).record() == {"type": "poisson", "exposure": 3.0, "read_noise": 2.0}
    with pytest.raises(InvalidInputError, match="read_noise"):
        synth.PoissonNoise(3.0, -1.0)


def test_derived_base_lobe_width_is_the_second_moment_of_the_finest_image():
    """fitting.truth_of's alpha_lobe for a synthetic measurement (√tr of micro + within-facet +
    binning covariance, from the recorded slope covariances) equals the second moment of the
    image at μ0 computed directly from its pixels (quadrature over the grid)."""
    from brdfscale import fitting

    field = synth.spectral_field(stats.GaussianCorrelation(0.4, 6.0), size=256, seed=3, micro=stats.Beckmann(0.04))
    extent, pixels = 0.6, 121
    mset = synth.gonioreflectometer(field, [2.0, 8.0], [0, 0, 1.0], extent=extent, pixels=pixels)
    image = mset.images[0]
    u = np.linspace(-extent, extent, pixels)
    ux, uy = np.meshgrid(u, u)
    v = np.asarray(image.values)
    mass = v.sum()
    mean_x, mean_y = (v * ux).sum() / mass, (v * uy).sum() / mass
    second = (v * ((ux - mean_x) ** 2 + (uy - mean_y) ** 2)).sum() / mass
    model = fitting.ParametricModel(law="gaussian_surface")
    truth = fitting.truth_of(model, mset.metadata)
    assert truth["alpha_lobe"] ** 2 == pytest.approx(second, rel=2e-3)
    within = np.trace(
        np.asarray(mset.metadata["truth"]["pixel_slope_covariance"])
        - np.asarray(mset.metadata["truth"]["facet_slope_covariance"][0])
    )
    assert within > 0.1 * second  # the within-facet slopes matter here, not only the micro lobe


def test_gonioreflectometer_rgb_and_metadata():
    field = synth.spectral_field(GAUSS_ISO, size=64, seed=0)
    mset = synth.gonioreflectometer(
        field, [4.0, 16.0], [[0, 0, 1.0], [0.6, 0, 0.8]], extent=0.5, pixels=17, albedo=[0.8, 0.5, 0.2]
    )
    assert len(mset.images) == 4 and mset.images[0].values.shape == (17, 17, 3)
    np.testing.assert_allclose(mset.images[0].values[..., 1] / 0.5, mset.images[0].values[..., 0] / 0.8)
    assert [p.mu for p in mset.images] == [4.0, 4.0, 16.0, 16.0]
    truth = mset.metadata["truth"]
    # Σ_xx(μ) for a Gaussian-correlated spectrum and a box window separates into 1D integrals
    sigma_h, ell, mu = 1.0, 8.0, 16.0
    sinc2 = lambda k: np.sinc(k * mu / (2 * np.pi)) ** 2  # noqa: E731  (np.sinc(x) = sin(πx)/(πx))
    ix = quad(lambda k: k**2 * np.exp(-((k * ell) ** 2) / 4) * sinc2(k), -np.inf, np.inf, epsabs=0, epsrel=1e-12)[0]
    iy = quad(lambda k: np.exp(-((k * ell) ** 2) / 4) * sinc2(k), -np.inf, np.inf, epsabs=0, epsrel=1e-12)[0]
    sxx = np.pi * ell * ell * sigma_h**2 * ix * iy / (2 * np.pi) ** 2
    np.testing.assert_allclose(
        np.asarray(truth["analytic_facet_slope_covariance"][1]), [[sxx, 0], [0, sxx]], rtol=1e-9, atol=1e-16
    )
    np.testing.assert_allclose(
        truth["facet_slope_covariance"][0], np.cov(synth.facet_slopes(field, 4.0).reshape(-1, 2).T)
    )
    assert mset.metadata["surface"]["spectrum"]["type"] == "GaussianCorrelation"


def test_scratches_are_v_grooves():
    field = synth.scratches(size=128, count=1, depth=1.0, width=8.0, length=40.0, seed=1)
    h = field.heights
    assert h.max() == 0 and h.min() == pytest.approx(-1.0, abs=0.15)
    slopes = synth.facet_slopes(field, 1.0).reshape(-1, 2)
    steep = np.linalg.norm(slopes, axis=1)
    assert steep.max() <= 2 * 1.0 / 8.0 * math.sqrt(2) + 1e-12  # wall slope 2 depth / width (× √2: diagonal pixels)
    assert np.mean(steep == 0) > 0.9  # sparse: most of the surface is untouched


def test_named_surfaces():
    for name in synth.SURFACES:
        field = synth.named_surface(name, size=64, seed=1)
        assert field.size == 64 and field.description["name"] == name
        assert np.all(np.isfinite(field.heights))
    with pytest.raises(InvalidInputError, match="unknown surface"):
        synth.named_surface("velvet")
    rough = synth.named_surface("gaussian", size=32, micro=stats.Beckmann(0.01))
    assert isinstance(rough.micro, stats.Gaussian)


def test_invalid_arguments():
    field = synth.spectral_field(GAUSS_ISO, size=16, seed=0)
    with pytest.raises(InvalidInputError, match="size"):
        synth.spectral_field(GAUSS_ISO, size=3, seed=0)
    with pytest.raises(InvalidInputError, match="seed"):
        synth.gonioreflectometer(field, [4.0], [0, 0, 1.0], extent=0.1, noise=synth.PoissonNoise(10.0))
    with pytest.raises(InvalidInputError, match="albedo"):
        synth.gonioreflectometer(field, [4.0], [0, 0, 1.0], extent=0.1, albedo=[1.0, 2.0])
    with pytest.raises(InvalidInputError, match="incident"):
        synth.gonioreflectometer(field, [4.0], [0, 0, -1.0], extent=0.1)
    with pytest.raises(InvalidInputError, match="period"):
        synth.blazed(size=64, period=10)
    with pytest.raises(InvalidInputError, match="exposure"):
        synth.PoissonNoise(0.0)
    with pytest.raises(InvalidInputError, match="heights"):
        synth.HeightField(np.full((8, 8), np.nan), 1.0)


def test_float32_parameters_agree_with_float64():
    """With jax_enable_x64 off, spectra and micro lobes evaluate in float32; the NumPy
    synthesis stays float64, so only the spectrum's and the kernel's rounding differ."""
    field64 = synth.spectral_field(stats.GaussianCorrelation(1.0, 8.0), size=64, seed=0).heights
    (lobe64,) = synth.facet_statistics(_flat(stats.GGX(0.01)), [4.0], bins=33, extent=0.05)
    with jax.enable_x64(False):
        spectrum32 = stats.GaussianCorrelation(1.0, 8.0)
        assert spectrum32.rms_height.dtype == np.float32
        field32 = synth.spectral_field(spectrum32, size=64, seed=0).heights
        (lobe32,) = synth.facet_statistics(_flat(stats.GGX(0.01)), [4.0], bins=33, extent=0.05)
    assert np.max(np.abs(field32 - field64)) < 1e-6 * np.max(np.abs(field64))
    v32, v64 = np.asarray(lobe32.lobe.values), np.asarray(lobe64.lobe.values)
    assert np.max(np.abs(v32 - v64)) < 1e-5 * v64.max()


def _refused_without_allocating(call, match):
    """``call`` raises InvalidInputError matching ``match`` having traced < 1 MB of allocations
    (NumPy reports its buffers to tracemalloc): the refusal comes before the work."""
    import tracemalloc

    tracemalloc.start()
    try:
        with pytest.raises(InvalidInputError, match=match):
            call()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2**20, peak


def test_grids_above_the_memory_cap_are_refused_before_allocating(monkeypatch):
    """Was: numpy MemoryError (7 TiB) or 'Maximum allowed dimension exceeded' from deep inside."""
    cap = "MAX_GRID_BYTES"
    _refused_without_allocating(lambda: synth.spectral_field(GAUSS_ISO, size=10**6, seed=0), cap)
    _refused_without_allocating(lambda: synth.named_surface("gaussian", size=10**6), cap)
    _refused_without_allocating(lambda: synth.blazed(size=10**6, period=4), cap)
    _refused_without_allocating(
        lambda: synth.scratches(size=10**6, count=1, depth=1.0, width=2.0, length=4.0, seed=0), cap
    )
    field = _flat(size=16)
    _refused_without_allocating(
        lambda: synth.gonioreflectometer(field, [4.0], [0, 0, 1.0], extent=0.1, resolution=1e6),
        r"image grid \(pixels=64, resolution=1e\+06\).*MAX_GRID_BYTES.*smaller resolution",
    )
    _refused_without_allocating(
        lambda: synth.gonioreflectometer(field, [4.0], [0, 0, 1.0], extent=0.1, resolution=1e300), cap
    )
    _refused_without_allocating(
        lambda: synth.gonioreflectometer(field, [4.0], [0, 0, 1.0], extent=0.1, pixels=10**6), cap
    )
    _refused_without_allocating(lambda: synth.facet_statistics(field, [4.0], bins=10**6), r"bins=1000000.*fewer bins")
    _refused_without_allocating(lambda: synth.global_slopes(field, bins=10**6), cap)
    rough = _flat(stats.Beckmann(0.5), size=16)  # a wide micro lobe pads a fine grid far out
    _refused_without_allocating(
        lambda: synth.facet_statistics(rough, [4.0], bins=65, extent=1e-7), "within-facet lobe grid"
    )
    # the cap is the documented constant, read when called: 64² float64 nodes pass, 68² do not
    assert synth.MAX_GRID_BYTES == 2**31
    monkeypatch.setattr("brdfscale.synth._surface.MAX_GRID_BYTES", 8 * 64 * 64)
    assert synth.spectral_field(GAUSS_ISO, size=64, seed=0).size == 64
    _refused_without_allocating(lambda: synth.spectral_field(GAUSS_ISO, size=68, seed=0), "32768 bytes")
    assert synth.gonioreflectometer(_flat(), [4.0], [0, 0, 1.0], extent=0.1, pixels=64).images[0].size == 64
    with pytest.raises(InvalidInputError, match="MAX_GRID_BYTES"):
        synth.gonioreflectometer(
            _flat(), [4.0], [0, 0, 1.0], extent=0.1, pixels=64, resolution=0.01
        )  # padded beyond 64


@pytest.mark.wrong_types
def test_a_spectrum_by_name_is_refused():
    with pytest.raises(InvalidInputError, match="spectrum"):
        synth.spectral_field("gaussian", size=16, seed=0)


@pytest.mark.parametrize(
    "size", [*(pytest.param(size, marks=pytest.mark.wrong_types) for size in (1e6, 64.0, "64", None)), True]
)
def test_size_must_be_an_integer(size):
    """Documented as int: an integral float is refused as well (no silent conversion)."""
    with pytest.raises(InvalidInputError, match=r"size \(pixels per side\) must be an integer ≥ 4"):
        synth.spectral_field(GAUSS_ISO, size=size, seed=0)


def test_poisson_counts_beyond_numpy_are_refused():
    """Was: numpy's bare 'lam value too large' ValueError when sampling. Refused instead (the
    class documents Poisson counts, not a normal approximation)."""
    with pytest.raises(InvalidInputError, match=r"exposure must be a positive number.*MAX_EXPECTED_COUNT = 1e\+18"):
        synth.PoissonNoise(1e30)
    assert synth.MAX_EXPECTED_COUNT == 1e18 < np.iinfo(np.int64).max - 10 * math.sqrt(np.iinfo(np.int64).max)
    noise = synth.PoissonNoise(synth.MAX_EXPECTED_COUNT)  # the cap itself is fine
    rng = np.random.default_rng(0)
    values, sigma = noise.sample(np.array([[1.0, 0.0]]), rng)
    assert values[0, 1] == 0 and abs(values[0, 0] - 1) < 1e-6 and sigma[0, 0] == pytest.approx(1e-9)
    with pytest.raises(InvalidInputError, match=r"largest expected count, 2e\+18.*use exposure ≤ 5e\+17"):
        noise.sample(np.array([[2.0]]), rng)
    with pytest.raises(InvalidInputError, match="values ≥ 0"):
        synth.PoissonNoise(10.0).sample(np.array([[-1.0]]), rng)
    field = synth.spectral_field(GAUSS_ISO, size=16, seed=0)
    with pytest.raises(InvalidInputError, match="largest expected count"):
        synth.gonioreflectometer(field, [4.0], [0, 0, 1.0], extent=0.5, pixels=9, noise=noise, seed=1)
    assert type(synth.PoissonNoise(np.float32(3.0)).exposure) is float  # JSON-ready in the metadata


def test_complex_heights_are_refused():
    """Was: cast to real with only a ComplexWarning."""
    with pytest.raises(InvalidInputError, match=r"heights must be real numbers.*complex128"):
        synth.HeightField(np.zeros((8, 8)) + 1j, 1.0)
    for bad in (np.zeros((8, 8), bool), None, "flat", [[0.0] * 8] * 7 + [[0.0]]):
        with pytest.raises(InvalidInputError, match="heights"):
            synth.HeightField(bad, 1.0)
    with pytest.raises(InvalidInputError, match="scales must be real"):
        synth.gonioreflectometer(_flat(), [4.0 + 0j], [0, 0, 1.0], extent=0.1)
    assert synth.HeightField(np.zeros((8, 8), np.int32), 2).heights.dtype == np.float64  # ints are widened


@pytest.mark.wrong_types
def test_complex_incident_directions_are_refused():
    with pytest.raises(InvalidInputError, match="incident must be real"):
        synth.gonioreflectometer(_flat(), [4.0], np.array([0, 0, 1.0]) + 0j, extent=0.1)


@pytest.mark.parametrize(
    "call, match",
    [
        pytest.param(
            lambda: synth.PoissonNoise("a"),
            "exposure must be a finite real number; got str",
            marks=pytest.mark.wrong_types,
        ),
        pytest.param(lambda: synth.PoissonNoise(None), "exposure", marks=pytest.mark.wrong_types),
        pytest.param(lambda: synth.GaussianNoise(None), "floor", marks=pytest.mark.wrong_types),
        pytest.param(lambda: synth.GaussianNoise(0.1, relative="x"), "relative", marks=pytest.mark.wrong_types),
        (lambda: synth.HeightField(np.zeros((8, 8)), "a"), "spacing must be a finite real number"),
        (lambda: synth.HeightField(np.zeros((8, 8)), None), "spacing"),
        (lambda: synth.HeightField(np.zeros((8, 8)), 1 + 0j), "spacing"),
        (lambda: synth.HeightField(np.zeros((8, 8)), 1.0, description=None), "description must be a dict"),
        (lambda: synth.spectral_field(GAUSS_ISO, size=16, spacing=True, seed=0), "spacing"),
        pytest.param(lambda: synth.blazed(size=16, period=4, slopes=None), "slopes", marks=pytest.mark.wrong_types),
        pytest.param(
            lambda: synth.blazed(size=16, period=4, slopes=("a", -1.0)), r"slopes\[0\]", marks=pytest.mark.wrong_types
        ),
        pytest.param(lambda: synth.blazed(size=16, period=4, spacing="a"), "spacing", marks=pytest.mark.wrong_types),
        pytest.param(
            lambda: synth.blazed(size=16, period=4, angle=np.zeros(2)), "angle", marks=pytest.mark.wrong_types
        ),
        pytest.param(
            lambda: synth.scratches(size=16, count=1, depth="a", width=2.0, length=4.0, seed=0),
            "depth",
            marks=pytest.mark.wrong_types,
        ),
        pytest.param(
            lambda: synth.scratches(size=16, count=1.0, depth=1.0, width=2.0, length=4.0, seed=0),
            "count",
            marks=pytest.mark.wrong_types,
        ),
        pytest.param(lambda: synth.named_surface(["gaussian"]), "unknown surface", marks=pytest.mark.wrong_types),
        pytest.param(lambda: synth.named_surface("blazed", size="64"), "size", marks=pytest.mark.wrong_types),
        pytest.param(
            lambda: synth.gonioreflectometer(_flat(), [4.0], [0, 0, 1.0], extent="a"),
            "extent",
            marks=pytest.mark.wrong_types,
        ),
        pytest.param(
            lambda: synth.gonioreflectometer(_flat(), [4.0], [0, 0, 1.0], extent=None),
            "extent",
            marks=pytest.mark.wrong_types,
        ),
        pytest.param(
            lambda: synth.gonioreflectometer(_flat(), [4.0], [0, 0, 1.0], extent=0.1, resolution=None),
            "resolution",
            marks=pytest.mark.wrong_types,
        ),
        pytest.param(
            lambda: synth.gonioreflectometer(_flat(), [4.0], [0, 0, 1.0], extent=0.1, pixels=33.0),
            "pixels",
            marks=pytest.mark.wrong_types,
        ),
        (lambda: synth.gonioreflectometer(_flat(), None, [0, 0, 1.0], extent=0.1), "scales"),
        pytest.param(
            lambda: synth.gonioreflectometer(_flat(), [4.0], "up", extent=0.1),
            "incident",
            marks=pytest.mark.wrong_types,
        ),
        (lambda: synth.gonioreflectometer(_flat(), [4.0], [0, 0, 1.0], extent=0.1, albedo="white"), "albedo"),
        (lambda: synth.facet_statistics(_flat(), "a"), "scales"),
        pytest.param(
            lambda: synth.facet_statistics(_flat(), [4.0], extent="a"), "extent", marks=pytest.mark.wrong_types
        ),
        pytest.param(
            lambda: synth.facet_slopes(None, 4.0),
            "field must be a brdfscale.synth.HeightField",
            marks=pytest.mark.wrong_types,
        ),
        pytest.param(lambda: synth.facet_slopes(_flat(), "a"), "mu", marks=pytest.mark.wrong_types),
        (lambda: synth.facet_slopes(_flat(), float("nan")), "mu"),
        pytest.param(lambda: synth.steepest_slope(np.zeros((8, 8))), "field", marks=pytest.mark.wrong_types),
    ],
    ids=lambda x: x if isinstance(x, str) else "",
)
def test_arguments_of_the_wrong_type_are_named(call, match):
    """Was: bare TypeError/ValueError from float() or numpy (strings, None, complex, arrays)."""
    with pytest.raises(InvalidInputError, match=match):
        call()


@pytest.mark.wrong_types
def test_plus_distribution_is_not_a_micro_lobe():
    """A plus-distribution has mass 0: refused wherever a micro lobe is taken, in Lobe's words."""
    from brdfscale import plus

    h0 = plus.PlusDistribution(0, 0.1)
    match = r"micro must be a probability density of facet slopes \(mass 1\); got PlusDistribution.*plus.NearlySpecular"
    for call in (
        lambda: synth.HeightField(np.zeros((8, 8)), 1.0, micro=h0),
        lambda: synth.spectral_field(GAUSS_ISO, size=16, seed=0, micro=h0),
        lambda: synth.named_surface("gaussian", size=16, micro=h0),
        lambda: synth.blazed(size=16, period=4, micro=h0),
        lambda: synth.scratches(size=16, count=1, depth=1.0, width=2.0, length=4.0, seed=0, micro=h0),
    ):
        with pytest.raises(InvalidInputError, match=match):
            call()
    # the suggested replacement works as a micro lobe: a flat field reflects all of its mass
    nearly = plus.NearlySpecular(0.9, [0.001], 0.01, smooth=stats.Beckmann(0.05), smooth_weight=0.1)
    image = synth.gonioreflectometer(_flat(nearly), [4.0], [0, 0, 1.0], extent=0.5, pixels=17).images[0]
    assert image.values.sum() * (1 / 16) ** 2 == pytest.approx(1.0, abs=0.02)  # coarse 17² grid


def test_an_image_that_cuts_its_lobe_warns_with_the_share_it_holds():
    """gonioreflectometer warns (brdfscale.LobeCutWarning) when an image holds less than synth.LIGHT_INSIDE of its
    lobe's light, with the share: here a mirror micro lobe, so the light inside is the share of the pixel facets'
    offsets from their facet's mean slope that land on the image — counted here by hand from facet_slopes."""
    import warnings

    from brdfscale import LobeCutWarning

    field = synth.spectral_field(GAUSS_ISO, size=64, seed=4)
    mu, pixels = 4.0, 33
    pixel = np.asarray(synth.facet_slopes(field, 1.0))
    facet = np.asarray(synth.facet_slopes(field, mu))
    offsets = pixel - np.repeat(np.repeat(facet, 4, axis=0), 4, axis=1)
    extent = 0.1 * synth.robust_extent(field)  # the offsets at μ = 4 are much narrower than the pixel slopes
    by_hand = np.mean(np.all(np.abs(offsets) <= extent, axis=-1))
    with pytest.warns(LobeCutWarning, match=r"μ = 4 holds only (\d+) % of its lobe's light .*offsets") as caught:
        synth.gonioreflectometer(field, [mu], [0, 0, 1.0], extent=extent, pixels=pixels)
    share = float(re.search(r"holds only (\d+) %", str(caught[0].message)).group(1)) / 100
    assert by_hand < synth.LIGHT_INSIDE and share == pytest.approx(by_hand, abs=0.02)  # a pitch's edge, rounding
    with warnings.catch_warnings():
        warnings.simplefilter("error", LobeCutWarning)  # the default extent holds the mirror lobe
        synth.gonioreflectometer(field, [mu], [0, 0, 1.0], extent=synth.robust_extent(field), pixels=pixels)
    rough = synth.spectral_field(GAUSS_ISO, size=64, seed=4, micro=stats.GGX(0.5))
    with pytest.warns(LobeCutWarning, match=r"rough micro-facet lobe's tails: GGX"):
        synth.gonioreflectometer(rough, [mu], [0, 0, 1.0], extent=synth.robust_extent(field), pixels=pixels)


def test_offset_moments_equal_the_offsets_computed_by_hand_on_a_field_with_holes():
    """synth.offset_moments against loops over the windows: every pixel facet of a window measured throughout,
    its forward-difference normal slope minus the mean of its window's (a non-periodic 23 × 29 field with two
    holes and windows of 3 × 3 pixel facets that do not tile it: the trailing row and column are left out)."""
    rng = np.random.default_rng(5)
    heights = rng.normal(size=(23, 29)).cumsum(axis=1) * 1e-3
    mask = np.ones(heights.shape, bool)
    mask[4, 7] = mask[15:17, 20] = False
    field = topography.from_array(heights, 1e-6, mask=mask, detrend=None)
    h = field.heights
    offsets = []
    for r0 in range(0, 21, 3):  # 22 × 28 pixel facets: 7 × 9 whole windows
        for c0 in range(0, 27, 3):
            if not field.mask[r0 : r0 + 4, c0 : c0 + 4].all():  # a pixel facet needs its corners measured
                continue
            m = [
                (-(h[r, c + 1] - h[r, c]) / 1e-6, -(h[r + 1, c] - h[r, c]) / 1e-6)
                for r in range(r0, r0 + 3)
                for c in range(c0, c0 + 3)
            ]
            m = np.asarray(m)
            offsets.extend(m - m.mean(axis=0))
    offsets = np.asarray(offsets)
    mean, cov = synth.offset_moments(field, 3e-6)
    np.testing.assert_allclose(mean, offsets.mean(axis=0), atol=1e-9)
    np.testing.assert_allclose(cov, np.cov(offsets.T, bias=True), rtol=1e-10)
    with pytest.raises(InvalidInputError, match="mu"):
        synth.offset_moments(field, 2.5e-6)


@pytest.mark.wrong_types
def test_offset_moments_refuses_a_field_that_is_not_a_height_field():
    with pytest.raises(InvalidInputError, match="HeightField"):
        synth.offset_moments(np.zeros((8, 8)), 3e-6)
