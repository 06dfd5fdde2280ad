"""fitting.moment_covariance_differences: ΔΣ(μ0, μk) from the images' own second moments, no model (issue 31
item 2). Checked against moments and finite-difference errors computed here with NumPy, against the scatter of
the estimate over noise realisations, against the recorded truth of noise-free synthesised images, and on cut
lobes, unequal pitches and masked pixels."""

import numpy as np
import pytest

from brdfscale import fitting, InvalidInputError, LobeImage, MeasurementSet, stats, synth
from tests.helpers import image_covariance


def _set(images, metadata=None):
    return fitting.Dataset.from_measurements(MeasurementSet(tuple(images), metadata or {}))


def _gaussian(extent, n, cov, amplitude=1.0, centre=(0.0, 0.0)):
    x = np.linspace(-extent, extent, n)
    ux, uy = np.meshgrid(x, x)
    d = np.stack((ux - centre[0], uy - centre[1]), axis=-1)
    inv = np.linalg.inv(cov)
    q = np.einsum("...a,ab,...b->...", d, inv, d)
    return amplitude * np.exp(-0.5 * q) / (2 * np.pi * np.sqrt(np.linalg.det(cov)))


def test_moments_and_errors_by_hand():
    """Values and standard errors against np.cov with the values as weights and the errors by central finite
    differences of that very np.cov in every pixel (linear propagation of independent σ)."""
    rng = np.random.default_rng(1)
    extent, n = 0.2, 7
    a = _gaussian(extent, n, [[0.004, 0.001], [0.001, 0.002]]) + rng.uniform(0, 0.5, (n, n))
    b = _gaussian(extent, n, [[0.008, -0.002], [-0.002, 0.006]]) + rng.uniform(0, 0.5, (n, n))
    sa, sb = rng.uniform(0.05, 0.2, (n, n)), rng.uniform(0.05, 0.2, (n, n))
    data = _set([LobeImage(1.0, (0, 0, 1.0), extent, a, sa), LobeImage(4.0, (0, 0, 1.0), extent, b, sb)])
    (entry,) = fitting.moment_covariance_differences(data)
    np.testing.assert_allclose(
        entry["value"], image_covariance(b, extent) - image_covariance(a, extent), rtol=1e-10, atol=1e-14
    )

    def errors(values, sigma):
        var = np.zeros((2, 2))
        for j in np.ndindex(values.shape):
            step = np.zeros_like(values)
            step[j] = 1e-6
            g = (image_covariance(values + step, extent) - image_covariance(values - step, extent)) / 2e-6
            var += (g * sigma[j]) ** 2
        return var

    np.testing.assert_allclose(entry["std"], np.sqrt(errors(a, sa) + errors(b, sb)), rtol=1e-5)
    assert entry["mu0"] == 1.0 and entry["mu"] == 4.0
    assert entry["truncated"]  # the uniform background reaches the edge far above its noise


def test_errors_match_the_scatter_over_noise_realisations():
    """400 noisy realisations of two Gaussian lobes (Gaussian noise of σ = 2 % of the peak): the standard deviation
    of the 400 estimates of each entry equals the reported error within 15 % (the sample standard deviation of
    400 normal draws is within 15 % of the truth at > 4 of its standard errors, 3.5 %), and the mean of the
    estimates is the clean images' ΔΣ within 4 standard errors of a mean."""
    rng = np.random.default_rng(2)
    extent, n = 0.3, 25
    clean = [_gaussian(extent, n, [[0.003, 0.001], [0.001, 0.002]]), _gaussian(extent, n, [[0.006, 0.0], [0.0, 0.005]])]
    sigma = [0.02 * c.max() * np.ones_like(c) for c in clean]
    truth = image_covariance(clean[1], extent) - image_covariance(clean[0], extent)
    draws, reported = [], None
    for _ in range(400):
        images = [
            LobeImage(mu, (0, 0, 1.0), extent, c + s * rng.standard_normal(c.shape), s)
            for mu, c, s in zip((1.0, 8.0), clean, sigma)
        ]
        (entry,) = fitting.moment_covariance_differences(_set(images))
        draws.append(entry["value"])
        reported = np.asarray(entry["std"])
    draws = np.asarray(draws)
    np.testing.assert_allclose(draws.std(axis=0, ddof=1), reported, rtol=0.15)
    assert np.all(np.abs(draws.mean(axis=0) - truth) < 4 * reported / np.sqrt(400))


def test_noise_free_synthesised_images_give_the_recorded_truth():
    """An anisotropic Gaussian field imaged by synth.gonioreflectometer with an extent that holds every lobe (twice
    its steepest slope: no offset is larger, no light outside): ΔΣ of the moments is the set's recorded truth (the
    offsets' covariances, fitting.covariance_truth) within 2 % of the cloud-in-cell term h²/6 (the term a sample
    adds; it cancels between two lobes whose light falls anywhere in the cells: measured 0.6 %). With μ0 = 1 pixel
    the μ0 lobe of mirror facets is a point on a node (every offset 0), which adds no cell term: ΔΣ is then h²/6
    too large per axis, and the entries say so."""
    field = synth.spectral_field(stats.GaussianCorrelation(0.6, (4.0, 12.0)), size=64, seed=2)
    extent = 2.1 * synth.steepest_slope(field)
    cell = (2 * extent / 128) ** 2 / 6
    for scales in ([2.0, 4.0, 16.0], [1.0, 4.0]):
        mset = synth.gonioreflectometer(field, scales, [0, 0, 1.0], extent=extent, pixels=129)
        entries = fitting.moment_covariance_differences(fitting.Dataset.from_measurements(mset, default_sigma=1e-3))
        truth = np.asarray(fitting.covariance_truth(mset.metadata, scales))
        values = np.asarray([e["value"] for e in entries])
        if scales[0] == 2.0:
            np.testing.assert_allclose(values, truth, rtol=0, atol=0.02 * cell)
            assert not any(e["truncated"] for e in entries)
        else:
            np.testing.assert_allclose(values - truth, [cell * np.eye(2)], rtol=0, atol=0.02 * cell)
            assert "narrower than a node pitch" in entries[0]["note"]


def test_a_lobe_past_the_edge_is_marked_truncated():
    """A lobe whose edge pixels hold light far above their noise is truncated (with the note saying so and what to
    do); the same lobe on a grid five times wider is not, and its ΔΣ is the lobes' (the Gaussians' covariance
    difference) within 1 %, where the cut one misses by far more."""
    cov0, cov1 = np.diag([0.002, 0.001]), np.diag([0.006, 0.004])
    wanted = cov1 - cov0
    out = {}
    for extent in (0.1, 0.5):
        images = [
            LobeImage(mu, (0, 0, 1.0), extent, _gaussian(extent, 61, c), 1e-3 * np.ones((61, 61)))
            for mu, c in ((1.0, cov0), (4.0, cov1))
        ]
        (out[extent],) = fitting.moment_covariance_differences(_set(images))
    cut, whole = out[0.1], out[0.5]
    assert cut["truncated"] and "larger extent" in cut["note"]
    assert not whole["truncated"] and "note" not in whole
    np.testing.assert_allclose(whole["value"], wanted, rtol=0.01, atol=1e-6)
    assert abs(cut["value"][0][0] - wanted[0, 0]) > 0.3 * wanted[0, 0]


def test_unequal_pitches_are_noted_and_masked_pixels_left_out():
    """Two scales imaged with different extents: the note says their cell terms do not cancel. A masked pixel
    (mask False: unmeasured) counts in no sum: the result equals the images with that pixel's value set to 0."""
    cov = np.diag([0.002, 0.002])
    a, b = _gaussian(0.2, 21, cov), _gaussian(0.25, 21, cov)
    s = 0.01 * np.ones((21, 21))
    (entry,) = fitting.moment_covariance_differences(
        _set([LobeImage(1.0, (0, 0, 1.0), 0.2, a, s), LobeImage(2.0, (0, 0, 1.0), 0.25, b, s)])
    )
    assert "node pitches differ" in entry["note"]
    zeroed = a.copy()
    zeroed[10, 12] = 0.0
    mask = np.ones((21, 21), bool)
    mask[10, 12] = False
    same = _gaussian(0.2, 21, np.diag([0.003, 0.0025]))
    with_hole = fitting.moment_covariance_differences(
        _set([LobeImage(1.0, (0, 0, 1.0), 0.2, a, s, mask=mask), LobeImage(2.0, (0, 0, 1.0), 0.2, same, s)])
    )
    zero = fitting.moment_covariance_differences(
        _set([LobeImage(1.0, (0, 0, 1.0), 0.2, zeroed, s), LobeImage(2.0, (0, 0, 1.0), 0.2, same, s)])
    )
    np.testing.assert_allclose(with_hole[0]["value"], zero[0]["value"], rtol=1e-12)
    assert with_hole[0]["std"][0][0] < zero[0]["std"][0][0]  # the masked pixel's σ is not counted


@pytest.mark.parametrize("incidences", [1, 3])
def test_several_images_of_a_scale_are_averaged(incidences):
    """Images of one scale at several incidences: their C are averaged, the errors those of a mean of independent
    images (σ/√k for k equal images)."""
    cov0, cov1 = np.diag([0.002, 0.001]), np.diag([0.004, 0.003])
    s = 0.02 * np.ones((31, 31))
    images = []
    for mu, c in ((1.0, cov0), (4.0, cov1)):
        for k in range(incidences):
            t = np.radians(10.0 * k)
            images.append(LobeImage(mu, (np.sin(t), 0.0, np.cos(t)), 0.25, _gaussian(0.25, 31, c), s))
    (entry,) = fitting.moment_covariance_differences(_set(images))
    (single,) = fitting.moment_covariance_differences(_set([images[0], images[incidences]]))
    np.testing.assert_allclose(entry["value"], single["value"], rtol=1e-12)
    np.testing.assert_allclose(entry["std"], np.asarray(single["std"]) / np.sqrt(incidences), rtol=1e-12)


def test_the_moments_of_other_values_on_the_same_nodes_keep_the_datas_errors():
    """``values=``: a model's prediction in data.values' layout gets the same estimator on the same pixels — its
    values by hand, the data's σ for the errors (so that fitting.assess can divide the two ΔΣ's difference by the
    data's); the data's own values give the default exactly; another shape is refused, naming the one needed."""
    rng = np.random.default_rng(3)
    extent, n = 0.2, 9
    clean = [_gaussian(extent, n, [[0.004, 0.001], [0.001, 0.003]]), _gaussian(extent, n, [[0.007, 0.0], [0.0, 0.005]])]
    sigma = [0.01 * np.ones_like(c) for c in clean]
    noisy = [c + s * rng.standard_normal(c.shape) for c, s in zip(clean, sigma)]
    data = _set([LobeImage(mu, (0, 0, 1.0), extent, v, s) for mu, v, s in zip((1.0, 2.0), noisy, sigma)])
    assert fitting.moment_covariance_differences(data, np.asarray(data.values)) == (
        fitting.moment_covariance_differences(data)
    )
    other = np.zeros(np.asarray(data.values).shape)
    for i, c in enumerate(clean):
        other[i, : n * n] = c.ravel()
    (entry,) = fitting.moment_covariance_differences(data, other)
    (own,) = fitting.moment_covariance_differences(data)
    want = image_covariance(clean[1], extent) - image_covariance(clean[0], extent)
    np.testing.assert_allclose(entry["value"], want, rtol=1e-10, atol=1e-14)
    # the errors: C's derivatives at the other values, weighted by the data's σ — the same to first order
    np.testing.assert_allclose(entry["std"], own["std"], rtol=0.05)
    with pytest.raises(InvalidInputError, match=r"values must have data.values' shape \(2, 81\)"):
        fitting.moment_covariance_differences(data, other[:, :80])
