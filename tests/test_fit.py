"""Inverse fitting (fitting/): data validation, parameter recovery, Laplace covariance against
SciPy, identifiability, emcee checkpoint/resume, the `brdfscale fit` command.

Recovery tests simulate from the parametric forward model (fitting.simulate) with known
truth and Gaussian noise; the estimates must lie within 4 stated standard deviations of the
truth (a 4σ miss has probability 6e-5 per quantity if the stated uncertainties are right).
The calibrated coverage of the 68 %/90 % intervals is measured by experiments/calibration_fit.py.
"""

import dataclasses
import json
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize
from hypothesis import given, settings, strategies as st

from brdfscale import fitting, InvalidInputError, LobeImage, MeasurementSet, stats
from brdfscale._cli import main
from tests.helpers import parametric_dataset, SCALES, TRUTHS


# -- data ---------------------------------------------------------------------------------


def _image(mu, sigma=True, mask=None, values=None):
    v = np.ones((4, 4)) if values is None else values
    return LobeImage(
        mu=mu,
        incident=np.array([0.0, 0.0, 1.0]),
        extent=0.1,
        values=v,
        sigma=np.full(v.shape, 0.1) if sigma else None,
        mask=mask,
    )


def test_dataset_refuses_what_cannot_be_fitted():
    with pytest.raises(InvalidInputError, match="at 2 or more distinct scales"):
        fitting.Dataset.from_measurements(MeasurementSet((_image(1.0), _image(1.0))))
    with pytest.raises(InvalidInputError, match="default_sigma"):
        fitting.Dataset.from_measurements(MeasurementSet((_image(1.0), _image(2.0, sigma=False))))
    with pytest.raises(InvalidInputError, match="no valid pixel"):
        fitting.Dataset.from_measurements(MeasurementSet((_image(1.0), _image(2.0, mask=np.zeros((4, 4), bool)))))


@pytest.mark.wrong_types
def test_dataset_names_what_is_not_a_measurement_set():
    with pytest.raises(InvalidInputError, match="MeasurementSet"):
        fitting.Dataset.from_measurements([_image(1.0)])


def test_dataset_whitening_masks_and_luminance():
    rgb = np.stack([np.full((4, 4), c) for c in (1.0, 2.0, 3.0)], axis=-1)
    mask = np.ones((4, 4), bool)
    mask[0, 0] = False
    d = fitting.Dataset.from_measurements(
        MeasurementSet(
            (
                _image(1.0, mask=mask),
                LobeImage(
                    mu=2.0, incident=np.array([0.0, 0.0, 1.0]), extent=0.1, values=rgb, sigma=np.full(rgb.shape, 0.1)
                ),
            )
        )
    )
    assert d.n_data == 31
    np.testing.assert_allclose(d.values[1], 0.2126 + 2 * 0.7152 + 3 * 0.0722)  # Rec. 709 luminance
    np.testing.assert_allclose(d.weight[1], 1 / (0.1 * np.sqrt(0.2126**2 + 0.7152**2 + 0.0722**2)))
    r = d.whitened(jnp.zeros_like(d.values))
    assert r[0] == 0 and r[1] == pytest.approx(-10.0)


@pytest.mark.parametrize("radial", [True, False])
def test_reduced_residuals_give_the_per_pixel_chi2_and_fisher_matrix(radial):
    """Least squares on the distinct points (Dataset.points) is exact: at any θ, ‖r‖² plus the
    within-group scatter equals the per-pixel χ², and JᵀJ (the Laplace precision) is the same."""
    rng = np.random.default_rng(0)
    model = fitting.ParametricModel()
    mset = fitting.simulate(model, TRUTHS[0], (0.5, 2.0, 8.0), size=9, extent=0.3, noise=0.05, replicates=2, seed=1)
    images = list(mset.images)
    mask = rng.random((9, 9)) > 0.2
    images[1] = LobeImage(
        mu=images[1].mu,
        incident=images[1].incident,
        extent=0.3,
        values=images[1].values,
        sigma=images[1].sigma * rng.uniform(0.5, 2.0, (9, 9)),
        mask=mask,
    )
    data = fitting.Dataset.from_measurements(MeasurementSet(tuple(images)))
    reduced = data.points(radial)
    # replicates merge (81 offsets per scale); radially also mirror pixels (15 radii on a 9 × 9 grid)
    i, j = np.meshgrid(np.arange(-4, 5), np.arange(-4, 5))
    assert np.count_nonzero(reduced.weight) == 3 * (np.unique(i**2 + j**2).size if radial else 81)
    problem = eqx.tree_at(lambda p: p.points, fitting.Problem(model, data), reduced)

    @jax.jit
    def both(theta):
        def per_pixel(t):
            return data.whitened(model.predict(t, data))

        return (
            per_pixel(theta),
            jax.jacfwd(per_pixel)(theta),
            problem.chi2(theta),
            jax.jacfwd(problem.residuals)(theta),
        )

    for _ in range(3):
        full, J_full, chi2, J = both(jnp.asarray(model.initial(data) + rng.normal(0, 0.3, 5)))
        assert float(chi2) == pytest.approx(float(full @ full), rel=1e-12)
        np.testing.assert_allclose(J.T @ J, J_full.T @ J_full, rtol=1e-10)


def test_models_refuse_bad_configurations():
    with pytest.raises(InvalidInputError, match="lobe must be"):
        fitting.ParametricModel("phong")
    with pytest.raises(InvalidInputError, match="cannot fix unknown"):
        fitting.ParametricModel(fixed={"roughness": 1.0})
    with pytest.raises(InvalidInputError, match="every parameter is fixed"):
        fitting.ParametricModel(fixed=dict(TRUTHS[0]))
    data = fitting.Dataset.from_measurements(MeasurementSet((_image(1.0), _image(2.0))))
    with pytest.raises(InvalidInputError, match="solver must be"):
        fitting.fit(fitting.ParametricModel(), data, solver="newton")


# -- recovery ------------------------------------------------------------------------------


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
@pytest.mark.parametrize("truth", TRUTHS)
@pytest.mark.parametrize("noise", [0.003, 0.03])
def test_parametric_recovery_within_stated_uncertainty(truth, noise):
    model = fitting.ParametricModel()
    _, data = parametric_dataset(model, truth, noise, seed=hash((noise, truth["amplitude"])) % 1000)
    res = fitting.fit(model, data, starts=3)
    assert res.status == "converged" and res.determined and not res.at_bounds
    assert 0.6 < res.chi2 / res.dof < 1.4
    for name, value in truth.items():
        assert abs(res.estimates[name] - value) < 4 * res.std[name], (name, res.estimates[name], value, res.std[name])


def test_laplace_covariance_and_optimum_agree_with_scipy():
    """SciPy's least_squares (finite-difference Jacobian) finds the same optimum; its
    Jacobian gives the same covariance (JᵀJ)⁻¹ as the jacfwd Laplace approximation."""
    model = fitting.ParametricModel()
    _, data = parametric_dataset(model, TRUTHS[0], 0.01, seed=5)
    res = fitting.fit(model, data, starts=2)
    problem = fitting.Problem(model, data)
    residuals = eqx.filter_jit(fitting._solve._residuals)
    f = lambda t: np.asarray(residuals(jnp.asarray(t), problem))  # noqa: E731
    ref = scipy.optimize.least_squares(f, model.initial(data), method="trf", x_scale="jac", xtol=1e-12, ftol=1e-12)
    assert ref.cost * 2 + float(problem.points.chi2_offset) == pytest.approx(res.chi2, rel=1e-7)
    np.testing.assert_allclose(ref.x, res.theta, atol=1e-4 * np.sqrt(np.diag(res.covariance)).max() * 100)
    cov_scipy = np.linalg.inv(ref.jac.T @ ref.jac)
    np.testing.assert_allclose(res.covariance, cov_scipy, rtol=2e-3)


@pytest.mark.slow  # 9 s on 2 cores: the default suite measured 402 s at ff4fa2c (budget 360)
def test_an_optimistix_solver_object_is_accepted_where_a_name_is():
    """``solver=optx.LevenbergMarquardt(...)`` is used as given: with the settings the name
    "lm" stands for, the same optimum and covariance; the result records the class name; a
    non-solver object is refused with a message naming both forms; fit_many takes it too."""
    import optimistix as optx

    model = fitting.ParametricModel()
    _, data = parametric_dataset(model, TRUTHS[0], 0.01, seed=5, size=12)
    by_name = fitting.fit(model, data, starts=2)
    by_object = fitting.fit(
        model, data, starts=2, solver=optx.LevenbergMarquardt(rtol=1e-6, atol=1e-6, norm=optx.rms_norm)
    )
    assert by_name.solver == "lm" and by_object.solver == "LevenbergMarquardt"
    assert by_object.status == "converged" and by_object.chi2 == pytest.approx(by_name.chi2, rel=1e-12)
    np.testing.assert_allclose(by_object.theta, by_name.theta, rtol=0, atol=1e-10)
    np.testing.assert_allclose(by_object.covariance, by_name.covariance, rtol=1e-8)
    (many,) = fitting.fit_many(
        model, [data], starts=2, solver=optx.LevenbergMarquardt(rtol=1e-6, atol=1e-6, norm=optx.rms_norm)
    )
    assert many.solver == "LevenbergMarquardt" and many.chi2 == pytest.approx(by_name.chi2, rel=1e-6)
    with pytest.raises(InvalidInputError, match="optimistix least-squares solver or minimiser object"):
        fitting.fit(model, data, solver=object())


@pytest.mark.slow  # 10 s on 2 cores: the default suite measured 372 s in a clean clone at fc7a33e (budget 360)
def test_normal_equation_steps_reach_the_optimum_of_qr_steps():
    """``solver="lm_normal"`` (Levenberg–Marquardt whose steps solve the normal equations by
    Cholesky) ends at the optimum and covariance of the default QR steps on a well-conditioned
    problem, and records its name."""
    model = fitting.ParametricModel()
    _, data = parametric_dataset(model, TRUTHS[0], 0.01, seed=5, size=12)
    qr = fitting.fit(model, data, starts=2)
    normal = fitting.fit(model, data, starts=2, solver="lm_normal")
    assert normal.solver == "lm_normal" and normal.status == "converged"
    assert normal.chi2 == pytest.approx(qr.chi2, rel=1e-9)
    np.testing.assert_allclose(normal.theta, qr.theta, rtol=0, atol=1e-6)
    np.testing.assert_allclose(normal.covariance, qr.covariance, rtol=1e-5)


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
@pytest.mark.parametrize("solver, max_steps", [("lm", 512), ("lm", 2), ("bfgs", 512)])
def test_solve_returns_chi2_and_jacobian_at_the_optimum(solver, max_steps):
    """The Gauss–Newton family hands back the linearisation its state holds at θ̂, other
    solvers evaluate it; either way they are r(θ̂) and jacfwd(r)(θ̂) — also when the solve
    stops at max_steps."""
    model = fitting.ParametricModel()
    _, data = parametric_dataset(model, TRUTHS[0], 0.01, seed=5, size=12)
    problem = fitting.Problem(model, data)
    y0 = jnp.asarray(np.clip(model.initial(data), *model.bounds(data)))
    theta, code, steps, chi2, jac = fitting._solve.solve(
        problem, y0, fitting._solve.make_solver(solver, 1e-6, 1e-6), max_steps
    )
    assert (int(code) == 0) == (max_steps > 2)
    assert float(chi2) == pytest.approx(float(problem.chi2(theta)), rel=1e-12)
    reference = jax.jacfwd(problem.residuals)(theta)
    np.testing.assert_allclose(
        np.asarray(jac), np.asarray(reference), rtol=0, atol=1e-12 * float(jnp.max(jnp.abs(reference)))
    )


@settings(max_examples=25, deadline=None)
@given(log_params=st.lists(st.floats(-4.0, 2.0), min_size=3, max_size=3), window=st.sampled_from(["box", "gaussian"]))
def test_scale_laws_narrow_with_mu_so_coarser_lobes_exist(log_params, window):
    """ParametricModel evolves without the run-time existence check: that rests on both laws'
    slope widths decreasing with μ (then S(W, μ0)/S(W, μ) ≤ 1 for μ > μ0), checked here over
    wide parameter ranges and six decades of μ."""
    mu = jnp.logspace(-3, 3, 400)
    a, b, c = (math.exp(x) for x in log_params)
    surface = stats.GaussianSurface(stats.GaussianCorrelation(a, b), window=window)
    variance = jax.vmap(lambda m: surface.spectrum.windowed_slope_variances(m, window)[0])(mu)
    assert np.all(np.diff(np.asarray(variance)) <= 1e-14 * float(variance[0]))
    width = jax.vmap(stats.WidthLaw(a, b, c))(mu)
    assert np.all(np.diff(np.asarray(width)) <= 0)


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_unchecked_predictions_are_the_checked_evolution():
    model = fitting.ParametricModel(law="gaussian_surface")
    _, data = parametric_dataset(
        model, dict(amplitude=0.8, alpha_lobe=0.05, rms_height=0.06, correlation_length=1.5), 0.01, seed=2, size=8
    )
    theta = jnp.asarray(model.initial(data))
    points = jnp.asarray(np.random.default_rng(0).normal(scale=0.1, size=(len(SCALES), 7, 2)))
    predicted = model.predict_points(theta, data.scales, points)
    for k, mu in enumerate(np.asarray(data.scales)[1:], start=1):
        reference = model.evolved(theta, data.scales[0], mu).density(points[k])
        np.testing.assert_allclose(np.asarray(predicted[k]), np.asarray(reference), rtol=1e-13)


# -- identifiability -----------------------------------------------------------------------


@pytest.mark.slow  # 7 s on 2 cores: the default suite measured 402 s at ff4fa2c (budget 360)
def test_two_scales_name_the_undetermined_law_combinations():
    """Two scales fix the base lobe and one ratio S(μ0)/S(μ1): the three width-law
    parameters cannot all be determined; the fit must say so instead of quoting errors."""
    model = fitting.ParametricModel()
    _, data = parametric_dataset(model, TRUTHS[0], 0.01, seed=3, scales=(0.5, 4.0))
    res = fitting.fit(model, data, starts=2)
    assert len(res.undetermined) >= 2
    assert all("log" in u["combination"] for u in res.undetermined)
    assert res.std["alpha_lobe"] is not None and res.std["amplitude"] is not None
    assert res.std["mu_c"] is None and res.quantiles["mu_c"] is None
    # the determined ones are still right
    for name in ("alpha_lobe", "amplitude"):
        assert abs(res.estimates[name] - TRUTHS[0][name]) < 4 * res.std[name]
    assert any("S(W, ∞) = 1" in note for note in res.notes)
    # what the data do determine is reported with its uncertainty: the ratio S(W, μ0)/S(W, μ1)
    # at three frequencies (against the truth's ratio), and the determined Fisher directions
    W = fitting.ratio_frequencies(data)
    true_ratios = np.asarray(
        model.relative_statistics(jnp.asarray(model.theta_from(TRUTHS[0])), jnp.asarray(W), data.scales)
    )[1]
    assert len(res.ratios) == 3 and all(r["std"] is not None and r["mu"] == 4.0 for r in res.ratios.values())
    for (name, r), truth in zip(res.ratios.items(), true_ratios):
        assert f"@ |W|={r['W']:.4g}" in name and abs(r["estimate"] - truth) < 4 * r["std"], (name, r, truth)
    assert len(res.combinations) + len(res.undetermined) == len(model.names)
    assert all(c["std"] <= 1.0 for c in res.combinations)
    doc = res.to_json()
    assert doc["ratios"] == res.ratios and doc["identifiability"]["determined_combinations"] == res.combinations
    # the report gives an undetermined parameter its prior range, never an interval
    rows = fitting.summarise(fitting.Problem(model, data), res, None, None)
    assert rows["mu_c"]["quantiles_5_50_95"] is None and rows["mu_c"]["std"] is None
    lo, hi = rows["mu_c"]["prior_range"]
    assert lo < res.estimates["mu_c"] < hi


# -- sampling ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_problem():
    model = fitting.ParametricModel()  # the recovery tests' layout: their compiled solve is reused
    _, data = parametric_dataset(model, TRUTHS[1], 0.02, seed=4)
    return fitting.Problem(model, data), fitting.fit(model, data, starts=1)


def test_interrupted_sampling_resumes_bit_identically(small_problem, tmp_path):
    problem, res = small_problem
    full = fitting.sample(
        problem, res, sampler="emcee", walkers=16, steps=90, chunk=30, checkpoint=tmp_path / "a.h5", progress=False
    )

    calls = {"n": 0}
    original = fitting._sample_emcee._batched_log_density

    def interrupting(zs, prob):
        calls["n"] += 1
        # initial walkers + 45 steps (2 calls each, one per half of every ensemble at once): inside chunk 2
        if calls["n"] == 1 + 2 * 45:
            raise KeyboardInterrupt
        return original(zs, prob)

    fitting._sample_emcee._batched_log_density = interrupting
    try:
        with pytest.raises(KeyboardInterrupt):
            fitting.sample(
                problem,
                res,
                sampler="emcee",
                walkers=16,
                steps=90,
                chunk=30,
                checkpoint=tmp_path / "b.h5",
                progress=False,
            )
    finally:
        fitting._sample_emcee._batched_log_density = original
    import h5py

    with h5py.File(tmp_path / "b.h5") as f:
        assert int(f.attrs["steps_done"]) == 30
    resumed = fitting.sample(
        problem, res, sampler="emcee", walkers=16, steps=90, chunk=30, checkpoint=tmp_path / "b.h5", progress=False
    )
    assert np.array_equal(full.chain, resumed.chain) and np.array_equal(full.log_prob, resumed.log_prob)
    kw = dict(sampler="emcee", walkers=16, steps=90, chunk=30, checkpoint=tmp_path / "b.h5", progress=False)
    # another run's checkpoint is not continued: other walkers, seed, moves, chains, sampler or data
    for other in ({"walkers": 18}, {"seed": 1}, {"moves": "de"}, {"chains": 2}):
        with pytest.raises(InvalidInputError, match="different run"):
            fitting.sample(problem, res, **{**kw, **other})
    other_data = fitting.Problem(problem.model, parametric_dataset(problem.model, TRUTHS[1], 0.02, seed=5)[1])
    with pytest.raises(InvalidInputError, match="different run"):
        fitting.sample(other_data, res, **kw)
    # a refit that differs in the last bits still resumes the run: the state comes from the file
    refit = dataclasses.replace(res, theta=res.theta * (1 + 1e-15))
    assert np.array_equal(fitting.sample(problem, refit, **kw).chain, full.chain)
    with pytest.raises(InvalidInputError, match="different run"):
        fitting.sample(problem, res, sampler="nuts", steps=90, chunk=30, checkpoint=tmp_path / "b.h5", progress=False)
    # a checkpoint of the earlier layout (one ensemble sampled in θ) is refused, not continued
    with h5py.File(tmp_path / "b.h5", "r+") as f:
        del f.attrs["format"]
        f.attrs["signature"] = json.dumps({"names": list(problem.model.names), "walkers": 16})
    with pytest.raises(InvalidInputError, match="earlier version of fitting.sample"):
        fitting.sample(problem, res, **kw)


def test_posterior_matches_laplace_on_a_well_determined_problem(small_problem):
    """Nearly linear problem: the emcee posterior std agrees with the Laplace std (15 %)."""
    problem, res = small_problem
    s = fitting.sample(problem, res, sampler="emcee", walkers=16, steps=1500, chunk=1500, progress=False, seed=1)
    np.testing.assert_allclose(s.samples.std(axis=0), np.sqrt(np.diag(res.covariance)), rtol=0.15)
    d = s.diagnostics()
    assert set(d["autocorrelation_time"]) == set(problem.model.names)
    assert all(np.isfinite(v) and v > 0 for v in d["effective_sample_size"].values())
    assert 0.2 < d["acceptance_fraction"] < 0.9


# -- command line --------------------------------------------------------------------------


@pytest.mark.slow  # 9 s on 2 cores: the default suite measured 372 s in a clean clone at fc7a33e (budget 360)
def test_fit_command_writes_report_and_refuses_to_overwrite(tmp_path, capsys):
    from brdfscale import exr

    model = fitting.ParametricModel()
    mset, _ = parametric_dataset(model, TRUTHS[1], 0.02, seed=9)
    path = tmp_path / "m.exr"
    exr.write_measurements(str(path), mset)
    out = tmp_path / "out"
    argv = [
        "fit",
        str(path),
        "--out",
        str(out),
        "--model",  # the simulated truth is the parametric model's
        "parametric",
        "--steps",
        "200",
        "--sampler",
        "emcee",
        "--walkers",
        "16",
        "--starts",
        "2",
        "--no-progress",
    ]
    code = main(argv)
    doc = json.loads((out / "fit.json").read_text())
    # the model generated the data, so the outcome is ok or — 200 emcee steps — the sampler not converged (exit 6,
    # after the complete report, with one line naming the failed criterion)
    assert (doc["outcome"]["status"], code) in (("ok", 0), ("not_converged", 6))
    if code == 6:
        assert "brdfscale fit: not converged: sampler not converged: " in capsys.readouterr().err
    for name in TRUTHS[1]:
        row = doc["parameters"][name]
        assert row["determined"] and len(row["quantiles_5_50_95"]) == 3 and row["truth"] == TRUTHS[1][name]
    assert doc["mcmc"]["steps"] == 200 and "identifiability" in doc
    for fig in ("data_vs_fit.png", "statistics.png", "corner.png"):
        assert (out / fig).read_bytes()[:4] == b"\x89PNG"
    assert exr.read_measurements(str(out / "evolved_lobes.exr")).scales.tolist() == list(SCALES)
    # the chains as ArviZ InferenceData in NetCDF beside fit.json, and ArviZ's figures in fit.json
    az = pytest.importorskip("arviz")
    posterior = az.from_netcdf(str(out / "posterior.nc"))
    # one ArviZ chain per independent emcee ensemble, its draws the 16 walkers' kept steps one after another
    assert doc["posterior"] == str(out / "posterior.nc") and doc["mcmc"]["walkers"] == 16
    assert posterior.posterior.sizes["chain"] == doc["mcmc"]["chains"]
    assert posterior.posterior.sizes["draw"] == 16 * (200 - doc["mcmc"]["burn_in"])
    assert "amplitude" in posterior.posterior.data_vars
    assert {"ess_bulk", "ess_tail", "r_hat", "mcse_mean"} <= set(doc["mcmc"]["summary"]["amplitude"])
    assert doc["mcmc"]["status"].startswith(("converged", "not converged"))
    assert main(argv) == 2
    assert "--force" in capsys.readouterr().err


# -- bad input: clear errors, nothing of the user's overwritten ------------------------------


def test_write_report_checks_every_file_before_writing(small_problem, tmp_path):
    """A user's figure in out_dir is not overwritten even without a fit.json there: every file
    the report would write is checked before the first is written, and the error lists them."""
    from brdfscale import MeasurementFileError

    problem, res = small_problem
    out = tmp_path / "out"
    out.mkdir()
    (out / "corner.png").write_text("mine")
    (out / "statistics.png").write_text("mine too")
    with pytest.raises(InvalidInputError, match=r"statistics\.png, corner\.png.*overwrite=True"):
        fitting.write_report(out, problem, res)
    assert sorted(p.name for p in out.iterdir()) == ["corner.png", "statistics.png"]
    assert (out / "corner.png").read_text() == "mine"
    not_a_dir = tmp_path / "file"
    not_a_dir.write_text("x")
    with pytest.raises(MeasurementFileError, match="not a directory"):
        fitting.write_report(not_a_dir, problem, res)
    with pytest.raises(InvalidInputError, match="truth"):
        fitting.write_report(tmp_path / "new", problem, res, truth={"amplitude": "big"})
    assert not (tmp_path / "new").exists()
    doc = fitting.write_report(out, problem, res, overwrite=True)
    assert (out / "corner.png").read_bytes()[:4] == b"\x89PNG" and doc["figures"][-1] == str(out / "corner.png")
    # no temporary file left; the run's lock file stays (removing it would race with a next run)
    assert [p.name for p in out.iterdir() if p.name.startswith(".")] == [".brdfscale.lock"]
    # overwritten by a report without figures: the earlier figures go with it, a user's file stays
    (out / "notes.txt").write_text("mine")
    doc = fitting.write_report(out, problem, res, overwrite=True, figures=False)
    assert doc["figures"] == [] and not list(out.glob("*.png")) and (out / "notes.txt").read_text() == "mine"
    assert json.loads((out / "fit.json").read_text())["figures"] == [] and doc["mcmc"] is None
    # a fit that was to be sampled and was not says why (brdfscale fit's inadequate fits)
    doc = fitting.write_report(out, problem, res, overwrite=True, figures=False, not_sampled="the reason")
    assert json.loads((out / "fit.json").read_text())["mcmc"] == {"status": "not sampled: the reason"}
    with pytest.raises(InvalidInputError, match="not_sampled must be None or"):
        fitting.write_report(out, problem, res, overwrite=True, figures=False, not_sampled="")
    # a problem found after the report (brdfscale fit --predict's rejected law) joins fit.json's outcome
    before = json.loads((out / "fit.json").read_text())
    ok = {**doc, "outcome": {**doc["outcome"], "status": "ok", "reason": "the fit is adequate"}}
    amended = fitting.record_problem(out, ok, "the law is rejected (test)")
    written = json.loads((out / "fit.json").read_text())
    assert written == amended and {k: v for k, v in written.items() if k != "outcome"} == {
        k: v for k, v in before.items() if k != "outcome"
    }
    assert written["outcome"]["problems"] == [*before["outcome"].get("problems", []), "the law is rejected (test)"]
    assert (written["outcome"]["status"], written["outcome"]["reason"]) == ("inadequate", "the law is rejected (test)")
    # ranked as assess ranks its checks: adequacy before convergence and identifiability, after resolution
    base = amended["outcome"]
    narrow = [{**row, "width_px": 0.5, "faint": False} for row in base["scales"]]
    for status, scales, kept in [
        ("not_converged", base["scales"], False),
        ("undetermined", base["scales"], False),  # identifiability: the rows' lobes are resolved
        ("undetermined", narrow, True),  # resolution: a lobe narrower than min_lobe_pixels
        ("inadequate", base["scales"], True),
    ]:
        earlier = {**amended, "outcome": {**base, "status": status, "reason": "earlier", "scales": scales}}
        now = fitting.record_problem(out, earlier, "x")
        assert (now["outcome"]["status"], now["outcome"]["reason"]) == (
            (status, "earlier") if kept else ("inadequate", "x")
        )
        assert now["outcome"]["problems"][-1] == "x" and json.loads((out / "fit.json").read_text()) == now
    assert all(row["width_px"] >= base["thresholds"]["min_lobe_pixels"] for row in base["scales"])
    with pytest.raises(InvalidInputError, match="needs the report write_report returned"):
        fitting.record_problem(out, {"figures": []}, "x")
    with pytest.raises(InvalidInputError, match="non-empty line"):
        fitting.record_problem(out, doc, " ")
    with pytest.raises(InvalidInputError, match="needs the report write_report returned"):
        fitting.record_problem(out, {**doc, "outcome": {**doc["outcome"], "problems": "one"}}, "x")


def test_sample_checkpoint_paths_and_first_chunk_resume(small_problem, tmp_path):
    """The checkpoint's temporary file cannot collide with a user's file; paths that are not a
    checkpoint give MeasurementFileError naming them; a run interrupted before its first chunk
    completed resumes."""
    import h5py

    from brdfscale import MeasurementFileError

    problem, res = small_problem
    kw = dict(sampler="emcee", walkers=10, steps=3, chunk=1, progress=False)
    path = tmp_path / "c.h5"
    (tmp_path / "c.h5.tmp").write_text("user's file")
    fitting.sample(problem, res, checkpoint=path, **kw)
    assert (tmp_path / "c.h5.tmp").read_text() == "user's file"
    assert sorted(p.name for p in tmp_path.iterdir()) == [".c.h5.brdfscale.lock", "c.h5", "c.h5.tmp"]  # + its lock
    (tmp_path / "text.h5").write_text("not HDF5")
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["x"] = 1
    for bad, match in [
        (tmp_path / "text.h5", "cannot be read as an HDF5 checkpoint"),
        (tmp_path / "other.h5", "is not an HDF5 checkpoint"),
        (tmp_path / "missing" / "c.h5", "does not exist"),
        (tmp_path, "is a directory"),
    ]:
        with pytest.raises(MeasurementFileError, match=match) as err:
            fitting.sample(problem, res, checkpoint=bad, **kw)
        assert str(bad) in str(err.value)
    assert (tmp_path / "text.h5").read_text() == "not HDF5"
    fitting.sample(problem, res, checkpoint=tmp_path / "text.h5", overwrite=True, **kw)  # asked: replaced
    # interrupted inside the first chunk: the checkpoint holds no step yet, and resumes
    original = fitting._sample_emcee._batched_log_density

    def interrupting(zs, prob):
        raise KeyboardInterrupt

    fitting._sample_emcee._batched_log_density = interrupting
    try:
        with pytest.raises(KeyboardInterrupt):
            fitting.sample(problem, res, checkpoint=tmp_path / "d.h5", **kw)
    finally:
        fitting._sample_emcee._batched_log_density = original
    resumed = fitting.sample(problem, res, checkpoint=tmp_path / "d.h5", **kw)
    assert np.array_equal(resumed.chain, fitting.sample(problem, res, checkpoint=path, **kw).chain)
    # a checkpoint longer than asked gives the first `steps` steps: the chain of that shorter run
    shorter = fitting.sample(problem, res, checkpoint=path, **{**kw, "steps": 2})
    assert np.array_equal(shorter.chain, resumed.chain[:2])


def test_inconsistent_or_out_of_range_arguments_are_refused(small_problem, tmp_path):
    problem, res = small_problem
    two = fitting.Dataset.from_measurements(MeasurementSet((_image(1.0), _image(2.0))))
    mset3 = MeasurementSet((_image(1.0), _image(2.0), _image(4.0)))
    three = fitting.Dataset.from_measurements(mset3)
    npm = fitting.NonParametricModel(three, base_nodes=3, n_knots=2)
    with pytest.raises(InvalidInputError, match="built for a dataset with 3 scales, but the data have 2"):
        fitting.fit(npm, two)
    with pytest.raises(InvalidInputError, match="fit is the result for 5 coordinates"):
        fitting.sample(fitting.Problem(npm, three), res, progress=False)
    with pytest.raises(InvalidInputError, match="fit is the result for 5 coordinates"):
        fitting.write_report(tmp_path / "r", fitting.Problem(npm, three), res)
    assert not (tmp_path / "r").exists()
    with pytest.raises(InvalidInputError, match="grid_size must be an integer ≥ 8"):
        fitting.NonParametricModel(three, grid_size=4)
    model = fitting.ParametricModel()
    for kw, match in [
        (dict(spread=-1), "spread must be a finite number ≥ 0"),
        (dict(seed=-1), "seed must be an integer ≥ 0"),
        (dict(starts=True), "starts"),
        (dict(rtol=float("nan")), "rtol must be a finite"),
        (dict(rtol=0, atol=0), "not both be 0"),
        (dict(undetermined_std=0), "undetermined_std"),
    ]:
        with pytest.raises(InvalidInputError, match=match):
            fitting.fit(model, two, **kw)
    for kw, match in [
        (dict(sampler="emcee", walkers=4), "walkers must be an integer ≥ 10"),
        (dict(steps=1), "steps must be an integer ≥ 2"),
        (dict(seed=-1), "seed"),
    ]:
        with pytest.raises(InvalidInputError, match=match):
            fitting.sample(problem, res, progress=False, **kw)


@pytest.mark.wrong_types
def test_arguments_of_the_wrong_type_are_named(small_problem):
    problem, res = small_problem
    mset3 = MeasurementSet((_image(1.0), _image(2.0), _image(4.0)))
    with pytest.raises(InvalidInputError, match="Dataset.from_measurements"):
        fitting.Problem(fitting.ParametricModel(), mset3)
    with pytest.raises(InvalidInputError, match="Dataset.from_measurements"):
        fitting.NonParametricModel(mset3)
    # what is not a model is named, with every model the library has (the anisotropic ones first: the default)
    two_images = fitting.Dataset.from_measurements(MeasurementSet((_image(1.0), _image(2.0))))
    with pytest.raises(InvalidInputError, match=r"needs a fitting model \(fitting.AnisotropicModel, .* got str"):
        fitting.Problem("anisotropic", two_images)
    with pytest.raises(InvalidInputError, match=r"fit\(model, data\) needs a fitting model \(fitting.AnisotropicModel"):
        fitting.fit("anisotropic", two_images)
    two = fitting.Dataset.from_measurements(MeasurementSet((_image(1.0), _image(2.0))))
    for kw, match in [
        (dict(starts="a"), "starts must be an integer ≥ 1"),
        (dict(max_steps=2.5), "max_steps"),
    ]:
        with pytest.raises(InvalidInputError, match=match):
            fitting.fit(fitting.ParametricModel(), two, **kw)
    for kw, match in [
        (dict(chunk="10"), "chunk"),
        (dict(overwrite=1), "overwrite"),
    ]:
        with pytest.raises(InvalidInputError, match=match):
            fitting.sample(problem, res, progress=False, **kw)


def test_parameters_taken_a_log_of_must_be_positive():
    model = fitting.ParametricModel()
    for bad in (-1.0, 0.0, float("nan"), float("inf"), "wide"):
        with pytest.raises(InvalidInputError, match="parameter alpha_lobe must be a positive, finite number"):
            model.theta_from({**TRUTHS[0], "alpha_lobe": bad})
    with pytest.raises(InvalidInputError, match="fixed value of mu_c"):
        fitting.ParametricModel(fixed={"mu_c": -2.0})
    negative = fitting.Dataset.from_measurements(MeasurementSet((_image(1.0), _image(2.0, values=-np.ones((4, 4))))))
    with pytest.raises(InvalidInputError, match="no positive valid pixel"):
        fitting.fit(model, negative)


def test_nonparametric_regularisation_arguments_are_checked():
    data = fitting.Dataset.from_measurements(MeasurementSet((_image(1.0), _image(2.0))))
    default = fitting.NonParametricModel(data, base_nodes=3, n_knots=2)
    assert default.smoothness == 3.0 and default.smoothness_choice is None
    assert fitting.NonParametricModel(data, base_nodes=3, n_knots=2, regularisation=5.0).smoothness == 5.0
    assert fitting.NonParametricModel(data, base_nodes=3, n_knots=2, smoothness=5.0).smoothness == 5.0
    for bad in ("gvc", "l_curve", "discrepancy"):
        with pytest.raises(InvalidInputError, match="one of \\('auto', 'gcv'\\)"):
            fitting.NonParametricModel(data, regularisation=bad)
    with pytest.raises(InvalidInputError, match="not both"):
        fitting.NonParametricModel(data, regularisation=1.0, smoothness=1.0)
    with pytest.raises(InvalidInputError, match="regularisation must be a finite number ≥ 0"):
        fitting.NonParametricModel(data, regularisation=-1.0)
