"""``brdfscale demo [--out DIR]``: the main job end to end on a built-in surface.

synthesise (brdfscale.synth: the built-in Gaussian-correlated surface, σ_h = 0.05 px,
ℓ = 8 px, Beckmann pixel facets α = 0.01, Poisson noise) → write EXR → read it back → fit
(Beckmann lobe, Gaussian-surface scale law) → sample (BlackJAX HMC, 4 chains) → report, then print truth
versus estimate ± uncertainty. ``--source model`` replaces the synthesis by the fitting
model's own forward map plus Gaussian noise (a pure check of the inverse machinery).
"""

import os
import time

from .._choices import SAMPLE
from .._errors import InvalidInputError
from ._fit import (
    add_fit_options,
    fit_measurements,
    load_fitting,
    outcome_status,
    print_outcome,
    print_truth,
)
from ._options import integer, make_directory, MAX_SEED, Parser, seed


_SCALES = (2.0, 4.0, 8.0, 16.0, 32.0)
#: Where each printed truth comes from (the table's "truth" column).
_TRUTH_SOURCES = {
    "synth": {
        "amplitude": "the surface's albedo",
        "alpha_lobe": "derived, the width of a Beckmann lobe with the second moment of the μ0 image (micro lobe, "
        "slopes within the μ0 facets of this surface, the instrument's bilinear binning); the fitted "
        "Beckmann shape only approximates that lobe, so a few σ between the two is model error",
        "rms_height": "the spectrum's (the ensemble; this 512² realisation differs by a few %)",
        "correlation_length": "the spectrum's (the ensemble)",
    },
    "model": {
        "amplitude": "simulated",
        "alpha_lobe": "simulated",
        "rms_height": "simulated",
        "correlation_length": "simulated",
    },
}
_MODEL_TRUTH = {"amplitude": 0.9, "alpha_lobe": 0.01, "rms_height": 0.05, "correlation_length": 8.0}


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="run the whole fitting chain on a built-in surface and print truth vs estimate",
        description="Synthesise a multi-scale measurement set of a built-in Gaussian random surface, write it "
        "as EXR, fit the surface's roughness (rms height, correlation length) and base lobe, sample the "
        "posterior and write the report.",
    )
    parser.add_argument("--out", default="brdfscale-demo", help="output directory (default ./brdfscale-demo)")
    parser.add_argument(
        "--source",
        choices=("synth", "model"),
        default="synth",
        help="synth: height-field simulation (default); model: the fit model plus noise",
    )
    parser.add_argument(
        "--steps",
        type=integer(0, 100_000),
        default=1000,
        help=f"HMC draws per chain after {SAMPLE.gradient_warmup} warm-up steps, 0–100000 (default 1000, 4 chains; "
        "0: Laplace only); HMC is the sampler that passes the diagnostics fastest here (docs/fitting.md)",
    )
    parser.add_argument(
        "--seed", type=seed, default=1, help=f"seed of surface, noise and sampler, 0–{MAX_SEED} (default 1)"
    )
    parser.add_argument(
        "--no-progress",
        action="store_true",
        help="no progress bar (BRDFSCALE_PROGRESS=0 in the environment turns off every bar)",
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="overwrite existing files in --out (a directory an earlier demo made is replaced without it)",
    )
    parser.set_defaults(func=run)


def _measurements(source: str, seed: int):
    if source == "synth":
        import numpy as np

        from .. import stats, synth

        field = synth.named_surface("gaussian", size=512, seed=seed, micro=stats.Beckmann(0.01))
        return synth.gonioreflectometer(
            field,
            _SCALES,
            np.array([0.0, 0.0, 1.0]),
            extent=0.05,
            pixels=33,
            noise=synth.PoissonNoise(0.05, read_noise=1.0),
            seed=seed + 1,
        )
    fitting = load_fitting()
    model = fitting.ParametricModel(law="gaussian_surface")
    return fitting.simulate(model, _MODEL_TRUTH, _SCALES, size=33, extent=0.05, noise=0.01, floor=0.05, seed=seed)


def run(args) -> int:
    load_fitting()  # first: float64 before any array is made

    from .. import exr, files

    start = time.perf_counter()
    make_directory(args.out)
    with files.exclusive(args.out, what="demo output directory"):
        marker = os.path.join(args.out, _MARKER)
        if os.path.exists(marker) and not args.force:
            # a directory the demo made itself: running it again replaces its own outputs
            print(f"{args.out} holds an earlier demo's outputs (marked by {_MARKER}); replacing them")
            args.force = True
        existing = [os.path.basename(p) for p in _outputs(args.out) if os.path.lexists(p)]
        if existing and not args.force:
            raise InvalidInputError(
                f"--out {args.out} already holds {', '.join(existing)} (not written by an earlier "
                "demo); choose another --out directory or pass --force to replace them."
            )
        if not os.path.exists(marker) and not existing:
            # nothing of the demo's is here yet, so whatever it writes here from now on is its own
            files.write_text(marker, _MARKER_TEXT)
        return _run(args, exr, start)


#: Marks a directory as the demo's own: a rerun may replace what the demo wrote there; the
#: files of a directory without it (a user's) are never replaced unless --force.
_MARKER = ".brdfscale-demo"


_MARKER_TEXT = "written by `brdfscale demo`; a rerun replaces the demo's files here\n"


def _outputs(out: str) -> list[str]:
    """The files the demo writes into ``out``."""
    return [os.path.join(out, "measurements.exr"), os.path.join(out, "chain.h5"), *load_fitting().report_files(out)]


def _run(args, exr, start) -> int:
    path = os.path.join(args.out, "measurements.exr")
    print(f"[1/4] synthesising ({args.source}) scales μ = {list(_SCALES)} px → {path}")
    exr.write_measurements(path, _measurements(args.source, args.seed), overwrite=args.force)
    print("[2/4] reading it back")
    mset = exr.read_measurements(path)
    print("[3/4] fitting and sampling")
    parser = Parser()
    add_fit_options(parser)
    options = parser.parse_args(
        [
            "--out",
            args.out,
            "--model",  # the demo's truth is a parametric law's (fit's default is the anisotropic model)
            "parametric",
            "--law",
            "gaussian_surface",
            "--starts",
            "4",
            "--steps",
            str(args.steps),
            "--sampler",
            "hmc",
            "--chains",
            "4",
            "--seed",
            str(args.seed),
        ]
        + ["--no-progress"] * args.no_progress
        + ["--force"] * args.force
    )
    doc = fit_measurements(mset, options)
    if "parameters" not in doc:  # refused before the fit (a lobe narrower than a few pixels): no report
        return outcome_status(doc["outcome"])
    print(f"[4/4] report in {args.out}/ (fit.json, data_vs_fit.png, statistics.png, corner.png)")
    print()
    print_truth(doc)
    print("\nthe truth column:")
    for name, text in _TRUTH_SOURCES[args.source].items():
        if name in doc["parameters"]:
            print(f"  {name:20s} {text}")
    print(f"reduced χ² = {doc['optimisation']['reduced_chi2']:.3f}; finished in {time.perf_counter() - start:.0f} s")
    print_outcome(doc)
    return outcome_status(doc["outcome"])  # the exit status tells the truth: 5, 6 or 7 as brdfscale fit
