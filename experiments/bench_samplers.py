"""ESS per second of fitting.sample's samplers on the demo's problem (issue 19; a first benchmark).

The problem is ``brdfscale demo --source model``'s: ``ParametricModel(law="gaussian_surface")``
(4 parameters) with ``fitting.simulate`` at μ = 2…32 px, 33² pixels, noise 0.01 (floor 0.05),
seed 1, fitted with 4 starts. Each sampler runs 4 chains (emcee: 4 ensembles of 16 walkers)
twice in one process: the first call compiles, the second reuses the compiled programs. The
figure of merit is the smallest ESS_bulk (ArviZ's estimator, :meth:`fitting.SampleResult.summary`)
over the quantities the fit determines, per second of the whole call (warm-up included), and
the run's status (R̂ ≤ 1.01, ESS_bulk ≥ 400, no divergences). Not yet here (issue 19): the
heavier GGX problem and the long emcee reference run of the issue's benchmark.

Run:  flock /tmp/brdfscale-bench.lock python -m experiments.bench_samplers [CONFIG ...]
Writes experiments/results/bench_samplers.json.
"""

import argparse
import time

import jax
import numpy as np

from experiments._bench import machine, write_json

TRUTH = {"amplitude": 0.9, "alpha_lobe": 0.01, "rms_height": 0.05, "correlation_length": 8.0}
STEPS = {"emcee": 1000, "emcee-long": 5000, "nuts": 1000, "hmc": 1000}


def configs(fitting) -> dict:
    return {
        "emcee": dict(sampler=fitting.Emcee(walkers=16), steps=STEPS["emcee"]),
        "emcee-long": dict(sampler=fitting.Emcee(walkers=16), steps=STEPS["emcee-long"]),
        "nuts": dict(sampler=fitting.NUTS(warmup=500), steps=STEPS["nuts"]),
        "hmc": dict(sampler=fitting.HMC(warmup=500), steps=STEPS["hmc"]),
    }


def run(names=None) -> dict:
    jax.config.update("jax_enable_x64", True)
    import fitting

    model = fitting.ParametricModel(law="gaussian_surface")
    mset = fitting.simulate(model, TRUTH, (2.0, 4.0, 8.0, 16.0, 32.0), size=33, extent=0.05, noise=0.01, floor=0.05,
                            seed=1)
    data = fitting.Dataset.from_measurements(mset)
    fit = fitting.fit(model, data, starts=4, seed=1)
    problem = fitting.Problem(model, data)
    table = configs(fitting)
    out = {}
    for name in names or table:
        times, results = [], []
        for seed in (1, 2):  # the first call compiles, the second reuses the compiled programs
            t = time.perf_counter()
            results.append(fitting.sample(problem, fit, chains=4, chunk=500, seed=seed, progress=False, **table[name]))
            times.append(time.perf_counter() - t)
        first, warm = results
        ess = [min(r.summary()[q]["ess_bulk"] for q in r.determined) for r in results]
        out[name] = {"steps": table[name]["steps"], "first_call_s": times[0], "warm_call_s": times[1],
                     "min_ess_bulk_first": ess[0], "min_ess_bulk_warm": ess[1],
                     "ess_per_s_first_call": ess[0] / times[0], "ess_per_s_warm": ess[1] / times[1],
                     "status": warm.status, "divergent": int(warm.divergent),
                     "mean_leapfrog_steps": (float(np.mean(warm.stats["integration_steps"][warm.burn:]))
                                             if warm.stats and "integration_steps" in warm.stats else None)}
        print(name, out[name], flush=True)
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("configs", nargs="*", help=f"samplers to run, of {', '.join(STEPS)} (default all)")
    args = parser.parse_args()
    unknown = sorted(set(args.configs) - set(STEPS))
    if unknown:
        parser.error(f"unknown configurations {unknown}; choose from {list(STEPS)}")
    results = run(args.configs or None)
    path = write_json("bench_samplers", {"benchmark": "bench_samplers", "machine": machine(), "chains": 4,
                                         "problem": "brdfscale demo --source model", "results": results})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
