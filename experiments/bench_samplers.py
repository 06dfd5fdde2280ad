"""ESS per second of fitting.sample's samplers, and their posteriors against a long emcee reference (issue 19).

Two problems:

* ``demo`` — ``brdfscale demo --source model``'s: ``ParametricModel(law="gaussian_surface")``
  (4 parameters, Beckmann closed form) with ``fitting.simulate`` at μ = 2…32 px (5 scales),
  33² pixels, noise 0.01 (floor 0.05), seed 1;
* ``ggx`` — the heavier one: ``ParametricModel(lobe="ggx", statistics="ggx", law="width")``
  (5 parameters, the radial Hankel path with 96 nodes) at μ = 1, 2, 4, 8 (4 scales), 64²
  pixels, noise 0.01 (floor 1e-3), seed 1.

Both are fitted with 4 starts. Each sampler runs 4 chains (emcee: 4 ensembles of 16 walkers)
twice in one process, seeds 1 and 2: the first call compiles, the second reuses the compiled
programs (one compiled program per problem shape). Per sampler and problem:

* ``compile_s`` = first call − second call (the same work but compiling);
* ``warmup_s``, ``sampling_s`` of the second call (``SampleResult.timing``: NUTS/HMC's warm-up
  steps and draws timed apart; emcee has no warm-up phase — its burn-in, found afterwards,
  is charged to ``warmup_s`` pro rata);
* ``ess_bulk_per_s`` = min ESS_bulk over the determined quantities (ArviZ's estimator,
  :meth:`fitting.SampleResult.summary`) ÷ (warm-up + sampling) of the second call —
  compilation excluded; ``ess_bulk_per_s_with_compile`` ÷ the first call's whole time;
  ``ess_tail_per_s`` likewise with ESS_tail; ``r_hat_max``; the status;
* the posterior mean and σ of every determined quantity against the reference: ``|mean −
  mean_ref| / σ_ref`` and ``σ / σ_ref − 1``.

The reference (``--reference``, its own run, written to bench_samplers_reference.json and read
by the main run): emcee, 4 ensembles × 32 walkers, as many steps that ≥ 10⁶ draws remain after
the burn-in. It measures no time, so it may share the machine with other work.

Targets (the issue's): on both problems the best gradient-based sampler ≥ 10× emcee's
ESS_bulk/s with compilation excluded and ≥ 2× with it included; every converged sampler's
means within 0.1 σ and σ within 10 % of the reference.

Run:  python -m experiments.bench_samplers --reference [PROBLEM ...]
      flock /tmp/brdfscale-bench.lock python -m experiments.bench_samplers [PROBLEM ...]
Writes experiments/results/bench_samplers_reference.json, experiments/results/bench_samplers.json.
"""

import argparse
import json
import math
import time

import jax
import numpy as np

from experiments._bench import machine, RESULTS, write_json


PROBLEMS = {
    "demo": dict(
        model=dict(law="gaussian_surface"),
        truth={"amplitude": 0.9, "alpha_lobe": 0.01, "rms_height": 0.05, "correlation_length": 8.0},
        scales=(2.0, 4.0, 8.0, 16.0, 32.0),
        size=33,
        extent=0.05,
        noise=0.01,
        floor=0.05,
    ),
    "ggx": dict(
        model=dict(lobe="ggx", statistics="ggx", law="width"),
        truth={"amplitude": 0.9, "alpha_lobe": 0.05, "alpha_max": 0.2, "mu_c": 4.0, "exponent": 1.0},
        scales=(1.0, 2.0, 4.0, 8.0),
        size=64,
        extent=0.5,
        noise=0.01,
        floor=1e-3,
    ),
}
STEPS = {"emcee": 1000, "nuts": 1000, "hmc": 1000}
REFERENCE_DRAWS = 1_000_000
REFERENCE_WALKERS = 32


def configs(fitting) -> dict:
    return {
        "emcee": dict(sampler=fitting.Emcee(walkers=16), steps=STEPS["emcee"]),
        "nuts": dict(sampler=fitting.NUTS(warmup=500), steps=STEPS["nuts"]),
        "hmc": dict(sampler=fitting.HMC(warmup=500), steps=STEPS["hmc"]),
    }


def problem(fitting, name):
    p = PROBLEMS[name]
    model = fitting.ParametricModel(**p["model"])
    mset = fitting.simulate(
        model, p["truth"], p["scales"], size=p["size"], extent=p["extent"], noise=p["noise"], floor=p["floor"], seed=1
    )
    data = fitting.Dataset.from_measurements(mset)
    t = time.perf_counter()
    fit = fitting.fit(model, data, starts=4, seed=1)
    return fitting.Problem(model, data), fit, time.perf_counter() - t


def moments(result) -> dict:
    """Posterior mean and σ of every determined quantity (the physical quantities' draws after the burn-in)."""
    out = {}
    for q in result.determined:
        v = np.asarray(result.quantities[q])[result.burn :].ravel()
        out[q] = {"mean": float(np.mean(v)), "std": float(np.std(v, ddof=1))}
    return out


def reference(names) -> dict:
    jax.config.update("jax_enable_x64", True)
    from brdfscale import fitting

    out = {}
    for name in names:
        prob, fit, _ = problem(fitting, name)
        trajectories = 4 * REFERENCE_WALKERS
        steps = math.ceil(REFERENCE_DRAWS / trajectories)
        t = time.perf_counter()
        while True:  # the burn-in (2 τ) is found afterwards: lengthen until ≥ 10⁶ draws remain after it
            r = fitting.sample(
                prob,
                fit,
                sampler=fitting.Emcee(walkers=REFERENCE_WALKERS),
                chains=4,
                steps=steps,
                chunk=1000,
                seed=12345,
                progress=False,
            )
            if (steps - r.burn) * trajectories >= REFERENCE_DRAWS:
                break
            steps = r.burn + math.ceil(REFERENCE_DRAWS / trajectories)
        out[name] = {
            "steps": steps,
            "burn": int(r.burn),
            "draws": int((steps - r.burn) * trajectories),
            "walkers": REFERENCE_WALKERS,
            "chains": 4,
            "status": r.status,
            "wall_s": time.perf_counter() - t,
            "r_hat_max": max(r.summary()[q]["r_hat"] for q in r.determined),
            "min_ess_bulk": min(r.summary()[q]["ess_bulk"] for q in r.determined),
            "moments": moments(r),
        }
        print(name, out[name], flush=True)
    return out


def run(problems, samplers) -> dict:
    jax.config.update("jax_enable_x64", True)
    from brdfscale import fitting

    table = configs(fitting)
    ref = json.loads((RESULTS / "bench_samplers_reference.json").read_text())["problems"]
    out = {}
    for pname in problems:
        prob, fit, fit_s = problem(fitting, pname)
        rows = {}
        for name in samplers:
            times, results = [], []
            for seed in (1, 2):  # the first call compiles, the second reuses the compiled programs
                t = time.perf_counter()
                results.append(fitting.sample(prob, fit, chains=4, chunk=500, seed=seed, progress=False, **table[name]))
                times.append(time.perf_counter() - t)
            first, warm = results
            s = warm.summary()
            ess_bulk = min(s[q]["ess_bulk"] for q in warm.determined)
            ess_tail = min(s[q]["ess_tail"] for q in warm.determined)
            ess_bulk_first = min(first.summary()[q]["ess_bulk"] for q in first.determined)
            run_s = warm.timing["warmup_s"] + warm.timing["sampling_s"]
            m, r = moments(warm), ref[pname]["moments"]
            rows[name] = {
                "steps": table[name]["steps"],
                "first_call_s": times[0],
                "warm_call_s": times[1],
                "compile_s": max(times[0] - times[1], 0.0),
                "warmup_s": warm.timing["warmup_s"],
                "sampling_s": warm.timing["sampling_s"],
                "min_ess_bulk": ess_bulk,
                "min_ess_tail": ess_tail,
                "ess_bulk_per_s": ess_bulk / run_s,
                "ess_tail_per_s": ess_tail / run_s,
                "ess_bulk_per_s_with_compile": ess_bulk_first / times[0],
                "r_hat_max": max(s[q]["r_hat"] for q in warm.determined),
                "status": warm.status,
                "divergent": int(warm.divergent),
                "mean_leapfrog_steps": (
                    float(np.mean(warm.stats["integration_steps"][warm.burn :]))
                    if warm.stats and "integration_steps" in warm.stats
                    else None
                ),
                "mean_offset_in_ref_sigma": {q: abs(m[q]["mean"] - r[q]["mean"]) / r[q]["std"] for q in m},
                "sigma_ratio_minus_1": {q: m[q]["std"] / r[q]["std"] - 1 for q in m},
            }
            print(pname, name, {k: v for k, v in rows[name].items() if not isinstance(v, dict)}, flush=True)
        gradient = [n for n in rows if n != "emcee" and rows[n]["status"] == "converged"]
        best = max(gradient, key=lambda n: rows[n]["ess_bulk_per_s"]) if gradient else None
        targets = None
        if best and "emcee" in rows:
            e, b = rows["emcee"], rows[best]
            targets = {
                "best_gradient_sampler": best,
                "speedup_compile_excluded": b["ess_bulk_per_s"] / e["ess_bulk_per_s"],
                "speedup_compile_included": b["ess_bulk_per_s_with_compile"] / e["ess_bulk_per_s_with_compile"],
                "max_mean_offset_in_ref_sigma": max(b["mean_offset_in_ref_sigma"].values()),
                "max_abs_sigma_ratio_minus_1": max(abs(v) for v in b["sigma_ratio_minus_1"].values()),
            }
            targets["met"] = (
                targets["speedup_compile_excluded"] >= 10
                and targets["speedup_compile_included"] >= 2
                and targets["max_mean_offset_in_ref_sigma"] <= 0.1
                and targets["max_abs_sigma_ratio_minus_1"] <= 0.1
            )
        out[pname] = {
            "settings": {k: v for k, v in PROBLEMS[pname].items()},
            "fit_s": fit_s,
            "parameters": len(prob.model.names),
            "distinct_points": int(np.prod(prob.points.mean.shape)),
            "reference": {k: v for k, v in ref[pname].items() if k != "moments"},
            "samplers": rows,
            "targets": targets,
        }
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("problems", nargs="*", help=f"problems to run, of {', '.join(PROBLEMS)} (default all)")
    parser.add_argument("--reference", action="store_true", help="run the long emcee reference instead")
    parser.add_argument("--samplers", nargs="*", default=list(STEPS), choices=list(STEPS))
    args = parser.parse_args()
    unknown = sorted(set(args.problems) - set(PROBLEMS))
    if unknown:
        parser.error(f"unknown problems {unknown}; choose from {list(PROBLEMS)}")
    names = args.problems or list(PROBLEMS)
    if args.reference:
        path = write_json(
            "bench_samplers_reference",
            {"benchmark": "bench_samplers_reference", "machine": machine(), "problems": reference(names)},
        )
    else:
        path = write_json(
            "bench_samplers",
            {"benchmark": "bench_samplers", "machine": machine(), "chains": 4, "problems": run(names, args.samplers)},
        )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
