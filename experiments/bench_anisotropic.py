"""Wall time of the anisotropic fit (issue 31, item 8): an 8-scale, 65² px measurement set made
from tests/data/topographies/mi-1.mi (synth.gonioreflectometer, Poisson 200 counts + 1 count read
noise), fitted by fitting.AnisotropicModel with fitting.fit's defaults — cold (first fit in a fresh
process, no persistent compilation cache) and warm (the same fit again in the process).

Run: ``flock /tmp/brdfscale-bench.lock python -m experiments.bench_anisotropic [--normal]`` (prints
JSON). ``--normal`` passes fitting.fit an optimistix Levenberg–Marquardt whose damped step solves the
normal equations by Cholesky (``lineax.Normal(lineax.Cholesky())``) instead of the default QR of
the stacked (rows + θ) × θ system: the same steps, ~16× cheaper per step with 33 800 rows × 27 θ.
"""

import json
import sys
import time

import jax
import numpy as np


def main(normal: bool = False) -> dict:
    jax.config.update("jax_enable_x64", True)
    import lineax as lx
    import optimistix as optx

    from brdfscale import fitting, synth, topography

    field = topography.read("tests/data/topographies/mi-1.mi")
    mus = field.scales(8, smallest=2)
    stats = synth.facet_statistics(field, mus, bins=17)
    spread = max(float(np.max(np.diag(stats[0].covariance - s.covariance))) for s in stats)
    mset = synth.gonioreflectometer(
        field, mus, [0.0, 0.0, 1.0], extent=4 * spread**0.5, pixels=65, noise=synth.PoissonNoise(200, 1), seed=1
    )
    data = fitting.Dataset.from_measurements(mset)
    model = fitting.AnisotropicModel(len(mus))
    times, results = [], []
    for _ in range(2):
        t0 = time.perf_counter()
        solver = (
            optx.LevenbergMarquardt(1e-6, 1e-6, norm=optx.rms_norm, linear_solver=lx.Normal(lx.Cholesky()))
            if normal
            else "lm"
        )
        results.append(fitting.fit(model, data, solver=solver))
        times.append(time.perf_counter() - t0)
    r = results[-1]
    return {
        "scales": len(mus),
        "pixels": 65,
        "solver": "lm, normal equations (Cholesky)" if normal else "lm (QR)",
        "parameters": len(model.names),
        "starts": len(r.starts),
        "cold_s": round(times[0], 2),
        "warm_s": round(times[1], 2),
        "status": r.status,
        "reduced_chi2": r.chi2 / r.dof,
        "steps": [s["steps"] for s in r.starts],
        "jax_devices": [str(d) for d in jax.devices()],
    }


if __name__ == "__main__":
    print(json.dumps(main("--normal" in sys.argv[1:]), indent=1))
