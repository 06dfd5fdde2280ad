"""The anisotropic non-parametric model on a real file's lobes, with and without its odd part (issue 31).

README's chain on tests/data's plu-1: ``brdfscale synth --topography plu-1.plu --out m.exr`` (its defaults: the
resolution is the file's slope quantum, ``brdfscale._cli._synth.default_resolution``), then
``fitting.fit(AnisotropicNonParametricModel(data, base_nodes=13, n_knots=8, odd_harmonics=M), data)`` — the
command's model at ``M = 2`` (its default) and the model without an odd part at ``M = 0`` — and
``fitting.assess`` of each: per scale χ²/dof and the lag-1 autocorrelation of the whitened residuals, the outcome,
the solver's status and steps, the wall time. Beside them the images' own standardised third moments along u_x and
u_y per scale (the skewness of the lobes the odd part lets change with the scale).

Run:  flock /tmp/brdfscale-bench.lock python -m experiments.real_nonparametric [--file PATH] [--out DIR]
Writes experiments/results/real_nonparametric.json (docs/fitting.md, "The anisotropic non-parametric model").
"""

import argparse
import tempfile
import time
from pathlib import Path

import jax


jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import brdfscale as bs  # noqa: E402
from brdfscale import fitting  # noqa: E402
from brdfscale._cli import main as cli  # noqa: E402
from brdfscale.choices import MODEL  # noqa: E402
from experiments._bench import code_commit, machine, write_json  # noqa: E402


PLU = Path(__file__).resolve().parent.parent / "tests" / "data" / "topographies" / "plu-1.plu"


def skewness(mset) -> list[dict]:
    """Per image: the standardised third central moments of the lobe along u_x and u_y (negative values clipped)."""
    rows = []
    for image in mset.images:
        v = np.clip(np.asarray(image.values, float), 0.0, None)
        u = np.linspace(-image.extent, image.extent, v.shape[0])
        ux, uy = np.meshgrid(u, u)
        w = v / v.sum()
        dx, dy = ux - np.sum(w * ux), uy - np.sum(w * uy)
        rows.append(
            {
                "mu": float(image.mu),
                "skewness_x": float(np.sum(w * dx**3) / np.sum(w * dx**2) ** 1.5),
                "skewness_y": float(np.sum(w * dy**3) / np.sum(w * dy**2) ** 1.5),
            }
        )
    return rows


def fit_one(data, odd: int) -> dict:
    model = fitting.AnisotropicNonParametricModel(
        data, base_nodes=MODEL.base_nodes, n_knots=MODEL.knots, odd_harmonics=odd
    )
    t0 = time.perf_counter()
    result = fitting.fit(model, data)
    wall = time.perf_counter() - t0
    outcome = fitting.assess(fitting.Problem(model, data), result)
    return {
        "odd_harmonics": odd,
        "parameters": len(model.names),
        "status": result.status,
        "steps": [s.get("steps") for s in result.starts],
        "reduced_chi2": result.chi2 / result.dof,
        "wall_s": wall,
        "outcome": outcome.status,
        "reason": outcome.reason,
        "scales": [
            {k: s.get(k) for k in ("mu", "reduced_chi2", "lag1_rows", "lag1_cols", "moments_z")} for s in outcome.scales
        ],
    }


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--file", default=str(PLU), help="the instrument file (default tests/data's plu-1)")
    parser.add_argument("--out", default=None, help="output folder (default experiments/results)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "m.exr"
        if cli(["--no-compilation-cache", "synth", "--topography", args.file, "--out", str(path)]) != 0:
            raise SystemExit("brdfscale synth failed")
        mset = bs.exr.read_measurements(str(path))
    data = fitting.Dataset.from_measurements(mset)
    payload = {
        "machine": machine(),
        "code_commit": code_commit(),
        "command": "python -m experiments.real_nonparametric",
        "file": Path(args.file).name,
        "synth_defaults": mset.metadata.get("defaults"),
        "skewness": skewness(mset),
        "fits": [fit_one(data, odd) for odd in (2, 0)],
    }
    for f in payload["fits"]:
        per_scale = ", ".join(f"{s['reduced_chi2']:.3g}" for s in f["scales"])
        print(f"odd_harmonics={f['odd_harmonics']}: {f['status']}, {f['wall_s']:.1f} s, χ²/dof per scale {per_scale}")
    write_json("real_nonparametric", payload, args.out)
    return payload


if __name__ == "__main__":
    main()
