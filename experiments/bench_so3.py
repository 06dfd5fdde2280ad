"""Benchmark of brdfscale.so3: SO(3) transforms, block evolution, s2fft baseline, band limits.

Writes experiments/results/bench_so3.json:

* forward + inverse time (wall and process CPU) and round-trip error of brdfscale.so3 versus
  the band limit B (16 … 128; sizes whose predicted cost would push the sweep past its budget
  are skipped and listed), with the load average around each size; the fitted scaling
  exponent of the time over B ≥ 32 (where the O(B⁴) terms dominate the O(B³ log B) FFTs and
  the per-call overhead) and over the full range, and the local exponent between neighbouring
  sizes (a cache cliff shows up there);
* block evolution cost versus B (regularised solves with precomputed statistics, and the
  matrix-exponential path of rotational diffusion);
* s2fft's exact Wigner transforms at equal band limit L = N = B in float64, measured in the
  same run: the Fourier/Δ method (``precompute_transforms.fourier_wigner``) and the
  precomputed kernel (``precompute_transforms.wigner``); the speed ratio at B = 64;
* the band limit chosen for a lobe width and an error target, with the error reached;
* with ``--baseline-rev REV``: brdfscale.so3 as of git revision REV (exported to a temporary
  directory and imported as a separate package), its forward + inverse timed against the
  current one at every B, calls interleaved round by round: a before/after comparison
  measured in the same run.

Run: ``python -m experiments.bench_so3`` (add ``--quick`` for B ≤ 32 only, written to
``bench_so3_quick.json``).
"""

import argparse
import importlib.util
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax


jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import brdfscale.so3 as so3  # noqa: E402
from experiments._bench import best_time, best_times_interleaved, machine, write_json  # noqa: E402


SWEEP_BUDGET_S = 240.0


def band_limited(B, rng):
    shape = (B, 2 * B - 1, 2 * B - 1)
    c = rng.normal(size=shape) + 1j * rng.normal(size=shape)
    M = np.abs(np.arange(-(B - 1), B))
    J = np.arange(B)[:, None, None]
    return np.where((M[None, :, None] <= J) & (M[None, None, :] <= J), c, 0.0)


def best_cpu_time(fn, repeat):
    """Best process CPU time (all threads) of ``repeat`` calls after a warm-up: less sensitive
    than wall time to other jobs taking the cores, though not to their use of the caches."""
    fn()
    best = float("inf")
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return best


def time_ours(B, rng, repeat):
    c = jnp.asarray(band_limited(B, rng))
    load_before = os.getloadavg()[0]
    t0 = time.perf_counter()
    f = so3.inverse(c).block_until_ready()
    back = so3.forward(f).block_until_ready()
    first = time.perf_counter() - t0
    err = float(jnp.max(jnp.abs(back - c)))
    t_inv = best_time(lambda: so3.inverse(c).block_until_ready(), repeat=repeat)
    t_fwd = best_time(lambda: so3.forward(f).block_until_ready(), repeat=repeat)
    cpu = best_cpu_time(lambda: (so3.inverse(c).block_until_ready(), so3.forward(f).block_until_ready()), repeat)
    return {
        "B": B,
        "inverse_s": t_inv,
        "forward_s": t_fwd,
        "total_s": t_inv + t_fwd,
        "total_cpu_s": cpu,
        "first_call_with_compile_s": first,
        "round_trip_max_abs_error": err,
        "max_abs_coefficient": float(jnp.max(jnp.abs(c))),
        "load_average_1min": [load_before, os.getloadavg()[0]],
    }


def exponent(rows, key, B_min=0):
    """Least-squares slope of log(time) against log(B) over the rows with B ≥ B_min."""
    fit = [r for r in rows if r["B"] >= B_min]
    if len(fit) < 2:
        return None
    return float(np.polyfit(np.log([r["B"] for r in fit]), np.log([r[key] for r in fit]), 1)[0])


def scaling(rows, key):
    """Fitted exponents over B ≥ 32 and over every measured size, and the local exponents."""
    Bs = [r["B"] for r in rows]
    return {
        "fit_B_ge_32": {"B": [b for b in Bs if b >= 32], "exponent": exponent(rows, key, 32)},
        "fit_all": {"B": Bs, "exponent": exponent(rows, key)},
        "local": [
            {"B": [a["B"], b["B"]], "exponent": float(math.log(b[key] / a[key]) / math.log(b["B"] / a["B"]))}
            for a, b in zip(rows[:-1], rows[1:])
        ],
    }


def to_s2fft(c):
    """Our f^J_{MM'} → s2fft flmn[N−1+n, l, L−1+m] (docs/dependencies.md index map)."""
    B = c.shape[0]
    J = np.arange(B)[:, None, None]
    M = np.arange(-(B - 1), B)
    sign = (-1.0) ** (M[:, None] - M[None, :])
    scaled = c * (8 * np.pi**2 / (2 * J + 1)) * sign  # [J, M, M']
    # flmn[N−1−M', J, L−1−M] = scaled[J, M, M']  ⇒ flmn[n', J, m'] with n' = N−1−M', m' = L−1−M
    return np.transpose(scaled[:, ::-1, ::-1], (2, 0, 1)).copy()


def time_s2fft(B, rng, repeat, methods):
    from s2fft.precompute_transforms import construct, fourier_wigner, wigner

    c = band_limited(B, rng)
    flmn = jnp.asarray(to_s2fft(c))
    out, calls = {"B": B}, {}
    if "fourier" in methods:
        t0 = time.perf_counter()
        pre = construct.fourier_wigner_kernel(B)
        pre = tuple(jnp.asarray(p) for p in pre)
        out["fourier_precompute_s"] = time.perf_counter() - t0
        inv = lambda: fourier_wigner.inverse_transform_jax(flmn, B, B, pre).block_until_ready()
        f = inv()
        fwd = lambda: fourier_wigner.forward_transform_jax(f, B, B, pre).block_until_ready()
        out["fourier_round_trip_max_abs_error"] = float(jnp.max(jnp.abs(fwd() - flmn)) * (2 * B - 1) / (8 * np.pi**2))
        out["fourier_inverse_s"] = best_time(inv, repeat=repeat)
        out["fourier_forward_s"] = best_time(fwd, repeat=repeat)
        out["fourier_total_s"] = out["fourier_inverse_s"] + out["fourier_forward_s"]
        calls["s2fft_fourier"] = lambda inv=inv, fwd=fwd: (inv(), fwd())
    if "precompute" in methods:
        t0 = time.perf_counter()
        k_inv = construct.wigner_kernel_jax(B, B, sampling="mw", forward=False)
        k_fwd = construct.wigner_kernel_jax(B, B, sampling="mw", forward=True)
        jax.block_until_ready((k_inv, k_fwd))
        out["precompute_kernel_build_s"] = time.perf_counter() - t0
        out["precompute_kernel_bytes"] = int(k_inv.nbytes + k_fwd.nbytes)
        inv = lambda: wigner.inverse(flmn, B, B, k_inv, sampling="mw", method="jax").block_until_ready()
        f = inv()
        fwd = lambda: wigner.forward(f, B, B, k_fwd, sampling="mw", method="jax").block_until_ready()
        out["precompute_round_trip_max_abs_error"] = float(
            jnp.max(jnp.abs(fwd() - flmn)) * (2 * B - 1) / (8 * np.pi**2)
        )
        out["precompute_inverse_s"] = best_time(inv, repeat=repeat)
        out["precompute_forward_s"] = best_time(fwd, repeat=repeat)
        out["precompute_total_s"] = out["precompute_inverse_s"] + out["precompute_forward_s"]
        calls["s2fft_precompute"] = lambda inv=inv, fwd=fwd: (inv(), fwd())
    return out, calls


def baseline_so3(rev: str):
    """``brdfscale.so3`` as of git revision ``rev``, imported as the package ``brdfscale_baseline``."""
    root = Path(__file__).resolve().parent.parent
    tmp = Path(tempfile.mkdtemp(prefix="so3_baseline_"))
    subprocess.run(f"git -C '{root}' archive {rev} brdfscale | tar -x -C '{tmp}'", shell=True, check=True)
    spec = importlib.util.spec_from_file_location(
        "brdfscale_baseline", tmp / "brdfscale" / "__init__.py", submodule_search_locations=[str(tmp / "brdfscale")]
    )
    package = importlib.util.module_from_spec(spec)
    sys.modules["brdfscale_baseline"] = package
    spec.loader.exec_module(package)
    return importlib.import_module("brdfscale_baseline.so3")


def before_after(old, sizes, rng, rounds=5):
    """Best forward + inverse of the baseline and the current version per B, interleaved."""
    rows = []
    for B in sizes:
        c = jnp.asarray(band_limited(B, rng))
        calls = {}
        for name, mod in (("before", old), ("after", so3)):
            f = mod.inverse(c).block_until_ready()
            err = float(jnp.max(jnp.abs(mod.forward(f) - c)))
            calls[name] = (
                lambda mod=mod, f=f: (mod.inverse(c).block_until_ready(), mod.forward(f).block_until_ready()),
                err,
            )
        best = best_times_interleaved({name: fn for name, (fn, _) in calls.items()}, repeat=rounds)
        rows.append(
            {
                "B": B,
                "before_s": best["before"],
                "after_s": best["after"],
                "speedup": best["before"] / best["after"],
                "before_round_trip_max_abs_error": calls["before"][1],
                "after_round_trip_max_abs_error": calls["after"][1],
                "load_average_1min": os.getloadavg()[0],
            }
        )
        print(rows[-1], flush=True)
    return rows


def time_evolution(B, rng, repeat):
    R = jnp.asarray(band_limited(B, rng))
    s0 = so3.RotationalDiffusion(0.02, D=[1.0, 0.4, 2.0])
    s1 = so3.RotationalDiffusion(0.01, D=[1.0, 0.4, 2.0])
    op0, op1 = s0.operator(B), s1.operator(B)
    solve = jax.jit(lambda R, a, b: so3.evolve(R, a, b))
    reg = jax.jit(lambda R, a, b: so3.evolve(R, a, b, regularisation=1e-3))
    expm = jax.jit(lambda R, D, t0, t1: so3.evolve_diffusion(R, D, t0, t1))  # traced D, τ: no constant folding
    D, t0, t1 = jnp.array([1.0, 0.4, 2.0]), jnp.asarray(0.02), jnp.asarray(0.01)
    return {
        "B": B,
        "solve_s": best_time(lambda: solve(R, op0, op1).block_until_ready(), repeat=repeat),
        "regularised_solve_s": best_time(lambda: reg(R, op0, op1).block_until_ready(), repeat=repeat),
        "diffusion_expm_s": best_time(lambda: expm(R, D, t0, t1).block_until_ready(), repeat=repeat),
        "consistency_max_abs_error": float(
            jnp.max(
                jnp.abs(
                    solve(R, op0, op1) @ jnp.conj(jnp.swapaxes(op1, -1, -2)) - R @ jnp.conj(jnp.swapaxes(op0, -1, -2))
                )
            )
        ),
    }


def band_limit_study():
    """Band limit for a lobe width and error target, and the error actually reached."""
    out = []
    for width, tol in ((0.2, 1e-6), (0.1, 1e-6), (0.1, 1e-10)):
        B, bound = so3.band_limit(width, tol)
        tau = width**2 / 2  # heat kernel with angular variance σ² per axis
        coeffs = so3.RotationalDiffusion(tau).coefficients(B)
        theta = np.linspace(0.0, 5 * width, 41)
        Jc = np.arange(int(12 / width) + 50)[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            chi = np.where(theta == 0, 2 * Jc + 1, np.sin((2 * Jc + 1) * theta / 2) / np.sin(theta / 2))
        exact = np.sum((2 * Jc + 1) / (8 * np.pi**2) * np.exp(-tau * Jc * (Jc + 1)) * chi, axis=0)
        ours = np.asarray(so3.synthesize(coeffs, theta, 0.0, 0.0)).real
        out.append(
            {
                "lobe": "SO(3) heat kernel (Gaussian)",
                "width_rad": width,
                "tol": tol,
                "B": B,
                "predicted_relative_error": bound,
                "measured_max_relative_error": float(np.max(np.abs(ours - exact)) / exact[0]),
            }
        )
    # an anisotropic Beckmann lobe, reference: the same lobe at 1.5 B
    lobe = so3.AnisotropicMicrofacetLobe(0.3, 0.2)
    tol = 1e-4
    B, bound = so3.band_limit(lobe.spectrum, tol)
    z = np.array([0.0, 0.0, 1.0])
    Bref = int(math.ceil(1.5 * B))
    rng = np.random.default_rng(1)
    a, b, g = rng.uniform(0, 2 * np.pi, 200), rng.uniform(0, 0.5, 200), rng.uniform(0, 2 * np.pi, 200)
    ours = np.asarray(so3.synthesize(lobe.coefficients(z, z, B), a, b, g)).real
    ref = np.asarray(so3.synthesize(lobe.coefficients(z, z, Bref), a, b, g)).real
    direct = np.asarray(lobe.evaluate(z, z, so3.euler_to_matrix(a, b, g)))
    out.append(
        {
            "lobe": "AnisotropicMicrofacetLobe Beckmann alpha=(0.3, 0.2), i = o = z",
            "tol": tol,
            "B": B,
            "predicted_relative_error": bound,
            "reference_B": Bref,
            "measured_max_relative_error_vs_reference": float(np.max(np.abs(ours - ref)) / direct.max()),
            "measured_max_relative_error_vs_direct": float(np.max(np.abs(ours - direct)) / direct.max()),
        }
    )
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="B ≤ 32 only")
    parser.add_argument(
        "--baseline-rev",
        default=None,
        help="also time brdfscale.so3 as of this git revision against the current one (before/after)",
    )
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    load_start = os.getloadavg()[0]
    sizes = [16, 32] if args.quick else [16, 24, 32, 48, 64, 96, 128]
    repeat = 5
    ours, skipped, spent = [], [], 0.0
    for i, B in enumerate(sizes):
        if ours and len(ours) >= 2:
            # predict from the last two sizes' scaling: (repeat + 2) calls of each direction
            p = math.log(ours[-1]["total_s"] / ours[-2]["total_s"]) / math.log(ours[-1]["B"] / ours[-2]["B"])
            calls = 3 * repeat + 4  # wall (each direction), CPU (both), warm-ups
            predicted = calls * ours[-1]["total_s"] * (B / ours[-1]["B"]) ** max(p, 3.0)
            if spent + predicted > SWEEP_BUDGET_S:
                skipped.extend(
                    {
                        "B": b,
                        "reason": f"predicted {calls * ours[-1]['total_s'] * (b / ours[-1]['B']) ** max(p, 3.0):.0f} s "
                        f"would exceed the {SWEEP_BUDGET_S:.0f} s sweep budget",
                    }
                    for b in sizes[i:]
                )
                break
        t0 = time.perf_counter()
        ours.append(time_ours(B, rng, repeat))
        spent += time.perf_counter() - t0
        print(ours[-1], flush=True)

    s2, ratio = [], {}
    ref_B = 32 if args.quick else 64
    for B in [16, 32] if args.quick else [16, 32, 64]:
        result, calls = time_s2fft(B, rng, repeat, ("fourier", "precompute"))
        s2.append(result)
        print(s2[-1], flush=True)
        if B == ref_B:
            c = jnp.asarray(band_limited(B, rng))
            f = so3.inverse(c)
            calls["brdfscale_so3"] = lambda: (so3.inverse(c).block_until_ready(), so3.forward(f).block_until_ready())
            best = best_times_interleaved(calls, repeat=5)
            fastest = min(
                ("fourier", best["s2fft_fourier"]), ("precompute", best["s2fft_precompute"]), key=lambda x: x[1]
            )
            ratio = {
                "B": B,
                "method": "interleaved rounds (5), best forward+inverse of each",
                "load_average_1min": os.getloadavg()[0],
                "times_s": best,
                "s2fft_fastest_exact_mode": fastest[0],
                "s2fft_total_s": fastest[1],
                "brdfscale_total_s": best["brdfscale_so3"],
                "speedup": fastest[1] / best["brdfscale_so3"],
            }
            print(ratio, flush=True)
        del calls

    evo = []
    for B in [8, 16, 32] if args.quick else [8, 16, 32, 64]:
        evo.append(time_evolution(B, rng, 5))
        print(evo[-1], flush=True)
    evo_fit = [r for r in evo if r["B"] >= 16]
    evo_exponent = float(np.polyfit(np.log([r["B"] for r in evo_fit]), np.log([r["solve_s"] for r in evo_fit]), 1)[0])

    comparison = None
    if args.baseline_rev:
        comparison = {
            "revision": args.baseline_rev,
            "method": "interleaved rounds (5), best forward+inverse of each version",
            "rows": before_after(baseline_so3(args.baseline_rev), sizes, rng),
        }
        comparison["before_exponent_B_ge_32"] = exponent(comparison["rows"], "before_s", 32)
        comparison["after_exponent_B_ge_32"] = exponent(comparison["rows"], "after_s", 32)

    payload = {
        "machine": machine(),
        "notes": (
            "Times are the best of 5 calls after a warm-up (compilation excluded), float64, "
            "complex random band-limited coefficients; forward+inverse = one call of each. Our grid is "
            "the Kostelec–Rockmore (2B)^3 grid; s2fft uses its MW grid (L x (2L-1) x (2N-1)) at L = N = B. "
            "s2fft errors are on coefficients rescaled to this library's normalisation. Exponents: "
            "least-squares slope of log time against log B, over B >= 32 (below that the O(B^3 log B) "
            "FFTs and fixed per-call costs dominate the O(B^4) terms) and over all sizes; 'local' between "
            "neighbouring sizes. Both wall time and process CPU time (all threads) are fitted; the 1-minute "
            "load average before and after each size is recorded: on a loaded machine the larger sizes "
            "(whose data leave the caches) suffer most, which inflates the exponents."
        ),
        "load_average_1min_at_start_and_end": [load_start, os.getloadavg()[0]],
        "transforms": ours,
        "skipped_sizes": skipped,
        "time_scaling_exponent_B_ge_32": exponent(ours, "total_s", 32),
        "time_scaling_exponent_all_B": exponent(ours, "total_s"),
        "time_scaling": {"wall": scaling(ours, "total_s"), "cpu": scaling(ours, "total_cpu_s")},
        "s2fft": s2,
        "ratio": ratio,
        "evolution": evo,
        "evolution_solve_scaling_exponent_B_ge_16": evo_exponent,
        "band_limits": band_limit_study(),
        "before_after": comparison,
    }
    path = write_json("bench_so3_quick" if args.quick else "bench_so3", payload)  # a quick run keeps the full results
    print("wrote", path)


if __name__ == "__main__":
    main()
