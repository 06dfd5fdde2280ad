"""What a library fit does to every material: the model and the fit's options (one place for
``brdfscale fit`` and ``brdfscale fit-library``)."""

import dataclasses
import math

from .._errors import InvalidInputError

__all__ = ["FitSpec", "make_model"]

_LAWS = {"width": "WidthLaw alpha(mu) = alpha_max (1 + (mu/mu_c)^2)^(-exponent/2)",
         "gaussian_surface": "GaussianSurface(GaussianCorrelation(rms_height, correlation_length), box window)"}


def make_model(fitting, data, *, model="parametric", family="beckmann", law="width", fixed=None, base_nodes=13,
               knots=8, regularisation=None, solver="lm"):
    """The fitting model for ``data`` and the report's description of it (``fit.json``'s
    ``model``): a :class:`fitting.ParametricModel` (``family`` for lobe and statistics, scale
    ``law``, ``fixed`` values checked inside their prior box for these data) or a
    :class:`fitting.NonParametricModel` built from ``data``.

    Raises:
        InvalidInputError: a fixed value outside its box (prefixed ``--fix:``), or the model's own refusals.
    """
    fixed = dict(fixed or {})
    if model == "parametric":
        try:
            built = fitting.ParametricModel(family, family, law=law, fixed=fixed)
            fitting.Problem(built, data)  # fixed values inside their prior box for these data
        except InvalidInputError as err:
            if not fixed:
                raise
            raise InvalidInputError(f"--fix: {err}") from None
        info = {"kind": "parametric", "lobe": family, "statistics": family, "scale_law": _LAWS[law], "fixed": fixed}
    elif model == "nonparametric":
        built = fitting.NonParametricModel(data, base_nodes=base_nodes, n_knots=knots, regularisation=regularisation)
        info = {"kind": "nonparametric", "base_nodes": built.base_nodes, "base_extent": built.base_extent,
                "knots_W": list(built.knots), "smoothness": built.smoothness}
    else:
        raise InvalidInputError(f"model must be 'parametric' or 'nonparametric'; got {model!r}.")
    info["solver"] = solver
    return built, info


@dataclasses.dataclass(frozen=True)
class FitSpec:
    """The options of a library fit, the same for every material, recorded in the library's
    index so that a rerun into the same directory continues the same job (a rerun with other
    options is refused rather than mixing two fits in one library).

    ``sampler`` None (default) gives the Laplace uncertainties of :func:`fitting.fit_many` only;
    ``"nuts"``, ``"hmc"`` or ``"emcee"`` also samples each material's posterior
    (:func:`fitting.sample`, ``chains`` × ``steps``, checkpointed in the material's directory).
    ``figures`` adds the report's three PNG figures per material (on a CPU they take longer than
    the fit; off by default).
    """

    model: str = "parametric"
    family: str = "beckmann"
    law: str = "width"
    fixed: tuple = ()
    base_nodes: int = 13
    knots: int = 8
    regularisation: object = None
    solver: str = "lm"
    starts: int = 6
    max_steps: int = 256
    seed: int = 0
    sampler: str | None = None
    chains: int = 4
    steps: int = 1000
    default_sigma: float | None = None
    figures: bool = False

    def __post_init__(self):
        if self.model not in ("parametric", "nonparametric"):
            raise InvalidInputError(f"model must be 'parametric' or 'nonparametric'; got {self.model!r}.")
        if self.sampler not in (None, "nuts", "hmc", "emcee"):
            raise InvalidInputError(f"sampler must be None, 'nuts', 'hmc' or 'emcee'; got {self.sampler!r}.")
        if self.default_sigma is not None and not (math.isfinite(self.default_sigma) and self.default_sigma > 0):
            raise InvalidInputError(f"default_sigma must be a positive number; got {self.default_sigma!r}.")
        object.__setattr__(self, "fixed", tuple(sorted(dict(self.fixed).items())))

    def to_json(self) -> dict:
        doc = dataclasses.asdict(self)
        doc["fixed"] = dict(self.fixed)
        return doc

    def model_for(self, fitting, data):
        """:func:`make_model` with these options."""
        return make_model(fitting, data, model=self.model, family=self.family, law=self.law, fixed=dict(self.fixed),
                          base_nodes=self.base_nodes, knots=self.knots, regularisation=self.regularisation,
                          solver=self.solver)
