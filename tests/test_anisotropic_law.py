"""fitting.AnisotropicLawModel: an anisotropic base lobe whose slope statistics follow a continuous
scale law in μ, so that it predicts unseen scales (issue 31, items 1 and 3).

The oracles are hand-written: NumPy Gaussians of covariance ``C0 + R(φ) diag(Δ_1, Δ_2) R(φ)ᵀ`` with
the width law ``α(μ) = α_max (1 + (μ/μ_c)²)^(−H/2)`` written out; the isotropic special case against
fitting.ParametricModel (Beckmann lobe and statistics, a different code path: brdfscale.evolve's
radial closed form); recovery of a known law from noisy images at scales the fit has not seen."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import brdfscale as bs
from brdfscale import InvalidInputError


jax.config.update("jax_enable_x64", True)

from helpers import gaussian, rotation  # noqa: E402

from brdfscale import fitting  # noqa: E402


MU0 = 1.0
LAW = {"phi": 0.5, "axes": [(0.12, 2.0, 1.0), (0.06, 3.0, 1.5)]}  # (alpha_max, mu_c, exponent) per axis
BASE = {
    "amplitude": 2.0,
    "mean": np.array([0.02, -0.01]),
    "C0": rotation(-0.3) @ np.diag([0.004, 0.0015]) @ rotation(-0.3).T,
}
SCALES = (1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
TRAIN = 4  # the four finest scales are fitted, the two coarsest predicted


def width(alpha_max, mu_c, exponent, mu):
    return alpha_max * (1 + (mu / mu_c) ** 2) ** (-exponent / 2)


def true_difference(mu, mu0=MU0, law=LAW):
    """ΔΣ(μ0, μ) by hand: R(φ) diag(α_a(μ0)²/2 − α_a(μ)²/2) R(φ)ᵀ."""
    d = [(width(*axis, mu0) ** 2 - width(*axis, mu) ** 2) / 2 for axis in law["axes"]]
    return rotation(law["phi"]) @ np.diag(d) @ rotation(law["phi"]).T


def theta_of(model, amplitude, c0, mean, law):
    L = np.linalg.cholesky(c0)
    theta = [math.log(amplitude), math.log(L[0, 0]), L[1, 0], math.log(L[1, 1])]
    if not model.centred:
        theta += list(mean)
    theta.append(law["phi"])
    for axis in law["axes"]:
        theta += [math.log(v) for v in axis]
    return jnp.asarray(theta)


def grid(n=21, extent=0.5):
    x = np.linspace(-extent, extent, n)
    return np.stack(np.meshgrid(x, x), axis=-1)


def dataset(scales, seed=0, noise=0.01, floor=1e-3, n=21):
    rng, u = np.random.default_rng(seed), grid(n)
    images = []
    for mu in scales:
        v = gaussian(u, BASE["mean"], BASE["C0"] + true_difference(mu), BASE["amplitude"])
        sigma = noise * v.max() + floor
        images.append(
            bs.LobeImage(
                mu=mu,
                incident=[0.0, 0.0, 1.0],
                extent=0.5,
                values=v + sigma * rng.standard_normal(v.shape),
                sigma=np.full(v.shape, sigma),
            )
        )
    return fitting.Dataset.from_measurements(bs.MeasurementSet(tuple(images)))


LAW_MODEL = fitting.AnisotropicLawModel()
_predict_at = jax.jit(lambda theta, mu, u: LAW_MODEL.predict_at(theta, MU0, mu, u))  # one compilation for the examples
_differences = eqx.filter_jit(lambda model, theta, mu: model.covariance_differences(theta, mu))
_sigma = eqx.filter_jit(lambda model, theta, mu: model.slope_covariance(theta, mu))


@settings(max_examples=20, deadline=None)
@given(
    phi=st.floats(-math.pi, math.pi),
    ratio=st.floats(1.0, 30.0),
    exponent=st.floats(0.2, 3.0),
    mu=st.floats(1.0, 1e3),
)
def test_prediction_at_any_coarser_scale_equals_a_hand_written_gaussian(phi, ratio, exponent, mu):
    """The lobe at μ ≥ μ0 — measured or not — is the Gaussian of covariance C0 + ΔΣ(μ0, μ), ΔΣ by
    hand, for any orientation φ and anisotropy ratio α_1²/α_2² of the law."""
    law = {"phi": phi, "axes": [(0.1 * math.sqrt(ratio), 2.0, exponent), (0.1, 5.0, 1.0)]}
    theta = theta_of(LAW_MODEL, BASE["amplitude"], BASE["C0"], BASE["mean"], law)
    u = grid(9, 0.4).reshape(1, -1, 2)
    got = np.asarray(_predict_at(theta, jnp.asarray([mu]), jnp.asarray(u)))[0]
    want = gaussian(u[0], BASE["mean"], BASE["C0"] + true_difference(mu, law=law), BASE["amplitude"])
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12 * want.max())
    d = np.asarray(_differences(LAW_MODEL, theta, jnp.asarray([MU0, mu])))[1]
    np.testing.assert_allclose(d, true_difference(mu, law=law), rtol=1e-10, atol=1e-15)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), law=st.sampled_from(["width", "spline"]))
def test_every_theta_in_the_box_gives_differences_positive_semidefinite_and_monotone(seed, law):
    """ΔΣ(μ0, μ) ⪰ 0 for μ > μ0 and ΔΣ(μ0, μ') − ΔΣ(μ0, μ) ⪰ 0 for μ' > μ, anywhere in the prior box,
    over ten decades of μ (fitted range and both extrapolations)."""
    model = fitting.AnisotropicLawModel(law, scales=SMALL.scales)
    lo, hi = model.bounds(SMALL)
    theta = jnp.asarray(np.random.default_rng(seed).uniform(lo, hi))
    mus = jnp.asarray(np.geomspace(1e-3, 1e7, 60))
    d = np.asarray(_differences(model, theta, mus))  # relative to μ0 = 1e-3
    scale = np.abs(d).max() + 1e-300
    assert np.all(np.isfinite(d))
    assert np.all(np.linalg.eigvalsh(d[1:]) >= -1e-12 * scale)
    assert np.all(np.linalg.eigvalsh(np.diff(d, axis=0)) >= -1e-12 * scale)
    sigma = np.asarray(_sigma(model, theta, mus))
    eig = np.linalg.eigvalsh(sigma)  # Σ(μ) positive (semi)definite at every scale, to rounding of its largest
    assert np.all(eig[:, 1] > 0) and np.all(eig[:, 0] >= -1e-13 * eig[:, 1])
    np.testing.assert_allclose(d, sigma[0] - sigma, rtol=1e-12, atol=1e-14 * scale)


SMALL = dataset(SCALES[:3], n=7)


def test_the_isotropic_case_equals_the_parametric_beckmann_model():
    """Both axes with one width law and a centred Beckmann base lobe (C0 = α_lobe²/2 I): the
    prediction is fitting.ParametricModel's (Beckmann lobe, Beckmann statistics, width law) at
    every measured scale and at scales it has not seen."""
    data = dataset(SCALES, n=7)
    parametric = fitting.ParametricModel()
    q = {"amplitude": 1.7, "alpha_lobe": 0.08, "alpha_max": 0.11, "mu_c": 2.5, "exponent": 1.3}
    model = fitting.AnisotropicLawModel(centred=True)
    law = {"phi": 0.7, "axes": [(q["alpha_max"], q["mu_c"], q["exponent"])] * 2}
    theta = theta_of(model, q["amplitude"], q["alpha_lobe"] ** 2 / 2 * np.eye(2), None, law)
    got = np.asarray(fitting._model.predict_images(model, theta, data))
    want = np.asarray(fitting._model.predict_images(parametric, jnp.asarray(parametric.theta_from(q)), data))
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12 * want.max())


@pytest.mark.slow  # the eager evaluations compile op by op: 30–90 s each on 2 shared cores
@pytest.mark.parametrize("law,shape", [("width", "gaussian"), ("spline", "student_t")])
def test_jit_grad_vmap_equal_eager(law, shape):
    """(The default suite's tests evaluate the model compiled, against hand-written oracles.)"""
    data = SMALL
    model = fitting.AnisotropicLawModel(law, scales=data.scales, shape=shape)
    points = data.points(model.radial).points
    theta0 = jnp.asarray(model.initial(data))

    def f(theta):
        return model.predict_points(theta, data.scales, points)

    eager = f(theta0)
    np.testing.assert_allclose(jax.jit(f)(theta0), eager, rtol=1e-12, atol=1e-14 * float(jnp.abs(eager).max()))

    def g(t):
        return jnp.sum(f(t) ** 2)

    grad_eager = jax.grad(g)(theta0)
    np.testing.assert_allclose(
        jax.jit(jax.grad(g))(theta0), grad_eager, rtol=1e-9, atol=1e-12 * float(jnp.abs(grad_eager).max())
    )
    batch = jnp.stack([theta0, theta0 + 0.01])
    batched = jax.jit(jax.vmap(f))(batch)
    np.testing.assert_allclose(batched[0], eager, rtol=1e-12, atol=1e-14 * float(jnp.abs(eager).max()))
    np.testing.assert_allclose(batched[1], jax.jit(f)(batch[1]), rtol=1e-12, atol=1e-14 * float(jnp.abs(eager).max()))
    g_jit = jax.jit(g)
    for i in (3, 6, 7, len(theta0) - 1):  # a base coordinate, φ, the law's first and last
        step = 1e-6 * jnp.eye(theta0.shape[0])[i]
        finite_difference = (g_jit(theta0 + step) - g_jit(theta0 - step)) / 2e-6
        assert float(grad_eager[i]) == pytest.approx(
            float(finite_difference), rel=1e-5, abs=1e-8 * float(jnp.abs(grad_eager).max())
        )


def test_relative_statistics_are_those_of_the_hand_written_covariance_differences():
    """R_k(W) = exp(−½ Wᵀ ΔΣ_k W) over the plane with ΔΣ by hand (true_difference), and at radii |W| the geometric
    mean of R_k over 720 directions of the circle (one compilation: eager evaluation compiles op by op);
    AnisotropicModel inherits the same methods (fitting._anisotropic.AbstractCovarianceModel), its ΔΣ tested in
    tests/test_anisotropic.py."""
    model = fitting.AnisotropicLawModel()
    theta = theta_of(model, BASE["amplitude"], BASE["C0"], BASE["mean"], LAW)
    scales = jnp.asarray(SCALES)
    W = np.array([[0.0, 0.0], [3.0, -1.0], [-2.0, 5.0], [7.0, 4.0]])
    differences = np.stack([true_difference(mu) for mu in SCALES])
    want = np.exp(-0.5 * np.einsum("wi,kij,wj->kw", W, differences, W))
    radii = np.array([0.0, 2.0, 6.0])
    both = eqx.filter_jit(
        lambda m, t, w, r: (m.relative_statistics_plane(t, w, scales), m.relative_statistics(t, r, scales))
    )
    plane, radial = (np.asarray(x) for x in both(model, theta, jnp.asarray(W), jnp.asarray(radii)))
    np.testing.assert_allclose(plane, want, rtol=1e-12)
    phi = np.arange(720) * (2 * np.pi / 720)  # the trapezoidal rule: exact for the quadratic form's harmonics
    circle = np.stack([np.cos(phi), np.sin(phi)], -1)
    log_r = -0.5 * np.einsum("pi,kij,pj->kp", circle, differences, circle)
    geometric = np.exp(np.outer(log_r.mean(axis=1), radii**2))
    np.testing.assert_allclose(radial, geometric)
    for method in ("relative_statistics", "relative_statistics_plane"):  # AnisotropicModel's are these same methods
        assert getattr(fitting.AnisotropicModel, method) is getattr(fitting.AnisotropicLawModel, method)


@pytest.fixture(scope="module")
def recovered():  # one fit: ≈ 20 s on 2 shared cores (the tests that use it are slow)
    data = dataset(SCALES[:TRAIN])
    model = fitting.AnisotropicLawModel()
    return model, data, fitting.fit(model, data, starts=2)


@pytest.mark.slow
def test_recovers_the_law_and_predicts_unseen_scales_within_three_standard_errors(recovered):
    """Fitted to the four finest scales, the law's ΔΣ(μ0, μ) at the two coarser, unseen scales (8
    and 16× the fitted range's middle) lies within 3 Laplace standard errors of the truth, the
    standard errors are not vacuous, and the predicted images match the held-out data to their noise."""
    model, data, result = recovered
    assert result.status == "converged" and not result.undetermined
    assert 0.8 < result.chi2 / result.dof < 1.2
    theta = jnp.asarray(result.theta)
    held = jnp.asarray([MU0, *SCALES[TRAIN:]])

    def flat(t):
        return model.covariance_differences(t, held)[1:].reshape(-1)

    value, jac = np.asarray(flat(theta)), np.asarray(jax.jacfwd(flat)(theta))
    std = np.sqrt(np.einsum("ij,jk,ik->i", jac, result.covariance, jac))
    truth = np.concatenate([true_difference(mu).reshape(-1) for mu in SCALES[TRAIN:]])
    assert np.all(np.abs(value - truth) <= 3 * std), (value, truth, std)
    assert np.all(std[[0, 3, 4, 7]] < 0.2 * np.abs(truth).max())
    full = dataset(SCALES, seed=0)
    chi2 = np.asarray(full.whitened(model.predict(theta, full)) ** 2).reshape(full.values.shape)  # weight = 1/σ
    held_images = [i for i, k in enumerate(full.scale_of_image) if k >= TRAIN]
    n = np.asarray(full.weight > 0)[held_images].sum()
    assert chi2[held_images].sum() / n < 1.3


@pytest.mark.slow
def test_reports_covariance_differences_and_law_quantities(recovered):
    model, data, result = recovered
    assert [d["mu"] for d in result.covariance_differences] == list(SCALES[1:TRAIN])
    for d in result.covariance_differences:
        value, std = np.array(d["value"]), np.array(d["std"])
        assert np.all(np.abs(value - true_difference(d["mu"])) < 3 * std)
    assert {"amplitude", "C0_xx", "C0_xy", "C0_yy", "mean_x", "mean_y", "phi", "alpha_max_1", "mu_c_2"} <= set(
        result.estimates
    )


def test_spline_law_extrapolates_as_the_power_law_of_its_end_rate():
    """Beyond the coarsest knot ln σ_a falls with the last rate: σ_a(μ) = σ_a(μ_max) (μ/μ_max)^(−r)."""
    model = fitting.AnisotropicLawModel("spline", scales=[1.0, 2.0, 8.0], knots=3)
    rates = np.array([[0.2, 0.5, 0.9], [0.1, 0.3, 0.4]])
    theta = jnp.asarray([0.0, -3.0, 0.0, -3.0, 0.0, 0.0, 0.3, math.log(0.1), math.log(0.05), *np.log(rates).ravel()])
    sigma = np.asarray(_sigma(model, theta, jnp.asarray([8.0, 80.0])))
    axes = rotation(0.3)
    principal = np.einsum("ia,kij,jb->kab", axes, sigma, axes)  # diag(σ_1², σ_2²) per scale
    np.testing.assert_allclose(
        np.diagonal(principal[1]) / np.diagonal(principal[0]), 10.0 ** (-2 * rates[:, -1]), rtol=1e-10
    )
    np.testing.assert_allclose(principal[:, 0, 1], 0.0, atol=1e-15)


def test_a_gaussian_lobe_is_predicted_at_a_finer_scale_where_it_exists():
    """Below μ0 the evolution is a deconvolution: C0 + ΔΣ(μ0, μ) with ΔΣ negative semidefinite."""
    theta = theta_of(LAW_MODEL, BASE["amplitude"], BASE["C0"], BASE["mean"], LAW)
    u = grid(9, 0.2).reshape(1, -1, 2)
    assert np.all(np.linalg.eigvalsh(true_difference(0.5)) <= 0)
    got = np.asarray(_predict_at(theta, jnp.asarray([0.5]), jnp.asarray(u)))[0]
    want = gaussian(u[0], BASE["mean"], BASE["C0"] + true_difference(0.5), BASE["amplitude"])
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12 * want.max())


@pytest.mark.wrong_types
def test_refuses_a_centred_flag_that_is_not_a_bool():
    with pytest.raises(InvalidInputError, match="centred must be True or False"):
        fitting.AnisotropicLawModel(centred=1)


def test_refuses_bad_arguments_and_scales_where_no_lobe_exists():
    with pytest.raises(InvalidInputError, match="law must be one of"):
        fitting.AnisotropicLawModel("gaussian_surface")
    with pytest.raises(InvalidInputError, match="needs the fitted scales"):
        fitting.AnisotropicLawModel("spline")
    with pytest.raises(InvalidInputError, match="shape must be one of"):
        fitting.AnisotropicLawModel(shape="cauchy")
    model = fitting.AnisotropicLawModel()
    theta = theta_of(model, BASE["amplitude"], BASE["C0"], BASE["mean"], LAW)
    u = np.zeros((1, 3, 2))
    wide = dict(LAW, axes=[(1.0, 3.0, 1.0), (0.06, 6.0, 1.5)])  # Σ(μ) far wider below μ0 than C0
    with pytest.raises(InvalidInputError, match="no lobe exists at μ"):
        model.predict_at(theta_of(model, 2.0, BASE["C0"], BASE["mean"], wide), MU0, [0.01], u)
    heavy = fitting.AnisotropicLawModel(shape="student_t")
    theta_t = jnp.concatenate([theta, jnp.asarray([math.log(4.0)])])
    with pytest.raises(InvalidInputError, match="no lobe at scales finer"):
        heavy.predict_at(theta_t, MU0, [0.5], u)
    with pytest.raises(InvalidInputError, match="u must have shape"):
        model.predict_at(theta, MU0, [2.0, 4.0], u)


def test_the_command_builds_it_and_compares_it():
    """``brdfscale fit --model anisotropic_law [--law spline] [--shape student_t]`` reaches the model
    (brdfscale.library.FitSpec, the one place a spec becomes a model), and ``--compare`` fits it
    beside the per-scale models."""
    from brdfscale._cli import build_parser
    from brdfscale._cli._fit import _candidates, check_fit_options, spec_of

    def spec(*extra):
        args = build_parser().parse_args(["fit", "m.exr", "--out", "d", *extra])
        check_fit_options(args)
        return spec_of(args)

    model, info = spec("--model", "anisotropic_law").model_for(SMALL)
    assert isinstance(model, fitting.AnisotropicLawModel) and "log alpha_max_1" in model.names
    assert info["kind"] == "anisotropic_law" and info["solver"] == "lm_normal" and "(width)" in info["scale_law"]
    model, info = spec("--model", "anisotropic_law", "--law", "spline", "--shape", "student_t").model_for(SMALL)
    assert "log rate_2_2" in model.names and model.names[-1] == "log nu"
    assert (model.law.mu_min, model.law.mu_max) == (SCALES[0], SCALES[2])  # the knots span the fitted scales
    with pytest.raises(InvalidInputError, match="law must be one of"):
        spec("--model", "anisotropic_law", "--law", "gaussian_surface").model_for(SMALL)
    names = [name for name, _ in _candidates(spec())]
    assert names == ["isotropic", "anisotropic", "anisotropic:student_t", "anisotropic:mixture", "anisotropic_law"]
    names = [name for name, _ in _candidates(spec("--model", "anisotropic_law", "--law", "spline"))]
    assert names[-1] == "anisotropic_law:gaussian:spline"
