"""fitting.predict_from_measured: unseen coarser scales from the lobe measured at the coarsest fitted scale,
widened by a fitted law's Gaussian increment (seed Eq. 4.4 started there; issue 31, the held-out target).

Oracles: the Gaussian identity written by hand (a Gaussian lobe of covariance C widened by ΔΣ is the Gaussian of
C + ΔΣ, helpers.gaussian) with the law's ΔΣ written out (tests/test_anisotropic_law.py's width law); central
differences for the gradient; eager for jit."""

import dataclasses
import functools
import json
import math
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import brdfscale as bs
from brdfscale import fitting, InvalidInputError


jax.config.update("jax_enable_x64", True)

from helpers import gaussian, rotation  # noqa: E402

from brdfscale.fitting._measured import widen  # noqa: E402


MU0 = 1.0
LAW = {"phi": 0.5, "axes": [(0.12, 2.0, 1.0), (0.06, 3.0, 1.5)]}  # (alpha_max, mu_c, exponent) per axis
MEAN = np.array([0.02, -0.01])
C0 = rotation(-0.3) @ np.diag([0.004, 0.0015]) @ rotation(-0.3).T
AMPLITUDE = 2.0
FITTED, UNSEEN = (1.0, 2.0, 4.0), (8.0, 16.0)
N, EXTENT = 41, 0.5  # pitch 0.025: the narrowest lobe's sd along its minor axis is ~1.5 pixels


def width(alpha_max, mu_c, exponent, mu):
    return alpha_max * (1 + (mu / mu_c) ** 2) ** (-exponent / 2)


def true_difference(mu, mu0=MU0):
    d = [(width(*axis, mu0) ** 2 - width(*axis, mu) ** 2) / 2 for axis in LAW["axes"]]
    return rotation(LAW["phi"]) @ np.diag(d) @ rotation(LAW["phi"]).T


def theta_of(c0=C0, mean=MEAN):
    L = np.linalg.cholesky(c0)
    theta = [math.log(AMPLITUDE), math.log(L[0, 0]), L[1, 0], math.log(L[1, 1]), *mean, LAW["phi"]]
    for axis in LAW["axes"]:
        theta += [math.log(v) for v in axis]
    return jnp.asarray(theta)


def truth(mu):
    x = np.linspace(-EXTENT, EXTENT, N)
    return gaussian(np.stack(np.meshgrid(x, x), axis=-1), MEAN, C0 + true_difference(mu), AMPLITUDE)


def _images(scales, noise=0.0, seed=0, n=N, incident=(0.0, 0.0, 1.0)):
    rng = np.random.default_rng(seed)
    images = []
    for mu in scales:
        v = truth(mu) if n == N else np.ones((n, n))
        sigma = noise * v.max() + 1e-3
        images.append(
            bs.LobeImage(
                mu=mu,
                incident=list(incident),
                extent=EXTENT,
                values=v + (sigma * rng.standard_normal(v.shape) if noise else 0.0),
                sigma=np.full(v.shape, sigma),
            )
        )
    return images


def dataset(scales, noise=0.0, seed=0, n=N):
    return fitting.Dataset.from_measurements(bs.MeasurementSet(tuple(_images(scales, noise, seed, n))))


MODEL = fitting.AnisotropicLawModel()


def _flat(data):
    return np.asarray(data.values)[:, : N * N]


@pytest.mark.parametrize("c0", [C0, np.diag([0.002, 0.006])], ids=["model's base right", "model's base wrong"])
def test_the_measured_lobe_widened_by_the_law_is_the_gaussian_of_the_summed_covariance(c0):
    """Noise-free Gaussian lobes at the fitted scales: the prediction at unseen scales is the hand-written
    Gaussian of C0 + ΔΣ(μ0, μ) (rotated, anisotropic, off-centre: a confusion of the grid's axes fails it) — also
    when the model's own base lobe is wrong, since the lobe comes from the measurement: the model fills only the
    padding beyond the image's edge, 4–8 standard deviations out, whose light moves in by the increment's width
    (1e-9 of the peak with the right base, 1e-7 with the wrong one, measured 1e-8); at a fitted scale it is the
    measured lobe itself."""
    data, target = dataset(FITTED), dataset(FITTED + UNSEEN)
    out = fitting.predict_from_measured(MODEL, theta_of(c0), data, target, base="measured")
    assert out.base == "measured" and out.validation is None and out.source_scales == (1.0, 2.0, 4.0, 4.0, 4.0)
    assert out.scales == FITTED + UNSEEN and out.images is target
    got = np.asarray(out.values)[:, : N * N]
    for i, mu in enumerate(FITTED + UNSEEN):
        want = truth(mu).ravel()
        np.testing.assert_allclose(got[i], want, rtol=0, atol=(1e-9 if c0 is C0 else 1e-7) * want.max())
    model_only = fitting.predict_from_measured(MODEL, theta_of(c0), data, target, base="model")
    error = np.abs(np.asarray(model_only.values)[3, : N * N] - truth(8.0).ravel()).max() / truth(8.0).max()
    assert (error < 1e-9) == (c0 is C0)  # the model's own prediction is right only with the right base


def test_masked_pixels_of_the_measured_lobe_are_filled_by_the_model():
    """Pixels no image measured (weight 0) take the model's lobe at that scale: with the true θ the prediction is
    unchanged; their measured values are not used (set to garbage)."""
    data, target = dataset(FITTED), dataset(UNSEEN)
    hole = np.zeros((len(FITTED), data.values.shape[1]), bool)
    hole[2, : N * N] = (np.arange(N * N) % 7) == 0
    damaged = dataclasses.replace(
        data, weight=jnp.where(hole, 0.0, data.weight), values=jnp.where(hole, 1e6, data.values)
    )
    got = np.asarray(fitting.predict_from_measured(MODEL, theta_of(), damaged, target, base="measured").values)
    for i, mu in enumerate(UNSEEN):
        np.testing.assert_allclose(got[i, : N * N], truth(mu).ravel(), rtol=0, atol=1e-9 * truth(mu).max())


def test_auto_keeps_the_measured_lobe_where_the_model_misses_and_the_model_where_noise_dominates():
    """base="auto" validates on the coarsest fitted scale: noise-free data and a model with the wrong base lobe →
    the measured lobe (its χ² ~0); the true θ and noise of 30 % of the peak → the model's lobe (the measured base
    adds its own noise)."""
    target = dataset(UNSEEN)
    wrong = fitting.predict_from_measured(MODEL, theta_of(np.diag([0.002, 0.006])), dataset(FITTED), target)
    assert wrong.base == "measured" and wrong.validation["measured"] < 1e-6 < wrong.validation["model"]
    assert wrong.validation["scales"] == (2.0, 4.0) and wrong.validation["n"] == N * N
    noisy = fitting.predict_from_measured(MODEL, theta_of(), dataset(FITTED, noise=0.3, seed=1), target)
    assert noisy.base == "model" and noisy.validation["model"] < noisy.validation["measured"]
    assert "base='model'" in repr(noisy) and "χ²/n measured" in repr(noisy)


def test_refuses_models_without_a_law_bad_bases_finer_scales_and_foreign_grids():
    data = dataset(FITTED)
    with pytest.raises(InvalidInputError, match="scale law defined at any μ.*got ParametricModel"):
        fitting.predict_from_measured(fitting.ParametricModel(), jnp.zeros(4), data, dataset(UNSEEN))
    with pytest.raises(InvalidInputError, match="per-scale AnisotropicModel .* give differences="):
        fitting.predict_from_measured(fitting.AnisotropicModel(3), jnp.zeros(12), data, dataset(UNSEEN))
    with pytest.raises(InvalidInputError, match="carries its own scale law: omit them"):
        fitting.predict_from_measured(MODEL, theta_of(), data, dataset(UNSEEN), differences=[])
    with pytest.raises(InvalidInputError, match="base must be one of 'auto', 'measured', 'model'; got 'best'"):
        fitting.predict_from_measured(MODEL, theta_of(), data, dataset(UNSEEN), base="best")
    with pytest.raises(InvalidInputError, match="finer than the finest fitted scale"):
        fitting.predict_from_measured(MODEL, theta_of(), data, dataset((0.5, 8.0)), base="measured")
    with pytest.raises(InvalidInputError, match="has the target's pixel grid"):
        fitting.predict_from_measured(MODEL, theta_of(), data, dataset(UNSEEN, n=31), base="measured")
    for bad in ([], [8.0, -1.0], float("nan")):
        with pytest.raises(InvalidInputError, match="target must be a fitting.Dataset or finite positive scales"):
            fitting.predict_from_measured(MODEL, theta_of(), data, bad)
    with pytest.raises(InvalidInputError, match="needs two fitted scales"):
        fitting.predict_from_measured(MODEL, theta_of(), _one_scale(data), dataset(UNSEEN))
    mixed = fitting.Dataset.from_measurements(bs.MeasurementSet((*_images((1.0, 2.0)), *_images((4.0,), n=31))))
    with pytest.raises(InvalidInputError, match="base='auto' validates .* other pixel grids; give base="):
        fitting.predict_from_measured(MODEL, theta_of(), mixed, [8.0])


@pytest.mark.wrong_types
def test_refuses_a_target_of_another_type():
    """A target neither a Dataset nor numbers: the library's own error (the annotation's check answers first
    where jaxtyping's runtime checks are on)."""
    for bad in (None, "x", {"mu": 8.0}, [[8.0]]):
        with pytest.raises(InvalidInputError, match="target must be a fitting.Dataset or finite positive scales"):
            fitting.predict_from_measured(MODEL, theta_of(), dataset(FITTED), bad)


def _one_scale(data):
    return dataclasses.replace(
        data,
        offsets=data.offsets[:1],
        values=data.values[:1],
        weight=data.weight[:1],
        scales=data.scales[:1],
        scale_of_image=(0,),
        image_sizes=data.image_sizes[:1],
        extents=data.extents[:1],
    )


def test_widen_under_jit_and_grad_equals_eager_and_central_differences():
    """The convolution core: jit equal to eager; its gradient in ΔΣ equal to central differences."""
    image = jnp.asarray(truth(1.0))
    steps = jnp.asarray([[EXTENT * 2 / (N - 1), 0.0], [0.0, EXTENT * 2 / (N - 1)]])
    delta = jnp.asarray(true_difference(8.0))
    eager = widen(image, steps, delta)
    np.testing.assert_allclose(jax.jit(widen)(image, steps, delta), eager, rtol=0, atol=1e-12 * float(eager.max()))
    probe = jnp.asarray(np.random.default_rng(2).standard_normal(image.shape))

    def f(d):
        return jnp.sum(widen(image, steps, d) * probe)

    grad = jax.jit(jax.grad(f))(delta)
    for a, b in ((0, 0), (0, 1), (1, 1)):
        e = np.zeros((2, 2))
        e[a, b] = e[b, a] = 1e-7
        fd = (f(delta + e) - f(delta - e)) / 2e-7
        analytic = grad[a, b] + (grad[b, a] if a != b else 0.0)
        assert float(analytic) == pytest.approx(float(fd), rel=1e-5)


def test_scales_as_target_predict_on_the_grids_of_the_coarsest_fitted_scale(tmp_path):
    """target=scales: one image per scale (sorted, distinct) on the grid of the coarsest fitted scale's image,
    equal to the prediction for a target Dataset of those images; ``images.image`` gives each one's grid."""
    data = dataset(FITTED)
    by_scales = fitting.predict_from_measured(MODEL, theta_of(), data, [16.0, 8.0, 16.0], base="measured")
    by_dataset = fitting.predict_from_measured(MODEL, theta_of(), data, dataset(UNSEEN), base="measured")
    assert by_scales.scales == UNSEEN and by_scales.source_scales == (4.0, 4.0)
    np.testing.assert_array_equal(np.asarray(by_scales.values), np.asarray(by_dataset.values))
    assert by_scales.images.image(1, by_scales.values[1]).shape == (N, N)
    assert repr(by_scales) == "MeasuredPrediction(2 images at μ = [8, 16], base='measured')"
    # as a measurement set, written and read back (float32 in the file)
    from brdfscale import exr

    exr.write_measurements(tmp_path / "p.exr", by_scales.to_measurements({"note": "mine"}))
    back = exr.read_measurements(tmp_path / "p.exr")
    assert [image.mu for image in back.images] == [8.0, 16.0] and back.metadata["note"] == "mine"
    assert back.metadata["base"] == "measured" and back.metadata["source_scales"] == [4.0, 4.0]
    assert back.metadata["masking"] == "none" and back.metadata["validation"] is None
    for i, image in enumerate(back.images):
        want = np.clip(by_scales.images.image(i, by_scales.values[i]), 0, None)
        np.testing.assert_allclose(np.asarray(image.values), want, rtol=1e-6, atol=1e-12)


def test_the_commands_predict_option_refuses_before_the_work(tmp_path):
    """``brdfscale fit --predict``: a malformed list is argparse's exit 2; a model without a law at any μ, with
    --compare, a scale finer than μ0 (check_predict), or an existing DIR/predicted_lobes.exr without --force
    unless the run resumes its own (check_predicted_file) are refused naming the fix, before any fit."""
    from brdfscale._cli import build_parser
    from brdfscale._cli._fit import check_predict, check_predicted_file, PREDICTED

    def args(*extra):
        return build_parser().parse_args(["fit", "m.exr", "--out", str(tmp_path), *extra])

    for bad in ("1,x", "", "0", "-2", ",".join(["1"] * 65)):
        with pytest.raises(SystemExit) as exit_:
            args("--predict", bad)
        assert exit_.value.code == 2
    assert args("--predict", "8, 16").predict == (8.0, 16.0)
    data = dataset(FITTED)
    check_predict(args("--model", "anisotropic_law"), data, None)  # no --predict: nothing to check
    check_predict(args("--model", "anisotropic_law", "--predict", "1,8"), data, None)  # μ0 itself is allowed
    # the default (per-scale) model: a law fitted to its ΔΣ, which needs four scales (seven coordinates)
    check_predict(args("--predict", "8"), dataset((*FITTED, 8.0)), None)
    with pytest.raises(InvalidInputError, match="--predict with --model anisotropic .* needs 4 measured scales, .* 3"):
        check_predict(args("--predict", "8"), data, None)
    for model in ("isotropic", "parametric"):
        with pytest.raises(InvalidInputError, match=f"--predict needs --model anisotropic, anisotropic_law.*{model}"):
            check_predict(args("--model", model, "--predict", "8"), data, None)
    with pytest.raises(InvalidInputError, match="without --compare"):
        check_predict(args("--model", "anisotropic_law", "--compare", "--predict", "8"), data, None)
    with pytest.raises(InvalidInputError, match="--predict 0.5: below the finest measured scale μ0 = 1 px"):
        check_predict(args("--model", "anisotropic_law", "--predict", "0.5,8"), data, None)
    (tmp_path / PREDICTED).write_text("the user's")
    with pytest.raises(InvalidInputError, match=f"{PREDICTED} exists; .*--force"):
        check_predicted_file(args("--model", "anisotropic_law", "--predict", "8"), resume=False)
    check_predicted_file(args("--model", "anisotropic_law", "--predict", "8", "--force"), resume=False)
    check_predicted_file(args("--model", "anisotropic_law", "--predict", "8"), resume=True)  # its own, resumed
    check_predicted_file(args("--model", "anisotropic_law"), resume=False)  # no --predict: not this run's file


@pytest.mark.slow
@pytest.mark.parametrize("model", ["anisotropic_law", "anisotropic"])
def test_the_command_writes_the_predicted_lobes(tmp_path, capsys, monkeypatch, model):
    """End to end: Gaussian lobes at four scales with white noise at their σ (1e-5 of the peak), ``brdfscale fit
    --model anisotropic_law --predict``
    and the default per-scale model's (a width law fitted to its ΔΣ estimates): DIR/predicted_lobes.exr holds the
    lobes at the two unseen scales, equal to the hand-written Gaussians of C0 + ΔΣ(μ0, μ) to 1e-3 of the peak (the
    law fitted, extrapolated; the file's float32 values), the command says what the prediction started from and
    exits 0 (the fit adequate, the law not rejected) — 5, with the law's reason, where the law is rejected."""
    import brdfscale._cli as cli
    from brdfscale import exr

    images, rng = [], np.random.default_rng(3)
    for mu in (*FITTED, 8.0):
        v = truth(mu) + rng.normal(0.0, 1e-3, (N, N))  # white noise at σ (1e-5 of the peak): the fit adequate
        sigma = np.full(v.shape, 1e-3)
        images.append(bs.LobeImage(mu=mu, incident=[0.0, 0.0, 1.0], extent=EXTENT, values=v, sigma=sigma))
    measurements = tmp_path / "m.exr"
    exr.write_measurements(measurements, bs.MeasurementSet(tuple(images)))
    out = tmp_path / "fit"
    argv = ["fit", str(measurements), "--model", model, "--steps", "0", "--out", str(out)]
    per_scale = model == "anisotropic"
    assert cli.main([*argv, "--predict", "32,16"]) == 0  # the law fits the ΔΣ estimates: the fit's verdict stands
    printed = capsys.readouterr().out
    assert re.search(
        r"predicted_lobes.exr: 2 lobes at μ = \[16, 32\] px, predicted from the "
        r"(measured lobe at μ = 8|model's lobe at μ = 1) px; at the coarsest fitted scale χ²/n .*"
        + (
            r"; ΔΣ from a width law fitted to the per-scale ΔΣ \(χ²/dof = .*/2, p (= [^)]*|< 1e-300)\)"
            if per_scale
            else ""
        ),
        printed,
    )
    predicted = exr.read_measurements(out / "predicted_lobes.exr")
    assert [image.mu for image in predicted.images] == [16.0, 32.0]
    start = {"measured": 8.0, "model": 1.0}[predicted.metadata["base"]]  # the model's lobe evolves from μ0
    assert predicted.metadata["source_scales"] == [start, start] and predicted.metadata["masking"] == "none"
    assert ("law" in predicted.metadata) == (model == "anisotropic")
    for image in predicted.images:
        want = truth(image.mu)
        np.testing.assert_allclose(np.asarray(image.values), want, rtol=0, atol=1e-3 * want.max())
    assert cli.main([*argv, "--predict", "16"]) == 2  # the file is there: refused without --force
    if model == "anisotropic":  # a law the ΔΣ reject turns the command's verdict to inadequate, its line on stderr
        reason = "the width law fitted to the per-scale ΔΣ estimates does not describe them (test)"
        monkeypatch.setattr(fitting.LawFromDifferences, "inadequate_because", lambda self, thresholds=None: reason)
        capsys.readouterr()
        assert cli.main([*argv, "--predict", "16", "--force"]) == 5
        shown = capsys.readouterr()
        assert f"brdfscale fit: inadequate: {reason}" in shown.err and f"outcome: inadequate — {reason}" in shown.out
        outcome = json.loads((out / "fit.json").read_text())["outcome"]  # the file says what the exit status says
        assert (outcome["status"], outcome["reason"], outcome["problems"][-1]) == ("inadequate", reason, reason)


def test_replicate_images_at_a_scale_are_averaged_by_their_weights():
    """Two images at each fitted scale on one grid (two incidences, independent noise): the measured base is their
    σ-weighted mean — the prediction equals the one from a set holding that mean alone — and a list of scales
    predicts one image per distinct grid, not one per replicate."""
    first = _images(FITTED, noise=0.05, seed=4)
    second = _images(FITTED, noise=0.1, seed=5, incident=(0.6, 0.0, 0.8))
    both = fitting.Dataset.from_measurements(bs.MeasurementSet((*first, *second)))
    out = fitting.predict_from_measured(MODEL, theta_of(), both, [8.0], base="measured")
    assert out.values.shape[0] == 1 and out.scales == (8.0,)
    w1, w2 = 1 / (0.05 * truth(4.0).max() + 1e-3) ** 2, 1 / (0.1 * truth(4.0).max() + 1e-3) ** 2
    mean = (w1 * first[2].values + w2 * second[2].values) / (w1 + w2)
    alone = [
        *first[:2],
        bs.LobeImage(mu=4.0, incident=[0.0, 0.0, 1.0], extent=EXTENT, values=mean, sigma=first[2].sigma),
    ]
    single = fitting.Dataset.from_measurements(bs.MeasurementSet(tuple(alone)))
    want = fitting.predict_from_measured(MODEL, theta_of(), single, [8.0], base="measured")
    np.testing.assert_allclose(np.asarray(out.values), np.asarray(want.values), rtol=0, atol=1e-12 * truth(8.0).max())


SCALES = (1.0, 2.0, 4.0, 8.0, 16.0)


def _per_scale_theta(differences):
    """The per-scale model's θ whose ΔΣ_k are ``differences`` (K−1 matrices of increasing, PD increments)."""
    theta, previous = list(np.asarray(theta_of())[:6]), np.zeros((2, 2))
    for d in differences:
        L = np.linalg.cholesky(d - previous)
        theta += [math.log(L[0, 0]), L[1, 0], math.log(L[1, 1])]
        previous = d
    return jnp.asarray(theta)


def _entries(differences, rel=1e-4):
    return [
        {"mu0": SCALES[0], "mu": mu, "value": d.tolist(), "std": [[rel * abs(d).max()] * 2] * 2}
        for mu, d in zip(SCALES[1:], differences)
    ]


def test_a_width_law_fitted_to_per_scale_differences_carries_them_to_unseen_scales():
    """ΔΣ_k of the per-scale model made by a known anisotropic width law (rotated, two different axes): the law
    fitted to them (fitting.law_from_differences) gives ΔΣ at the unseen scales 32 and 64 equal to the true law's
    to 1e-6 of its largest entry, with χ² ≈ 0 on 12 − 7 = 5 dof; predict_from_measured with the per-scale model and
    its differences then equals the prediction of the true law model (1e-9 of the peak)."""
    data = dataset(SCALES)
    truths = [true_difference(mu) for mu in SCALES[1:]]
    model = fitting.AnisotropicModel(len(SCALES))
    law = fitting.law_from_differences(model, _per_scale_theta(truths), _entries(truths), data)
    assert law.dof == 5 and law.chi2 < 1e-12 and isinstance(law.model, fitting.AnisotropicLawModel)
    assert re.fullmatch(r"LawFromDifferences\(Width law on 5 scales, χ²/dof = .*/5, φ = .* rad\)", repr(law))
    got = np.asarray(law.model.covariance_differences(law.theta, jnp.asarray([1.0, 32.0, 64.0])))[1:]
    for mu, g in zip((32.0, 64.0), got):
        np.testing.assert_allclose(g, true_difference(mu), rtol=0, atol=1e-6 * abs(true_difference(mu)).max())
    out = fitting.predict_from_measured(
        model, _per_scale_theta(truths), data, [32.0], base="measured", differences=_entries(truths)
    )
    want = fitting.predict_from_measured(MODEL, theta_of(), data, [32.0], base="measured")
    np.testing.assert_allclose(np.asarray(out.values), np.asarray(want.values), rtol=0, atol=1e-9 * truth(32.0).max())
    assert out.law is not None and out.to_measurements().metadata["law"]["dof"] == 5
    assert re.fullmatch(r"MeasuredPrediction\(1 images at μ = \[32\], base='measured', law χ²/dof .*/5\)", repr(out))


@settings(max_examples=12, deadline=None)
@given(
    phi=st.floats(-1.5, 1.5),
    log_ratio=st.floats(0.0, 1.3),
    mu_c=st.tuples(st.floats(0.0, 1.0), st.floats(0.0, 1.0)),
    exponent=st.tuples(st.floats(0.5, 2.5), st.floats(0.5, 2.5)),
)
def test_the_law_fitted_to_differences_over_orientations_and_anisotropy(phi, log_ratio, mu_c, exponent):
    """Over orientations φ, anisotropy ratios 1–20 and each axis' μ_c and exponent: the width law that made the
    per-scale ΔΣ_k is recovered, its ΔΣ at the unseen scale 32 to 1e-6 of its largest entry."""
    axes = [(0.1, 10 ** mu_c[0], exponent[0]), (0.1 / math.sqrt(10**log_ratio), 10 ** mu_c[1], exponent[1])]

    def difference(mu):
        d = [(width(*axis, MU0) ** 2 - width(*axis, mu) ** 2) / 2 for axis in axes]
        return rotation(phi) @ np.diag(d) @ rotation(phi).T

    truths = [difference(mu) for mu in SCALES[1:]]
    model = fitting.AnisotropicModel(len(SCALES))
    law = fitting.law_from_differences(model, _per_scale_theta(truths), _entries(truths), dataset_of_scales())
    got = np.asarray(law.model.covariance_differences(law.theta, jnp.asarray([MU0, 32.0])))[1]
    np.testing.assert_allclose(got, difference(32.0), rtol=0, atol=1e-6 * abs(difference(32.0)).max())
    assert law.converged


@functools.cache
def dataset_of_scales():
    return dataset(SCALES)


def test_law_from_differences_refuses_what_it_cannot_fit():
    """Another model or the isotropic per-scale one, a θ of the wrong length, entries not one per coarser scale or
    at other scales, damaged entries, fewer determined components than the law's coordinates: the library's error
    naming the fix."""
    data = dataset(SCALES)
    truths = [true_difference(mu) for mu in SCALES[1:]]
    model, theta, entries = fitting.AnisotropicModel(len(SCALES)), _per_scale_theta(truths), _entries(truths)
    with pytest.raises(InvalidInputError, match="isotropic AnisotropicModel .* not determined"):
        fitting.law_from_differences(fitting.AnisotropicModel(len(SCALES), isotropic=True), theta[:6], entries, data)
    with pytest.raises(InvalidInputError, match="theta must be the model's 18 finite coordinates"):
        fitting.law_from_differences(model, theta[:-1], entries, data)
    with pytest.raises(InvalidInputError, match="one entry per coarser scale \\(4 for these data\\)"):
        fitting.law_from_differences(model, theta, entries[:-1], data)
    with pytest.raises(InvalidInputError, match="has μ = 3.0, the data's μ = 2 there"):
        fitting.law_from_differences(model, theta, [{**entries[0], "mu": 3.0}, *entries[1:]], data)
    with pytest.raises(InvalidInputError, match="has μ0 = 99.0, the data's μ0 = 1 there"):
        fitting.law_from_differences(model, theta, [{**entries[0], "mu0": 99.0}, *entries[1:]], data)
    with pytest.raises(InvalidInputError, match="must hold 'mu', 'value' and 'std'"):
        fitting.law_from_differences(model, theta, [{"mu": 2.0}, *entries[1:]], data)
    for bad in ([[1.0, 2.0]], 3.0, [["a", 0.0], [0.0, 1.0]], [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]):
        with pytest.raises(InvalidInputError, match=r"differences\[0\]\['std'\] must be a 2 × 2 matrix of numbers"):
            fitting.law_from_differences(model, theta, [{**entries[0], "std": bad}, *entries[1:]], data)
    with pytest.raises(InvalidInputError, match="theta must be the model's 18 finite coordinates"):
        fitting.law_from_differences(model, theta.at[0].set(jnp.nan), entries, data)
    few = [{**e, "std": [[None, None], [None, None]]} for e in entries[:3]] + entries[3:]
    with pytest.raises(InvalidInputError, match="has 7 coordinates .* only 3 determined components: .* at least 4"):
        fitting.law_from_differences(model, theta, few, data)
    assert fitting.LawFromDifferences.scales_needed() == 4 and fitting.LawFromDifferences.scales_needed("spline") == 4
    # the isotropic per-scale model is refused by predict_from_measured as by law_from_differences, with or without
    with pytest.raises(InvalidInputError, match="isotropic AnisotropicModel"):
        fitting.predict_from_measured(fitting.AnisotropicModel(len(SCALES), isotropic=True), theta[:6], data, [32.0])


@pytest.mark.wrong_types
def test_law_from_differences_refuses_a_model_or_theta_of_another_type():
    """A law model in place of the per-scale one, a θ of strings: the library's own error (the annotation's check
    answers first where jaxtyping's runtime checks are on)."""
    data = dataset(SCALES)
    truths = [true_difference(mu) for mu in SCALES[1:]]
    model, theta, entries = fitting.AnisotropicModel(len(SCALES)), _per_scale_theta(truths), _entries(truths)
    with pytest.raises(InvalidInputError, match="per-scale fitting.AnisotropicModel .* got AnisotropicLawModel"):
        fitting.law_from_differences(MODEL, theta_of(), entries, data)
    with pytest.raises(InvalidInputError, match="theta must be the model's 18 finite coordinates"):
        fitting.law_from_differences(model, ["a"] * 18, entries, data)
    assert theta.shape == (18,)


def _components(differences):
    """The xx, xy, yy of each 2 × 2 matrix, flattened (FitResult.differences_covariance's order)."""
    return np.concatenate([[d[0, 0], d[0, 1], d[1, 1]] for d in differences])


def _correlated(truths, rel=1e-3, rho=0.6):
    """A covariance of the components of ``truths`` with correlations ρ^|i − j| and std ``rel`` × each scale's
    largest entry, and the entries (FitResult.covariance_differences) of ``values`` with its std."""
    std = np.repeat([rel * abs(d).max() for d in truths], 3)
    i = np.arange(std.size)
    return rho ** np.abs(i[:, None] - i[None, :]) * np.outer(std, std)


def _with_std(values, covariance):
    std = np.sqrt(np.diag(covariance)).reshape(-1, 3)
    out = []
    for mu, v, s in zip(SCALES[1:], values.reshape(-1, 3), std):
        out.append(
            {
                "mu0": SCALES[0],
                "mu": mu,
                "value": [[v[0], v[1]], [v[1], v[2]]],
                "std": [[s[0], s[1]], [s[1], s[2]]],
            }
        )
    return out


def test_with_the_joint_covariance_the_laws_chi2_is_the_generalised_one_and_a_calibrated_test():
    """ΔΣ_k of a known width law plus noise drawn from a covariance with correlations 0.6^|i−j| between the
    components: with ``covariance=`` the law's χ² equals rᵀ C⁻¹ r written by hand at the fitted law (r its ΔΣ
    minus the data), is at most that of the true law (an optimum), ``p_value`` is SciPy's χ²(5) survival function
    of it, and over 24 draws the p-values are uniform (Kolmogorov–Smirnov p > 1e-3; their χ² mean within 3
    standard errors of 5). Without the covariance χ² is the diagonal one and p_value None."""
    from scipy import stats

    data = dataset(SCALES)
    truths = [true_difference(mu) for mu in SCALES[1:]]
    model, theta = fitting.AnisotropicModel(len(SCALES)), _per_scale_theta(truths)
    covariance = _correlated(truths)
    root = np.linalg.cholesky(covariance)
    rng = np.random.default_rng(7)
    chi2, p = [], []
    for draw in range(24):
        values = _components(truths) + root @ rng.standard_normal(12)
        law = fitting.law_from_differences(model, theta, _with_std(values, covariance), data, covariance=covariance)
        assert law.correlated and law.dof == 5 and law.converged
        fitted = _components(np.asarray(law.model.covariance_differences(law.theta, jnp.asarray(SCALES)))[1:])
        r = fitted - values
        assert law.chi2 == pytest.approx(r @ np.linalg.solve(covariance, r), rel=1e-8)
        z = np.linalg.solve(root, values - _components(truths))
        assert law.chi2 <= z @ z * (1 + 1e-9)
        assert law.p_value == pytest.approx(stats.chi2.sf(law.chi2, 5), rel=1e-12)
        chi2.append(law.chi2)
        p.append(law.p_value)
        if draw == 0:
            shown = r"LawFromDifferences\(Width law on 5 scales, χ²/dof = .*/5, p = .*, φ = .*\)"
            assert re.fullmatch(shown, repr(law))
            assert law.to_json()["p_value"] == law.p_value
            diagonal = fitting.law_from_differences(model, theta, _with_std(values, covariance), data)
            assert not diagonal.correlated and diagonal.p_value is None and diagonal.inadequate_because() is None
    assert stats.kstest(p, "uniform").pvalue > 1e-3
    assert abs(np.mean(chi2) - 5) < 3 * math.sqrt(2 * 5 / len(chi2))


def test_a_law_the_differences_reject_makes_the_prediction_inadequate():
    """ΔΣ_k that no width law makes (the third scale's change halved: not monotone in μ) with errors of 1e-3: with
    the joint covariance the law is rejected — ``inadequate_because`` names the generalised χ² and p — and the
    exact ones are not; predict_from_measured carries the covariance through (the law's p in its repr)."""
    data = dataset(SCALES)
    truths = [true_difference(mu) for mu in SCALES[1:]]
    model, theta = fitting.AnisotropicModel(len(SCALES)), _per_scale_theta(truths)
    covariance = _correlated(truths)
    exact = fitting.law_from_differences(
        model, theta, _with_std(_components(truths), covariance), data, covariance=covariance
    )
    assert exact.inadequate_because() is None and exact.p_value > 0.99
    bent = [t * f for t, f in zip(truths, (1.0, 1.0, 0.5, 1.0))]
    law = fitting.law_from_differences(
        model, theta, _with_std(_components(bent), covariance), data, covariance=covariance
    )
    assert re.fullmatch(
        r"the width law fitted to the per-scale ΔΣ estimates does not describe them \(generalised χ²/dof = .*/5, "
        r"p (= .*|< 1e-300) < 0.001\): predictions beyond the measured scales extrapolate through it",
        law.inadequate_because() or "",
    )
    assert law.p_text == ("p < 1e-300" if law.p_value == 0 else f"p = {law.p_value:.2g}")
    assert (
        exact.p_text == f"p = {exact.p_value:.2g}"
        and fitting.law_from_differences(model, theta, _with_std(_components(truths), covariance), data).p_text is None
    )
    out = fitting.predict_from_measured(
        model,
        theta,
        data,
        [32.0],
        base="measured",
        differences=_with_std(_components(truths), covariance),
        differences_covariance=covariance,
    )
    assert out.law is not None and out.law.correlated and "p = " in repr(out.law)


def test_the_generalised_chi2_keeps_components_of_any_units_and_reads_fit_json():
    """Independent components whose standard errors differ by 10⁶ (the first scale's measured far better): every one
    is kept (dof 5, χ² equal to the diagonal fit's), as the cut is made on the correlation matrix; the covariance as
    fit.json holds it — nested lists, null where an entry has no std — and one off by rounding from symmetric give
    the same law as the array."""
    data = dataset(SCALES)
    truths = [true_difference(mu) for mu in SCALES[1:]]
    model, theta = fitting.AnisotropicModel(len(SCALES)), _per_scale_theta(truths)
    std = np.repeat([1e-9, 1e-3, 1e-3, 1e-3], 3) * abs(truths[-1]).max()
    covariance = np.diag(std**2)
    values = _components(truths) + np.random.default_rng(1).standard_normal(12) * std
    entries = _with_std(values, covariance)
    law = fitting.law_from_differences(model, theta, entries, data, covariance=covariance)
    diagonal = fitting.law_from_differences(model, theta, entries, data)
    assert law.dof == diagonal.dof == 5 and law.chi2 == pytest.approx(diagonal.chi2, rel=1e-6)
    covariance = _correlated(truths)
    entries = _with_std(_components(truths) * 1.001, covariance)
    want = fitting.law_from_differences(model, theta, entries, data, covariance=covariance)
    as_json = [[float(x) for x in row] for row in covariance]
    as_json[0][5] = as_json[0][5] * (1 + 1e-13)  # J Cov Jᵀ is symmetric to rounding only
    entries[1]["std"][0][1] = entries[1]["std"][1][0] = None  # an entry without std: its row and column null
    as_json[4] = [None] * 12
    for row in as_json:
        row[4] = None
    got = fitting.law_from_differences(model, theta, entries, data, covariance=as_json)
    assert got.dof == want.dof - 1 and got.correlated and got.p_value is not None


def test_law_from_differences_refuses_a_covariance_that_is_not_the_differences():
    """A covariance of another shape, asymmetric, not finite over the determined entries, whose diagonal is not their
    squared std, or not positive semi-definite: the library's error naming what to give."""
    data = dataset(SCALES)
    truths = [true_difference(mu) for mu in SCALES[1:]]
    model, theta = fitting.AnisotropicModel(len(SCALES)), _per_scale_theta(truths)
    covariance = _correlated(truths)
    entries = _with_std(_components(truths), covariance)

    def refused(c, match):
        with pytest.raises(InvalidInputError, match=match):
            fitting.law_from_differences(model, theta, entries, data, covariance=c)

    refused(covariance[:-1, :-1], "12 × 12 .* got shape \\(11, 11\\)")
    asymmetric = covariance.copy()
    asymmetric[0, 1] *= 2
    refused(asymmetric, "finite and symmetric")
    refused(np.where(np.eye(12, dtype=bool), np.nan, covariance), "finite and symmetric")
    refused(2 * covariance, "diagonal is not the square of differences' standard errors")
    s = np.sqrt(np.diag(covariance))
    refused(np.outer(s, s) * (np.eye(12) * 2 - 1), "not positive semi-definite")
    with pytest.raises(InvalidInputError, match="differences_covariance= are for the per-scale AnisotropicModel"):
        fitting.predict_from_measured(MODEL, theta_of(), data, [32.0], differences_covariance=covariance)
