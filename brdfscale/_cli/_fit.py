"""``brdfscale fit MEASUREMENTS.exr --out DIR``: the main job (fitting package, issue 6).

Reads a measurement set, fits a model (optimistix, multi-start), samples its posterior
(emcee, checkpointed to DIR/chain.h5 so an interrupted run resumes), and writes
DIR/fit.json, the figures and the evolved lobe tables (:func:`fitting.write_report`).
"""

import math
import os

from .._errors import InvalidInputError
from ..library._spec import make_model
from ._options import MAX_SEED, integer, output_directory, real, seed


#: The chain is held in memory (and in chain.h5): walkers × steps × parameters × 8 bytes at most.
CHAIN_BUDGET = 2 * 2**30


def _fixed(text: str) -> tuple[str, float]:
    import argparse

    name, sep, value = text.partition("=")
    try:
        number = float(value)
    except ValueError:
        number = None
    if not sep or not name.strip() or number is None:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE (e.g. mu_c=1.0); got {text!r:.60}")
    if not (math.isfinite(number) and number > 0):
        raise argparse.ArgumentTypeError(f"the value must be a positive finite number (every parameter is); got {text!r:.60}")
    return name.strip(), number


def _smoothness(text: str):
    """``auto``/``gcv`` or a weight in [0, 1e6]."""
    if text in ("auto", "gcv"):
        return text
    return real(0.0, 1e6)(text)


def add_fit_options(parser) -> None:
    """Options shared by ``fit`` and ``demo``."""
    parser.add_argument("--out", required=True, help="output directory (fit.json, figures, tables, chain.h5); "
                        "one run at a time: a second run into it is refused (exit 3)")
    parser.add_argument("--model", choices=("parametric", "nonparametric"), default="parametric",
                        help="parametric lobe + width law (default), or tabulated lobe + relative statistics")
    parser.add_argument("--family", choices=("beckmann", "ggx"), default="beckmann",
                        help="family of the base lobe and of the slope statistics (parametric model; default beckmann)")
    parser.add_argument("--law", choices=("width", "gaussian_surface"), default="width",
                        help="scale law of the parametric model: width (α(μ) power law, default) or gaussian_surface "
                        "(Gaussian-correlated random surface: rms_height, correlation_length; beckmann only)")
    parser.add_argument("--fix", type=_fixed, action="append", default=[], metavar="NAME=VALUE",
                        help="hold a parametric quantity fixed (e.g. mu_c=1.0) at a value inside its prior box "
                        "(docs/fitting.md); repeatable, once per name")
    parser.add_argument("--solver", choices=("lm", "gauss_newton", "dogleg", "bfgs"), default="lm",
                        help="optimistix solver (default lm: Levenberg–Marquardt)")
    parser.add_argument("--starts", type=integer(1, 256), default=6, help="multi-start count, 1–256 (default 6)")
    parser.add_argument("--max-steps", type=integer(1, 100_000), default=256,
                        help="solver steps per start, 1–100000 (default 256); a start that needs more is reported")
    parser.add_argument("--base-nodes", type=integer(3, 41), default=13,
                        help="non-parametric model: base lobe tabulated on N × N nodes, 3–41 (default 13)")
    parser.add_argument("--knots", type=integer(2, 64), default=8,
                        help="non-parametric model: W knots of the relative statistics, 2–64 (default 8)")
    parser.add_argument("--regularisation", type=_smoothness, default=None, metavar="auto|WEIGHT",
                        help="non-parametric model: weight of the smoothness prior, a number in [0, 1e6] (default "
                        "3) or auto (generalised cross-validation about a pilot fit; docs/fitting.md)")
    parser.add_argument("--sampler", choices=("nuts", "hmc", "emcee"), default="nuts",
                        help="posterior sampler: nuts (default; BlackJAX NUTS, Laplace-preconditioned), hmc (BlackJAX "
                        "HMC of fixed trajectory length) or emcee (affine-invariant ensembles); docs/fitting.md")
    parser.add_argument("--chains", type=integer(1, 64), default=4,
                        help="independent chains (emcee: independent ensembles), 1–64 (default 4; R̂ needs ≥ 2)")
    parser.add_argument("--steps", type=integer(0, 1_000_000), default=2000,
                        help="draws per chain after the warm-up (nuts, hmc) or emcee steps per walker, 0–1000000 "
                        "(default 2000; 0: Laplace only); the chains are kept in memory: chains × walkers × steps × "
                        f"parameters × 8 bytes ≤ {CHAIN_BUDGET // 2**30} GiB")
    parser.add_argument("--walkers", type=integer(2, 4096), default=None,
                        help="emcee only: walkers per ensemble, even, ≥ 2 × parameters, ≤ 4096 (default max(32, 4 × "
                        "parameters))")
    parser.add_argument("--seed", type=seed, default=0, help=f"seed of the starts and the sampler, 0–{MAX_SEED} (default 0)")
    parser.add_argument("--no-progress", action="store_true",
                        help="no progress bar (BRDFSCALE_PROGRESS=0 in the environment turns off every bar)")
    parser.add_argument("--force", action="store_true", help="overwrite DIR/fit.json and restart DIR/chain.h5")


def check_fit_options(args) -> None:
    """Cross-option checks that need no data: each --fix name once."""
    names = [name for name, _ in args.fix]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise InvalidInputError(f"--fix {', '.join(repeated)} given more than once; fix each quantity once.")
    if args.fix and args.model != "parametric":
        raise InvalidInputError("--fix applies to the parametric model only.")
    if args.regularisation is not None and args.model != "nonparametric":
        raise InvalidInputError("--regularisation applies to the non-parametric model only (--model nonparametric).")


def check_sampler_options(args, n_parameters: int) -> None:
    """--sampler, --chains, --walkers and --steps against the model's size, before the fit runs."""
    if args.steps == 1:
        raise InvalidInputError("--steps 1 has no transition to measure (no acceptance rate, no τ); give 0 or ≥ 2.")
    sampler = getattr(args, "sampler", "emcee")
    chains = getattr(args, "chains", 1)
    if sampler != "emcee" and args.walkers is not None:
        raise InvalidInputError(f"--walkers applies to --sampler emcee only; {sampler} runs --chains {chains} chains.")
    walkers = 1
    if sampler == "emcee":
        walkers = args.walkers if args.walkers is not None else max(32, 4 * n_parameters)
        if walkers < 2 * n_parameters:
            raise InvalidInputError(f"--walkers {walkers}: the model has {n_parameters} parameters, so emcee needs at "
                                    f"least {2 * n_parameters} walkers.")
        walkers += walkers % 2
    size = chains * walkers * args.steps * n_parameters * 8
    if size > CHAIN_BUDGET:
        raise InvalidInputError(f"--chains {chains} × {walkers} walkers × --steps {args.steps} × {n_parameters} parameters "
                                f"is {size / 2**30:.1f} GiB of chains; at most {CHAIN_BUDGET // 2**30} GiB (fewer steps, "
                                "chains or walkers).")


def load_fitting():
    """The fitting package, with JAX switched to float64 (the command owns its process; the
    library itself changes no global setting)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from .. import fitting

    return fitting


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
    parser.add_argument("--default-sigma", type=real(0.0, 1e30, strict_lo=True), default=None,
                        help="noise σ > 0 for images without a sigma channel (lobe units)")
    parser.set_defaults(func=run)


def fit_measurements(mset, args, *, stream=print) -> dict:
    """Fit, sample and report ``mset`` according to the parsed options; returns fit.json's content."""
    from .. import files

    fitting = load_fitting()

    check_fit_options(args)
    data = fitting.Dataset.from_measurements(mset, default_sigma=getattr(args, "default_sigma", None))
    if args.model == "nonparametric" and args.regularisation in ("auto", "gcv"):
        stream("choosing the smoothness weight by generalised cross-validation (one pilot fit) ...")
    model, info = make_model(fitting, data, model=args.model, family=args.family, law=args.law, fixed=dict(args.fix),
                             base_nodes=args.base_nodes, knots=args.knots, regularisation=args.regularisation,
                             solver=args.solver)
    if args.steps > 0:
        check_sampler_options(args, len(model.names))
    truth = fitting.truth_of(model, mset.metadata)  # a damaged truth is refused before the work, not after
    fitting.check_report_directory(args.out, args.force)  # before the long work: every report file, not only fit.json
    with files.exclusive(args.out, what="output directory"):
        return _fit_and_report(fitting, mset, data, model, info, truth, args, stream)


def _fit_and_report(fitting, mset, data, model, info, truth, args, stream) -> dict:
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
        sampler = getattr(args, "sampler", "emcee")
        if sampler == "emcee":
            sampler = fitting.Emcee(walkers=args.walkers)
        samples = fitting.sample(problem, result, sampler=sampler, chains=getattr(args, "chains", 4), steps=args.steps,
                                 seed=args.seed, checkpoint=os.path.join(args.out, "chain.h5"), overwrite=args.force,
                                 progress=not args.no_progress)
        stream(sampling_line(samples.diagnostics()))
    return fitting.write_report(args.out, fitting.Problem(model, data), result, samples, truth=truth,
                                model_info=info, overwrite=args.force)


def run(args) -> int:
    load_fitting()  # first: float64 before any array is made
    from .. import exr

    output_directory(args.out)
    mset = exr.read_measurements(args.measurements)
    doc = fit_measurements(mset, args)
    print(f"wrote {os.path.join(args.out, 'fit.json')}")
    print_determined(doc)
    return 0


def sampling_line(diag: dict) -> str:
    """One line on a sampling run: sampler, chains, draws, the smallest ESS_bulk, the largest R̂, its status."""
    summary = diag.get("summary") or {}
    checked = set((diag.get("criteria") or {}).get("checked") or summary)
    ess = [row["ess_bulk"] for name, row in summary.items() if name in checked and row.get("ess_bulk") is not None]
    rhat = [row["r_hat"] for name, row in summary.items() if name in checked and row.get("r_hat") is not None]
    sizes = (f"{diag['chains']} ensembles × {diag['walkers'] // max(diag['chains'], 1)} walkers"
             if diag["sampler"] == "emcee" else f"{diag['chains']} chains")
    figures = (f", min ESS_bulk = {min(ess):.0f}" if ess else "") + (f", max R̂ = {max(rhat):.3f}" if rhat else "")
    return (f"  {diag['sampler']}: {sizes} × {diag['steps']} steps (warm-up/burn-in {diag['burn_in']}){figures}; "
            f"{diag['status']}")


def print_determined(doc: dict, stream=print) -> None:
    """The parameters (undetermined ones with their prior range, no interval), then the ratios
    S(W, μ0)/S(W, μk) the data determine, from a report document (fitting.write_report)."""
    summary = (doc.get("mcmc") or {}).get("summary") or {}
    for name, row in doc["parameters"].items():
        if name.startswith("D["):
            continue
        value = row["median"] if row["median"] is not None else row["estimate_map"]
        if row["determined"] and row["std"] is not None:
            figures = summary.get(name) or {}
            arviz = "".join(f", {label} {figures[key]:{fmt}}" for key, label, fmt in
                            (("ess_bulk", "ESS_bulk", ".0f"), ("ess_tail", "ESS_tail", ".0f"), ("r_hat", "R̂", ".3f"),
                             ("mcse_mean", "MCSE", ".2g")) if figures.get(key) is not None)
            stream(f"  {name:12s} {value:.5g} ± {row['std']:.4g}{arviz}")
        else:
            lo, hi = row.get("prior_range") or (float("nan"), float("nan"))
            stream(f"  {name:12s} undetermined by the data (prior range {lo:.3g} … {hi:.3g}; best fit {value:.4g})")
    if doc.get("ratios"):
        stream("  what the data determine — S(W, μ0)/S(W, μk):")
        for name, r in doc["ratios"].items():
            value = r["median"] if r.get("median") is not None else r["estimate"]
            std = f"± {r['std']:.3g}" if r["std"] is not None else "(undetermined)"
            stream(f"    {name:28s} {value:.4g} {std}   (μ0 = {r['mu0']:g}, μk = {r['mu']:g})")
