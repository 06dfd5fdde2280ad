"""Calibration study of the fit's uncertainties (issue 6): empirical coverage of the 68 % and 90 %
intervals over many simulated replicas.

For each configuration (ground truth × noise level) ``--replicas`` data sets are simulated
from the parametric forward model (fitting.simulate, independent noise seeds), fitted
(Levenberg–Marquardt, Laplace covariance), and the truth's θ (log-parameters) is checked
against the central Laplace intervals θ̂ ± 1.000σ (68.3 %) and θ̂ ± 1.645σ (90 %). For the
first ``--mcmc-replicas`` replicas of each configuration the emcee posterior's 16–84 % and
5–95 % percentile intervals are checked as well. With correct uncertainties the coverage is
0.683 / 0.90 up to the binomial error √(p(1−p)/n) (±0.047 / ±0.030 for n = 100).

Writes experiments/results/calibration_fit.json. Slow (minutes); run:
``python -m experiments.calibration_fit [--replicas 100] [--mcmc-replicas 100] [--steps 600]``.
"""

import argparse
import os
import time

import jax
import numpy as np

import fitting

jax.config.update("jax_enable_x64", True)  # the fits need float64; fitting changes no global setting
from experiments._bench import machine, write_json

SCALES = (0.5, 1.0, 2.0, 4.0, 8.0)
CONFIGS = {
    "truth_A_noise_1pct": (dict(amplitude=0.8, alpha_lobe=0.05, alpha_max=0.2, mu_c=1.0, exponent=0.8), 0.01),
    "truth_A_noise_5pct": (dict(amplitude=0.8, alpha_lobe=0.05, alpha_max=0.2, mu_c=1.0, exponent=0.8), 0.05),
    "truth_B_noise_2pct": (dict(amplitude=2.5, alpha_lobe=0.08, alpha_max=0.15, mu_c=2.0, exponent=1.5), 0.02),
}
Z68, Z90 = 1.0, 1.6448536269514722


def run_config(model, truth, noise, replicas, mcmc_replicas, steps, seed0):
    theta_true = model.theta_from(truth)
    hits = {"laplace_68": [], "laplace_90": [], "mcmc_68": [], "mcmc_90": []}
    statuses, pulls = [], []
    for r in range(replicas):
        mset = fitting.simulate(model, truth, SCALES, size=24, extent=0.5, noise=noise, floor=1e-3, seed=seed0 + r)
        data = fitting.Dataset.from_measurements(mset)
        res = fitting.fit(model, data, starts=2, seed=r)
        statuses.append(res.status if res.determined else "undetermined")
        std = np.sqrt(np.diag(res.covariance))
        z = (res.theta - theta_true) / std
        pulls.append(z.tolist())
        hits["laplace_68"].append((np.abs(z) <= Z68).tolist())
        hits["laplace_90"].append((np.abs(z) <= Z90).tolist())
        if r < mcmc_replicas:
            s = fitting.sample(fitting.Problem(model, data), res, sampler="emcee", chains=1, walkers=32, steps=steps, chunk=steps,
                               progress=False, seed=r)
            lo68, hi68, lo90, hi90 = np.percentile(s.samples, [15.865, 84.135, 5, 95], axis=0)
            hits["mcmc_68"].append(((lo68 <= theta_true) & (theta_true <= hi68)).tolist())
            hits["mcmc_90"].append(((lo90 <= theta_true) & (theta_true <= hi90)).tolist())
    out = {"noise": noise, "truth": truth, "replicas": replicas, "mcmc_replicas": mcmc_replicas,
           "mcmc_steps": steps, "statuses": {s: statuses.count(s) for s in set(statuses)}, "coverage": {}}
    for key, values in hits.items():
        if not values:
            continue
        a = np.asarray(values, dtype=float)
        out["coverage"][key] = {
            "per_parameter": dict(zip(model.names, a.mean(axis=0).tolist())),
            "all_parameters": float(a.mean()),
            "n": int(a.shape[0]),
            "binomial_std_per_parameter": float(np.sqrt((0.683 if "68" in key else 0.9) * (0.317 if "68" in key else 0.1) / a.shape[0])),
        }
    p = np.asarray(pulls)
    out["pull_mean"] = dict(zip(model.names, p.mean(axis=0).tolist()))
    out["pull_std"] = dict(zip(model.names, p.std(axis=0).tolist()))
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replicas", type=int, default=100)
    parser.add_argument("--mcmc-replicas", type=int, default=100)
    parser.add_argument("--steps", type=int, default=600)
    args = parser.parse_args()
    model = fitting.ParametricModel()
    t0 = time.perf_counter()
    results = {"machine": machine(), "settings": vars(args), "scales": SCALES, "configs": {}}
    for i, (name, (truth, noise)) in enumerate(CONFIGS.items()):
        results["configs"][name] = run_config(model, truth, noise, args.replicas, args.mcmc_replicas, args.steps,
                                              seed0=10_000 * (i + 1))
        print(name, {k: round(v["all_parameters"], 3) for k, v in results["configs"][name]["coverage"].items()},
              flush=True)
    results["wall_s"] = time.perf_counter() - t0
    results["load_average"] = os.getloadavg()
    print("wrote", write_json("calibration_fit", results))


if __name__ == "__main__":
    main()
