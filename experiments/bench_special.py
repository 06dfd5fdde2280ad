"""Cost of J0/J1 (brdfscale._special) against the 96-node trapezoidal rule they replaced, and what it buys a GGX fit.

The baseline, evaluated at run time as brdfscale did until 2026-12-02: ``J_n(x) = mean over 96
nodes τ of cos(nτ − x sin τ)`` for |x| ≤ 25, the 24-term Hankel expansion beyond (both
branches computed, as under ``jnp.where``). Both are timed jitted on the same arguments (the
radial path's: 115 200 values in [0, 60], about one χ² of the benchmark's GGX problem), best
of repeated calls, in the same run; also the χ² and its gradient of experiments/bench_samplers'
GGX problem (4 scales of 64² pixels, 96 radial nodes) with the library's J0 — the forward
model's cost per posterior evaluation.

Run:  flock /tmp/brdfscale-bench.lock python -m experiments.bench_special
Writes experiments/results/bench_special.json.
"""

import jax
import jax.numpy as jnp
import numpy as np

from experiments._bench import best_time, machine, write_json


def trapezoid_j(n: int, x):
    """The replaced evaluation (baseline)."""
    from brdfscale._special import _hankel_coefficients

    tau = jnp.arange(96, dtype=x.dtype) * (2 * np.pi / 96)
    large = jnp.abs(x) > 25.0
    xs = jnp.where(large, 0.0, x)
    near = jnp.mean(jnp.cos(n * tau - xs[..., None] * jnp.sin(tau)), axis=-1)
    ax = jnp.abs(jnp.where(large, x, 50.0))
    a = _hankel_coefficients(n, 24)
    p = sum((-1) ** (k // 2) * float(a[k]) / ax**k for k in range(0, 24, 2))
    q = sum((-1) ** ((k - 1) // 2) * float(a[k]) / ax**k for k in range(1, 24, 2))
    chi = ax - (n / 2 + 0.25) * np.pi
    far = jnp.sqrt(2.0 / (np.pi * ax)) * (p * jnp.cos(chi) - q * jnp.sin(chi))
    return jnp.where(large, far, near)


def run() -> dict:
    jax.config.update("jax_enable_x64", True)
    from brdfscale import fitting
    from brdfscale._special import j0, j1
    from experiments import bench_samplers

    x = jnp.linspace(0.0, 60.0, 115_200)
    out = {"arguments": int(x.size)}
    for name, f in (
        ("j0", j0),
        ("j1", j1),
        ("j0_trapezoid_baseline", lambda v: trapezoid_j(0, v)),
        ("j1_trapezoid_baseline", lambda v: trapezoid_j(1, v)),
    ):
        g = jax.jit(f)
        out[f"{name}_ms"] = 1e3 * best_time(lambda: g(x).block_until_ready(), repeat=20)
    ref = np.asarray(trapezoid_j(0, x))
    out["max_abs_difference_j0_vs_baseline"] = float(np.max(np.abs(np.asarray(j0(x)) - ref)))
    out["speedup_j0"] = out["j0_trapezoid_baseline_ms"] / out["j0_ms"]
    out["speedup_j1"] = out["j1_trapezoid_baseline_ms"] / out["j1_ms"]

    prob, fit, _ = bench_samplers.problem(fitting, "ggx")
    theta = jnp.asarray(fit.theta)
    chi2 = jax.jit(lambda t: prob.chi2(t))
    grad = jax.jit(jax.grad(lambda t: prob.chi2(t)))
    out["ggx_chi2_ms"] = 1e3 * best_time(lambda: chi2(theta).block_until_ready(), repeat=10)
    out["ggx_grad_ms"] = 1e3 * best_time(lambda: grad(theta).block_until_ready(), repeat=10)
    return out


def main():
    results = run()
    print(results)
    print(
        "wrote", write_json("bench_special", {"benchmark": "bench_special", "machine": machine(), "results": results})
    )


if __name__ == "__main__":
    main()
