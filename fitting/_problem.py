"""The fitting problem: a model paired with its data as whitened residual rows ``r(θ)``.

:class:`Problem` is what :func:`fitting.fit` and :func:`fitting.sample` take; :class:`Rows` is
its pure-array part (one material of :func:`fitting.fit_many`); the checks that a model, data
and fit belong together live here, once.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from brdfscale import InvalidInputError
from brdfscale.checks import require_float64
from brdfscale.show import Shown

from ._data import Dataset, PointData
from ._derived import covariance_differences
from ._joint import TopographyData
from ._model import AbstractModel, require_dataset
from ._result import FitResult


__all__ = ["Problem", "Rows", "check_fit", "check_pair", "stack_trees", "starting_points"]


class Problem(Shown, eqx.Module):
    """A model paired with its data: the whitened residual vector ``r(θ)``.

    The data rows of ``r`` are ``√c_u (f_u(θ) − v̄_u)`` over the distinct points ``u`` of the
    dataset (grouped by radius for radially symmetric models, :meth:`Dataset.points`), then
    the model's prior rows; ``chi2(θ) = ‖r‖² + (within-group scatter)`` is the χ² over all
    valid pixels (plus the prior rows), exactly.

    θ is clipped to the model's prior box before the prediction, so no solver step can
    reach parameters where the forward model does not exist (e.g. a lobe width that
    underflows to 0); inside the box (where every reported optimum lies) the clip is the
    identity.

    Raises:
        InvalidInputError: ``model`` is not a fitting model, ``data`` not a
            :class:`~fitting.Dataset`, or the two do not belong together (a
            :class:`~fitting.NonParametricModel` built from data with another number of scales).
    """

    model: AbstractModel
    data: Dataset
    points: PointData
    lower: jax.Array
    upper: jax.Array

    def __init__(self, model: AbstractModel, data: Dataset):
        require_float64("fitting.Problem")
        if not isinstance(model, AbstractModel):
            raise InvalidInputError(f"Problem(model, data) needs {FITTING_MODEL} as model; got {type(model).__name__}.")
        require_dataset(data, "Problem(model, data)")
        model.check_data(data)
        if data.topography is not None:  # a joint fit compares ΔΣ: the model must have finite second moments
            zero = jnp.zeros(len(model.names), jnp.float64)
            if not np.all(np.isfinite(np.asarray(covariance_differences(model, zero, data.scales)[1:]))):
                raise InvalidInputError(
                    f"a joint fit with a topography compares ΔΣ(μ0, μk), which {type(model).__name__} does not "
                    "define (GGX slopes have no finite variance); use Beckmann statistics or AnisotropicModel."
                )
        self.model, self.data = model, data
        self.points = data.points(model.radial)
        lo, hi = model.bounds(data)
        self.lower, self.upper = jnp.asarray(lo, jnp.float64), jnp.asarray(hi, jnp.float64)

    def _show_items(self):
        return [("model", self.model), ("data", self.data), ("coordinates", len(self.model.names))]

    def residuals(self, theta: Float[Array, " n"]) -> Float[Array, " m"]:
        return self.rows().residuals(theta)

    def rows(self) -> "Rows":
        """What the residuals depend on, without the dataset's layout (:class:`Rows`)."""
        return Rows(self.model, self.data.scales, self.points, self.lower, self.upper, self.data.topography)

    def chi2(self, theta: Float[Array, " n"]) -> Float[Array, ""]:
        """χ² over every valid pixel plus the prior rows."""
        return self.chi2_of_residuals(self.residuals(theta))

    def chi2_of_residuals(self, r: Float[Array, " m"]) -> Float[Array, ""]:
        """χ² from the reduced residuals ``r`` (adds the within-group constant back)."""
        return self.rows().chi2_of_residuals(r)


class Rows(eqx.Module):
    """The whitened residual rows of a :class:`Problem` as a pure pytree of arrays: the model,
    the scales, the distinct points and the prior box — not the dataset, whose layout (image
    sizes, extents) is static and would make every dataset compile its own solve. One
    material of :func:`fitting.fit_many` is one ``Rows``; stacked along a leading axis they
    are a batch (``fitting._batch``)."""

    model: AbstractModel
    scales: jax.Array
    points: PointData
    lower: jax.Array
    upper: jax.Array
    topography: TopographyData | None = None  # a joint fit's ΔΣ rows (fitting._joint)

    def residuals(self, theta: Float[Array, " n"]) -> Float[Array, " m"]:
        """``(√c_u (f_u(θ) − v̄_u), prior rows[, topography rows])`` with θ clipped to the prior box
        (:class:`Problem`); a joint fit appends the whitened ΔΣ rows of :class:`fitting.TopographyData`."""
        theta = jnp.clip(theta, self.lower, self.upper)
        p = self.points
        # jnp.asarray: fit_many and sample pad the points in NumPy (fitting._batch); traced, they pass as they are
        fitted = self.model.predict_points(theta, self.scales, jnp.asarray(p.points))
        rows = [((fitted - p.mean) * p.weight).ravel(), self.model.penalty(theta)]
        if self.topography is not None:
            rows.append(self.topography.residuals(covariance_differences(self.model, theta, self.scales)))
        return jnp.concatenate(rows)

    def chi2_of_residuals(self, r: Float[Array, " m"]) -> Float[Array, ""]:
        """χ² from the reduced residuals ``r`` (adds the within-group constant back)."""
        return r @ r + self.points.chi2_offset

    def chi2(self, theta: Float[Array, " n"]) -> Float[Array, ""]:
        """χ² over every valid pixel plus the prior rows (:meth:`Problem.chi2`)."""
        return self.chi2_of_residuals(self.residuals(theta))


FITTING_MODEL = (
    "a fitting model (fitting.AnisotropicModel, AnisotropicLawModel, AnisotropicNonParametricModel, "
    "ParametricModel, NonParametricModel, or a subclass of fitting.AbstractModel of your own)"
)
"""What :class:`Problem` and :func:`check_pair` ask for, in their messages."""


def check_pair(model, data, what: str) -> None:
    """InvalidInputError naming ``what`` unless ``model`` is a fitting model and ``data`` a Dataset."""
    if not isinstance(model, AbstractModel) or not isinstance(data, Dataset):
        raise InvalidInputError(
            f"{what} needs {FITTING_MODEL} and a fitting.Dataset "
            f"(fitting.Dataset.from_measurements); got {type(model).__name__} and {type(data).__name__}."
        )


def check_fit(problem, fit, what: str) -> None:
    """Raise :class:`~brdfscale.InvalidInputError` unless ``fit`` is a :class:`FitResult` of
    ``problem``'s model (same θ coordinates); ``what`` names the caller in the message."""
    if not isinstance(problem, Problem):
        raise InvalidInputError(f"{what} needs a fitting.Problem as problem; got {type(problem).__name__}.")
    if not isinstance(fit, FitResult):
        raise InvalidInputError(f"{what} needs the FitResult of fitting.fit as fit; got {type(fit).__name__}.")
    names = tuple(problem.model.names)
    theta, cov = np.asarray(fit.theta), np.asarray(fit.covariance)
    if tuple(fit.names) != names or theta.shape != (len(names),) or cov.shape != (len(names), len(names)):

        def brief(n):
            return f"{len(n)} coordinates ({', '.join(n[:3])}{', …' if len(n) > 3 else ''})"

        raise InvalidInputError(
            f"{what}: fit is the result for {brief(tuple(fit.names))}, but the problem's model has "
            f"{brief(names)}; pass the fit of this model and data (fitting.fit(problem.model, problem.data))."
        )


def starting_points(problem, options) -> np.ndarray:
    """The model's data-driven start and ``options.starts − 1`` jittered copies (normal,
    standard deviation ``options.spread`` times the model's :meth:`~fitting.AbstractModel.start_scales`
    in θ, seed ``options.seed``), clipped to the box."""
    lo, hi = np.asarray(problem.lower), np.asarray(problem.upper)
    theta0 = np.clip(problem.model.initial(problem.data), lo, hi)
    rng = np.random.default_rng(options.seed)
    jitter = rng.normal(0.0, options.spread, (options.starts - 1, theta0.size)) * problem.model.start_scales(theta0)
    return np.clip(np.vstack([theta0, theta0 + jitter]), lo, hi)


def stack_trees(trees):
    """Pytrees of one structure stacked leaf by leaf along a new leading axis (NumPy on the host)."""
    return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *trees)
