"""Calibration study of the fit's uncertainties (issues 6 and 19): empirical coverage of the 68 % and
90 % intervals over many simulated replicas, for the Laplace approximation and for every sampler.

For each configuration (ground truth × noise level) ``--replicas`` data sets are simulated
from the parametric forward model (fitting.simulate, independent noise seeds) and fitted
(Levenberg–Marquardt, Laplace covariance). Then, on the same data, every sampler of
``--samplers`` (emcee, NUTS, HMC: ``fitting.sample`` with 4 independent chains) draws from the
posterior. Three kinds of quantity are checked against the truth:

* every parameter θ_i (log-parameter) the fit determines (a replica where the fit names θ_i
  undetermined does not count for it: the report gives it no interval);
* every ratio ``S(W, μ0)/S(W, μ_k)`` of ``FitResult.ratios`` (what multi-scale data determine
  whatever the parametrisation), its truth ``model.relative_statistics(θ_true, W, data.scales)``;
* the determined eigen-combinations ``v_j·θ`` of the Fisher matrix (``FitResult.combinations``,
  best determined first), truth ``v_j·θ_true``.

Intervals: Laplace θ̂ ± 1.000σ (68.3 %) and ± 1.645σ (90 %) for θ and the combinations, the
reported 5–95 % quantiles and estimate ± σ for the ratios; a sampler's central 15.87–84.13 %
and 5–95 % percentile intervals of its draws. With correct uncertainties the coverage is
0.683 / 0.90 up to the binomial error √(p(1−p)/n) (±0.047 / ±0.030 for n = 100); the issue's
target is coverage within ±0.05 of nominal for every sampler offered.

Writes experiments/results/calibration_fit.json. Slow (tens of minutes on 2 cores); run:
``python -m experiments.calibration_fit [--replicas 100] [--samplers emcee nuts hmc]``.
"""

import argparse
import os
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from brdfscale import fitting
from brdfscale.laplace import combination


jax.config.update("jax_enable_x64", True)  # the fits need float64; fitting changes no global setting
from experiments._bench import machine, write_json


SCALES = (0.5, 1.0, 2.0, 4.0, 8.0)
CONFIGS = {
    "truth_A_noise_1pct": (dict(amplitude=0.8, alpha_lobe=0.05, alpha_max=0.2, mu_c=1.0, exponent=0.8), 0.01),
    "truth_A_noise_5pct": (dict(amplitude=0.8, alpha_lobe=0.05, alpha_max=0.2, mu_c=1.0, exponent=0.8), 0.05),
    "truth_B_noise_2pct": (dict(amplitude=2.5, alpha_lobe=0.08, alpha_max=0.15, mu_c=2.0, exponent=1.5), 0.02),
}
Z68, Z90 = 1.0, 1.6448536269514722
NOMINAL = {"68": 0.6827, "90": 0.90}


def samplers(names, steps, warmup):
    table = {
        "emcee": (fitting.Emcee(walkers=32), steps["emcee"]),
        "nuts": (fitting.NUTS(warmup=warmup), steps["gradient"]),
        "hmc": (fitting.HMC(warmup=warmup), steps["gradient"]),
    }
    return {n: table[n] for n in names}


def _ratios(model, thetas, W, data):
    """Ratios S(μ0)/S(μk), k ≥ 1, flattened in FitResult.ratios' order, at every θ of ``thetas``."""
    return np.asarray(_ratios_compiled(model, jnp.atleast_2d(jnp.asarray(thetas)), W, data))


@eqx.filter_jit  # one program per model and shape, reused across replicas (W and the data are arguments)
def _ratios_compiled(model, thetas, W, data):
    return jax.vmap(lambda t: model.relative_statistics(t, W, data.scales)[1:].ravel())(thetas)


def _inside(lo, hi, truth):
    return ((lo <= truth) & (truth <= hi)).astype(float)


def replica(model, truth, noise, seed, runs, chains):
    theta_true = model.theta_from(truth)
    mset = fitting.simulate(model, truth, SCALES, size=24, extent=0.5, noise=noise, floor=1e-3, seed=seed)
    data = fitting.Dataset.from_measurements(mset)
    fit = fitting.fit(model, data, starts=2, seed=seed)
    names = list(model.names)
    determined = np.array([fit.std.get(n.removeprefix("log "), 1.0) is not None for n in names])
    W = jnp.asarray(sorted({r["W"] for r in fit.ratios.values()}))
    ratio_names = list(fit.ratios)
    r_true = _ratios(model, theta_true, W, data)[0]
    basis = np.array([_direction(fit, c["combination"]) for c in fit.combinations])  # (k, d)
    c_true = basis @ theta_true if len(basis) else np.zeros(0)
    out = {"status": fit.status, "determined": determined.tolist(), "ratio_names": ratio_names, "hits": {}}

    # Laplace
    std = np.sqrt(np.diag(fit.covariance))
    z = (fit.theta - theta_true) / std
    r_est = np.array([fit.ratios[n]["estimate"] for n in ratio_names])
    r_std = np.array([fit.ratios[n]["std"] if fit.ratios[n]["std"] is not None else np.inf for n in ratio_names])
    r_q = np.array([fit.ratios[n]["quantiles_5_50_95"] or [-np.inf, 0, np.inf] for n in ratio_names])
    c_est = np.array([c["value"] for c in fit.combinations])
    c_std = np.array([c["std"] for c in fit.combinations])
    out["hits"]["laplace"] = {
        "theta_68": (np.abs(z) <= Z68).astype(float).tolist(),
        "theta_90": (np.abs(z) <= Z90).astype(float).tolist(),
        "ratio_68": _inside(r_est - r_std, r_est + r_std, r_true).tolist(),
        "ratio_90": _inside(r_q[:, 0], r_q[:, 2], r_true).tolist(),
        "combination_68": (np.abs(c_est - c_true) <= Z68 * c_std).astype(float).tolist(),
        "combination_90": (np.abs(c_est - c_true) <= Z90 * c_std).astype(float).tolist(),
    }
    out["pull"] = z.tolist()
    out["samplers"] = {}
    problem = fitting.Problem(model, data)
    for name, (sampler, steps) in runs.items():
        s = fitting.sample(
            problem, fit, sampler=sampler, chains=chains, steps=steps, chunk=steps, progress=False, seed=seed
        )
        draws = s.samples
        p = np.percentile(draws, [15.865, 84.135, 5, 95], axis=0)
        rd = _ratios(model, draws, W, data)
        rp = np.percentile(rd, [15.865, 84.135, 5, 95], axis=0)
        cd = draws @ basis.T if len(basis) else np.zeros((len(draws), 0))
        cp = np.percentile(cd, [15.865, 84.135, 5, 95], axis=0) if len(basis) else np.zeros((4, 0))
        out["samplers"][name] = s.status
        out["hits"][name] = {
            "theta_68": _inside(p[0], p[1], theta_true).tolist(),
            "theta_90": _inside(p[2], p[3], theta_true).tolist(),
            "ratio_68": _inside(rp[0], rp[1], r_true).tolist(),
            "ratio_90": _inside(rp[2], rp[3], r_true).tolist(),
            "combination_68": _inside(cp[0], cp[1], c_true).tolist(),
            "combination_90": _inside(cp[2], cp[3], c_true).tolist(),
        }
    return out


def _direction(fit, text):
    """The unit vector of the combination ``text`` of FitResult.combinations: the eigenvector
    that brdfscale.laplace.combination prints so, with its printed sign."""
    V = np.asarray(fit.eigenvectors)
    for j in range(V.shape[1]):
        if combination(V[:, j], fit.names) == text:
            return V[:, j] if V[np.argmax(np.abs(V[:, j])), j] >= 0 else -V[:, j]
    raise ValueError(f"combination {text!r} not among the fit's eigenvectors")


def coverage(replicas, key, names, mask=None):
    """Mean hit rate per name over replicas (entries where ``mask`` is False left out)."""
    a = np.asarray([r["hits"][key] for r in replicas], dtype=float)
    keep = np.ones_like(a, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    per = {n: (float(a[keep[:, i], i].mean()) if keep[:, i].any() else None) for i, n in enumerate(names)}
    n = {name: int(keep[:, i].sum()) for i, name in enumerate(names)}
    return per, n


def summarise(model, replicas, methods):
    out = {}
    determined = np.asarray([r["determined"] for r in replicas])
    ratio_names = replicas[0]["ratio_names"]
    k = min(len(r["hits"]["laplace"]["combination_68"]) for r in replicas)
    comb_names = [f"combination {j + 1}" for j in range(k)]
    for method in methods:
        rows = {}
        for level in ("68", "90"):
            for kind, names, mask in (
                ("theta", list(model.names), determined),
                ("ratio", ratio_names, None),
                ("combination", comb_names, None),
            ):
                key = f"{kind}_{level}"
                hits = [{"hits": {key: r["hits"][method][key][: len(names)]}} for r in replicas]
                per, n = coverage(hits, key, names, mask)
                rows[key] = {"per_quantity": per, "n": n}
        values = [v for key, row in rows.items() for v in row["per_quantity"].values() if v is not None]
        worst = {
            level: max(
                (
                    abs(v - NOMINAL[level])
                    for key, row in rows.items()
                    if key.endswith(level)
                    for v in row["per_quantity"].values()
                    if v is not None
                ),
                default=None,
            )
            for level in NOMINAL
        }
        out[method] = {"coverage": rows, "worst_deviation_from_nominal": worst, "quantities": len(values) // 2}
    return out


def run_config(model, truth, noise, replicas, runs, chains, seed0):
    results = [replica(model, truth, noise, seed0 + r, runs, chains) for r in range(replicas)]
    methods = ["laplace", *runs]
    out = {
        "noise": noise,
        "truth": truth,
        "replicas": replicas,
        "fit_statuses": {s: [r["status"] for r in results].count(s) for s in {r["status"] for r in results}},
        "sampler_statuses": {
            m: {s: [r["samplers"][m] for r in results].count(s) for s in {r["samplers"][m] for r in results}}
            for m in runs
        },
        "methods": summarise(model, results, methods),
    }
    p = np.asarray([r["pull"] for r in results])
    out["pull_mean"] = dict(zip(model.names, p.mean(axis=0).tolist()))
    out["pull_std"] = dict(zip(model.names, p.std(axis=0).tolist()))
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replicas", type=int, default=100)
    parser.add_argument("--samplers", nargs="*", default=["emcee", "nuts", "hmc"], choices=["emcee", "nuts", "hmc"])
    parser.add_argument("--chains", type=int, default=4)
    parser.add_argument(
        "--emcee-steps", type=int, default=1500, help="emcee steps per walker (32 walkers per ensemble)"
    )
    parser.add_argument("--steps", type=int, default=1000, help="NUTS/HMC draws per chain after the warm-up")
    parser.add_argument("--warmup", type=int, default=500)
    parser.add_argument("--configs", nargs="*", default=list(CONFIGS), choices=list(CONFIGS))
    args = parser.parse_args()
    model = fitting.ParametricModel()
    runs = samplers(args.samplers, {"emcee": args.emcee_steps, "gradient": args.steps}, args.warmup)
    t0 = time.perf_counter()
    results = {"machine": machine(), "settings": vars(args), "scales": SCALES, "nominal": NOMINAL, "configs": {}}
    for i, name in enumerate(args.configs):
        truth, noise = CONFIGS[name]
        results["configs"][name] = run_config(
            model, truth, noise, args.replicas, runs, args.chains, seed0=10_000 * (list(CONFIGS).index(name) + 1)
        )
        print(
            name,
            {m: v["worst_deviation_from_nominal"] for m, v in results["configs"][name]["methods"].items()},
            f"{time.perf_counter() - t0:.0f} s",
            flush=True,
        )
    results["wall_s"] = time.perf_counter() - t0
    results["load_average"] = os.getloadavg()
    print("wrote", write_json("calibration_fit", results))


if __name__ == "__main__":
    main()
