"""``brdfscale fit MEASUREMENTS.exr --out DIR``: the main job (fitting package, issue 6).

Reads a measurement set, fits a model (optimistix, multi-start), samples its posterior
(emcee, checkpointed to DIR/chain.h5 so an interrupted run resumes), and writes
DIR/fit.json, the figures and the evolved lobe tables (:func:`fitting.write_report`).
"""

import os

from .._errors import InvalidInputError


def _fixed(text: str) -> tuple[str, float]:
    import argparse

    name, sep, value = text.partition("=")
    try:
        return name.strip(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE (e.g. mu_c=1.0); got {text!r}") from None


def add_fit_options(parser) -> None:
    """Options shared by ``fit`` and ``demo``."""
    parser.add_argument("--out", required=True, help="output directory (fit.json, figures, tables, chain.h5)")
    parser.add_argument("--model", choices=("parametric", "nonparametric"), default="parametric",
                        help="parametric lobe + width law (default), or tabulated lobe + relative statistics")
    parser.add_argument("--family", choices=("beckmann", "ggx"), default="beckmann",
                        help="family of the base lobe and of the slope statistics (parametric model; default beckmann)")
    parser.add_argument("--law", choices=("width", "gaussian_surface"), default="width",
                        help="scale law of the parametric model: width (α(μ) power law, default) or gaussian_surface "
                        "(Gaussian-correlated random surface: rms_height, correlation_length; beckmann only)")
    parser.add_argument("--fix", type=_fixed, action="append", default=[], metavar="NAME=VALUE",
                        help="hold a parametric quantity fixed (e.g. mu_c=1.0); repeatable")
    parser.add_argument("--solver", choices=("lm", "gauss_newton", "dogleg", "bfgs"), default="lm",
                        help="optimistix solver (default lm: Levenberg–Marquardt)")
    parser.add_argument("--starts", type=int, default=6, help="multi-start count (default 6)")
    parser.add_argument("--max-steps", type=int, default=256,
                        help="solver steps per start (default 256); a start that needs more is reported as such")
    parser.add_argument("--base-nodes", type=int, default=13,
                        help="non-parametric model: base lobe tabulated on N × N nodes (default 13)")
    parser.add_argument("--knots", type=int, default=8,
                        help="non-parametric model: W knots of the relative statistics (default 8)")
    parser.add_argument("--steps", type=int, default=2000, help="emcee steps (default 2000; 0: Laplace only)")
    parser.add_argument("--walkers", type=int, default=None, help="emcee walkers (default max(32, 4·dim))")
    parser.add_argument("--seed", type=int, default=0, help="seed of the starts and the sampler (default 0)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--force", action="store_true", help="overwrite DIR/fit.json and restart DIR/chain.h5")


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "fit",
        help="fit slope statistics and base lobe to a multi-scale measurement set (EXR)",
        description="Recover the facet-slope statistics S(W, μ) and the base lobe at the finest scale from "
        "lobe images at several scales, with uncertainties (optimistix + emcee). Writes DIR/fit.json, "
        "figures and the evolved lobe tables.",
    )
    parser.add_argument("measurements", help="multi-part OpenEXR measurement set (brdfscale.exr format)")
    add_fit_options(parser)
    parser.add_argument("--default-sigma", type=float, default=None,
                        help="noise σ for images without a sigma channel (lobe units)")
    parser.set_defaults(func=run)


def fit_measurements(mset, args, *, stream=print) -> dict:
    """Fit, sample and report ``mset`` according to the parsed options; returns fit.json's content."""
    import fitting
    from fitting._report import check_out_dir

    data = fitting.Dataset.from_measurements(mset, default_sigma=getattr(args, "default_sigma", None))
    fixed = dict(args.fix)
    if args.model == "parametric":
        model = fitting.ParametricModel(args.family, args.family, law=args.law, fixed=fixed)
        law = {"width": "WidthLaw alpha(mu) = alpha_max (1 + (mu/mu_c)^2)^(-exponent/2)",
               "gaussian_surface": "GaussianSurface(GaussianCorrelation(rms_height, correlation_length), box window)"}
        info = {"kind": "parametric", "lobe": args.family, "statistics": args.family,
                "scale_law": law[args.law], "fixed": fixed}
    else:
        if fixed:
            raise InvalidInputError("--fix applies to the parametric model only.")
        model = fitting.NonParametricModel(data, base_nodes=args.base_nodes, n_knots=args.knots)
        info = {"kind": "nonparametric", "base_nodes": model.base_nodes, "base_extent": model.base_extent,
                "knots_W": list(model.knots), "smoothness": model.smoothness}
    info["solver"] = args.solver
    check_out_dir(args.out, args.force)  # before the long work: every report file, not only fit.json
    stream(f"fitting {len(data.scale_of_image)} images at scales μ = {[float(s) for s in data.scales]} "
           f"({data.n_data} valid pixels), {len(model.names)} parameters, {args.starts} starts ...")
    result = fitting.fit(model, data, solver=args.solver, starts=args.starts, seed=args.seed, max_steps=args.max_steps)
    stream(f"  {result.status}: χ²/dof = {result.chi2 / result.dof:.3f}, "
           f"{sum(s['at_best'] for s in result.starts)}/{len(result.starts)} starts at the optimum")
    for item in result.undetermined:
        stream(f"  not determined by the data: {item['combination']}")
    samples = None
    if args.steps > 0:
        problem = fitting.Problem(model, data)
        samples = fitting.sample(problem, result, walkers=args.walkers, steps=args.steps, seed=args.seed,
                                 checkpoint=os.path.join(args.out, "chain.h5"), overwrite=args.force,
                                 progress=not args.no_progress)
        diag = samples.diagnostics()
        stream(f"  emcee: {diag['walkers']} walkers × {diag['steps']} steps, burn-in {diag['burn_in']}, "
               f"max τ = {max(diag['autocorrelation_time'].values()):.1f}, "
               f"min ESS = {min(diag['effective_sample_size'].values()):.0f} ({diag['tau_note']})")
    truth = fitting.truth_of(model, mset.metadata)
    return fitting.write_report(args.out, fitting.Problem(model, data), result, samples, truth=truth,
                                model_info=info, overwrite=args.force)


def run(args) -> int:
    import fitting  # noqa: F401  (first: it switches JAX to float64 before any array is made)

    from .. import exr

    mset = exr.read_measurements(args.measurements)
    doc = fit_measurements(mset, args)
    print(f"wrote {os.path.join(args.out, 'fit.json')}")
    for name, row in doc["parameters"].items():
        if name.startswith("D["):
            continue
        std = f"± {row['std']:.4g}" if row["determined"] and row["std"] is not None else "undetermined"
        print(f"  {name:12s} {row['median'] if row['median'] is not None else row['estimate_map']:.5g} {std}")
    return 0
