"""brdfscale.laplace: one identifiability policy, checked against a linear-Gaussian model whose
posterior is exact, and used by both fits of the project (fitting.fit, plus.fit_strengths)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from brdfscale import InvalidInputError, plus, stats
from brdfscale.laplace import laplace


jax.config.update("jax_enable_x64", True)


def test_linear_gaussian_posterior_is_exact():
    """r = (Aθ − y)/σ: the posterior of θ under a flat prior is N((AᵀA)⁻¹Aᵀy, (AᵀA)⁻¹) exactly."""
    rng = np.random.default_rng(0)
    A = rng.standard_normal((50, 3)) * [1.0, 10.0, 0.1]
    analysis = laplace(A, ("a", "b", "c"))
    assert np.allclose(analysis.covariance, np.linalg.inv(A.T @ A), rtol=1e-10)
    assert analysis.undetermined == [
        {
            "combination": "1.00·c",
            "fisher_eigenvalue": pytest.approx(np.linalg.eigvalsh(A.T @ A)[0]),
            "std": pytest.approx(np.linalg.eigvalsh(A.T @ A)[0] ** -0.5),
        }
    ]  # σ_c > 1
    exact = laplace(A, ("a", "b", "c"), undetermined_std=np.inf)
    assert exact.determined
    g = rng.standard_normal((4, 3))
    assert np.allclose(exact.std(g), np.sqrt(np.einsum("qi,ij,qj->q", g, np.linalg.inv(A.T @ A), g)), rtol=1e-10)


def test_the_joint_covariance_of_quantities_is_g_cov_gt_with_the_variances_on_its_diagonal():
    """covariance_of: for a linear Gaussian posterior g (AᵀA)⁻¹ gᵀ (an undetermined direction included: the
    floor only touches null ones); its diagonal the two parts of variances() summed, wherever a direction is null."""
    rng = np.random.default_rng(2)
    A = rng.standard_normal((50, 3)) * [1.0, 10.0, 0.1]
    g = rng.standard_normal((4, 3))
    analysis = laplace(A, ("a", "b", "c"))
    np.testing.assert_allclose(analysis.covariance_of(g), g @ np.linalg.inv(A.T @ A) @ g.T, rtol=1e-10)
    null = laplace(np.column_stack([A[:, :2], A[:, 0]]), ("a", "b", "c"))
    determined, undetermined = null.variances(g)
    np.testing.assert_allclose(np.diag(null.covariance_of(g)), determined + undetermined, rtol=1e-12)


def test_a_null_direction_is_named_and_quantities_along_it_get_no_error():
    rng = np.random.default_rng(1)
    A = rng.standard_normal((40, 2))
    A = np.column_stack([A, A[:, 0]])  # a and c enter only as a + c
    analysis = laplace(A, ("a", "b", "c"))
    assert [u["combination"] for u in analysis.undetermined] == ["0.71·a − 0.71·c"] or [
        u["combination"] for u in analysis.undetermined
    ] == ["0.71·c − 0.71·a"]
    assert analysis.undetermined[0]["std"] is None
    assert np.allclose(analysis.covariance, np.linalg.pinv(A.T @ A), atol=1e-10)
    std = analysis.std(np.array([[1.0, 0.0, 1.0], [1.0, 0.0, -1.0], [0.0, 1.0, 0.0]]))
    assert np.isfinite(std[0]) and std[1] is None and np.isfinite(std[2])  # a + c and b are determined, a − c not


@pytest.mark.parametrize(
    "jacobian, names, match",
    [
        (np.ones((3, 2)), ("a",), "len\\(names\\)"),
        (np.array([[np.nan, 1.0]]), ("a", "b"), "non-finite"),
    ],
)
def test_bad_jacobians_are_refused(jacobian, names, match):
    with pytest.raises(InvalidInputError, match=match):
        laplace(jacobian, names)


@pytest.mark.slow  # 9 s on 2 cores: the default suite measured 402 s at ff4fa2c (budget 360)
def test_fit_strengths_names_an_undetermined_cut_off_instead_of_raising():
    """A lobe with no nearly-specular tail (all c_n = 0): the cut-off x0 leaves the model
    unchanged, so the data cannot determine it — named, σ NaN, the amplitude still measured."""
    kernel = stats.Gaussian(sigma=0.004)
    rng = np.random.default_rng(3)
    radius, angle = rng.uniform(0, 0.08, 200), rng.uniform(0, 2 * np.pi, 200)
    u = np.stack([radius * np.cos(angle), radius * np.sin(angle)], -1)
    clean = 2.0 * np.asarray(plus.observe(plus.NearlySpecular(1.0, (0.0,), 0.05), kernel).density(jnp.asarray(u)))
    sigma = 5e-4 * clean.max() + 0.01 * clean
    fit = plus.fit_strengths(u, clean, sigma, kernel=kernel, orders=1, x0=0.03)
    assert not fit.determined and any("ln x0" in c for c in fit.undetermined)
    assert fit.x0_sigma is None  # undetermined: None (brdfscale.laplace), not NaN
    assert float(fit.amplitude) == pytest.approx(2.0, rel=1e-6) and np.isfinite(float(fit.amplitude_sigma))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_quantity_with_a_non_finite_gradient_is_undetermined(bad):
    """A gradient holding NaN or ±∞ (a quantity not differentiable at θ̂) gives no comparison of
    variances to trust: the quantity is undetermined (std None, never NaN), whatever the other
    quantities' gradients."""
    rng = np.random.default_rng(2)
    analysis = laplace(rng.standard_normal((30, 3)), ("a", "b", "c"), undetermined_std=np.inf)
    g = np.array([[1.0, 0.0, 0.0], [bad, 0.0, 0.0], [0.0, bad, 1.0]])
    assert analysis.quantity_is_determined(g).tolist() == [True, False, False]
    std = analysis.std(g)
    assert np.isfinite(std[0]) and std[1] is None and std[2] is None
