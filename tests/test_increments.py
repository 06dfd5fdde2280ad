"""Mixture increments: ``fitting.AnisotropicModel(increments="mixture")`` and the models and functions that carry
it (issue 31, items 1 and 3: heavy-tailed changes between scales).

Oracles: SciPy's Gauss–Legendre quadrature (300² nodes) of the convolution of the base lobe with the kernel written
out with SciPy's multivariate normal density (not the model's closed form), the kernel's characteristic function and
second moments by the same quadrature, the Gaussian-increment model (the limit f → 1), and eager evaluation for
jit/grad/vmap."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import stats as sst

from brdfscale import fitting, InvalidInputError


jax.config.update("jax_enable_x64", True)

from helpers import (  # noqa: E402
    ANISO_SCALES as SCALES,
    ANISO_TRUTH,
    anisotropic_differences as true_differences,
    anisotropic_grid as grid,
    anisotropic_theta,
    noisy_dataset,
    rotation,
)


def theta_of(model, amplitude, c0, mean, differences, w, f, nu=None):
    """θ of a mixture-increment model for physical values: the Cholesky coordinates, then logit w, log(f − 1)
    (then log ν)."""
    theta = list(np.asarray(anisotropic_theta(model, amplitude, c0, mean, differences)))
    theta += [math.log(w / (1 - w)), math.log(f - 1)]
    return jnp.asarray(theta + ([math.log(nu)] if nu is not None else []))


def kernel(d, delta, w, f):
    """``(1 − w) N(d; 0, s_c ΔΣ) + w N(d; 0, s_t ΔΣ)``, s_c = 1/(1 − w + w f), s_t = f s_c, by SciPy."""
    core = 1 / (1 - w + w * f)
    return (1 - w) * sst.multivariate_normal(np.zeros(2), core * delta).pdf(d) + w * sst.multivariate_normal(
        np.zeros(2), f * core * delta
    ).pdf(d)


def _box(delta, f):
    """Integration limits: ±12 standard deviations of the kernel's wide component along x and y."""
    return 12 * math.sqrt(f * delta[0, 0]), 12 * math.sqrt(f * delta[1, 1])


def quadrature(integrand, delta, f, nodes=300):
    """``∫∫ integrand(x, y) dx dy`` over :func:`_box` by SciPy's Gauss–Legendre rule on ``nodes`` × ``nodes`` points
    (the integrand vectorised over arrays of x and y)."""
    from scipy.special import roots_legendre

    t, wt = roots_legendre(nodes)
    bx, by = _box(delta, f)
    x, y = np.meshgrid(bx * t, by * t, indexing="ij")
    return float(np.sum(np.outer(wt, wt) * integrand(x, y)) * bx * by)


def convolution_by_quadrature(u, mean, c0, delta, w, f, amplitude):
    """``A ∫ N(u − d; m0, C0) K(d) dd`` by :func:`quadrature`."""
    base = sst.multivariate_normal(mean, c0)

    def at(p):
        return quadrature(
            lambda x, y: base.pdf(np.stack([p[0] - x, p[1] - y], -1)) * kernel(np.stack([x, y], -1), delta, w, f),
            delta,
            f,
        )

    return amplitude * np.array([at(p) for p in u])


STEP = rotation(0.7) @ np.diag([0.004, 0.001]) @ rotation(0.7).T
C0 = rotation(-0.4) @ np.diag([0.006, 0.002]) @ rotation(-0.4).T
MEAN = np.array([0.02, -0.01])


def test_mixture_lobe_is_scipy_quadrature_of_the_convolution():
    """A rotated, off-centre Gaussian lobe at μ0 convolved with the mixture kernel of ΔΣ_k: the model's lobe at
    μ_k equals the convolution by SciPy's Gauss–Legendre quadrature to 1e-8 of the peak (and at μ0 the lobe itself)."""
    model = fitting.AnisotropicModel(3, increments="mixture")
    differences = [np.zeros((2, 2)), STEP, 2.5 * STEP]
    w, f = 0.2, 9.0
    theta = theta_of(model, 1.5, C0, MEAN, differences, w, f)
    u = np.array([[0.02, -0.01], [0.1, 0.05], [-0.25, 0.2], [0.4, -0.1]])
    got = np.asarray(model.predict_points(theta, jnp.asarray(SCALES), jnp.asarray(np.stack([u, u, u]))))
    np.testing.assert_allclose(got[0], 1.5 * sst.multivariate_normal(MEAN, C0).pdf(u), rtol=1e-12)
    for k in (1, 2):
        expected = convolution_by_quadrature(u, MEAN, C0, differences[k], w, f, 1.5)
        np.testing.assert_allclose(got[k], expected, rtol=0, atol=1e-8 * expected.max())
    q = model.quantities(theta)
    assert float(q["w_tail"]) == pytest.approx(w, rel=1e-12) and float(q["f_tail"]) == pytest.approx(f, rel=1e-12)
    np.testing.assert_allclose(
        np.asarray(model.covariance_differences(theta, jnp.asarray(SCALES))), differences, atol=1e-15
    )


def test_relative_statistics_are_the_kernels_characteristic_function_and_its_covariance_is_delta_sigma():
    """``relative_statistics_plane`` equals ``∫ cos(W·d) K(d) dd`` by Gauss–Legendre quadrature at points of the W
    plane; ``−∇²_W log R_k`` at W = 0 (jax.hessian of the model's R_k) is ΔΣ_k, as are the second moments of the
    kernel written out, by the same quadrature (to 1e-9), whatever w and f — so ΔΣ_k stays the second-moment
    difference a topography measures."""
    model = fitting.AnisotropicModel(2, increments="mixture")
    w, f = 0.3, 6.0
    theta = theta_of(model, 1.0, C0, MEAN, [np.zeros((2, 2)), STEP], w, f)
    W = np.array([[0.0, 0.0], [10.0, 0.0], [5.0, -12.0], [-20.0, 8.0]])
    got = np.asarray(model.relative_statistics_plane(theta, jnp.asarray(W), jnp.asarray(SCALES[:2])))
    for j, omega in enumerate(W):
        expected = quadrature(
            lambda x, y: np.cos(omega[0] * x + omega[1] * y) * kernel(np.stack([x, y], -1), STEP, w, f), STEP, f
        )
        assert got[1, j] == pytest.approx(expected, abs=1e-9)
        assert got[0, j] == pytest.approx(1.0, abs=1e-15)  # ΔΣ_0 = 0: no change at μ0
    # ΔΣ_k = −∇²_W log R_k(W) at W = 0 (the second-moment difference the reports give for every model), from the model
    hessian = jax.hessian(
        lambda x: jnp.log(model.relative_statistics_plane(theta, x[None], jnp.asarray(SCALES[:2]))[1, 0])
    )(jnp.zeros(2))
    np.testing.assert_allclose(-np.asarray(hessian), STEP, rtol=1e-12, atol=1e-15)
    for a, b in ((0, 0), (0, 1), (1, 1)):  # and the kernel written out has that covariance (the oracle's own check)
        moment = quadrature(lambda x, y: (x, y)[a] * (x, y)[b] * kernel(np.stack([x, y], -1), STEP, w, f), STEP, f)
        assert moment == pytest.approx(STEP[a, b], abs=1e-9 * abs(STEP).max())


@settings(max_examples=25, deadline=None)
@given(
    w=st.floats(0.01, 0.9),
    f=st.floats(1.1, 500.0),
    phi=st.floats(0.0, math.pi),
    ratio=st.floats(1.0, 30.0),
)
def test_the_mixture_keeps_delta_sigma_over_orientations_anisotropy_and_tails(w, f, phi, ratio):
    """Over tail weights, width ratios, orientations and anisotropy ratios: the components' weights sum to 1 and
    their covariance multipliers average to 1 (the kernel's covariance is ΔΣ); R = 1 at W = 0 and falls below 1; for
    an isotropic ΔΣ the radial relative statistics equal the plane's along any direction; the excess kurtosis of
    the kernel along any axis, ``3[(1 − w + w f²)/(1 − w + w f)² − 1]``, is that of the weights and multipliers."""
    model = fitting.AnisotropicModel(2, increments="mixture")
    step = rotation(phi) @ np.diag([0.004, 0.004 / ratio]) @ rotation(phi).T
    theta = theta_of(model, 1.0, C0, MEAN, [np.zeros((2, 2)), step], w, f)
    v, s = (np.asarray(x) for x in model.increment_mixture(theta))
    assert v.sum() == pytest.approx(1.0, abs=1e-14) and (v * s).sum() == pytest.approx(1.0, rel=1e-12)
    kurtosis = 3 * ((v * s**2).sum() / (v * s).sum() ** 2 - 1)
    assert kurtosis == pytest.approx(3 * ((1 - w + w * f**2) / (1 - w + w * f) ** 2 - 1), rel=1e-10)
    W = jnp.asarray([[0.0, 0.0], [3.0, 1.0], [-30.0, 40.0]])
    r = np.asarray(model.relative_statistics_plane(theta, W, jnp.asarray([1.0, 2.0])))[1]
    assert r[0] == pytest.approx(1.0, abs=1e-15) and np.all(r[1:] < 1) and np.all(r[1:] > 0)
    iso = fitting.AnisotropicModel(2, isotropic=True, increments="mixture")
    t_iso = jnp.asarray([0.0, math.log(0.01), math.log(0.014), math.log(w / (1 - w)), math.log(f - 1)])  # ΔΣ = 0.004 I
    radii = jnp.asarray([0.0, 5.0, 25.0])
    along = np.stack([np.cos(phi) * np.asarray(radii), np.sin(phi) * np.asarray(radii)], axis=-1)
    np.testing.assert_allclose(
        np.asarray(iso.relative_statistics(t_iso, radii, jnp.asarray([1.0, 2.0])))[1],
        np.asarray(iso.relative_statistics_plane(t_iso, jnp.asarray(along), jnp.asarray([1.0, 2.0])))[1],
        rtol=1e-12,
    )


@pytest.mark.parametrize("shape", ["gaussian", "student_t"])
def test_width_ratio_one_is_the_gaussian_increment(shape):
    """f → 1 (log(f − 1) = −40): the mixture model's lobes are the Gaussian-increment model's, for a Gaussian and a
    Student-t base lobe (12 digits)."""
    nu = 4.0 if shape == "student_t" else None
    mixture = fitting.AnisotropicModel(3, shape=shape, increments="mixture")
    plain = fitting.AnisotropicModel(3, shape=shape)
    differences = [np.zeros((2, 2)), STEP, 2.5 * STEP]
    theta = np.array(theta_of(mixture, 1.5, C0, MEAN, differences, 0.3, 2.0, nu))
    theta[len(mixture.names) - len(mixture.tail_names) + 1] = -40.0
    plain_theta = np.delete(theta, [len(plain.names) - len(plain.tail_names) + i for i in (0, 1)])
    assert mixture.names[-1] == ("log nu" if nu else "log f-1") and "logit w" not in plain.names
    u = jnp.asarray(np.stack([grid().reshape(-1, 2)] * 3))
    got = np.asarray(mixture.predict_points(jnp.asarray(theta), jnp.asarray(SCALES), u))
    want = np.asarray(plain.predict_points(jnp.asarray(plain_theta), jnp.asarray(SCALES), u))
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * want.max())


def _mixture_dataset(seed, w=0.25, f=8.0, size=33, extent=0.5):
    """Images of the helpers' anisotropic truth (rotated, off-centre) evolved by mixture increments of its ΔΣ_k,
    written out with SciPy (the two Gaussians of each component pair), 1 % noise, on ``size``² pixels over ±``extent``
    (33 px: the μ0 lobe's narrower axis spans 1.4 pixels, resolved for fitting.assess)."""
    x = np.linspace(-extent, extent, size)
    u = np.stack(np.meshgrid(x, x), axis=-1)
    core = 1 / (1 - w + w * f)
    lobes = []
    for d in true_differences():
        lobe = sum(
            weight * sst.multivariate_normal(ANISO_TRUTH["mean"], ANISO_TRUTH["C0"] + s * d, allow_singular=True).pdf(u)
            for weight, s in ((1 - w, core), (w, f * core))
        )
        lobes.append(ANISO_TRUTH["amplitude"] * lobe)
    return noisy_dataset(lobes, SCALES, extent, np.random.default_rng(seed))


@pytest.fixture(scope="module")
def mixture_data():
    return _mixture_dataset(2)


@pytest.mark.slow  # ~12 s of compilations: the default suite keeps under 6 minutes
def test_jit_grad_vmap_equal_eager(mixture_data):
    """The mixture model's residuals under jit and vmap equal eager ones; its χ² gradient equals central
    differences, jitted or not."""
    model = fitting.AnisotropicModel(3, increments="mixture")
    problem = fitting.Problem(model, mixture_data)
    theta = jnp.asarray(model.initial(mixture_data))
    eager = problem.residuals(theta)
    np.testing.assert_allclose(jax.jit(lambda t: problem.residuals(t))(theta), eager, rtol=1e-12, atol=1e-12)
    batched = jax.vmap(lambda t: problem.residuals(t))(jnp.stack([theta, theta + 0.01]))
    np.testing.assert_allclose(batched[0], eager, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(batched[1], problem.residuals(theta + 0.01), rtol=1e-12, atol=1e-12)
    chi2 = jax.jit(lambda t: problem.chi2(t))
    grad = jax.grad(lambda t: problem.chi2(t))(theta)
    for i in (0, 4, len(theta) - 2, len(theta) - 1):
        e = jnp.zeros_like(theta).at[i].set(1e-6)
        numeric = (chi2(theta + e) - chi2(theta - e)) / 2e-6
        assert abs(float(grad[i]) - float(numeric)) <= 1e-5 * max(1.0, abs(float(numeric)))
    np.testing.assert_allclose(jax.jit(jax.grad(lambda t: problem.chi2(t)))(theta), grad, rtol=1e-10)


@pytest.mark.slow  # two fits of two starts each: ~10 s
def test_fit_recovers_mixture_increments_and_the_gaussian_increment_is_flagged(mixture_data):
    """Lobes changed by mixture increments (w = 0.25, f = 8): the mixture model fits (χ²/dof < 1.3), every ΔΣ_k
    component, w and f within 3 standard errors of the truth; the Gaussian-increment model is inadequate by
    fitting.assess and BIC prefers the mixture."""
    model = fitting.AnisotropicModel(3, increments="mixture")
    heavy = fitting.fit(model, mixture_data, starts=2)
    assert heavy.status == "converged" and heavy.chi2 / heavy.dof < 1.3
    for d, t in zip(heavy.covariance_differences, true_differences()[1:]):
        value, std = np.array(d["value"]), np.array(d["std"])
        assert np.all(np.abs(value - t) < 3 * std), (value, t, std)
    for name, true in (("logit w", math.log(0.25 / 0.75)), ("log f-1", math.log(7.0))):
        i = heavy.names.index(name)
        assert abs(heavy.theta[i] - true) < 3 * math.sqrt(heavy.covariance[i, i]), name
    light = fitting.fit(fitting.AnisotropicModel(3), mixture_data, starts=2)
    assert fitting.compare({"mixture": heavy, "gaussian": light}).preferred["bic"] == "mixture"
    assert fitting.assess(fitting.Problem(fitting.AnisotropicModel(3), mixture_data), light).status == "inadequate"
    assert fitting.assess(fitting.Problem(model, mixture_data), heavy).status == "ok"


def _law_theta():
    """θ of ``AnisotropicLawModel(increments="mixture")``: the base lobe C0, MEAN, φ = 0.5, two width laws, w = 0.2,
    f = 6."""
    L = np.linalg.cholesky(C0)
    return jnp.asarray(
        [math.log(2.0), math.log(L[0, 0]), L[1, 0], math.log(L[1, 1]), *MEAN, 0.5]
        + [math.log(v) for v in (0.12, 2.0, 1.0, 0.06, 3.0, 1.5)]
        + [math.log(0.2 / 0.8), math.log(5.0)]
    )


def test_the_law_model_carries_the_increments():
    """AnisotropicLawModel(increments="mixture"): θ ends with the mixture's coordinates (then ν); no lobe finer
    than μ0."""
    law = fitting.AnisotropicLawModel(increments="mixture", shape="student_t")
    assert law.names[-3:] == ("logit w", "log f-1", "log nu") and law.increments == "mixture"
    model = fitting.AnisotropicLawModel(increments="mixture")
    assert model.names[-2:] == ("logit w", "log f-1")
    theta = _law_theta()
    with pytest.raises(InvalidInputError, match="mixture increments has no lobe at scales finer than"):
        model.predict_at(theta, 1.0, [0.5], jnp.zeros((1, 3, 2)))


@pytest.mark.slow  # ~10 s: predictions on 41² grids and a law fit
def test_law_from_differences_and_the_measured_prediction_carry_the_increments():
    """law_from_differences of a mixture model gives a mixture law model with the fit's w and f; and
    predict_from_measured widens a noise-free measured lobe of a mixture law model by Eq. 4.4's ratio of the
    mixture's relative statistics, which equals the model's own lobe at the unseen scale (1e-7 of the peak: the
    padding), where a Gaussian widening by ΔΣ(μ_s, μ) misses it."""
    import brdfscale as bs

    model = fitting.AnisotropicLawModel(increments="mixture")
    theta = _law_theta()
    n, extent = 41, 0.5
    x = np.linspace(-extent, extent, n)
    u = np.stack(np.meshgrid(x, x), axis=-1).reshape(1, -1, 2)
    fitted, unseen = (1.0, 2.0, 4.0), 8.0

    def lobe(mu):
        return np.asarray(model.predict_at(theta, 1.0, [mu], jnp.asarray(u)))[0].reshape(n, n)

    images = tuple(
        bs.LobeImage(mu=mu, incident=[0.0, 0.0, 1.0], extent=extent, values=lobe(mu), sigma=np.full((n, n), 1e-3))
        for mu in fitted
    )
    data = fitting.Dataset.from_measurements(bs.MeasurementSet(images))
    out = fitting.predict_from_measured(model, theta, data, [unseen], base="measured")
    want = lobe(unseen).ravel()
    np.testing.assert_allclose(np.asarray(out.values)[0, : n * n], want, rtol=0, atol=1e-7 * want.max())
    # the Gaussian widening by ΔΣ(μ_s, μ) alone misses it: the ratio is what carries the tails
    gaussian_law = fitting.AnisotropicLawModel()
    plain = fitting.predict_from_measured(gaussian_law, theta[:-2], data, [unseen], base="measured")
    assert np.abs(np.asarray(plain.values)[0, : n * n] - want).max() > 1e-4 * want.max()

    per_scale = fitting.AnisotropicModel(4, increments="mixture")
    differences = [np.zeros((2, 2))] + [
        np.asarray(model.covariance_differences(theta, jnp.asarray([1.0, mu])))[1] for mu in (2.0, 4.0, 8.0)
    ]
    theta_k = theta_of(per_scale, 2.0, C0, MEAN, differences, 0.2, 6.0)
    entries = [
        {"mu0": 1.0, "mu": mu, "value": d.tolist(), "std": (1e-3 * np.abs(d) + 1e-6).tolist()}
        for mu, d in zip((2.0, 4.0, 8.0), differences[1:])
    ]
    data4 = fitting.Dataset.from_measurements(
        bs.MeasurementSet(
            images
            + (
                bs.LobeImage(
                    mu=8.0, incident=[0.0, 0.0, 1.0], extent=extent, values=lobe(8.0), sigma=np.full((n, n), 1e-3)
                ),
            )
        )
    )
    fitted_law = fitting.law_from_differences(per_scale, theta_k, entries, data4)
    assert fitted_law.model.increments == "mixture"
    q = fitted_law.model.quantities(fitted_law.theta)
    assert float(q["w_tail"]) == pytest.approx(0.2, rel=1e-12) and float(q["f_tail"]) == pytest.approx(6.0, rel=1e-12)


def test_unknown_increments_are_refused_naming_the_accepted_ones():
    from brdfscale.library import FitSpec

    for build in (
        lambda: fitting.AnisotropicModel(3, increments="cauchy"),
        lambda: fitting.AnisotropicLawModel(increments="cauchy"),
        lambda: FitSpec(increments="cauchy"),
    ):
        with pytest.raises(InvalidInputError, match="'gaussian'.*'mixture'"):
            build()


@pytest.mark.slow  # a fit through the command with its report: ~20 s
def test_the_command_fits_mixture_increments_and_refuses_them_where_they_do_not_apply(tmp_path, capsys):
    """``brdfscale fit --increments mixture`` builds the mixture model (fit.json's model and θ's names say so); with
    a model that has no increments it is refused before any work (exit 2, naming where it applies)."""
    import json

    from brdfscale import exr
    from brdfscale._cli import main

    mset = fitting.simulate(
        fitting.ParametricModel(),
        dict(amplitude=0.8, alpha_lobe=0.06, alpha_max=0.2, mu_c=1.0, exponent=0.8),
        (0.5, 2.0, 8.0),
        size=21,
        extent=0.35,
        noise=0.01,
        floor=1e-3,
        seed=2,
    )
    path = tmp_path / "m.exr"
    exr.write_measurements(str(path), mset)
    code = main(["fit", str(path), "--out", str(tmp_path / "p"), "--model", "parametric", "--increments", "mixture"])
    assert code == 2 and "--increments applies to the anisotropic" in capsys.readouterr().err
    assert not (tmp_path / "p").exists()
    out = tmp_path / "a"
    argv = ["fit", str(path), "--out", str(out), "--increments", "mixture", "--steps", "0", "--no-progress"]
    code = main(argv + ["--starts", "2"])
    doc = json.loads((out / "fit.json").read_text())
    # data without heavy tails leave w and f loosely determined: whatever the verdict, the exit status is its own
    assert code == {"ok": 0, "inadequate": 5, "not_converged": 6, "undetermined": 7}[doc["outcome"]["status"]]
    assert doc["model"]["increments"].startswith("mixture:")
    assert {"w_tail", "f_tail"} <= set(doc["parameters"])
