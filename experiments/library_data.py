"""Synthetic material libraries of mixed sizes for tests/test_library.py and experiments/bench_library.py.

Material ``i`` of a library is a Beckmann lobe with a Beckmann width law (the demo's
parametric model) at truths drawn around the ranges of ``tests/test_fit.py``, measured at five
scales with its own image size (16–32 px), extent (0.4–0.6) and number of replicate images
(1 or 2) — a lab whose set-up changes from sample to sample, so that no two materials need
share a compiled fit unless the fits are bucketed (``fitting.fit_many``).
"""

import os

import numpy as np

SIZES = (16, 20, 24, 28, 32)
EXTENTS = (0.4, 0.5, 0.6)
SCALES = (0.5, 1.0, 2.0, 4.0, 8.0)


def truth(i: int, seed: int = 0) -> dict:
    rng = np.random.default_rng([seed, i])
    return dict(amplitude=float(rng.uniform(0.3, 2.5)), alpha_lobe=float(rng.uniform(0.04, 0.08)),
                alpha_max=float(rng.uniform(0.15, 0.25)), mu_c=float(rng.uniform(0.7, 2.0)),
                exponent=float(rng.uniform(0.6, 1.5)))


def material(i: int, seed: int = 0, noise: float = 0.02):
    """The measurement set of material ``i`` (needs float64 JAX)."""
    from brdfscale import fitting

    rng = np.random.default_rng([seed, i, 1])
    model = fitting.ParametricModel()
    return fitting.simulate(model, truth(i, seed), SCALES, size=int(rng.choice(SIZES)),
                            extent=float(rng.choice(EXTENTS)), noise=noise, floor=1e-3,
                            replicates=int(rng.integers(1, 3)), seed=int(rng.integers(2**31)))


def write_library(directory: str, n: int, seed: int = 0) -> list[str]:
    """Write materials 0 … n−1 as ``directory/material_NNN.exr``; return the paths."""
    from brdfscale import exr

    os.makedirs(directory, exist_ok=True)
    paths = []
    for i in range(n):
        path = os.path.join(directory, f"material_{i:03d}.exr")
        exr.write_measurements(path, material(i, seed), overwrite=True)
        paths.append(path)
    return paths
