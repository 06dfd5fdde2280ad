"""``fitting.fit_many`` on an accelerator: materials per second for 64…4096 synthetic materials
on every visible device (and on one device, the baseline in the same run), the first call
(compilation included) and a second call of the same shapes (compiled), and the largest |Δθ|
of the two device counts. Up to 256 materials, one device also runs with ``lanes=1`` (each
solve by itself, the CPU default) against the accelerator's default (all vmapped in lock-step).

Run on the accelerator's machine, as it is:  python -m experiments.bench_library_gpu [--max 4096]
Writes experiments/results/bench_library_gpu.json (machine, versions, devices). On a CPU it runs
too (slowly; ``--max 64`` for a smoke run).
"""

import argparse
import time

import numpy as np

from experiments._bench import machine, write_json


def run(max_materials: int, starts: int = 6) -> dict:
    import jax

    jax.config.update("jax_enable_x64", True)
    from brdfscale import fitting
    from tests.helpers import material

    devices = jax.devices()
    sizes = [n for n in (64, 256, 1024, 4096) if n <= max_materials]
    base = [fitting.Dataset.from_measurements(material(i)) for i in range(min(64, max(sizes)))]
    model = fitting.ParametricModel()
    rows = []
    for n in sizes:
        data = [base[i % len(base)] for i in range(n)]  # 64 distinct materials, repeated
        thetas = {}
        configs = [(count, None) for count in sorted({1, len(devices)})] + ([(1, 1)] if n <= 256 else [])
        for count, lanes in configs:
            row = {
                "materials": n,
                "devices": count,
                "platform": devices[0].platform,
                "lanes": "default" if lanes is None else lanes,
            }
            for call in ("first", "compiled"):
                t0 = time.perf_counter()
                results = fitting.fit_many(model, data, starts=starts, batch=n, devices=count, lanes=lanes)
                row[f"{call}_s"] = time.perf_counter() - t0
            row["materials_per_s_compiled"] = n / row["compiled_s"]
            row["converged"] = sum(r.status == "converged" for r in results)
            theta = np.stack([r.theta for r in results])
            if lanes is None:
                thetas[count] = theta
            if (count, lanes) != (1, None):
                row["max_abs_theta_difference_vs_one_device"] = float(np.max(np.abs(thetas[1] - theta)))
            rows.append(row)
            print(row, flush=True)
    return {
        "benchmark": "bench_library_gpu",
        "machine": machine(),
        "devices": [str(d) for d in devices],
        "starts": starts,
        "rows": rows,
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--max", type=int, default=4096, help="largest library size (default 4096)")
    args = parser.parse_args(argv)
    print("wrote", write_json("bench_library_gpu", run(args.max)))


if __name__ == "__main__":
    main()
