"""The model interface: forward maps from unconstrained parameter vectors θ to predicted lobe images.

Every model predicts, for each measured scale μ_k, the lobe ``A·g_{μ_k}(u)`` at the pixel
offsets of the dataset through the core evolution operator (seed Eq. 4.4, docs/conventions.md §2)

    G(W, μ_k) = G(W, μ0) · S(W, μ0) / S(W, μ_k),

with μ0 the finest measured scale. θ lives in ℝⁿ; each model maps it onto the valid
domain of its physical quantities (logarithms for positive quantities, softplus for
non-negative increments), so optimisers and samplers need no bounds.

* :class:`ParametricModel` — base lobe family (Beckmann or GGX: width ``alpha_lobe`` and
  amplitude ``A`` at μ0) and statistics family (Beckmann or GGX) whose width follows
  :class:`brdfscale.stats.WidthLaw` ``α(μ) = alpha_max (1 + (μ/mu_c)²)^{−exponent/2}``.
  The law tends to δ as μ → ∞, which supplies the boundary condition ``S(W, ∞) = 1`` that
  multi-scale data alone cannot (docs/conventions.md §2).
* :class:`NonParametricModel` — a tabulated base lobe at μ0 and, for each coarser scale, the
  *relative statistics* ``r_k`` defined by ``s(μ0) = r_k ∗ s(μ_k)``, i.e.
  ``R_k(W) = S(W, μ0)/S(W, μ_k) = exp(−D_k(|W|))`` on a radial W grid: exactly the
  combinations the data determine. Positivity (``R_k > 0``), monotone decay in |W|,
  monotone ordering in μ (``D_{k+1} ≥ D_k``) are built into the parameterisation,
  smoothness is a Gaussian prior on second differences (extra residual rows).

This module holds the interface and what every model shares; the models are in
:mod:`fitting._parametric` and :mod:`fitting._nonparametric`, the smoothness choice of the
non-parametric one in :mod:`fitting._smoothness`.
"""

import abc
import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from brdfscale import InvalidInputError, MeasurementSet
from brdfscale.choices import FIT
from brdfscale.show import Shown

from ._data import Dataset


__all__ = ["AbstractModel", "require_dataset", "predict_images", "moments"]


def moments(data: Dataset) -> tuple[float, np.ndarray]:
    """Robust amplitude and width² of the measured lobe at each scale (for starting points).

    For a Gaussian lobe ``A exp(−|u|²/α²)/(π α²)`` the area where the lobe exceeds half its
    peak is ``π α² ln 2``; that gives α², and the amplitude is ``peak · π α²``. Pixels below
    half the peak (where the noise lives) do not enter.

    Raises:
        InvalidInputError: an image has no positive valid pixel (no lobe to measure).
    """
    n_scales = data.scales.shape[0]
    amp, width2, count = np.zeros(n_scales), np.zeros(n_scales), np.zeros(n_scales)
    weights, values = np.asarray(data.weight), np.asarray(data.values)  # one copy each; slices on the host
    for i, k in enumerate(data.scale_of_image):
        n, a = data.image_sizes[i], data.extents[i]
        valid = weights[i, : n * n] > 0
        v = np.where(valid, values[i, : n * n], -np.inf)
        peak = v.max()
        if not peak > 0:
            raise InvalidInputError(
                f"image {i} (μ = {float(data.scales[k]):g}) has no positive valid pixel (largest value {peak:g}); "
                "a lobe image must be positive where the lobe is, or no amplitude and width can be estimated."
            )
        area = np.count_nonzero(v > peak / 2) * (2 * a / (n - 1)) ** 2
        w2 = max(area, (2 * a / (n - 1)) ** 2) / (math.pi * math.log(2))
        width2[k] += w2
        amp[k] += peak * math.pi * w2
        count[k] += 1
    return float(np.mean(amp / count)), width2 / count


class AbstractModel(Shown, eqx.Module):
    """A forward map θ ↦ predicted images, with names, a prior box and starting points."""

    _show_hidden = ("smoothness_choice", "knots")

    #: The solver that ``solver="auto"`` (the default of :func:`fitting.fit`) uses for this model:
    #: Levenberg–Marquardt with QR steps; the anisotropic models, whose rows far outnumber their
    #: parameters, take its normal-equation steps ("lm_normal", :mod:`fitting._solve`), the anisotropic
    #: non-parametric one "gauss_newton_edm" (:mod:`fitting._gauss_newton`).
    preferred_solver: ClassVar[str] = "lm"

    #: The number of starts that ``starts="auto"`` (the default of :func:`fitting.fit`) gives this
    #: model: ``brdfscale.choices.FIT.model_starts`` (8); the anisotropic non-parametric model, whose
    #: hundreds of coordinates a jittered copy of its data-driven start does not explore, takes 1.
    preferred_starts: ClassVar[int] = FIT.model_starts

    #: Whether ``brdfscale fit`` and :func:`brdfscale.library.fit_library` sample this model's posterior
    #: when a sampler is asked for without a number of steps (``--steps`` / ``FitSpec.steps`` None; the rule
    #: of :meth:`brdfscale.library.FitSpec.not_sampled_because`): True; the anisotropic non-parametric
    #: model, whose hundreds of coordinates make a chain far slower than its fit, keeps its Laplace
    #: uncertainties unless steps are given.
    sampled_by_default: ClassVar[bool] = True

    @property
    @abc.abstractmethod
    def names(self) -> tuple[str, ...]:
        """Names of the unconstrained coordinates θ_i (e.g. ``"log alpha_lobe"``)."""

    @property
    @abc.abstractmethod
    def radial(self) -> bool:
        """Whether every predicted lobe is radially symmetric (then it depends on |u| only)."""

    @abc.abstractmethod
    def predict_points(
        self, theta: Float[Array, " n"], scales: Float[Array, " n_scales"], points: Float[Array, "n_scales n_points 2"]
    ) -> Float[Array, "n_scales n_points"]:
        """The lobe at ``scales[k]`` evaluated at the offsets ``points[k]`` (``scales[0]`` = μ0).

        ``scales`` ascend (``scales[0]`` the finest, as :class:`~fitting.Dataset` orders them):
        models evolve from μ0 towards coarser scales and may rely on it (ParametricModel
        leaves out the run-time existence check, which holds only in that direction)."""

    def predict(self, theta: Float[Array, " n"], data: Dataset) -> Float[Array, "n_img n_pix"]:
        """The predicted lobe at every pixel of every image (padding pixels: anything)."""
        n_scales, n_pix = data.scales.shape[0], data.values.shape[1]
        groups = [data.images_of_scale(k) for k in range(n_scales)]
        n = max(len(g) for g in groups) * n_pix
        points = jnp.stack(
            [jnp.pad(data.offsets[jnp.asarray(g)].reshape(-1, 2), ((0, n - len(g) * n_pix), (0, 0))) for g in groups]
        )
        if self.radial:
            points = jnp.stack([jnp.linalg.norm(points, axis=-1), jnp.zeros(points.shape[:-1])], axis=-1)
        values = self.predict_points(theta, data.scales, points)
        rows = {i: values[k, j * n_pix : (j + 1) * n_pix] for k, g in enumerate(groups) for j, i in enumerate(g)}
        return jnp.stack([rows[i] for i in range(len(data.scale_of_image))])

    @abc.abstractmethod
    def quantities(self, theta: Float[Array, " n"]) -> dict[str, Float[Array, ""]]:
        """The physical quantities of θ by name (what a report prints)."""

    @abc.abstractmethod
    def initial(self, data: Dataset) -> np.ndarray:
        """A data-driven starting point θ0."""

    @abc.abstractmethod
    def bounds(self, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
        """The prior support ``lo ≤ θ ≤ hi`` (a uniform prior in θ; see docs/fitting.md)."""

    @abc.abstractmethod
    def relative_statistics(
        self, theta: Float[Array, " n"], W: Float[Array, " w"], scales: Float[Array, " k"]
    ) -> Float[Array, "k w"]:
        """``S(W, μ0)/S(W, μ_k)`` for every measured scale ``scales[k]`` (ascending, as
        :attr:`Dataset.scales`; row 0 is 1): the data-determined part. It takes the scales, not
        the dataset, so that one compiled program serves every dataset of a library."""

    @property
    @abc.abstractmethod
    def identifiability_notes(self) -> tuple[str, ...]:
        """What the model assumes to make absolute quantities determinable (docs/conventions.md §2)."""

    def start_scales(self, theta0: np.ndarray) -> np.ndarray:
        """Per coordinate of θ, the standard deviation of a jittered start per unit of ``spread``
        (:func:`fitting.fit`'s starts, :func:`fitting._problem.starting_points`), given the
        data-driven start ``theta0``: 1 by default (logarithms of positive quantities, or
        coordinates of order 1); a model with coordinates in other units (a lobe's centre in
        slope units) scales them by its own widths."""
        return np.ones_like(np.asarray(theta0, dtype=float))

    def penalty(self, theta: Float[Array, " n"]) -> Float[Array, " m"]:
        """Whitened prior residuals appended to the data residuals (none by default)."""
        return jnp.zeros((0,), dtype=theta.dtype)

    def check_data(self, data: Dataset) -> None:
        """Raise :class:`~brdfscale.InvalidInputError` unless ``data`` is a :class:`~fitting.Dataset`
        this model can be fitted to (a model built from one dataset fixes its layout)."""
        require_dataset(data, f"{type(self).__name__}.check_data(data)")


def require_dataset(data, where: str) -> None:
    """InvalidInputError naming ``where`` unless ``data`` is a :class:`~fitting.Dataset`."""
    if not isinstance(data, Dataset):
        hint = (
            " (build one with fitting.Dataset.from_measurements(measurement_set))"
            if isinstance(data, MeasurementSet)
            else ""
        )
        raise InvalidInputError(f"{where}: data must be a fitting.Dataset{hint}; got {type(data).__name__}.")


@eqx.filter_jit
def predict_images(model: AbstractModel, theta: Float[Array, " n"], data: Dataset) -> Float[Array, "n_img n_pix"]:
    """``model.predict(theta, data)``, compiled once per model and data layout."""
    return model.predict(theta, data)
