"""What a fit does to every material: the model and the fit's options (one place for
``brdfscale fit`` and ``brdfscale fit-library``), their defaults read from :mod:`brdfscale.choices`."""

import dataclasses
import math
import os
import types

from .._choices import FAMILIES, FIT, INCREMENTS, LAWS, MASKING, MODEL, MODELS, SAMPLE, SAMPLERS, SHAPES, SOLVERS
from .._errors import InvalidInputError


__all__ = ["FitSpec", "make_model", "model_class"]

#: The fitting class each name of :data:`brdfscale.choices.MODELS` builds (``fitting.<name>``): the one
#: name → class decision, for :func:`make_model` and for what a spec asks of a class before any data
#: (:meth:`FitSpec.starts_count`, :meth:`FitSpec.not_sampled_because`).
_MODEL_CLASSES = {
    "anisotropic": "AnisotropicModel",
    "isotropic": "AnisotropicModel",
    "anisotropic_law": "AnisotropicLawModel",
    "parametric": "ParametricModel",
    "nonparametric": "NonParametricModel",
    "nonparametric_anisotropic": "AnisotropicNonParametricModel",
}


def _fitting() -> types.ModuleType:
    """The fitting package, imported on first use (a Ray driver that only schedules tasks never
    imports the fitting stack)."""
    from .. import fitting

    return fitting


def model_class(model: str) -> type:
    """The :mod:`fitting` class that the model name ``model`` (:data:`brdfscale.choices.MODELS`) builds.

    Raises:
        InvalidInputError: not a model name (naming those accepted).
    """
    MODELS.check(model)
    return getattr(_fitting(), _MODEL_CLASSES[model])


def make_model(
    data,
    *,
    model=MODEL.model,
    shape=MODEL.shape,
    increments=MODEL.increments,
    family=MODEL.family,
    law=MODEL.law,
    fixed=None,
    base_nodes=MODEL.base_nodes,
    knots=MODEL.knots,
    regularisation=MODEL.regularisation,
    solver=FIT.solver,
):
    """The fitting model for ``data`` and the report's description of it (``fit.json``'s
    ``model``): a :class:`fitting.AnisotropicModel` (default; base lobe ``shape``; ``"isotropic"``
    its isotropic special case), a :class:`fitting.ParametricModel` (``family`` for lobe and
    statistics, scale ``law``, ``fixed`` values checked inside their prior box for these data) or a
    non-parametric model built from ``data``; ``increments`` the change between scales of the anisotropic models
    (:data:`brdfscale.choices.INCREMENTS`). The report's ``solver`` is the one ``solver`` stands
    for with this model (``"auto"`` resolved).

    Raises:
        InvalidInputError: a fixed value outside its box (prefixed ``fixed:``), or the model's own refusals.
    """
    fitting = _fitting()
    fixed = dict(fixed or {})
    cls = model_class(model)
    if model == "parametric":
        try:
            built = cls(family, family, law=law, fixed=fixed)
            fitting.Problem(built, data)  # fixed values inside their prior box for these data
        except InvalidInputError as err:
            if not fixed:
                raise
            raise InvalidInputError(f"fixed: {err}") from None
        info = {
            "kind": "parametric",
            "lobe": family,
            "statistics": family,
            "scale_law": LAWS.summary(law),
            "fixed": fixed,
        }
    elif model in ("anisotropic", "isotropic"):
        isotropic = model == "isotropic"
        built = cls(len(data.scales), isotropic=isotropic, shape=shape, increments=increments)
        info = {
            "kind": model,
            "lobe": f"{shape} ({'isotropic, centred' if isotropic else 'full covariance, free centre'})",
            "scale_law": "ΔΣ per scale" + (" (d_k I)" if isotropic else " (full 2 × 2)"),
            "increments": f"{increments}: {INCREMENTS.summary(increments)}",
        }
    elif model == "anisotropic_law":
        built = cls(law, scales=data.scales, shape=shape, increments=increments)
        axes = "α_a a width law" if law == "width" else "ln σ_a a monotone spline in ln μ"
        info = {
            "kind": model,
            "lobe": f"{shape} (full covariance, free centre)",
            "scale_law": f"Σ(μ) = R(φ) diag(σ_1²(μ), σ_2²(μ)) R(φ)ᵀ, {axes} per principal axis ({law})",
            "increments": f"{increments}: {INCREMENTS.summary(increments)}",
        }
    elif model == "nonparametric_anisotropic":
        if isinstance(regularisation, str):
            raise InvalidInputError(
                f"the anisotropic non-parametric model takes a number as regularisation; got {regularisation!r} "
                "(the automatic choice is the isotropic non-parametric model's)."
            )
        weight = MODEL.smoothness if regularisation is None else regularisation
        built = cls(data, base_nodes=base_nodes, n_knots=knots, regularisation=weight)
        info = {
            "kind": "nonparametric_anisotropic",
            "base_nodes": built.base_nodes,
            "knots_W": list(built.knots),
            "harmonics": built.harmonics,
            "odd_harmonics": built.odd_harmonics,
            "smoothness": built.smoothness,
        }
    else:
        built = cls(data, base_nodes=base_nodes, n_knots=knots, regularisation=regularisation)
        info = {
            "kind": "nonparametric",
            "base_nodes": built.base_nodes,
            "base_extent": built.base_extent,
            "knots_W": list(built.knots),
            "smoothness": built.smoothness,
        }
    info["solver"] = fitting.resolve_solver(solver, [built])
    return built, info


@dataclasses.dataclass(frozen=True)
class FitSpec:
    """The model and options of a fit, the same for every material of a library, recorded in the
    library's index so that a rerun into the same directory continues the same job (a rerun with
    other options is refused rather than mixing two fits in one library). The defaults are those
    of :mod:`brdfscale.choices` (``fitting.fit``'s, ``fitting.sample``'s and the models').

    ``sampler`` None (default) gives the Laplace uncertainties of :func:`fitting.fit_many` only;
    a name of :data:`brdfscale.choices.SAMPLERS` (``"nuts"``, ``"hmc"``, ``"emcee"``, ``"imh"``, ``"auto"``) also
    samples each material's posterior
    (:func:`fitting.sample`, ``chains`` × ``steps``, checkpointed in the material's directory).
    ``figures`` adds the report's three PNG figures per material (on a CPU they take longer than
    the fit; off by default).

    A fit whose verdict before sampling (:func:`fitting.assess` without samples) is "inadequate" or
    "undetermined" is not sampled — the posterior of a model its data reject says nothing more about the
    surface, and on real surfaces it is the slowest to sample; a statistic without a standard error stays so
    whatever the chains do (the verdict reads the Laplace analysis), so sampling could only add exit status 6 to
    a 7 after minutes — unless ``sample_inadequate``: the rule of :meth:`not_sampled_because`, which
    ``brdfscale fit`` and :func:`brdfscale.library.fit_library` both apply (``--sample-inadequate`` on the
    command line).

    :meth:`model_for`, :meth:`fit` and :meth:`sample` hand the options on to :mod:`fitting`:
    the one place where a spec becomes arguments.
    """

    model: str = MODEL.model
    shape: str = MODEL.shape
    increments: str = MODEL.increments
    family: str = MODEL.family
    law: str = MODEL.law
    fixed: tuple = ()
    base_nodes: int = MODEL.base_nodes
    knots: int = MODEL.knots
    regularisation: float | str | None = MODEL.regularisation
    solver: str = FIT.solver
    starts: int | str = FIT.starts
    max_steps: int = FIT.max_steps
    seed: int = FIT.seed
    sampler: str | None = None
    chains: int = SAMPLE.chains
    steps: int | None = SAMPLE.steps  # None: the sampler's own default_steps
    default_sigma: float | None = None
    masking: str = MASKING.default
    figures: bool = False
    sample_inadequate: bool = False

    def __post_init__(self):
        MODELS.check(self.model)
        SHAPES.check(self.shape)
        INCREMENTS.check(self.increments)
        FAMILIES.check(self.family)
        LAWS.check(self.law)
        MASKING.check(self.masking)
        SOLVERS.check(self.solver)
        if self.sampler is not None and self.sampler not in SAMPLERS:
            raise InvalidInputError(
                f"sampler must be None or one of {', '.join(map(repr, SAMPLERS.names))}; got {self.sampler!r}."
            )
        if self.default_sigma is not None and not (math.isfinite(self.default_sigma) and self.default_sigma > 0):
            raise InvalidInputError(f"default_sigma must be a positive number; got {self.default_sigma!r}.")
        if not isinstance(self.sample_inadequate, bool):
            raise InvalidInputError(f"sample_inadequate must be True or False; got {self.sample_inadequate!r}.")
        object.__setattr__(self, "fixed", tuple(sorted(dict(self.fixed).items())))

    def to_json(self) -> dict:
        doc = dataclasses.asdict(self)
        doc["fixed"] = dict(self.fixed)
        return doc

    def starts_count(self, starts=None) -> int:
        """The number of starts ``starts`` (default: this spec's) means for this spec's model: an integer as it is,
        ``"auto"`` the model's ``preferred_starts`` (:func:`fitting.resolve_starts`; 1 for the anisotropic
        non-parametric model, 8 for the others)."""
        return _fitting().resolve_starts(self.starts if starts is None else starts, [model_class(self.model)])

    def model_for(self, data):
        """:func:`make_model` with these options: ``(model, info)``."""
        return make_model(
            data,
            model=self.model,
            shape=self.shape,
            increments=self.increments,
            family=self.family,
            law=self.law,
            fixed=dict(self.fixed),
            base_nodes=self.base_nodes,
            knots=self.knots,
            regularisation=self.regularisation,
            solver=self.solver,
        )

    def dataset(self, measurements):
        """:meth:`fitting.Dataset.from_measurements` of a measurement set with ``default_sigma`` and ``masking``."""
        return _fitting().Dataset.from_measurements(
            measurements, default_sigma=self.default_sigma, masking=self.masking
        )

    @property
    def batched(self) -> bool:
        """Whether ``sampler`` samples many materials' posteriors in one program (:meth:`sample_many`: NUTS, HMC);
        False for the samplers that run per material (:meth:`sample`: emcee, imh, auto) and for no sampler."""
        if self.sampler is None:
            return False
        try:
            _fitting().SAMPLERS[self.sampler]().check_batched()
        except InvalidInputError:
            return False
        return True

    @property
    def not_sampled_by_default(self) -> str | None:
        """Why this spec samples no fit at all, known before any fit (the first rule of :meth:`not_sampled_because`;
        ``brdfscale fit`` then checks no sampler options): a sampler asked for without steps for a model not
        ``sampled_by_default`` (the anisotropic non-parametric model); None otherwise."""
        if self.sampler is None or self.steps is not None or model_class(self.model).sampled_by_default:
            return None
        return (
            f"the {self.model} model's posterior is sampled only where steps are given (--steps N, "
            "FitSpec(steps=N)): its hundreds of coordinates make a chain far slower than the fit; the "
            "uncertainties are the Laplace approximation's"
        )

    def not_sampled_because(
        self, problem, fit, *, unit: str | None = None, covariance_truth: list | None = None
    ) -> str | None:
        """Why this spec does not sample ``fit`` of ``problem``, or None where it samples it: it samples (``sampler``
        set), and either ``steps`` is None for a model not ``sampled_by_default`` (the anisotropic non-parametric
        model) or ``sample_inadequate`` is False and :func:`fitting.assess` of the fit without samples (computed only
        then; ``unit`` the scales' length unit, ``covariance_truth`` the set's recorded ΔΣ where known) says
        "inadequate" or "undetermined". The reason is what :func:`fitting.write_report`'s ``not_sampled`` records."""
        if self.sampler is None:
            return None
        if self.not_sampled_by_default is not None:
            return self.not_sampled_by_default
        if self.sample_inadequate:
            return None
        outcome = _fitting().assess(problem, fit, unit=unit, covariance_truth=covariance_truth)
        anyway = "--sample-inadequate (FitSpec(sample_inadequate=True)) samples it anyway"
        if outcome.status == "inadequate":
            return f"the model is inadequate before sampling (exit status 5 either way); {anyway}"
        if outcome.status == "undetermined":  # an unresolved lobe, or a statistic without a standard error
            return (
                "the fit is undetermined before sampling, which no chain changes (exit status 7 either way: the "
                f"verdict reads the data's resolution and the Laplace analysis) — {outcome.reason}; {anyway}"
            )
        return None

    def fit(self, model, data):
        """:func:`fitting.fit` of ``model`` to ``data`` with these options."""
        return _fitting().fit(
            model, data, solver=self.solver, starts=self.starts, seed=self.seed, max_steps=self.max_steps
        )

    def fit_many(self, models, datasets, *, batch: int, errors: str = "return"):
        """:func:`fitting.fit_many` with these options."""
        return _fitting().fit_many(
            models,
            datasets,
            batch=batch,
            solver=self.solver,
            starts=self.starts,
            max_steps=self.max_steps,
            seed=self.seed,
            errors=errors,
        )

    def sample(
        self,
        problem,
        fit,
        *,
        walkers: int | None = None,
        checkpoint: str | os.PathLike | None = None,
        overwrite: bool = False,
        progress: bool = True,
        time_limit: float | None = None,
    ):
        """:func:`fitting.sample` with these options (``sampler`` must be set); ``walkers``: emcee's
        walkers per ensemble (default ``max(32, 4·dim)``); ``time_limit``: seconds after which the run ends
        early (:func:`fitting.sample`'s; a condition of this run, not an option of the spec)."""
        fitting = _fitting()
        if self.sampler is None:
            raise InvalidInputError(
                f"this FitSpec samples nothing (sampler=None); give sampler= one of {', '.join(map(repr, SAMPLERS))}."
            )
        sampler = fitting.Emcee(walkers=walkers) if self.sampler == "emcee" else self.sampler
        return fitting.sample(
            problem,
            fit,
            sampler=sampler,
            chains=self.chains,
            steps=self.steps,
            seed=self.seed,
            checkpoint=checkpoint,
            overwrite=overwrite,
            progress=progress,
            time_limit=time_limit,
        )

    def sample_many(self, problems, fits, *, batch: int, errors: str = "return"):
        """:func:`fitting.sample_many` (NUTS or HMC) with these options."""
        return _fitting().sample_many(
            problems,
            fits,
            sampler=self.sampler,
            chains=self.chains,
            steps=self.steps,
            seed=self.seed,
            batch=batch,
            errors=errors,
        )
