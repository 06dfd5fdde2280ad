"""The solver ``"gauss_newton_edm"`` (fitting._gauss_newton, issue 31 item 8): line-searched
Gauss–Newton with the undetermined directions left out, stopped on the expected distance to the
minimum. Checked against what nobody here wrote: NumPy's least squares (linear problems, the
minimum-norm step for a rank-deficient one) and SciPy's ``least_squares`` (a nonlinear model), and
against the library's own Levenberg–Marquardt on the same problem; σ scaled by 60 decades; the
vmapped/mapped solve of ``fitting.fit_many`` against ``fitting.fit``."""

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
import scipy.optimize

from brdfscale import choices, fitting, InvalidInputError
from tests.helpers import Linear, linear_measurements, parametric_dataset, TRUTHS


jax.config.update("jax_enable_x64", True)

EDM_TOLERANCE = fitting._gauss_newton.EDM_TOLERANCE  # the package's private module, as tests/test_fit.py reads _solve
GaussNewtonEDM = fitting._gauss_newton.GaussNewtonEDM


def _design(model, data):
    """The whitened design matrix and data of a linear model: r(θ) = A θ − b."""
    problem = fitting.Problem(model, data)
    n = len(model.names)
    b = -np.asarray(problem.residuals(jnp.zeros(n)))
    A = np.asarray(jax.jacfwd(problem.residuals)(jnp.zeros(n)))
    return A, b


def test_linear_problem_lands_on_lstsq_in_one_step_and_stops():
    """A linear problem: the first (full, accepted) step is NumPy's lstsq solution; the EDM there is 0,
    so the solve stops on the next check — two steps, status converged."""
    model, data = Linear(), fitting.Dataset.from_measurements(linear_measurements(seed=4))
    A, b = _design(model, data)
    best = np.linalg.lstsq(A, b, rcond=None)[0]
    result = fitting.fit(model, data, starts=1, solver="gauss_newton_edm")
    assert result.solver == "gauss_newton_edm" and result.status == "converged"
    np.testing.assert_allclose(result.theta, best, rtol=0, atol=1e-10)
    assert result.chi2 == pytest.approx(float(np.sum((A @ best - b) ** 2)), rel=1e-12)
    assert result.starts[0]["steps"] <= 2


def test_rank_deficient_problem_leaves_the_null_direction_where_it_started():
    """``Linear(duplicate=True)``: θ2 and θ3 multiply the same basis, so θ2 − θ3 is not determined.
    The step is the minimum-norm least-squares step (NumPy's lstsq of the rank-deficient design, which
    leaves out singular values below its rcond too): θ2 − θ3 keeps its start, χ² is the minimum.
    (Levenberg–Marquardt moves that direction by whatever its damping gives it.)"""
    model, data = Linear(duplicate=True), fitting.Dataset.from_measurements(linear_measurements(seed=5))
    A, b = _design(model, data)
    start = np.array([0.3, -0.2, 1.5, -0.5])
    problem = fitting.Problem(model, data)
    theta, code, steps, chi2, _ = fitting._solve.solve(problem, jnp.asarray(start), GaussNewtonEDM(1e-6, 1e-6), 64)
    expected = start + np.linalg.lstsq(A, b - A @ start, rcond=None)[0]
    assert fitting._solve.result_name(int(code)) == "successful"
    np.testing.assert_allclose(np.asarray(theta), expected, rtol=0, atol=1e-9)
    assert float(theta[2] - theta[3]) == pytest.approx(start[2] - start[3], abs=1e-9)
    assert float(chi2) == pytest.approx(float(np.sum((A @ expected - b) ** 2)), rel=1e-12)


def test_nonlinear_fit_stops_within_its_edm_of_scipys_optimum():
    """The parametric model (nonlinear) on a noisy set: SciPy's ``least_squares`` (trust region,
    tolerances at 1e-15) gives the optimum. The EDM stop leaves at most EDM ≤ τ·‖r‖²/m of ½χ² to gain
    (r the m rows the solver sees), so χ² − χ²_min ≤ 2τ·‖r‖²/m up to the quadratic model's error (a factor 2
    allowed for it), and θ̂ within √(2 EDM) ≈ 0.045 standard errors of the optimum
    (0.1 allowed, by the Laplace covariance)."""
    model = fitting.ParametricModel()
    _, data = parametric_dataset(model, TRUTHS[1], 0.01, seed=7)
    problem = fitting.Problem(model, data)
    result = fitting.fit(model, data, starts=1, solver="gauss_newton_edm")
    assert result.status == "converged"
    fun = jax.jit(lambda t: problem.residuals(t))
    jac = jax.jit(jax.jacfwd(lambda t: problem.residuals(t)))
    reference = scipy.optimize.least_squares(
        lambda t: np.asarray(fun(jnp.asarray(t))),
        result.theta,
        jac=lambda t: np.asarray(jac(jnp.asarray(t))),
        bounds=(np.asarray(problem.lower), np.asarray(problem.upper)),
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
    )
    r = np.asarray(fun(jnp.asarray(result.theta)))  # the rows the solver sees (replicate pixels merged)
    offset = result.chi2 - float(r @ r)  # χ²'s within-group constant (fitting.Problem)
    chi2_min = 2 * reference.cost + offset
    assert chi2_min <= result.chi2 <= chi2_min + 2 * 2 * EDM_TOLERANCE * float(r @ r) / np.count_nonzero(r)
    delta = result.theta - reference.x
    assert float(np.sqrt(delta @ np.linalg.solve(result.covariance, delta))) < 0.1


def _linear_problem(seed=6, rows=60, columns=4):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(rows, columns)), rng.normal(size=rows)


# 1e-30 in the slow step (the default suite's 6-minute budget; the other extreme runs by default)
@pytest.mark.parametrize("factor", [pytest.param(1e-30, marks=pytest.mark.slow), 1e30])
def test_the_stop_does_not_depend_on_the_scale_of_the_residuals(factor):
    """The solver alone (optimistix.least_squares, no normalisation by fitting._solve) on the parametric
    model's whitened rows times c = 1e±30: the same steps and θ̂ to 1e-8 (every test it makes — the line
    search, the directions left out, the EDM stop — compares quantities that scale alike)."""
    model = fitting.ParametricModel()
    _, data = parametric_dataset(model, TRUTHS[1], 0.01, seed=7, size=12)
    problem = fitting.Problem(model, data)
    y0 = jnp.asarray(model.initial(data))

    def solve(c):
        sol = optx.least_squares(
            lambda t, _: c * problem.residuals(t), GaussNewtonEDM(1e-6, 1e-6), y0, max_steps=256, throw=False
        )
        return np.asarray(sol.value), int(sol.stats["num_steps"]), sol.result

    one, steps, result = solve(1.0)
    other, other_steps, other_result = solve(factor)
    assert result == other_result == optx.RESULTS.successful
    assert other_steps == steps
    np.testing.assert_allclose(other, one, rtol=1e-8, atol=1e-8)


def test_a_start_that_meets_the_stop_is_converged_not_stopped_at_start():
    """A start 0.01 standard errors from the optimum of a linear problem meets the EDM stop at once: the solve
    returns it unmoved, and fitting._solve reports it converged ("successful"), not "stopped_at_start" (its
    cosine test alone would: the cosine there exceeds 1e-4)."""
    model, data = Linear(), fitting.Dataset.from_measurements(linear_measurements(seed=4))
    A, b = _design(model, data)
    best = np.linalg.lstsq(A, b, rcond=None)[0]
    std = np.sqrt(np.diag(np.linalg.inv(A.T @ A)))
    start = best + 0.01 * std
    problem = fitting.Problem(model, data)
    theta, code, steps, chi2, jac = fitting._solve.solve(problem, jnp.asarray(start), GaussNewtonEDM(1e-6, 1e-6), 64)
    r = A @ np.asarray(theta) - b
    assert np.all(np.asarray(theta) == start)  # unmoved
    assert np.max(np.abs(r @ A) / (np.linalg.norm(A, axis=0) * np.linalg.norm(r))) > fitting._solve.STATIONARY_COSINE
    assert fitting._solve.result_name(int(code)) == "successful"


def _solve_linear(A, b, start):
    sol = optx.least_squares(
        lambda t, _: jnp.asarray(A) @ t - jnp.asarray(b), GaussNewtonEDM(1e-6, 1e-6), jnp.asarray(start), max_steps=64
    )
    assert sol.result == optx.RESULTS.successful
    return np.asarray(sol.value)


def _tests_at(A, b, theta):
    """Curvature c and predicted gain G (module docstring of fitting._gauss_newton) of every eigen-direction of
    ``AᵀA`` at ``theta``, in ascending eigenvalue order, with the eigenvectors."""
    values, vectors = np.linalg.eigh(A.T @ A)
    r = A @ theta - b
    per_variance = len(b) / (r @ r)
    along = vectors.T @ (A.T @ r)
    return values * per_variance, along**2 / values * per_variance, vectors


@pytest.mark.parametrize("scale, kept", [(0.05, False), (0.5, True)])
def test_directions_the_noise_does_not_determine_are_left_out(scale, kept):
    """A linear problem whose last column is scaled down (the others high signal-to-noise, × 1e5), its eigenvalue
    above the rounding level (RCOND × the largest). Flatter than the noise (curvature λ·m/‖r‖² < DETERMINED) and
    no significant gain from moving it: that coordinate keeps its start (lstsq would move it) and the others are
    the least-squares solution without it. Determined by the noise (curvature ≥ DETERMINED): it is fitted like
    the others — NumPy's lstsq of the whole problem — rather than left where it started and reported determined."""
    A, b = _linear_problem()
    A = A * np.array([1e5, 1e5, 1e5, scale])
    start = np.array([0.0, 0.0, 0.0, 0.7])
    best = np.linalg.lstsq(A, b, rcond=None)[0]
    lam, lam_max = np.sum(A[:, 3] ** 2), np.linalg.norm(A, 2) ** 2
    assert lam > fitting._gauss_newton.RCOND * lam_max
    curvature = lam * len(b) / np.sum((A @ best - b) ** 2)
    assert (curvature >= fitting._gauss_newton.DETERMINED) == kept
    theta = _solve_linear(A, b, start)
    if kept:
        np.testing.assert_allclose(theta, best, rtol=1e-6, atol=0)
    else:
        first = np.concatenate([np.linalg.lstsq(A[:, :3], b - A[:, 3] * start[3], rcond=None)[0], start[3:]])
        c, gain, _ = _tests_at(A, b, first)  # where the solve is after its first step: nothing asks for θ3
        assert c[0] < fitting._gauss_newton.DETERMINED and gain[0] < fitting._gauss_newton.SIGNIFICANT_GAIN
        assert abs(best[3] - start[3]) > 1.0  # lstsq would move it
        assert theta[3] == pytest.approx(start[3], abs=1e-6)  # the kept eigenvectors' share of it: ~1e-9
        np.testing.assert_allclose(theta[:3], first[:3], rtol=1e-6, atol=0)


def test_a_direction_of_ordinary_size_that_the_noise_does_not_determine_is_left_out():
    """Four columns of one size, the last × 0.05: its eigenvalue is 1e-3 of the largest — far above the rounding
    level (and above the 1e-9 that alone kept a direction before) — but its curvature λ·m/‖r‖² is below
    DETERMINED and moving along it promises less than SIGNIFICANT_GAIN. The solve does not move θ along that
    eigenvector (its share of θ − start stays at the rounding level), fits the others — the gradient vanishes on
    the kept subspace — and so ends above the full least-squares χ²."""
    A, b = _linear_problem()
    A = A * np.array([1.0, 1.0, 1.0, 0.05])
    start = np.array([0.3, -0.2, 0.1, 0.7])
    c, gain, vectors = _tests_at(A, b, start)
    values = np.linalg.eigvalsh(A.T @ A)
    assert values[0] > 1e-4 * values[-1] and np.all(c[1:] >= fitting._gauss_newton.DETERMINED)
    assert fitting._gauss_newton.FLAT <= c[0] < fitting._gauss_newton.DETERMINED
    assert gain[0] < fitting._gauss_newton.SIGNIFICANT_GAIN
    theta = _solve_linear(A, b, start)
    assert abs(vectors[:, 0] @ (theta - start)) < 1e-9  # the undetermined direction: not moved
    np.testing.assert_allclose(vectors[:, 1:].T @ (A.T @ (A @ theta - b)), 0.0, atol=1e-9)  # the rest: fitted
    best = np.linalg.lstsq(A, b, rcond=None)[0]
    assert np.sum((A @ theta - b) ** 2) > np.sum((A @ best - b) ** 2)


def test_an_undetermined_direction_the_data_ask_for_is_fitted():
    """The same problem started 40 away along θ3: the direction is as flat (curvature < DETERMINED) but the step
    along it promises a decrease of χ² above SIGNIFICANT_GAIN × the reduced χ² — a log-amplitude whose lobe
    the data show brighter than the start — so it is kept, and the linear problem is solved: NumPy's lstsq."""
    A, b = _linear_problem()
    A = A * np.array([1.0, 1.0, 1.0, 0.05])
    start = np.array([0.3, -0.2, 0.1, 40.7])
    c, gain, _ = _tests_at(A, b, start)
    assert fitting._gauss_newton.FLAT <= c[0] < fitting._gauss_newton.DETERMINED
    assert gain[0] > 2 * fitting._gauss_newton.SIGNIFICANT_GAIN
    np.testing.assert_allclose(_solve_linear(A, b, start), np.linalg.lstsq(A, b, rcond=None)[0], rtol=1e-6, atol=1e-8)


def test_a_direction_flatter_than_flat_is_left_out_whatever_it_promises():
    """The last column × 1e-3: curvature below FLAT (a standard deviation above 10 in θ). Started 2000 away, the
    step along it promises a large decrease, but so flat a direction is where a log-amplitude drifts towards 0
    by one unit per step: it is left out — θ does not move along it."""
    A, b = _linear_problem()
    A = A * np.array([1.0, 1.0, 1.0, 1e-3])
    start = np.array([0.3, -0.2, 0.1, 2000.0])
    c, gain, vectors = _tests_at(A, b, start)
    assert c[0] < fitting._gauss_newton.FLAT and gain[0] > fitting._gauss_newton.SIGNIFICANT_GAIN
    assert abs(vectors[:, 0] @ (_solve_linear(A, b, start) - start)) < 1e-9  # not moved along it


def _orthogonal_problem(scales, rows=2000, seed=11):
    """``A = Q diag(scales)`` (Q: orthonormal columns, so the eigen-directions of ``AᵀA`` are the coordinates) and
    ``b = A θ* + e``, e orthogonal to A's range with ``‖e‖² = rows``: the optimum is θ* exactly, at a reduced χ²
    of 1."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(rows, len(scales) + 1)))
    truth = rng.normal(size=len(scales))
    noise = q[:, -1] * np.sqrt(rows)
    A = q[:, :-1] * np.asarray(scales)
    return A, A @ truth + noise, truth


def test_the_joint_test_keeps_the_largest_gains_until_the_rest_is_not_significant():
    """Worked by hand: candidate gains 4, 5, 4.5, 3, 6, 2 (and a non-candidate's 100) sum to 24.5 ≥ q_6 = 20.06
    (the χ²₆ upper 0.0027 quantile, from tables); without the 6 the rest sum 18.5 ≥ q_5 = 18.21; without the 5
    too 13.5 < q_4 = 16.25: the 6 and the 5 are kept. At 0.3 times those gains (7.35 < 20.06) none is. q_1 is the single
    test's 9; jit gives what eager gives."""
    g = fitting._gauss_newton
    thresholds = g.joint_thresholds(6)
    assert thresholds[0] == np.inf and thresholds[1] == pytest.approx(g.SIGNIFICANT_GAIN, rel=1e-12)
    assert thresholds[6] == pytest.approx(20.062, abs=1e-3) and thresholds[5] == pytest.approx(18.205, abs=1e-3)
    candidate = jnp.array([True, True, False, True, True, True, True])
    gain = jnp.array([4.0, 5.0, 100.0, 4.5, 3.0, 6.0, 2.0])
    expected = [False, True, False, False, False, True, False]
    assert list(np.asarray(g._jointly_significant(candidate, gain))) == expected
    assert list(np.asarray(jax.jit(g._jointly_significant)(candidate, gain))) == expected
    assert not np.any(np.asarray(g._jointly_significant(candidate, 0.3 * gain)))
    assert not np.any(np.asarray(g._jointly_significant(jnp.zeros(7, bool), gain)))


def test_directions_that_ask_for_it_together_are_fitted():
    """Three determined coordinates and six flat ones (curvature 0.2–0.3, between FLAT and DETERMINED), each of the six
    started where moving it alone promises a χ² decrease of about 8 — below SIGNIFICANT_GAIN, so the test of one
    direction at a time leaves all six where they started — while together they promise about 50, far above
    χ²₆'s upper 0.0027 quantile (20.06). The joint test fits them: at the end at most one is left out, and what is
    left out promises less than its threshold; χ² falls by more than 40 below what fitting the determined three
    alone leaves."""
    g = fitting._gauss_newton
    flat = np.array([0.45, 0.47, 0.49, 0.51, 0.53, 0.55])  # distinct: the eigen-directions are the coordinates
    A, b, truth = _orthogonal_problem(np.concatenate([[100.0, 110.0, 120.0], flat]))
    offsets = np.sqrt(8.5) / flat * np.array([1, -1, 1, -1, 1, -1])
    start = truth + np.concatenate([[0.0, 0.0, 0.0], offsets])
    c, gain, _ = _tests_at(A, b, start)  # ascending eigenvalues: the six flat ones first
    assert np.all((c[:6] >= g.FLAT) & (c[:6] < g.DETERMINED)) and np.all(c[6:] >= g.DETERMINED)
    assert np.all(gain[:6] < g.SIGNIFICANT_GAIN) and np.sum(gain[:6]) > 2 * g.joint_thresholds(6)[6]
    theta = _solve_linear(A, b, start)
    np.testing.assert_allclose(theta[:3], truth[:3], rtol=0, atol=1e-8)
    moved = np.abs(theta[3:] - truth[3:]) < 1e-6
    assert moved.sum() >= 5
    c_end, gain_end, vectors = _tests_at(A, b, theta)
    left = np.abs(vectors.T @ (theta - truth)) > 1e-6
    assert np.sum(gain_end[left]) < g.joint_thresholds(int(left.sum()))[int(left.sum())]
    alone = np.sum((A @ np.concatenate([truth[:3], start[3:]]) - b) ** 2)  # the determined three fitted, not the six
    assert np.sum((A @ theta - b) ** 2) < alone - 40


def test_the_step_under_jit_and_vmap_is_the_eager_step():
    """``truncated_step`` (with the joint test) jitted and vmapped over three problems — the six flat directions
    that together ask to be fitted, the same started at their optimum (none asks), a rank-deficient design — gives
    the eager step and EDM: the same directions kept (the steps agree to rounding)."""
    g = fitting._gauss_newton
    flat = np.array([0.45, 0.47, 0.49, 0.51, 0.53, 0.55])
    A, b, truth = _orthogonal_problem(np.concatenate([[100.0, 110.0, 120.0], flat]), rows=400)
    gains = 7.6 + 0.25 * np.arange(6)  # distinct: which one the joint test leaves out is not a tie
    away = truth + np.concatenate([[0.0, 0.0, 0.0], np.sqrt(gains) / flat * np.array([1, -1, 1, -1, 1, -1])])
    deficient = A.copy()
    deficient[:, 8] = deficient[:, 7]
    jacs = np.stack([A, A, deficient])
    residuals = np.stack([A @ away - b, A @ truth - b, deficient @ away - b])
    eager = [g.truncated_step(jnp.asarray(j), jnp.asarray(r)) for j, r in zip(jacs, residuals)]
    jitted = [jax.jit(g.truncated_step)(jnp.asarray(j), jnp.asarray(r)) for j, r in zip(jacs, residuals)]
    mapped = jax.vmap(g.truncated_step)(jnp.asarray(jacs), jnp.asarray(residuals))
    for k, (step, edm) in enumerate(eager):
        scale = max(float(np.max(np.abs(step))), 1.0)  # at the optimum the step is rounding: ~1e-18
        for other_step, other_edm in (jitted[k], (mapped[0][k], mapped[1][k])):
            np.testing.assert_allclose(np.asarray(other_step), np.asarray(step), rtol=0, atol=1e-9 * scale)
            assert float(other_edm) == pytest.approx(float(edm), rel=1e-9, abs=1e-12)
    moved = np.abs(np.asarray(eager[0][0])[3:]) > 1e-6  # the first problem: the joint test keeps five of six
    assert moved.sum() == 5 and not np.any(np.abs(np.asarray(eager[1][0])) > 1e-9)


# "all" (the vmapped lanes of accelerators) in the slow step: the default suite's 6-minute budget
@pytest.mark.parametrize("lanes", [None, pytest.param("all", marks=pytest.mark.slow)])
def test_fit_many_gives_what_fit_gives(lanes):
    """``fitting.fit_many`` with this solver — the solves mapped over materials × starts one by one (``lanes=None``
    on CPUs) and vmapped (``"all"``, as on accelerators): the optimum and χ² of ``fitting.fit`` for each material."""
    model = fitting.ParametricModel()
    data = [parametric_dataset(model, TRUTHS[i], 0.01, seed=i, size=12)[1] for i in (0, 1)]
    many = fitting.fit_many(model, data, starts=2, solver="gauss_newton_edm", lanes=lanes)
    for d, m in zip(data, many):
        single = fitting.fit(model, d, starts=2, solver="gauss_newton_edm")
        assert m.solver == single.solver == "gauss_newton_edm" and m.status == single.status
        np.testing.assert_allclose(m.theta, single.theta, rtol=0, atol=1e-9)
        assert m.chi2 == pytest.approx(single.chi2, rel=1e-10)


def test_the_choice_names_the_solver():
    """The name is one of brdfscale.choices.SOLVERS, with its summary, and make_solver builds this class
    with the tolerances given."""
    assert "gauss_newton_edm" in choices.SOLVERS.names and "expected distance" in choices.SOLVERS.summary(
        "gauss_newton_edm"
    )
    solver = fitting._solve.make_solver("gauss_newton_edm", 1e-5, 1e-7)
    assert isinstance(solver, GaussNewtonEDM) and (solver.rtol, solver.atol) == (1e-5, 1e-7)


def test_the_anisotropic_non_parametric_model_takes_this_solver_from_one_start():
    """``solver="auto"``, ``starts="auto"`` (the defaults of fit, fit_many and the command) resolve to this
    solver and one start for the anisotropic non-parametric model, to lm_normal and 8 starts for the
    anisotropic model; a batch of both takes the most starts; a bad count is refused naming "auto"."""
    data = fitting.Dataset.from_measurements(linear_measurements(size=9))
    nonparametric = fitting.AnisotropicNonParametricModel(data, base_nodes=5, n_knots=2)
    anisotropic = fitting.AnisotropicModel(2)
    assert fitting.resolve_solver("auto", [nonparametric]) == "gauss_newton_edm"
    assert fitting.resolve_starts("auto", [nonparametric]) == 1
    assert fitting.resolve_starts("auto", [anisotropic]) == choices.FIT.model_starts == 8
    assert fitting.resolve_starts("auto", [nonparametric, anisotropic]) == 8
    assert fitting.resolve_starts(3, [nonparametric]) == 3
    assert fitting.explain_plan(nonparametric, [data]).starts == 1
    with pytest.raises(InvalidInputError, match="starts must be an integer ≥ 1 or 'auto'"):
        fitting.fit(anisotropic, data, starts="many")
    with pytest.raises(InvalidInputError, match="starts must be an integer ≥ 1"):
        fitting.fit(anisotropic, data, starts=0)
