"""Accuracy of the plus-distribution transforms H_n (n = 0…6) over z = |W| x0 ∈ [1e-6, 1e8].

References (tests/references/plus_transform.py, mpmath): the power series summed with enough digits
for z ≤ 3000, and beyond that mpmath's Taylor coefficients of the Gamma-function ratio minus
mpmath's Hankel-function quadrature of the decaying part. Writes
experiments/results/plus_transform_accuracy/accuracy.json with the maximum relative error
of float64 and float32 per order and per branch (series z ≤ 8, expansion z > 8).

    python -m experiments.plus_transform_accuracy            # ~10 min on 2 busy cores
"""

import argparse

import jax


jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import mpmath as mp  # noqa: E402
import numpy as np  # noqa: E402

from brdfscale import plus  # noqa: E402
from brdfscale.plus import _transform  # noqa: E402
from experiments._studies import progress, study_dir, write_results  # noqa: E402
from tests.references.plus_transform import reference  # noqa: E402


def grid(per_decade: int, large_per_decade: int) -> np.ndarray:
    series_region = np.logspace(-6, np.log10(3000), int(round((np.log10(3000) + 6) * per_decade)) + 1)
    switch = _transform.SWITCH * np.array([0.999, 1 - 1e-9, 1 + 1e-9, 1.001])
    large = np.logspace(4, 8, 4 * large_per_decade + 1)
    return np.unique(np.concatenate([series_region, switch, large]))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-decade", type=int, default=10)
    parser.add_argument("--large-per-decade", type=int, default=1)
    parser.add_argument("--out", default=None)
    args = parser.parse_args()

    z = grid(args.per_decade, args.large_per_decade)
    all64 = np.asarray(_transform.transforms_from_square(jnp.asarray(z) ** 2, plus.MAX_ORDER))
    all32 = np.asarray(_transform.transforms_from_square(jnp.asarray(z, jnp.float32) ** 2, plus.MAX_ORDER), np.float64)
    with mp.workdps(30):
        ref = np.array([[reference(n, v) for n in range(plus.MAX_ORDER + 1)] for v in progress(z)])
    err64 = np.abs(all64 - ref) / np.abs(ref)
    err32 = np.abs(all32 - ref) / np.abs(ref)
    series = z <= _transform.SWITCH
    summary = {}
    for n in range(plus.MAX_ORDER + 1):
        summary[f"H_{n}"] = {
            "float64_max_relative_error": float(err64[:, n].max()),
            "float64_max_relative_error_series_branch": float(err64[series, n].max()),
            "float64_max_relative_error_expansion_branch": float(err64[~series, n].max()),
            "float64_worst_z": float(z[np.argmax(err64[:, n])]),
            "float32_max_relative_error": float(err32[:, n].max()),
        }
    out = study_dir("plus_transform_accuracy", args.out)
    path = write_results(
        out,
        "accuracy",
        {
            "z_range": [float(z.min()), float(z.max())],
            "points": int(z.size),
            "switch": _transform.SWITCH,
            "summary": summary,
            "table": {
                "z": z.tolist(),
                "float64_relative_error": err64.tolist(),
                "float32_relative_error": err32.tolist(),
            },
        },
    )
    for name, row in summary.items():
        print(
            f"{name}: float64 max {row['float64_max_relative_error']:.2e} (series "
            f"{row['float64_max_relative_error_series_branch']:.2e},"
            f" expansion {row['float64_max_relative_error_expansion_branch']:.2e}); "
            f"float32 max {row['float32_max_relative_error']:.2e}"
        )
    print(path)


if __name__ == "__main__":
    main()
