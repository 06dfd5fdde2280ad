"""Benchmark of Smith's Λ of a tabulated slope density (issue 32 item 4): the exact tent-sum path of
:func:`brdfscale.stats.smith_lambda` for ``stats.Tabulated`` against the transform quadrature it replaced for
tables (the generic Fourier path, still the path of every density without a closed form or a table).

For tables of 33², 65² and 129² nodes (a smooth off-centre lobe with a ripple, extent 1) and directions drawn at
random (θ < 86°, any azimuth; the batch a 65² lobe image's pixels ask for is 4225 per incidence): the first call's
wall time (compilation included) and the best per-direction time of later calls, of both paths, in float64 on
this machine's CPU; and the largest difference between the two, absolute and relative to Λ where Λ > 1e-6 (the
Fourier path's own accuracy: ~1e-8 relative, tests/test_masking.py).

Run:  flock /tmp/brdfscale-bench.lock python -m experiments.bench_masking [--quick]
Writes experiments/results/bench_masking.json.
"""

import argparse
import time

import numpy as np

from experiments._bench import best_time, machine, write_json


SIZES = (33, 65, 129)
DIRECTIONS = {"exact": 4225, "fourier": 200}  # the Fourier path costs ~25 ms a direction at 65²


def _table(n: int):
    from brdfscale import stats

    x = np.linspace(-1.0, 1.0, n)
    X, Y = np.meshgrid(x, x)
    values = np.exp(-((X - 0.1) ** 2 + 2 * (Y + 0.05) ** 2) / 0.08) * (1 + 0.3 * np.cos(6 * X))
    return stats.Tabulated(values, extent=1.0, center=[0.02, -0.03])


def _directions(count: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    theta, phi = rng.uniform(0, np.radians(86), count), rng.uniform(0, 2 * np.pi, count)
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)


def run(sizes, counts) -> list[dict]:
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from brdfscale import stats
    from brdfscale.stats import _masking

    @eqx.filter_jit
    def fourier(density, w):  # the path tables took before: the transform's quadrature
        v = w[..., :2] / w[..., 2:3]
        return jnp.maximum(_masking._generic_hinge(density, v, _masking._mean(density)), 0.0)

    every = _directions(max(counts.values()))  # the Fourier path's directions are the first of the exact path's
    rows = []
    for n in sizes:
        density = _table(n)
        row = {"nodes": f"{n}²"}
        results = {}
        for name, fn in (("exact", stats.smith_lambda), ("fourier", fourier)):
            w = jnp.asarray(every[: counts[name]])
            t0 = time.perf_counter()
            results[name] = np.asarray(jax.block_until_ready(fn(density, w)))
            first = time.perf_counter() - t0
            best = best_time(lambda fn=fn, w=w: jax.block_until_ready(fn(density, w)), repeat=3)
            row[name] = {
                "directions": counts[name],
                "first_call_s": round(first, 3),
                "per_direction_ms": round(1e3 * best / counts[name], 4),
            }
        k = counts["fourier"]
        a, b = results["exact"][:k], results["fourier"]
        big = b > 1e-6
        row["max_abs_difference"] = float(np.max(np.abs(a - b)))
        row["max_rel_difference_where_lambda_gt_1e-6"] = float(np.max(np.abs(a - b)[big] / b[big]))
        row["speedup_per_direction"] = round(row["fourier"]["per_direction_ms"] / row["exact"]["per_direction_ms"], 1)
        rows.append(row)
        print(row, flush=True)
    return rows


def main(argv=None) -> None:
    import jax

    jax.config.update("jax_enable_x64", True)
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="one small table, few directions (a smoke run)")
    args = parser.parse_args(argv)
    sizes = (17,) if args.quick else SIZES
    counts = {"exact": 64, "fourier": 16} if args.quick else DIRECTIONS
    doc = {
        "benchmark": "bench_masking",
        "what": "Smith Λ of a stats.Tabulated: the exact tent-sum path vs the transform quadrature (float64, CPU)",
        "command": "flock /tmp/brdfscale-bench.lock python -m experiments.bench_masking",
        "quick": args.quick,
        "machine": machine(),
        "rows": run(sizes, counts),
    }
    if not args.quick:
        write_json("bench_masking", doc)


if __name__ == "__main__":
    main()
