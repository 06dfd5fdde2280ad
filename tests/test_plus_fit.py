"""Fits of nearly-specular strengths: recovery within the stated (Laplace) uncertainties."""

import jax.numpy as jnp
import numpy as np
import pytest

from brdfscale import BrdfscaleError, InvalidInputError, plus, stats


TRUTH = {"amplitude": 2.0, "x0": 0.05, "c": (0.12, 0.03)}
KERNEL = stats.Gaussian(sigma=0.004)


def _synthetic(seed, count=300):
    """A lobe seen by KERNEL at random offsets within |u| < 0.08, with 1 % + floor Gaussian noise."""
    rng = np.random.default_rng(seed)
    radius, angle = rng.uniform(0, 0.08, count), rng.uniform(0, 2 * np.pi, count)
    u = np.stack([radius * np.cos(angle), radius * np.sin(angle)], -1)
    seen = plus.observe(plus.NearlySpecular(1.0, TRUTH["c"], TRUTH["x0"]), KERNEL)
    clean = TRUTH["amplitude"] * np.asarray(seen.density(jnp.asarray(u)))
    sigma = 5e-4 * clean.max() + 0.01 * clean
    return u, clean, sigma, rng


def _fit(u, y, sigma):
    fit = plus.fit_strengths(u, y, sigma, kernel=KERNEL, orders=2, x0=0.03)
    estimate = np.array([float(fit.amplitude), float(fit.x0), *np.asarray(fit.strengths)])
    sd = np.array([float(fit.amplitude_sigma), float(fit.x0_sigma), *np.asarray(fit.strengths_sigma)])
    return fit, estimate, sd


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_recovery_within_stated_uncertainties():
    u, clean, sigma, rng = _synthetic(seed=1)
    truth = np.array([TRUTH["amplitude"], TRUTH["x0"], *TRUTH["c"]])
    estimates, sds = [], []
    for _ in range(5):
        fit, estimate, sd = _fit(u, clean + sigma * rng.standard_normal(clean.shape), sigma)
        assert np.all(np.abs(estimate - truth) < 3 * sd), (estimate, truth, sd)
        assert abs(fit.chi2 - fit.dof) < 4 * np.sqrt(2 * fit.dof)  # χ² consistent with the noise
        estimates.append(estimate)
        sds.append(sd)
    # σ sensible: small but not vanishing, and matching the scatter over noise realisations
    sds, estimates = np.array(sds), np.array(estimates)
    assert np.all(sds < 0.1 * np.abs(truth)) and np.all(sds > 1e-4 * np.abs(truth))
    ratio = estimates.std(axis=0, ddof=1) / sds.mean(axis=0)
    assert np.all((0.3 < ratio) & (ratio < 1.9)), ratio  # 4-dof χ interval, generously
    assert fit.names == ("amplitude", "x0", "c_0", "c_1")
    np.testing.assert_allclose(np.sqrt(np.diag(np.asarray(fit.covariance))), sds[-1])


def test_undetermined_parameters_are_named():
    u, clean, sigma, _ = _synthetic(seed=2, count=5)
    with pytest.raises(BrdfscaleError, match="5 samples for 9 parameters"):
        plus.fit_strengths(u, clean, sigma, kernel=KERNEL, orders=7, x0=0.03)
    # many samples at only two offsets: four parameters, two independent data
    u2 = np.repeat(u[:2], 10, axis=0)
    y2, sigma2 = np.repeat(clean[:2], 10), np.repeat(sigma[:2], 10)
    with pytest.raises(BrdfscaleError, match="undetermined combination"):
        plus.fit_strengths(u2, y2, sigma2, kernel=KERNEL, orders=2, x0=0.03)


@pytest.mark.wrong_types
def test_fit_strengths_refuses_a_kernel_that_is_no_gaussian_and_offsets_that_are_no_2_vectors():
    u, clean, sigma, _ = _synthetic(seed=3, count=20)
    with pytest.raises(InvalidInputError, match="kernel"):
        plus.fit_strengths(u, clean, sigma, kernel=stats.Disk(0.01), orders=1, x0=0.03)
    with pytest.raises(InvalidInputError, match="shape"):
        plus.fit_strengths(u[:, :1], clean, sigma, kernel=KERNEL, orders=1, x0=0.03)


def test_bad_arguments():
    u, clean, sigma, _ = _synthetic(seed=3, count=20)
    with pytest.raises(InvalidInputError, match="orders"):
        plus.fit_strengths(u, clean, sigma, kernel=KERNEL, orders=0, x0=0.03)
