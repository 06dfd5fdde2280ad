"""``brdfscale fit MEASUREMENTS.exr --out DIR``: the main job (the fitting package).

Reads a measurement set, fits a model (optimistix, multi-start), samples its posterior
(NUTS by default, checkpointed to DIR/chain.h5 so an interrupted run resumes), and writes
DIR/fit.json, the figures and the evolved lobe tables (:func:`fitting.write_report`).

The options' names, choices and defaults come from :mod:`brdfscale.choices` (the library's
own), and the parsed options become one :class:`brdfscale.library.FitSpec` (:func:`spec_of`),
which hands them to fitting.
"""

import argparse
import math
import os
import sys
import types
from typing import TYPE_CHECKING

from .._choices import (
    ADEQUACY,
    FAMILIES,
    FIT,
    INCREMENTS,
    LAWS,
    MASKING,
    MODEL,
    MODELS,
    SAMPLE,
    SAMPLERS,
    SHAPES,
    SOLVERS,
)
from .._errors import InvalidInputError
from ._options import integer, MAX_SEED, output_directory, real, seed


if TYPE_CHECKING:
    from ..library import FitSpec
from ._rewind import add_rewind_option, rewind
from ._topography import outliers_note


#: The combinations the data do not determine printed after the fit (the rest are in fit.json's identifiability):
#: the anisotropic non-parametric model leaves dozens of its base lobe's edge nodes undetermined.
SHOWN_UNDETERMINED = 5

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
        raise argparse.ArgumentTypeError(
            f"the value must be a positive finite number (every parameter is); got {text!r:.60}"
        )
    return name.strip(), number


def _starts(text: str):
    """``auto`` or an integer in [1, 256]."""
    if text == "auto":
        return text
    try:
        return integer(1, 256)(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"must be auto or an integer in [1, 256]; got {text!r:.40}") from None


def _smoothness(text: str):
    """``auto``/``gcv`` or a weight in [0, 1e6]."""
    if text in ("auto", "gcv"):
        return text
    return real(0.0, 1e6)(text)


PREDICTED = "predicted_lobes.exr"
"""The file ``--predict`` writes into the output directory."""

PREDICTING_MODELS = ("anisotropic", "anisotropic_law")
"""The ``--model`` names ``--predict`` takes: :func:`fitting.predict_from_measured`'s models (AnisotropicModel with
its ΔΣ estimates, AnisotropicLawModel; library._spec makes them from these names)."""


def _scale_list(text: str) -> tuple[float, ...]:
    """``--predict``'s type: 1–64 comma-separated finite positive scales μ (numbers, the set's unit of μ)."""
    items = [t.strip() for t in text.split(",")] if isinstance(text, str) and len(text) <= 2000 else []
    parse = real(0.0, 1e30, strict_lo=True)
    try:
        values = tuple(parse(t) for t in items)
    except argparse.ArgumentTypeError:
        values = ()
    if not 1 <= len(values) <= 64:
        raise argparse.ArgumentTypeError(
            f"must be 1 to 64 comma-separated positive numbers (scales μ in the set's unit); got {text!r:.60}"
        )
    return values


def add_fit_options(parser) -> None:
    """Options shared by ``fit`` and ``demo``."""
    parser.add_argument(
        "--out",
        required=True,
        help="output directory (fit.json, figures, tables, chain.h5); "
        "one run at a time: a second run into it is refused (exit 3)",
    )
    parser.add_argument("--model", choices=MODELS.names, default=MODEL.model, help=f"the model — {MODELS.help()}")
    parser.add_argument(
        "--shape",
        choices=SHAPES.names,
        default=MODEL.shape,
        help=f"base lobe shape of the anisotropic, isotropic and anisotropic_law models — {SHAPES.help()}",
    )
    parser.add_argument(
        "--increments",
        choices=INCREMENTS.names,
        default=MODEL.increments,
        help=f"the change of the lobe between scales in the anisotropic, isotropic and anisotropic_law models — "
        f"{INCREMENTS.help()}",
    )
    parser.add_argument(
        "--family",
        choices=FAMILIES.names,
        default=MODEL.family,
        help=f"family of the base lobe and of the slope statistics (parametric model) — {FAMILIES.help()}",
    )
    parser.add_argument(
        "--law",
        choices=LAWS.names,
        default=MODEL.law,
        help=f"scale law of the parametric and anisotropic_law models — {LAWS.help()}",
    )
    parser.add_argument(
        "--masking",
        choices=MASKING.names,
        default=MASKING.default,
        help=f"masking and shadowing in the forward model (docs/masking.md) — {MASKING.help()}",
    )
    parser.add_argument(
        "--fix",
        type=_fixed,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="hold a parametric quantity fixed (e.g. mu_c=1.0) at a value inside its prior box "
        "(docs/fitting.md); repeatable, once per name",
    )
    parser.add_argument(
        "--solver", choices=SOLVERS.names, default=FIT.solver, help=f"optimistix solver — {SOLVERS.help()}"
    )
    parser.add_argument(
        "--starts",
        type=_starts,
        default=FIT.starts,
        help=f"multi-start count, 1–256, or auto: the model's own count, {FIT.model_starts} (1 for the anisotropic "
        f"non-parametric model) (default {FIT.starts}, fitting.fit's; earlier releases of the command "
        "defaulted to 6, then 8)",
    )
    parser.add_argument(
        "--max-steps",
        type=integer(1, 100_000),
        default=FIT.max_steps,
        help=f"solver steps per start, 1–100000 (default {FIT.max_steps}); a start that needs more is reported",
    )
    parser.add_argument(
        "--base-nodes",
        type=integer(3, 41),
        default=MODEL.base_nodes,
        help=f"non-parametric model: base lobe tabulated on N × N nodes, 3–41 (default {MODEL.base_nodes})",
    )
    parser.add_argument(
        "--knots",
        type=integer(2, 64),
        default=MODEL.knots,
        help=f"non-parametric model: W knots of the relative statistics, 2–64 (default {MODEL.knots})",
    )
    parser.add_argument(
        "--regularisation",
        type=_smoothness,
        default=MODEL.regularisation,
        metavar="auto|WEIGHT",
        help="non-parametric model: weight of the smoothness prior, a number in [0, 1e6] (default "
        f"{MODEL.smoothness:g}) or auto (generalised cross-validation about a pilot fit; docs/fitting.md)",
    )
    parser.add_argument(
        "--sampler",
        choices=SAMPLERS.names,
        default=SAMPLE.sampler,
        help=f"posterior sampler — {SAMPLERS.help()}; docs/fitting.md (fitting.sample defaults to "
        f"{SAMPLE.sampler} too; nuts before it, emcee in earlier releases)",
    )
    parser.add_argument(
        "--sample-inadequate",
        action="store_true",
        help="sample the posterior even where the fit is inadequate (exit status 5) or its reported statistics "
        "undetermined (7) before sampling (by default such a fit is reported with its Laplace uncertainties only)",
    )
    parser.add_argument(
        "--chains",
        type=integer(1, 64),
        default=SAMPLE.chains,
        help=f"independent chains (emcee: independent ensembles), 1–64 (default {SAMPLE.chains}; R̂ needs ≥ 2)",
    )
    parser.add_argument(
        "--steps",
        type=integer(0, 1_000_000),
        default=SAMPLE.steps,
        help="draws per chain after the warm-up (nuts, hmc), steps per chain (imh) or emcee steps per walker, "
        f"0–1000000 (default: {SAMPLE.steps_text()}; 0: Laplace only; not given, --model nonparametric_anisotropic "
        "is not sampled: its hundreds of coordinates make a chain far slower than its fit); the chains are kept in "
        "memory: "
        f"chains × walkers × steps × parameters × 8 bytes ≤ {CHAIN_BUDGET // 2**30} GiB",
    )
    parser.add_argument(
        "--time-limit",
        type=real(0.0, 1e7, strict_lo=True),
        default=None,
        metavar="SECONDS",
        help="end the sampling after SECONDS (the warm-up always completes, then at least two draws; the chunks of "
        "draws are paced to the time left): the report is written with the steps done and its status is not "
        "converged (exit status 6); the same command run again continues the chain from DIR/chain.h5 (default: "
        "no limit)",
    )
    parser.add_argument(
        "--walkers",
        type=integer(2, 4096),
        default=None,
        help="emcee only: walkers per ensemble, even, ≥ 2 × parameters, ≤ 4096 (default max(32, 4 × parameters))",
    )
    parser.add_argument(
        "--seed",
        type=seed,
        default=FIT.seed,
        help=f"seed of the starts and the sampler, 0–{MAX_SEED} (default {FIT.seed})",
    )
    parser.add_argument(
        "--no-progress",
        action="store_true",
        help="no progress bar (BRDFSCALE_PROGRESS=0 in the environment turns off every bar)",
    )
    parser.add_argument("--force", action="store_true", help="overwrite DIR/fit.json and restart DIR/chain.h5")


def undetermined_lines(undetermined: list[dict]) -> list[str]:
    """The lines printed after the fit for the combinations the data do not determine: the first
    :data:`SHOWN_UNDETERMINED`, then how many more fit.json lists."""
    lines = [f"  not determined by the data: {item['combination']}" for item in undetermined[:SHOWN_UNDETERMINED]]
    if len(undetermined) > SHOWN_UNDETERMINED:
        lines.append(
            f"  … and {len(undetermined) - SHOWN_UNDETERMINED} more combinations not determined by the data "
            "(all in fit.json: identifiability.undetermined_combinations)"
        )
    return lines


SHAPED_MODELS = ("anisotropic", "isotropic", "anisotropic_law")
"""The models that take ``--shape`` and ``--increments`` (and are named ``model:shape[:increments]`` by --compare)."""


def check_fit_options(args) -> None:
    """Cross-option checks that need no data: each --fix name once, options of one model given for it only (--steps
    not given stays None: the sampler's own default, :func:`asked_steps`)."""
    names = [name for name, _ in args.fix]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise InvalidInputError(f"--fix {', '.join(repeated)} given more than once; fix each quantity once.")
    if args.fix and args.model != "parametric":
        raise InvalidInputError("--fix applies to the parametric model only (--model parametric).")
    if args.shape != MODEL.shape and args.model not in SHAPED_MODELS:
        raise InvalidInputError(
            "--shape applies to the anisotropic and isotropic models and to anisotropic_law only (--model anisotropic)."
        )
    if args.increments != MODEL.increments and args.model not in SHAPED_MODELS:
        raise InvalidInputError(
            "--increments applies to the anisotropic and isotropic models and to anisotropic_law only "
            "(--model anisotropic)."
        )
    if args.regularisation is not None and args.model != "nonparametric":
        raise InvalidInputError("--regularisation applies to the non-parametric model only (--model nonparametric).")


def check_predict(args, data, unit) -> None:
    """``--predict`` against the model and the data, before the work: a model with a scale law at any μ
    (``--model anisotropic_law``) or the per-scale one (``anisotropic``, the default: a width law fitted to its ΔΣ
    estimates carries them on, fitting.law_from_differences) — not ``--compare``'s choice — and no
    scale finer than the finest measured one (:func:`check_predicted_file`: nothing overwritten)."""
    predict = getattr(args, "predict", None)
    if predict is None:
        return
    compare = getattr(args, "compare", False)
    if args.model not in PREDICTING_MODELS or compare:
        raise InvalidInputError(
            f"--predict needs --model {', '.join(PREDICTING_MODELS)} (a scale law, or per-scale ΔΣ a law is fitted "
            f"to), without --compare; got --model {args.model}{' --compare' if compare else ''}."
        )
    needed = load_fitting().LawFromDifferences.scales_needed()
    if args.model == "anisotropic" and len(data.scales) < needed:
        raise InvalidInputError(
            f"--predict with --model anisotropic fits a width law to the per-scale ΔΣ: it needs {needed} measured "
            f"scales, the data have {len(data.scales)}; measure more scales or use --model anisotropic_law."
        )
    finest = float(data.scales[0])
    finer = [mu for mu in predict if mu < finest * (1 - 1e-9)]
    if finer:
        raise InvalidInputError(
            f"--predict {', '.join(f'{mu:g}' for mu in finer)}: below the finest measured scale μ0 = {finest:g} "
            f"{unit or 'px'}; predict at μ ≥ μ0 (towards finer scales the evolution is a deconvolution)."
        )


def check_predicted_file(args, resume: bool) -> None:
    """``--predict`` writes DIR/predicted_lobes.exr: an existing one is replaced only with ``--force`` or when the
    run resumes an interrupted one (whose predictions it is)."""
    path = os.path.join(args.out, PREDICTED)
    if getattr(args, "predict", None) is not None and os.path.lexists(path) and not (args.force or resume):
        raise InvalidInputError(f"{path} exists; choose another --out or pass --force to replace it.")


def write_predictions(fitting, problem, result, args, unit, resume: bool = False) -> tuple[str, str | None]:
    """``--predict``: :func:`fitting.predict_from_measured` at the clipped estimate (the printed one; for the
    per-scale model, with the law fitted to the report's ΔΣ estimates — computed at that clipped estimate too — by
    their joint covariance), written as a measurement set to DIR/predicted_lobes.exr (atomic; replaced only with --force
    or on resuming); returns one line saying what, and why the law is inadequate (``LawFromDifferences.
    inadequate_because``) or None. With ``--masking`` the lobes are the model's, masking removed (recorded as
    ``masking``)."""
    import jax.numpy as jnp

    from .. import exr

    theta = jnp.clip(jnp.asarray(result.theta), problem.lower, problem.upper)
    per_scale = isinstance(problem.model, fitting.AnisotropicModel)  # ΔΣ beyond its scales: a law fitted to them
    differences, joint = (result.covariance_differences, result.differences_covariance) if per_scale else (None, None)
    out = fitting.predict_from_measured(
        problem.model, theta, problem.data, args.predict, differences=differences, differences_covariance=joint
    )
    metadata = {"source": "brdfscale fit --predict (fitting.predict_from_measured)", **({"unit": unit} if unit else {})}
    path = os.path.join(args.out, PREDICTED)
    exr.write_measurements(path, out.to_measurements(metadata), overwrite=args.force or resume)
    shown = scales_text(sorted(set(out.scales)), unit)
    why = (
        ""
        if out.validation is None
        else f"; at the coarsest fitted scale χ²/n {out.validation['measured']:.3g} from the measured lobe, "
        f"{out.validation['model']:.3g} from the model's"
    )
    starts = ", ".join(f"{mu:.4g}" for mu in sorted(set(out.source_scales)))
    lobe = "measured lobe" if out.base == "measured" else "model's lobe"
    removed = "" if problem.data.masking == "none" else f" ({problem.data.masking} masking removed, as fitted)"
    source = f"the {lobe} at μ = {starts} {unit or 'px'}{removed}"
    law = (
        ""
        if out.law is None
        else f"; ΔΣ from a {type(out.law.model.law).__name__.lower()} law fitted to the per-scale ΔΣ "
        f"(χ²/dof = {out.law.chi2:.3g}/{out.law.dof}"
        f"{'' if out.law.p_text is None else f', {out.law.p_text}'}"
        f"{'' if out.law.converged else ', its solve not converged'})"
    )
    return f"wrote {path}: {len(out.scales)} lobes at {shown}, predicted from {source}{why}{law}", (
        None if out.law is None else out.law.inadequate_because()
    )


def asked_steps(args) -> int:
    """--steps, or where it is not given the most steps --sampler runs by its own default
    (:meth:`brdfscale.choices.SampleDefaults.steps_for`; auto: the larger of its two choices')."""
    return SAMPLE.steps_for(args.sampler) if args.steps is None else args.steps


def check_sampler_options(args, n_parameters: int) -> None:
    """--sampler, --chains, --walkers and --steps against the model's size, before the fit runs."""
    steps = asked_steps(args)
    if steps == 1:
        raise InvalidInputError("--steps 1 has no transition to measure (no acceptance rate, no τ); give 0 or ≥ 2.")
    sampler, chains = args.sampler, args.chains
    if sampler != "emcee" and args.walkers is not None:
        raise InvalidInputError(f"--walkers applies to --sampler emcee only; {sampler} runs --chains {chains} chains.")
    walkers = 1
    if sampler == "emcee":
        walkers = args.walkers if args.walkers is not None else max(32, 4 * n_parameters)
        if walkers < 2 * n_parameters:
            raise InvalidInputError(
                f"--walkers {walkers}: the model has {n_parameters} parameters, so emcee needs at "
                f"least {2 * n_parameters} walkers."
            )
        walkers += walkers % 2
    size = chains * walkers * steps * n_parameters * 8
    if size > CHAIN_BUDGET:
        raise InvalidInputError(
            f"--chains {chains} × {walkers} walkers × --steps {steps} × {n_parameters} parameters "
            f"is {size / 2**30:.1f} GiB of chains; at most {CHAIN_BUDGET // 2**30} GiB (fewer steps, "
            "chains or walkers)."
        )


def spec_of(args, *, sampler: bool = True):
    """The :class:`brdfscale.library.FitSpec` of the parsed options (``sampler`` False or
    ``--steps 0``: no sampling)."""
    from ..library import FitSpec

    return FitSpec(
        model=args.model,
        shape=args.shape,
        increments=args.increments,
        family=args.family,
        law=args.law,
        fixed=tuple(args.fix),
        base_nodes=args.base_nodes,
        knots=args.knots,
        regularisation=args.regularisation,
        solver=args.solver,
        starts=args.starts,
        max_steps=args.max_steps,
        seed=args.seed,
        sampler=args.sampler if sampler and asked_steps(args) > 0 else None,
        chains=args.chains,
        steps=args.steps,  # None: the sampler's own (auto: that of the sampler it chooses)
        default_sigma=getattr(args, "default_sigma", None),
        masking=args.masking,
        figures=getattr(args, "figures", True),
        sample_inadequate=bool(getattr(args, "sample_inadequate", False)),
    )


def load_fitting() -> types.ModuleType:
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
        f"lobe images at several scales, with uncertainties (optimistix, then the sampler --sampler names, by default "
        f"{SAMPLE.sampler}: {SAMPLERS.summary(SAMPLE.sampler)}; a fit inadequate before sampling is not sampled). "
        "Writes DIR/fit.json, figures and the evolved lobe tables. Every default is the library's "
        f"own (brdfscale.choices): --starts {FIT.starts} ({FIT.model_starts}, 1 for the anisotropic non-parametric "
        "model; 6 in earlier releases of the command).",
    )
    parser.add_argument("measurements", help="multi-part OpenEXR measurement set (brdfscale.exr format)")
    add_fit_options(parser)
    add_rewind_option(parser)
    parser.add_argument(
        "--default-sigma",
        type=real(0.0, 1e30, strict_lo=True),
        default=None,
        help="noise σ > 0 for images without a sigma channel (lobe units)",
    )
    parser.add_argument(
        "--topography",
        default=None,
        metavar="FILE",
        help="joint fit: a height map of the same surface (read as brdfscale topography reads it); its facet "
        "statistics Σ(μ) with standard errors at the measured scales enter the likelihood as ΔΣ(μ0, μk) "
        "(the scales μ in the file's length unit, metres)",
    )
    parser.add_argument(
        "--compare",
        action="store_true",
        help="fit the candidate models (" + ", ".join(name for name, _ in COMPARED) + ", and --model's if "
        "another) to the data, print their AIC and BIC (fitting.compare) and report — sample, write, exit status — "
        "the one of smallest BIC; the table in fit.json's model.comparison",
    )
    parser.add_argument(
        "--predict",
        type=_scale_list,
        default=None,
        metavar="MU[,MU...]",
        help=f"with --model {', '.join(PREDICTING_MODELS)}: the lobes at these scales μ (the set's unit of μ, none "
        "finer than its finest), predicted from the lobe measured at the coarsest fitted scale widened by the fitted "
        "law (the per-scale model: a width law fitted to its ΔΣ estimates by their joint covariance; exit status 5 "
        "where they reject it) — or from the model's own lobe where that predicts the coarsest fitted scale better "
        f"from the next finer one (fitting.predict_from_measured) — written to DIR/{PREDICTED}",
    )
    parser.set_defaults(func=run)


#: The candidates of ``--compare``: (name in the table, FitSpec fields); the anisotropic
#: non-parametric model is left out (minutes per fit; name it with --model to include it).
COMPARED = (
    ("isotropic", {"model": "isotropic", "shape": "gaussian", "increments": "gaussian"}),
    ("anisotropic", {"model": "anisotropic", "shape": "gaussian", "increments": "gaussian"}),
    ("anisotropic:student_t", {"model": "anisotropic", "shape": "student_t", "increments": "gaussian"}),
    ("anisotropic:mixture", {"model": "anisotropic", "shape": "gaussian", "increments": "mixture"}),
    ("anisotropic_law", {"model": "anisotropic_law", "shape": "gaussian", "increments": "gaussian", "law": "width"}),
)


def _candidates(spec: "FitSpec") -> "list[tuple[str, FitSpec]]":
    """``--compare``'s specs by name: :data:`COMPARED`, and ``spec``'s own model if it is another."""
    import dataclasses

    specs = [(name, dataclasses.replace(spec, **fields)) for name, fields in COMPARED]
    key = (spec.model, spec.shape, spec.increments, spec.law)
    if all((s.model, s.shape, s.increments, s.law) != key for _, s in specs):
        own = spec.model if spec.model not in SHAPED_MODELS else f"{spec.model}:{spec.shape}"
        own += f":{spec.increments}" if spec.model in SHAPED_MODELS and spec.increments != "gaussian" else ""
        own += f":{spec.law}" if spec.model == "anisotropic_law" else ""
        specs.append((own, spec))
    return specs


def _compare(fitting, spec, data, stream, unit=None):
    """Fit every candidate of ``--compare``; returns the preferred (smallest BIC) model's
    ``(spec, model, info, result)`` with the comparison table in ``info["comparison"]``."""
    stream(
        f"comparing models on {len(data.scale_of_image)} images at scales {scales_text(data.scales, unit)} "
        f"({data.n_data} valid pixels), "
        + ("each model's own number of starts" if spec.starts == "auto" else f"{spec.starts} starts each")
        + " ..."
    )
    fitted = {}
    for name, candidate in _candidates(spec):
        model, info = candidate.model_for(data)
        stream(f"  comparing: fitting {name} ({len(model.names)} parameters) ...")
        fitted[name] = (candidate, model, info, candidate.fit(model, data))
    table = fitting.compare({name: entry[3] for name, entry in fitted.items()})
    stream("  which model the data prefer (AIC = χ² + 2p, BIC = χ² + p ln n; the smaller the better):")
    for line in table.lines():
        stream(line)
    chosen, model, info, result = fitted[table.preferred["bic"]]
    stream(f"  reporting {table.preferred['bic']}, the model of smallest BIC")
    info = {**info, "comparison": {**table.to_json(), "reported": table.preferred["bic"]}}
    return chosen, model, info, result


def fit_measurements(mset, args, *, stream=print) -> dict:
    """Fit, sample and report ``mset`` according to the parsed options; returns fit.json's content."""
    from .. import files

    fitting = load_fitting()

    check_fit_options(args)
    spec = spec_of(args)
    data = spec.dataset(mset)
    if getattr(args, "topography", None) is not None:
        from .. import topography

        field = topography.read(args.topography)
        data = data.with_topography(fitting.TopographyData.from_field(field, data.scales))
        stream(f"joint fit with the facet statistics of {args.topography} at the {len(data.scales)} measured scales")
    unit = mu_unit(mset.metadata)
    check_predict(args, data, unit)  # before the work: a prediction that cannot be made, or would overwrite
    resolved = fitting.resolution(data, unit=unit)  # a lobe narrower than a few pixels is refused before the work
    if not resolved.ok:  # the caller prints the one-line reason with the exit status (outcome_status)
        return {"outcome": resolved.to_json(), "data": {"unit": unit}}
    if spec.model == "nonparametric" and spec.regularisation in ("auto", "gcv"):
        stream("choosing the smoothness weight by generalised cross-validation (one pilot fit) ...")
    result = None
    if getattr(args, "compare", False):
        spec, model, info, result = _compare(fitting, spec, data, stream, unit)
    else:
        model, info = spec.model_for(data)
    sampling = spec.sampler is not None and spec.not_sampled_by_default is None
    if sampling:
        check_sampler_options(args, len(model.names))
    truth = fitting.truth_of(model, mset.metadata)  # a damaged truth is refused before the work, not after
    delta_truth = fitting.covariance_truth(mset.metadata, data.scales)  # ΔΣ of the set's own surface, if recorded
    if isinstance(truth_record := mset.metadata.get("truth"), dict):
        outliers_note(truth_record)  # a damaged slope-outlier record refused before the work, as the truth is
    # before the long work: a complete report refused, an incomplete one beside a complete chain resumed
    checkpoint = os.path.join(args.out, "chain.h5")
    if getattr(args, "rewind_checkpoint", False):  # a damaged chain's verified chunks kept first
        stream(rewind(fitting, checkpoint, args.force))
    resuming = fitting.resume_report(args.out, args.force, checkpoint=checkpoint, steps=args.steps if sampling else 0)
    if resuming:
        stream(resuming)
    check_predicted_file(args, resume=resuming is not None)
    with files.exclusive(args.out, what="output directory"):
        return _fit_and_report(
            fitting,
            spec,
            data,
            model,
            info,
            truth,
            args,
            stream,
            resume=resuming is not None,
            unit=unit,
            result=result,
            covariance_truth=delta_truth,
        )


def _fit_and_report(
    fitting, spec, data, model, info, truth, args, stream, resume=False, unit=None, result=None, covariance_truth=None
) -> dict:
    """Fit (unless ``result``, --compare's fit of this model, is given), sample and write the report."""
    if result is None:
        stream(
            f"fitting {len(data.scale_of_image)} images at scales {scales_text(data.scales, unit)} "
            f"({data.n_data} valid pixels), {len(model.names)} parameters, "
            f"{fitting.resolve_starts(spec.starts, [model])} start(s) ..."
        )
        result = spec.fit(model, data)
    stream(
        f"  {result.status}: χ²/dof = {result.chi2 / result.dof:.3f}, "
        f"{sum(s['at_best'] for s in result.starts)}/{len(result.starts)} starts at the optimum"
    )
    for line in undetermined_lines(result.undetermined):
        stream(line)
    problem = fitting.Problem(model, data)
    samples = None
    # FitSpec's rule: not where inadequate (the set's recorded ΔΣ included)
    not_sampled = spec.not_sampled_because(problem, result, unit=unit, covariance_truth=covariance_truth)
    if not_sampled is not None:
        stream(f"  not sampled: {not_sampled}")
    if spec.sampler is not None and not_sampled is None:
        samples = spec.sample(
            problem,
            result,
            walkers=args.walkers,
            checkpoint=os.path.join(args.out, "chain.h5"),
            overwrite=args.force,
            progress=not args.no_progress,
            time_limit=getattr(args, "time_limit", None),
        )
        stream(sampling_line(samples.diagnostics()))
    doc = fitting.write_report(
        args.out,
        problem,
        result,
        samples,
        truth=truth,
        model_info=info,
        overwrite=args.force or resume,  # resumed: the partial report's files are written anew
        unit=unit,
        covariance_truth=covariance_truth,
        not_sampled=not_sampled,
    )
    if getattr(args, "predict", None) is not None:  # after the report: a failure here loses no fit
        line, law_problem = write_predictions(fitting, problem, result, args, unit, resume=resume)
        stream(line)
        if law_problem is not None:
            # the law the predictions rest on is tested here (its record: predicted_lobes.exr's metadata "law"); a
            # rejected one joins fit.json's outcome, so the file says what the command's exit status says
            doc = fitting.record_problem(args.out, doc, law_problem)
    return doc


def run(args) -> int:
    load_fitting()  # first: float64 before any array is made
    from .. import exr

    output_directory(args.out)
    mset = exr.read_measurements(args.measurements)
    doc = fit_measurements(mset, args)
    if "parameters" in doc:  # a report was written (a refused fit writes none)
        print(f"wrote {os.path.join(args.out, 'fit.json')}")
        print_determined(doc)
        print_truth(doc, surface=mset.metadata)
        print_outcome(doc)
    return outcome_status(doc["outcome"])


def scales_text(scales, unit: str | None) -> str:
    """``μ = [a, b, …] UNIT`` for a progress line: μ's length unit (:func:`mu_unit`; px where None)."""
    return f"μ = [{', '.join(f'{float(s):.4g}' for s in scales)}] {unit or 'px'}"


def mu_unit(metadata) -> str | None:
    """The length unit of the scales μ from a measurement set's metadata (``unit``, written by
    brdfscale synth for a topography); None: pixels of a built-in surface."""
    unit = metadata.get("unit") if isinstance(metadata, dict) else None
    return unit if isinstance(unit, str) and unit else None


def outcome_status(outcome: dict) -> int:
    """The exit status of :func:`fitting.assess`'s verdict (brdfscale._cli's table: 0, 5, 6, 7),
    after its one-line reason on stderr."""
    from . import EXIT_INADEQUATE, EXIT_NOT_CONVERGED, EXIT_OK, EXIT_UNDETERMINED

    status = outcome["status"]
    if status != "ok":
        print(f"brdfscale fit: {status.replace('_', ' ')}: {outcome['reason']}", file=sys.stderr)
    return {
        "ok": EXIT_OK,
        "inadequate": EXIT_INADEQUATE,
        "not_converged": EXIT_NOT_CONVERGED,
        "undetermined": EXIT_UNDETERMINED,
    }[status]


def print_outcome(doc: dict, stream=print) -> None:
    """The per-scale adequacy table of a report's ``outcome`` (fitting.assess) and its verdict."""
    outcome, unit = doc["outcome"], (doc.get("data") or {}).get("unit") or "px"
    t = outcome["thresholds"]
    stream(
        f"  model adequacy per scale — inadequate where χ²/dof > {t['max_reduced_chi2']:g}, the lag-1 "
        f"autocorrelation of the whitened residuals > {t['max_lag1']:g} (each at p < {t['p_value']:g}), or the "
        f"model's ΔΣ(μ0, μ) over the images' pixels misses their own second moments (ΔΣ z: the largest of xx, xy, "
        f"yy in standard errors; p < {t['p_value']:g}); lobe width: rms along its narrower axis in image pixels "
        f"(≥ {t['min_lobe_pixels']:g} needed); away: the share of χ² − n where the model predicts < "
        f"{t.get('away_fraction', ADEQUACY.away_fraction):g} of its peak (near 1: the misfit lies beyond the lobe):"
    )
    stream(
        f"    {'μ (' + unit + ')':>14s} {'χ²/dof':>8s} {'p':>8s} {'lag-1 rows':>10s} {'lag-1 cols':>10s} "
        f"{'p':>8s} {'ΔΣ z':>8s} {'p':>8s} {'width':>6s} {'away':>5s}"
    )
    for k, row in enumerate(outcome["scales"]):
        # None: the prediction is not finite at a valid pixel of the scale (fitting.assess), no figure at all;
        # reports written before the second-moment test have no moments_z (—)
        figures = (("reduced_chi2", "8.3f"), ("chi2_p", "8.2g"), ("lag1_rows", "10.3f"), ("lag1_cols", "10.3f"))
        figures += (("lag1_p", "8.2g"), ("moments_z", "+8.3g"), ("moments_p", "8.2g"), ("width_px", "6.2f"))
        figures += (("away_share", "5.2f"),)
        cells = []
        for key, spec in figures:
            missing = "—" if key.startswith("moments") and (k == 0 or key not in row) else "undefined"
            if key == "away_share" and (row.get("reduced_chi2") is not None or key not in row):
                missing = "—"  # no χ² excess to place, or a report written before the column
            cells.append(table_cell(row.get(key), spec, missing))
        stream(f"    {row['mu']:14.4g} " + " ".join(cells))
    stream(f"  outcome: {outcome['status']}" + (f" — {outcome['reason']}" if outcome["reason"] else ""))


def print_truth(doc: dict, stream=print, surface: dict | None = None) -> None:
    """Truth against estimate for every quantity with a known truth in the measurement set's
    metadata (:func:`fitting.truth_of`), with the pull |estimate − truth|/std, then ΔΣ(μ0, μk) against the
    set's own surface where it records its facet statistics (:func:`fitting.covariance_truth`) with the pull
    (estimate − truth)/std per entry and, where ``surface`` (the set's metadata) records that a few pixel slopes
    carry most of that surface's Σ (``truth.slope_outliers``, written by ``brdfscale synth --topography``), the
    note saying so; nothing without truth."""
    print_covariance_truth(doc, stream, surface)
    rows = {name: row for name, row in doc["parameters"].items() if row.get("truth") is not None}
    if not rows:
        return
    stream(
        f"{'quantity':20s} {'truth':>10s} {'estimate':>10s} {'± std':>10s} {'5 %':>10s} {'95 %':>10s}  |est−truth|/std"
    )
    for name, row in doc["parameters"].items():
        truth = row.get("truth")
        q = row["quantiles_5_50_95"] or [None] * 3  # None: undetermined by the data (no std, no interval)
        std = row["std"]
        est = row["median"] if row["median"] is not None else row["estimate_map"]
        pull = f"{abs(est - truth) / std:.2f}" if truth is not None and std is not None and std > 0 else "—"
        cells = (table_cell(truth, "10.4g", "unknown"), table_cell(est, "10.4g", "undefined"))
        cells += (table_cell(std, "10.3g", "undetermined"), table_cell(q[0], "10.4g", "—"))
        cells += (table_cell(q[2], "10.4g", "—"),)
        stream(f"{name:20s} {' '.join(cells)}  {pull}")


def print_covariance_truth(doc: dict, stream=print, surface: dict | None = None) -> None:
    """ΔΣ(μ0, μk) of the fit and of the images' own second moments (fit.json's ``moment_covariance_differences``)
    against the truth of the surface the set was made from (fitting.covariance_truth), per entry xx, xy, yy:
    truth, each estimate ± std and its pull (estimate − truth)/std (— where there is no std or the model fixes the
    entry); per estimate how many entries lie within 3 std and the largest |pull|; then the note of
    ``surface["truth"]["slope_outliers"]`` where a few pixel slopes carry most of the surface's Σ (the truth is
    then theirs). Nothing where fit.json's entries carry no truth."""
    rows = [d for d in doc.get("covariance_differences") or () if d.get("truth") is not None]
    if not rows:
        return
    moments = [d for d in doc.get("moment_covariance_differences") or () if d.get("truth") is not None]
    moments = moments if len(moments) == len(rows) else [None] * len(rows)
    unit = (doc.get("data") or {}).get("unit") or "px"
    stream("ΔΣ(μ0, μk) against the surface the file was made from (fitting.covariance_truth; slope²):")
    header = f"  {'μ0, μk':>16s} {'entry':>5s} {'truth':>10s} {'fit':>10s} {'± std':>9s} {'pull':>7s}"
    stream(header + (f" {'moments':>10s} {'± std':>9s} {'pull':>7s}" if moments[0] is not None else ""))
    pulls = {"fit": [], "moments": []}
    for d, m in zip(rows, moments):
        for name, a, b in load_fitting().DIFFERENCE_ENTRIES:
            cells = [table_cell(d["truth"][a][b], "10.4g", "unknown")]
            for label, e in (("fit", d), ("moments", m)):
                if e is None:
                    continue
                pull = e["pull"][a][b]
                if pull is not None:
                    pulls[label].append(abs(pull))
                cells += [table_cell(e["value"][a][b], "10.4g", "undefined"), table_cell(e["std"][a][b], "9.3g", "—")]
                cells.append(table_cell(pull, "7.2f", "—"))
            scales = f"{d['mu0']:g}, {d['mu']:g} {unit}"
            stream(f"  {scales:>16s} {name:>5s} {' '.join(cells)}")
    for label, found in pulls.items():
        if found:
            within = sum(p <= 3 for p in found)
            largest = f"largest |pull| {max(found):.3g}"
            stream(f"  {label}: {within} of {len(found)} entries within 3 std of the truth; {largest}")
    truth = (surface or {}).get("truth")
    if isinstance(truth, dict) and (note := outliers_note(truth)):
        stream(f"  {note}")


def table_cell(value, spec: str, missing: str) -> str:
    """``value`` in the format ``spec`` (width first) of a text table, or the word ``missing``
    right-aligned in that width where it is None or not finite: a table never prints nan."""
    if value is not None and math.isfinite(value):
        return f"{value:{spec}}"
    width = int(spec.split(".")[0] or 0)
    return f"{missing:>{width}s}"


def sampling_line(diag: dict) -> str:
    """One line on a sampling run: sampler, chains, draws, the smallest ESS_bulk, the largest R̂, its status."""
    summary = diag.get("summary") or {}
    checked = set((diag.get("criteria") or {}).get("checked") or summary)
    ess = [row["ess_bulk"] for name, row in summary.items() if name in checked and row.get("ess_bulk") is not None]
    rhat = [row["r_hat"] for name, row in summary.items() if name in checked and row.get("r_hat") is not None]
    sizes = (
        f"{diag['chains']} ensembles × {diag['walkers']} walkers"
        if diag["sampler"] == "emcee"
        else f"{diag['chains']} chains"
    )
    figures = (f", min ESS_bulk = {min(ess):.0f}" if ess else "") + (f", max R̂ = {max(rhat):.3f}" if rhat else "")
    chosen = diag.get("chosen_by")
    if chosen:  # fitting.Auto's choice and why
        k = "∞" if chosen["pareto_k"] is None else f"{chosen['pareto_k']:.2f}"
        relation = "≤" if chosen["pareto_k"] is not None and chosen["pareto_k"] <= chosen["limit"] else ">"
        chosen = f" ({chosen['name']}: Pareto k̂ of its proposal's weights {k} {relation} {chosen['limit']:.2f})"
    return (
        f"  {diag['sampler']}{chosen or ''}: {sizes} × {diag['steps']} steps (warm-up/burn-in {diag['burn_in']})"
        f"{figures}; {diag['status']}"
    )


def print_determined(doc: dict, stream=print) -> None:
    """The parameters (undetermined ones with their prior range, no interval), then the ratios
    S(W, μ0)/S(W, μk) the data determine, from a report document (fitting.write_report)."""
    summary = (doc.get("mcmc") or {}).get("summary") or {}
    unit = (doc.get("data") or {}).get("unit") or "px"
    at_bounds = set((doc.get("optimisation") or {}).get("at_prior_bounds") or ())
    for name, row in doc["parameters"].items():
        if name.startswith("D["):
            continue
        value = row["median"] if row["median"] is not None else row["estimate_map"]
        if row["determined"] and row["std"] is not None:
            figures = summary.get(name) or {}
            arviz = "".join(
                f", {label} {figures[key]:{fmt}}"
                for key, label, fmt in (
                    ("ess_bulk", "ESS_bulk", ".0f"),
                    ("ess_tail", "ESS_tail", ".0f"),
                    ("r_hat", "R̂", ".3f"),
                    ("mcse_mean", "MCSE", ".2g"),
                )
                if figures.get(key) is not None
            )
            bound = " — its estimate is at a bound of its prior range" if f"log {name}" in at_bounds else ""
            stream(f"  {name:12s} {value:.5g} ± {row['std']:.4g}{arviz}{bound}")
        else:
            lo, hi = row.get("prior_range") or (None, None)
            prior = f"{table_cell(lo, '.3g', '?')} … {table_cell(hi, '.3g', '?')}"
            stream(f"  {name:12s} undetermined by the data (prior range {prior}; best fit {value:.4g})")
    unnamed = sorted(at_bounds - {f"log {name}" for name in doc["parameters"]})
    if unnamed:  # coordinates of θ that no line above names (a Cholesky factor, a mixture's w or f, …)
        stream(f"  θ coordinates at a prior bound: {', '.join(unnamed)} (fit.json's optimisation.at_prior_bounds)")
    if doc.get("covariance_differences"):
        stream("  what the data determine — ΔΣ(μ0, μk) = Σ(μ0) − Σ(μk), [xx, xy, yy] ± std (slope²):")
        for d in doc["covariance_differences"]:
            fixed = d.get("fixed") or [[False] * 2] * 2  # by an isotropic model (fitting._derived)
            entries = ", ".join(
                "undetermined"
                if d["value"][a][b] is None
                else f"{d['value'][a][b]:.4g} (fixed by the isotropic model)"
                if fixed[a][b]
                else f"{d['value'][a][b]:.4g}" + (f" ± {d['std'][a][b]:.2g}" if d["std"][a][b] is not None else " (±?)")
                for a, b in ((0, 0), (0, 1), (1, 1))
            )
            stream(f"    μ0 = {d['mu0']:g} {unit}, μk = {d['mu']:g} {unit}: [{entries}]")
    if doc.get("moment_covariance_differences"):
        stream("  the same from the images' own second moments, no model (fitting.moment_covariance_differences):")
        for d in doc["moment_covariance_differences"]:
            entries = ", ".join(
                "undefined" if d["value"][a][b] is None else f"{d['value'][a][b]:.4g} ± {d['std'][a][b]:.2g}"
                for a, b in ((0, 0), (0, 1), (1, 1))
            )
            cut = " — truncated: the lobe passes an image's edge" if d.get("truncated") else ""
            stream(f"    μ0 = {d['mu0']:g} {unit}, μk = {d['mu']:g} {unit}: [{entries}]{cut}")
    if doc.get("ratios"):
        stream("  what the data determine — S(W, μ0)/S(W, μk):")
        for name, r in doc["ratios"].items():
            value = r["median"] if r.get("median") is not None else r["estimate"]
            std = f"± {r['std']:.3g}" if r["std"] is not None else "(undetermined)"
            # None: no finite value at the estimate (fitting.summarise_ratios), "undetermined" as a std of None
            shown = f"{value:.4g} {std}" if value is not None else "undetermined (no finite value at the estimate)"
            stream(f"    {name:28s} {shown}   (μ0 = {r['mu0']:g} {unit}, μk = {r['mu']:g} {unit})")
