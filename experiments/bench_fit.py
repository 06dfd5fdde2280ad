"""Benchmark of the fitting chain (issue 6): optimistix vs SciPy on the same problem, emcee throughput.

For each problem (parametric model, simulated 5-scale data set, 32×32 pixels per image,
5120 pixels; least squares on the data set's distinct points, :meth:`fitting.Dataset.points`):

* ``fit``: :func:`fitting.fit` with 4 starts (solve + Jacobian + Laplace quantities) —
  the first call in the process (compilation included) and a warm call; their difference
  is the compile time a user waits for once per model and data layout;
* ``compile_breakdown``: the compiled solve again, ahead of time: tracing, lowering and
  XLA compilation times, the size of the lowered program (characters of StableHLO) and the
  number of XLA kernels (fusions) in the compiled solve and in the residuals with their
  forward-mode Jacobian alone;
  tracing re-uses what the fit above already traced (a lower bound), the XLA compilation
  is a fresh one;
* ``jax_lm``: one warm optimistix Levenberg–Marquardt solve (``fit``'s solver and default
  tolerances, the Jacobian at the optimum included) from the model's data-driven start,
  compiled ahead of time with the problem as constants like the baseline. Timed in 41
  rounds (see :func:`_solve_times`): the median of its warm calls and of its first call
  after SciPy's (``solve_after_scipy_s``: caches filled by SciPy's Python);
* ``scipy_trf_fd`` / ``scipy_lm_fd``: ``scipy.optimize.least_squares`` with 2-point
  finite-difference Jacobians (SciPy's default tolerances) on the *same* residual function —
  the jit-compiled JAX residuals, compiled ahead of time, called with NumPy arrays — from
  the same start: median wall time (same rounds), evaluations, χ², and the largest |θ difference| from the
  JAX optimum (also in units of the Laplace standard deviation);
* ``error_vs_time``: run time against error, for both sides at several tolerances — the JAX
  solve at ``rtol = atol`` ∈ ``JAX_TOLERANCES`` (``fit``'s default among them) and each SciPy
  method at ``ftol = xtol = gtol`` ∈ ``SCIPY_TOLERANCES`` (SciPy's default first), all timed in
  the same rounds; each solution's error is its distance from the least-squares optimum θ*
  (the JAX solve converged to ``REFERENCE_TOLERANCE``) in the metric of the Fisher information
  JᵀJ at θ*: the residuals are whitened, so JᵀJ is the inverse Laplace covariance and
  ‖J(θ − θ*)‖ is the distance in Laplace standard deviations. ``equal_accuracy`` pairs each
  SciPy point with the JAX point of fewest steps (then loosest tolerance) among those at
  least as close to θ* — a choice by work done, not by the noisier timings — and gives the
  speed-up "to the same optimum" at equal accuracy;
* ``dispatch_s``: a compiled call that does nothing with the same arguments (the fixed cost
  of every warm solve);
* ``optimistix_floor`` (once): the same Levenberg–Marquardt settings on a trivial problem of
  the same size, ``r(θ) = tanh(Aθ) − b`` with a 545 × 5 Gaussian A: optimistix's own cost
  per step, below which no residual function can bring a solve — with ``fit``'s linear
  solver (optimistix's default, QR of [J; √λ I]) and with Cholesky of the damped normal
  equations (the alternative, measured to show whether it would pay);
* ``emcee``: log-posterior evaluations per second and ensemble steps per second (32 walkers,
  vectorised jit log-probability), with and without HDF5 checkpoints.

Writes experiments/results/bench_fit.json (machine, versions, load average, all timings and
the speed-up ratios against the baseline measured in the same run).
Run: ``flock /tmp/brdfscale-bench.lock python -m experiments.bench_fit``.
"""

import json
import os
import tempfile
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
import scipy.optimize

from brdfscale import fitting


jax.config.update("jax_enable_x64", True)  # the fits need float64; fitting changes no global setting
from brdfscale.fitting._solve import make_solver as _make_solver, solve as _solve
from experiments._bench import best_time, interleaved_times, machine, median, rotated, write_json


SCALES = (0.5, 1.0, 2.0, 4.0, 8.0)
PROBLEMS = {
    "beckmann_width_law": (
        dict(law="width"),
        dict(amplitude=0.8, alpha_lobe=0.05, alpha_max=0.2, mu_c=1.0, exponent=0.8),
    ),
    "beckmann_gaussian_surface": (
        dict(law="gaussian_surface"),
        dict(amplitude=0.8, alpha_lobe=0.05, rms_height=0.06, correlation_length=1.5),
    ),
}
FIT_DEFAULTS = dict(rtol=1e-6, atol=1e-6, max_steps=256)  # fitting.fit's defaults
ROUNDS = 41  # rounds of SciPy solves and JAX solves (see _solve_times); medians are the figures
JAX_TOLERANCES = (1e-4, 1e-5, 1e-6, 1e-8)  # rtol = atol of the error-vs-time ladder (1e-6: fit's default)
SCIPY_TOLERANCES = (1e-8, 1e-10)  # ftol = xtol = gtol (1e-8: SciPy's default)
REFERENCE_TOLERANCE = 1e-13  # θ*, the optimum every error is measured from


def _wall(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def _compile_breakdown(problem, y0, solver):
    dynamic, static = eqx.partition(problem, eqx.is_array)
    solve = jax.jit(lambda d, y: _solve.__wrapped__(eqx.combine(d, static), y, solver, FIT_DEFAULTS["max_steps"]))
    trace_s, traced = _wall(lambda: solve.trace(dynamic, y0))
    lower_s, lowered = _wall(traced.lower)
    compile_s, compiled = _wall(lowered.compile)
    model_part = jax.jit(jax.jacfwd(problem.residuals)).lower(y0).compile()
    return {
        "trace_s": trace_s,
        "lower_s": lower_s,
        "xla_compile_s": compile_s,
        "hlo_chars": len(lowered.as_text()),
        # XLA:CPU runs each fusion as a kernel of its own: the solve's kernels, and those of
        # the residuals with their forward-mode Jacobian (the model's share of every step)
        "xla_fusions_in_solve": _fusions(compiled),
        "xla_fusions_in_residuals_and_jacobian": _fusions(model_part),
    }


def _fusions(compiled) -> int:
    """Fusion instructions (kernels) in a compiled XLA program."""
    return sum(" fusion(" in line for line in compiled.as_text().splitlines())


def optimistix_floor(rows=545, n=5):
    rng = np.random.default_rng(0)
    args = (jnp.asarray(rng.normal(size=(rows, n)) / np.sqrt(n)), jnp.asarray(rng.normal(size=rows) * 0.1))

    @eqx.filter_jit
    def solve(args, y0, solver):
        sol = optx.least_squares(
            lambda y, a: jnp.tanh(a[0] @ y) - a[1],
            solver,
            y0,
            args=args,
            max_steps=FIT_DEFAULTS["max_steps"],
            throw=False,
        )
        return sol.value, sol.stats["num_steps"]

    y0 = jnp.zeros(n)
    record = {"rows": rows, "parameters": n}
    solvers = {
        "fit_solver": _make_solver("lm", FIT_DEFAULTS["rtol"], FIT_DEFAULTS["atol"]),  # QR of [J; √λ I]
        "normal_cholesky": optx.LevenbergMarquardt(
            rtol=FIT_DEFAULTS["rtol"],
            atol=FIT_DEFAULTS["atol"],
            norm=optx.rms_norm,
            linear_solver=lx.Normal(lx.Cholesky()),
        ),
    }
    # the two alternated in rounds (back-to-back phases differ measurably on this machine);
    # medians, like the problems' solves
    times = interleaved_times(
        {name: (lambda s=solver: jax.block_until_ready(solve(args, y0, s))) for name, solver in solvers.items()},
        repeat=ROUNDS,
    )
    for name, solver in solvers.items():
        steps = int(solve(args, y0, solver)[1])
        record[name] = {"warm_solve_s": median(times[name]), "steps": steps, "per_step_s": median(times[name]) / steps}
    return record


def _solve_times(scipy_solves: dict, jax_solves: dict) -> dict:
    """Wall times over ``ROUNDS`` rounds, each: every SciPy solve once; the first JAX solve
    (``fit``'s default tolerance) once more, timed as ``"jax_after_scipy"`` (caches filled by
    SciPy's Python); then every JAX solve four times, the last three counted (warm, as in a
    loop of fits: the first call brings that solve's program back into the caches after the
    others ran). Within each block the order rotates from round to round, so that no solve
    always runs in the same position. Sorted lists per name; the medians compare like with
    like (single calls on both sides)."""
    for fn in (*scipy_solves.values(), *jax_solves.values()):
        fn()  # warm-up
    times = {"jax_after_scipy": [], **{name: [] for name in (*scipy_solves, *jax_solves)}}
    default = next(iter(jax_solves))

    for round_ in range(ROUNDS):
        for name in rotated(scipy_solves, round_):
            times[name].append(_wall(scipy_solves[name])[0])
        times["jax_after_scipy"].append(_wall(jax_solves[default])[0])
        for name in rotated(jax_solves, round_):
            jax_solves[name]()
            times[name] += [_wall(jax_solves[name])[0] for _ in range(3)]
    return {name: sorted(t) for name, t in times.items()}


def _equal_accuracy(points: list) -> dict:
    """Each SciPy point (``solver`` other than ``"jax_lm"``) against the JAX point of fewest
    steps, then loosest tolerance, among those whose error is at most the SciPy point's;
    keyed ``"<solver>@<tolerance>"``, with None entries where no JAX point is that close."""
    jax_points = [p for p in points if p["solver"] == "jax_lm"]
    out = {}
    for p in points:
        if p["solver"] == "jax_lm":
            continue
        as_close = [q for q in jax_points if q["error_laplace_std"] <= p["error_laplace_std"]]
        best = min(as_close, key=lambda q: (q["evaluations"], -q["tolerance"])) if as_close else None
        out[f"{p['solver']}@{p['tolerance']:g}"] = {
            "scipy_error_laplace_std": p["error_laplace_std"],
            "scipy_s": p["median_s"],
            "scipy_evaluations": p["evaluations"],
            "jax_tolerance": None if best is None else best["tolerance"],
            "jax_error_laplace_std": None if best is None else best["error_laplace_std"],
            "jax_steps": None if best is None else best["evaluations"],
            "jax_s": None if best is None else best["median_s"],
            "speedup": None if best is None else p["median_s"] / best["median_s"],
        }
    return out


def bench_problem(options, truth):
    model = fitting.ParametricModel(**options)
    mset = fitting.simulate(model, truth, SCALES, size=32, extent=0.5, noise=0.01, floor=1e-3, seed=0)
    data = fitting.Dataset.from_measurements(mset)
    problem = fitting.Problem(model, data)
    y0 = jnp.asarray(np.clip(model.initial(data), *model.bounds(data)))

    first_fit, result = _wall(lambda: fitting.fit(model, data, starts=4))
    warm_fit = best_time(lambda: fitting.fit(model, data, starts=4), repeat=5)
    solver = _make_solver("lm", FIT_DEFAULTS["rtol"], FIT_DEFAULTS["atol"])
    record_compile = _compile_breakdown(problem, y0, solver)
    nothing = eqx.filter_jit(lambda p, y: y)
    dispatch = best_time(lambda: jax.block_until_ready(nothing(problem, y0)), repeat=5, number=100)
    compiled = jax.jit(lambda t: problem.residuals(t)).lower(y0).compile()

    def f(t):
        return np.asarray(compiled(t))

    def scipy_solver(method, tol):
        return lambda: scipy.optimize.least_squares(
            f, np.asarray(y0), jac="2-point", method=method, ftol=tol, xtol=tol, gtol=tol
        )

    def jax_solver(tol):
        # compiled ahead of time with the problem's arrays as constants, exactly as the SciPy
        # baseline's residual function: both sides pay one dispatch of a one-argument call
        solve = (
            jax.jit(lambda y: _solve(problem, y, _make_solver("lm", tol, tol), FIT_DEFAULTS["max_steps"]))
            .lower(y0)
            .compile()
        )
        return lambda: jax.block_until_ready(solve(y0))

    # the error-vs-time ladder; the first entries are the defaults of both sides
    jax_tols = (FIT_DEFAULTS["rtol"], *(t for t in JAX_TOLERANCES if t != FIT_DEFAULTS["rtol"]))
    jax_solves = {f"jax_lm@{tol:g}": jax_solver(tol) for tol in jax_tols}
    scipy_solves = {
        f"scipy_{method}_fd@{tol:g}": scipy_solver(method, tol) for method in ("trf", "lm") for tol in SCIPY_TOLERANCES
    }
    times = _solve_times(scipy_solves, jax_solves)
    default = f"jax_lm@{FIT_DEFAULTS['rtol']:g}"
    warm = median(times[default])
    theta, code, steps, chi2, _ = jax_solves[default]()
    theta = np.asarray(theta)
    std = np.sqrt(np.diag(result.covariance))
    record = {
        "parameters": len(model.names),
        "pixels": data.n_data,
        "residual_rows": int(problem.residuals(y0).size),
        "fit_4_starts": {"first_call_s": first_fit, "warm_s": warm_fit, "compile_s": first_fit - warm_fit},
        "compile_breakdown": record_compile,
        "dispatch_s": dispatch,
        "jax_lm": {
            "warm_solve_s": warm,
            "solve_after_scipy_s": median(times["jax_after_scipy"]),
            "steps": int(steps),
            "per_step_s": warm / int(steps),
            "chi2": float(chi2),
            "result_code": int(code),
            "tolerances": FIT_DEFAULTS,
        },
        "rounds": ROUNDS,
    }
    record["residual_call_s"] = best_time(lambda: f(np.asarray(y0)), repeat=5, number=200)

    # errors: distance from θ* in the Fisher metric JᵀJ(θ*) (whitened residuals: Laplace σ)
    reference = _solve(
        problem, y0, _make_solver("lm", REFERENCE_TOLERANCE, REFERENCE_TOLERANCE), FIT_DEFAULTS["max_steps"]
    )
    theta_star, jac_star = np.asarray(reference[0]), np.asarray(reference[4])

    def error(x):
        d = jac_star @ (np.asarray(x) - theta_star)
        return float(np.sqrt(d @ d))

    points = []
    for name, solve in jax_solves.items():
        out = solve()
        points.append(
            {
                "solver": "jax_lm",
                "tolerance": float(name.split("@")[1]),
                "evaluations": int(out[2]),
                "error_laplace_std": error(out[0]),
                "median_s": median(times[name]),
            }
        )
    offset = float(problem.points.chi2_offset)
    for name, solve in scipy_solves.items():
        out = solve()
        solver_name, tol = name.split("@")
        points.append(
            {
                "solver": solver_name,
                "tolerance": float(tol),
                "evaluations": int(out.nfev),
                "error_laplace_std": error(out.x),
                "median_s": median(times[name]),
            }
        )
        if float(tol) == SCIPY_TOLERANCES[0]:  # SciPy's defaults: the baseline's own record
            t_scipy = median(times[name])
            chi2_ref = 2 * float(out.cost) + offset
            difference = np.abs(out.x - theta)
            record[solver_name] = {
                "solve_s": t_scipy,
                "nfev": int(out.nfev),
                "chi2": chi2_ref,
                "success": bool(out.success),
                "max_abs_theta_difference": float(difference.max()),
                "max_theta_difference_in_laplace_std": float((difference / std).max()),
                "same_optimum": bool(abs(chi2_ref - float(chi2)) <= 1e-6 * float(chi2)),
                "speedup_of_jax_warm_solve": t_scipy / warm,
                "speedup_of_jax_solve_after_scipy": t_scipy / median(times["jax_after_scipy"]),
                "target_10x_met": bool(t_scipy / warm >= 10),
            }
    equal = _equal_accuracy(points)
    at_defaults = {method: equal[f"scipy_{method}_fd@{SCIPY_TOLERANCES[0]:g}"]["speedup"] for method in ("trf", "lm")}
    record["error_vs_time"] = {
        "reference": {"tolerance": REFERENCE_TOLERANCE, "steps": int(reference[2]), "result_code": int(reference[1])},
        "scipy_default_tolerance": SCIPY_TOLERANCES[0],
        "jax_default_tolerance": FIT_DEFAULTS["rtol"],
        "points": points,
        "equal_accuracy": equal,
        "target_10x_met_at_equal_accuracy_vs_scipy_defaults": {
            method: speedup is not None and speedup >= 10 for method, speedup in at_defaults.items()
        },
    }

    walkers, steps = 32, 400
    first_mcmc, _ = _wall(
        lambda: fitting.sample(
            problem, result, sampler="emcee", chains=1, walkers=walkers, steps=20, chunk=20, progress=False
        )
    )
    t_mcmc, _ = _wall(
        lambda: fitting.sample(
            problem, result, sampler="emcee", chains=1, walkers=walkers, steps=steps, chunk=steps, progress=False
        )
    )
    with tempfile.TemporaryDirectory() as tmp:
        t_ckpt, _ = _wall(
            lambda: fitting.sample(
                problem,
                result,
                sampler="emcee",
                chains=1,
                walkers=walkers,
                steps=steps,
                chunk=100,
                checkpoint=os.path.join(tmp, "c.h5"),
                progress=False,
            )
        )
    record["emcee"] = {
        "walkers": walkers,
        "steps": steps,
        "first_20_steps_with_compile_s": first_mcmc,
        "steps_per_s": steps / t_mcmc,
        "log_prob_evaluations_per_s": steps * walkers / t_mcmc,
        "steps_per_s_with_hdf5_checkpoints_every_100": steps / t_ckpt,
    }
    return record


def main():
    results = {"machine": machine(), "load_average_at_start": os.getloadavg(), "problems": {}}
    results["optimistix_floor"] = optimistix_floor()
    for name, (options, truth) in PROBLEMS.items():
        results["problems"][name] = bench_problem(options, truth)
        print(name, json.dumps(results["problems"][name], indent=1), flush=True)
    results["load_average_at_end"] = os.getloadavg()
    print("wrote", write_json("bench_fit", results))


if __name__ == "__main__":
    main()
