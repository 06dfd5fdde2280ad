"""Benchmark of the fitting chain (issue 6): optimistix vs SciPy on the same problem, emcee throughput.

For each problem (parametric model, simulated 5-scale data set, 32×32 pixels per image):

* JAX/optimistix Levenberg–Marquardt (jacfwd Jacobians): compile time (first call minus a
  warm call) and the wall time of a warm solve (median of repeats), from the model's
  data-driven start;
* SciPy ``least_squares`` with 2-point finite-difference Jacobians, methods "trf" and "lm",
  on the *same* residual function (the jit-compiled JAX residuals, called with NumPy
  arrays), from the same start; time, residual evaluations and the χ² it reaches;
* emcee: log-posterior evaluations per second and ensemble steps per second (32 walkers,
  vectorised jit log-probability).

Writes experiments/results/bench_fit.json (machine, versions, all timings, speed-up ratios).
Run: ``python experiments/bench_fit.py``.
"""

import json
import os
import statistics
import tempfile
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy
import scipy.optimize

import fitting
from _bench import machine, write_json
from fitting._estimate import _make_solver, _residuals, _solve

SCALES = (0.5, 1.0, 2.0, 4.0, 8.0)
PROBLEMS = {
    "beckmann_width_law": (dict(law="width"),
                           dict(amplitude=0.8, alpha_lobe=0.05, alpha_max=0.2, mu_c=1.0, exponent=0.8)),
    "beckmann_gaussian_surface": (dict(law="gaussian_surface"),
                                  dict(amplitude=0.8, alpha_lobe=0.05, rms_height=0.06, correlation_length=1.5)),
}


def _timed(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def bench_problem(name, options, truth):
    model = fitting.ParametricModel(**options)
    mset = fitting.simulate(model, truth, SCALES, size=32, extent=0.5, noise=0.01, floor=1e-3, seed=0)
    data = fitting.Dataset.from_measurements(mset)
    problem = fitting.Problem(model, data)
    y0 = jnp.asarray(np.clip(model.initial(data), *model.bounds(data)))
    solver = _make_solver("lm", 1e-8, 1e-8)

    def jax_solve():
        out = _solve(problem, y0, solver, 256)
        jax.block_until_ready(out)
        return out

    t0 = time.perf_counter()
    jax_solve()
    first = time.perf_counter() - t0
    warm, (theta, code, steps, chi2) = _timed(jax_solve, 5)
    record = {
        "parameters": len(model.names), "residuals": int(problem.residuals(y0).size),
        "jax_lm": {"compile_s": first - warm, "first_call_s": first, "warm_solve_s": warm,
                   "steps": int(steps), "chi2": float(chi2), "result_code": int(code)},
    }

    residual = eqx.filter_jit(_residuals)
    jax.block_until_ready(residual(y0, problem))
    f = lambda t: np.asarray(residual(jnp.asarray(t), problem))  # noqa: E731
    for method in ("trf", "lm"):
        def scipy_solve():
            return scipy.optimize.least_squares(f, np.asarray(y0), jac="2-point", method=method,
                                                xtol=1e-10, ftol=1e-10, gtol=1e-10)
        t_scipy, ref = _timed(scipy_solve, 3)
        chi2_ref = 2 * float(ref.cost)
        record[f"scipy_{method}_fd"] = {
            "solve_s": t_scipy, "nfev": int(ref.nfev), "chi2": chi2_ref, "success": bool(ref.success),
            "max_abs_theta_difference": float(np.max(np.abs(ref.x - np.asarray(theta)))),
            "same_optimum": bool(abs(chi2_ref - float(chi2)) <= 1e-6 * float(chi2)),
            "speedup_of_jax_warm_solve": t_scipy / warm,
            "speedup_including_jax_compile": t_scipy / first,
        }

    result = fitting.fit(model, data, starts=1)
    t_fit, _ = _timed(lambda: fitting.fit(model, data, starts=4), 3)
    record["fit_4_starts_with_laplace_s"] = t_fit

    walkers, steps = 32, 400
    t0 = time.perf_counter()
    fitting.sample(problem, result, walkers=walkers, steps=20, chunk=20, progress=False)
    warmup = time.perf_counter() - t0
    t0 = time.perf_counter()
    fitting.sample(problem, result, walkers=walkers, steps=steps, chunk=steps, progress=False)
    t_mcmc = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        fitting.sample(problem, result, walkers=walkers, steps=steps, chunk=100, checkpoint=os.path.join(tmp, "c.h5"),
                       progress=False)
        t_ckpt = time.perf_counter() - t0
    record["emcee"] = {
        "walkers": walkers, "steps": steps, "first_20_steps_with_compile_s": warmup,
        "steps_per_s": steps / t_mcmc, "log_prob_evaluations_per_s": steps * walkers / t_mcmc,
        "steps_per_s_with_hdf5_checkpoints_every_100": steps / t_ckpt,
    }
    return record


def main():
    results = {"machine": machine(), "load_average_at_start": os.getloadavg(), "problems": {}}
    for name, (options, truth) in PROBLEMS.items():
        results["problems"][name] = bench_problem(name, options, truth)
        print(name, json.dumps(results["problems"][name], indent=1), flush=True)
    results["load_average_at_end"] = os.getloadavg()
    print("wrote", write_json("bench_fit", results))


if __name__ == "__main__":
    main()
