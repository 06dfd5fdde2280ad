"""Unseen scales predicted from the measured lobe: seed Eq. 4.4 started at the coarsest measured scale
(:func:`predict_from_measured`).

A scale law fitted to multi-scale measurements predicts the lobe at any coarser scale μ as its base lobe at μ0
evolved by ``ΔΣ(μ0, μ)`` (:meth:`fitting.AnisotropicLawModel.predict_at`). Where the lobe's *shape* is not the
model's — the measured lobes of real surfaces are skewed, heavy-tailed or carry satellite peaks — the error of
that prediction is the shape's, at every scale. Eq. 4.4 holds between any two scales, ``G(W, μ) = G(W, μ_s)
S(W, μ_s)/S(W, μ)``, so the lobe at μ can instead start from the lobe *measured* at the coarsest fitted scale
``μ_s ≤ μ``, widened by the law's Gaussian increment only:

    g(u, μ) = (g_measured(·, μ_s) ⊛ N(0, ΔΣ(μ_s, μ)))(u),    ΔΣ(μ_s, μ) = Σ(μ_s) − Σ(μ),

with the model's Σ(μ) (positive semidefinite and monotone for μ ≥ μ_s by the law's construction). For a Gaussian
lobe this is the model's own prediction (covariances add); for every shape of
:class:`fitting.AnisotropicLawModel` (Gaussian, GGX, Student-t) the law's increment is this Gaussian convolution.
The convolution is exact on the image grid for a band-limited lobe: the image's discrete Fourier transform times
the Gaussian's characteristic function ``exp(−½ WᵀΔΣW)`` at the grid's frequencies, the image padded by half its
size on every side with the model's own lobe at μ_s (its masked pixels too), so that the light the measurement did
not see is the model's rather than none.

Noise in the measured lobe passes into the prediction. ``base="auto"`` decides between the measured and the
model's lobe by the data themselves: it predicts the coarsest fitted scale from the next finer one both ways (the
measured lobe at ``μ_{K−1}`` widened by ``ΔΣ(μ_{K−1}, μ_K)``, and the model's lobe at ``μ_K``) and keeps the base
whose χ² against the measured images at ``μ_K`` is smaller. Both χ² count the target's noise alike; the measured
one counts its base's noise too, so it wins only where the model's shape misses by more than the noise. The model
was fitted to ``μ_K`` too, so its χ² there is in-sample: the choice leans towards the model by its few degrees of
freedom against the thousands of pixels, a bias towards the smoother prediction. The two coarsest fitted scales'
images must share a pixel grid for this validation (else give ``base``).
Verified in tests/test_measured_prediction.py (the Gaussian identity against the closed form, masked pixels,
replicate images, the choice on noisy and on mis-shaped data, refusals; the convolution core :func:`widen` under
jit and grad). The function itself runs on concrete arrays (its choices are Python's), not under ``jax.jit``.
"""

import dataclasses
import math
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.special
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from brdfscale import InvalidInputError, LobeImage, MeasurementSet

from ._anisotropic import AnisotropicModel
from ._data import Dataset
from ._law_from_differences import law_from_differences, LawFromDifferences


__all__ = ["BASES", "MeasuredPrediction", "predict_from_measured"]

BASES = ("auto", "measured", "model")
"""The bases of :func:`predict_from_measured`: chosen by validation, the measured lobe, or the model's lobe."""

_GRID_RTOL = 1e-7
"""Two images share a grid (and an image's offsets form one) when the offsets agree to this fraction of the image's
largest |offset|."""


@dataclasses.dataclass(frozen=True)
class MeasuredPrediction:
    """What :func:`predict_from_measured` returns.

    ``values`` (n_img, n_pix): the predicted lobe at every pixel of every target image (padding pixels: 0);
    ``scales``: each target image's scale μ; ``source_scales``: the fitted scale μ_s each starts from (with
    ``base="model"``: μ0, the model's lobe evolving from there);
    ``images``: the target :class:`Dataset` (its grids: :meth:`Dataset.image` reshapes a row of ``values``);
    ``base``: ``"measured"`` or ``"model"``, the lobe the predictions start from; ``validation``: with
    ``base="auto"``, the χ²/n of the two bases at the coarsest fitted scale (keys ``measured``, ``model``, ``n``
    pixels, ``scales`` (μ_{K−1}, μ_K)), else None.
    """

    values: Float[Array, "n_img n_pix"]
    base: str
    scales: tuple[float, ...]
    source_scales: tuple[float, ...]
    images: Dataset
    validation: dict | None = None
    law: LawFromDifferences | None = None

    def to_measurements(self, metadata: dict | None = None) -> MeasurementSet:
        """The predicted lobes as a :class:`brdfscale.MeasurementSet` (one :class:`brdfscale.LobeImage` per target
        image, values clipped at 0, no σ, incident along the normal — the lobe in slope offsets does not depend on
        it), for :func:`brdfscale.exr.write_measurements`; its metadata: ``metadata`` and the prediction's
        ``base``, ``source_scales``, ``validation`` and ``masking`` (that of the fitted images: with masking
        other than none, lobes without masking–shadowing, as the model's are)."""
        images = tuple(
            LobeImage(
                mu=mu,
                incident=np.array([0.0, 0.0, 1.0]),
                extent=self.images.extents[i],
                values=np.clip(self.images.image(i, self.values[i]), 0, None),
            )
            for i, mu in enumerate(self.scales)
        )
        record = {
            "base": self.base,
            "source_scales": list(self.source_scales),
            "validation": self.validation,
            "masking": self.images.masking,
            **({"law": self.law.to_json()} if self.law is not None else {}),
        }
        return MeasurementSet(images, metadata={**(metadata or {}), **record})

    def __repr__(self) -> str:
        chosen = (
            ""
            if self.validation is None
            else (f", χ²/n measured {self.validation['measured']:.3g} vs model {self.validation['model']:.3g}")
        )
        law = "" if self.law is None else f", law χ²/dof {self.law.chi2:.3g}/{self.law.dof}"
        shown = ", ".join(f"{mu:.4g}" for mu in sorted(set(self.scales)))
        return f"MeasuredPrediction({self.values.shape[0]} images at μ = [{shown}], base={self.base!r}{chosen}{law})"


def _grid(data: Dataset, i: int) -> tuple[np.ndarray, np.ndarray]:
    """``(offsets (n, n, 2), E)`` of image ``i``: its pixel offsets on the grid and the 2 × 2 matrix whose columns
    are the offset steps along the grid's axes 1 and 0 (``u = u_00 + E · (j1, j0)``)."""
    n = data.image_sizes[i]
    u = np.asarray(data.offsets[i, : n * n], dtype=float).reshape(n, n, 2)
    if n < 2:
        raise InvalidInputError(f"image {i} has {n} pixel per side; predicting from a measured lobe needs a grid.")
    e = np.stack([u[0, 1] - u[0, 0], u[1, 0] - u[0, 0]], axis=1)
    j0, j1 = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    affine = u[0, 0] + np.einsum("ab,ijb->ija", e, np.stack([j1, j0], axis=-1))
    if not np.allclose(affine, u, rtol=0, atol=_GRID_RTOL * max(float(np.abs(u).max()), 1e-300)):
        raise InvalidInputError(f"image {i}'s pixel offsets are not a regular grid; give images on regular grids.")
    return u, e


def _padded_points(u: np.ndarray, e: np.ndarray, pad: int) -> np.ndarray:
    """The grid of ``u`` extended by ``pad`` pixels on every side (same pitch), (n + 2 pad, n + 2 pad, 2)."""
    n = u.shape[0]
    idx = np.arange(-pad, n + pad)
    j0, j1 = np.meshgrid(idx, idx, indexing="ij")
    return u[0, 0] + np.einsum("ab,ijb->ija", e, np.stack([j1, j0], axis=-1))


def widen(
    image: Float[Array, "m m"],
    steps: Float[Array, "2 2"],
    delta: Float[Array, "2 2"],
    mixture: tuple[Float[Array, " i"], Float[Array, " i"], Float[Array, "2 2"]] | None = None,
) -> Float[Array, "m m"]:
    """``image ⊛ N(0, delta)`` on its grid: the DFT of ``image`` times ``exp(−½ WᵀΔW)`` at the grid's frequencies
    (``steps``: the offset steps along the grid's axes 1 and 0 as columns), periodic — pad the image first.
    ``mixture = (v, s, before)``: the change between two scales of a model with mixture increments
    (:meth:`fitting.AnisotropicModel.increment_mixture`, ``before`` = ΔΣ(μ0, μ_s), ``delta`` = ΔΣ(μ_s, μ)): the
    factor is seed Eq. 4.4's ``S(W, μ_s)/S(W, μ) = R(W, μ)/R(W, μ_s)`` with ``R = Σ_i v_i exp(−½ s_i Wᵀ ΔΣ(μ0, ·)
    W)`` (by log-sum-exp; bounded, as ΔΣ grows with μ). Pure jax.numpy: differentiable in ``delta`` and ``image``."""
    m = image.shape[0]
    omega = 2 * jnp.pi * jnp.fft.fftfreq(m)  # radians per pixel along each grid axis
    w0, w1 = jnp.meshgrid(omega, omega, indexing="ij")  # axis 0, axis 1 of the image
    # W · u = ω · j for u = E j: W = E^{-T} ω, with ω = (ω1, ω0) against E's columns (axis 1, axis 0)
    winv = jnp.linalg.inv(steps).T
    wx = winv[0, 0] * w1 + winv[0, 1] * w0
    wy = winv[1, 0] * w1 + winv[1, 1] * w0

    def quadratic(d):
        return d[0, 0] * wx**2 + 2 * d[0, 1] * wx * wy + d[1, 1] * wy**2

    q = quadratic(delta)
    if mixture is None:
        factor = jnp.exp(-0.5 * q)
    else:
        v, s, before = mixture
        qb = quadratic(before)
        log_v, s = jnp.log(v)[:, None, None], s[:, None, None]
        factor = jnp.exp(
            jax.scipy.special.logsumexp(log_v - 0.5 * s * (qb + q)[None], axis=0)
            - jax.scipy.special.logsumexp(log_v - 0.5 * s * qb[None], axis=0)
        )
    return jnp.real(jnp.fft.ifft2(jnp.fft.fft2(image) * factor))


# compiled once per model and grid size: the work of one prediction is a few array programs, which eager dispatch
# would compile op by op (the existence checks of predict_at hold here: every scale is ≥ μ0, checked before)
_lobe_at = eqx.filter_jit(lambda model, theta, mu0, mu, u: model.predict_at(theta, mu0, mu, u))
_differences = eqx.filter_jit(lambda model, theta, scales: model.covariance_differences(theta, scales))
_widen = jax.jit(widen)


def _law_model(model, theta, data: Dataset, differences, covariance):
    """``(model, θ, law)`` to predict with: a model with a scale law at any μ as it is (law None); the per-scale
    :class:`fitting.AnisotropicModel` with the law fitted to its ``differences`` (:func:`law_from_differences`,
    by their joint ``covariance`` where given)."""
    if isinstance(model, AnisotropicModel):
        if differences is None and not model.isotropic:
            raise InvalidInputError(
                "the per-scale AnisotropicModel determines ΔΣ at the measured scales only: give differences= "
                "(the fit's FitResult.covariance_differences), to which a width law is fitted to reach other scales "
                "(fitting.law_from_differences)."
            )
        # the isotropic per-scale model (with or without differences) is refused by law_from_differences, in one place
        entries = [] if differences is None else differences
        law = law_from_differences(model, theta, entries, data, covariance=covariance)
        return law.model, law.theta, law
    if not (callable(getattr(model, "predict_at", None)) and callable(getattr(model, "covariance_differences", None))):
        raise InvalidInputError(
            "model must carry a scale law defined at any μ (fitting.AnisotropicLawModel: predict_at and "
            f"covariance_differences at any scales), or be the per-scale fitting.AnisotropicModel with its "
            f"differences; got {type(model).__name__}. The non-parametric models determine ΔΣ at the measured "
            "scales only."
        )
    if differences is not None or covariance is not None:
        raise InvalidInputError(
            f"differences= and differences_covariance= are for the per-scale AnisotropicModel; "
            f"{type(model).__name__} carries its own scale law: omit them."
        )
    return model, theta, None


def _source_scale(scales: np.ndarray, mu: float) -> int:
    """Index of the coarsest fitted scale ≤ ``mu`` (to a relative 1e-9)."""
    below = np.nonzero(scales <= mu * (1 + 1e-9))[0]
    if below.size == 0:
        raise InvalidInputError(
            f"μ = {mu:g} is finer than the finest fitted scale μ0 = {scales[0]:g}: a measured lobe is widened "
            "towards coarser scales only (towards finer ones Eq. 4.4 is a deconvolution); predict at μ ≥ μ0."
        )
    return int(below[-1])


def _on_grid(data: Dataset, i: int, u: np.ndarray) -> bool:
    """Whether image ``i`` of ``data`` lies on the grid of offsets ``u`` (n, n, 2)."""
    n = u.shape[0]
    if data.image_sizes[i] != n:
        return False
    mine = np.asarray(data.offsets[i, : n * n]).reshape(n, n, 2)
    return bool(np.allclose(mine, u, rtol=0, atol=_GRID_RTOL * max(float(np.abs(u).max()), 1e-300)))


def _same_grid(data: Dataset, i: int, j: int) -> bool:
    n = data.image_sizes[j]
    return _on_grid(data, i, np.asarray(data.offsets[j, : n * n]).reshape(n, n, 2))


def _measured_base(model, theta, data: Dataset, k: int, u: np.ndarray, e: np.ndarray, pad: int):
    """The σ-weighted mean of ``data``'s images at scale ``k`` on the grid ``u``, padded by ``pad`` pixels, with
    the model's lobe at that scale wherever no image measured a pixel."""
    n = u.shape[0]
    same = [i for i in data.images_of_scale(k) if _on_grid(data, i, u)]
    if not same:
        raise InvalidInputError(
            f"no fitted image at μ = {float(data.scales[k]):g} has the target's pixel grid ({n} × {n} pixels, "
            f"offsets {u[0, 0].tolist()} … {u[-1, -1].tolist()}); the measured lobe is widened on its own grid: "
            "measure the unseen scale on the grid of the fitted images."
        )
    points = _padded_points(u, e, pad)
    mu0, mu = float(data.scales[0]), float(data.scales[k])
    model_lobe = _lobe_at(model, theta, mu0, jnp.asarray([mu]), jnp.asarray(points.reshape(1, -1, 2)))[0]
    model_lobe = model_lobe.reshape(points.shape[:2])
    w2 = jnp.stack([data.weight[i, : n * n] ** 2 for i in same]).reshape(len(same), n, n)
    v = jnp.stack([data.values[i, : n * n] for i in same]).reshape(len(same), n, n)
    total = w2.sum(axis=0)
    mean = jnp.where(total > 0, (w2 * v).sum(axis=0) / jnp.where(total > 0, total, 1.0), 0.0)
    inner = model_lobe[pad : pad + n, pad : pad + n]
    return model_lobe.at[pad : pad + n, pad : pad + n].set(jnp.where(total > 0, mean, inner))


def _predict(model, theta, data: Dataset, target: Dataset, base: str):
    scales = np.asarray(data.scales, dtype=float)
    mu0 = float(scales[0])
    rows, sources, mus = [], [], []
    bases = {}  # the padded measured lobe per (source scale, grid): made once for every target it serves
    n_pix = target.values.shape[1]
    for j, k_t in enumerate(target.scale_of_image):
        mu = float(target.scales[k_t])
        s = _source_scale(scales, mu)
        sources.append(mu0 if base == "model" else float(scales[s]))  # the model's lobe evolves from μ0
        mus.append(mu)
        u, e = _grid(target, j)
        n = u.shape[0]
        if base == "model":
            row = _lobe_at(model, theta, mu0, jnp.asarray([mu]), jnp.asarray(u.reshape(1, -1, 2)))[0]
        else:
            pad = max(2, math.ceil(n / 2))
            key = (s, n, *u[0, 0].tolist(), *e.ravel().tolist())
            if key not in bases:
                bases[key] = _measured_base(model, theta, data, s, u, e, pad)
            image = bases[key]
            mixture = None
            if getattr(model, "increments", "gaussian") == "mixture":  # the change from μ_s by Eq. 4.4's ratio
                d = _differences(model, theta, jnp.asarray([mu0, scales[s], mu]))
                delta, mixture = d[2] - d[1], (*model.increment_mixture(theta), d[1])
            else:
                delta = _differences(model, theta, jnp.asarray([scales[s], mu]))[1]
            row = _widen(image, jnp.asarray(e), delta, mixture)[pad : pad + n, pad : pad + n].reshape(-1)
        rows.append(jnp.pad(row, (0, n_pix - n * n)))
    return jnp.stack(rows), tuple(mus), tuple(sources)


def _chi2(prediction, data: Dataset, images) -> tuple[float, int]:
    w = np.asarray(data.weight)[images]
    r = (np.asarray(prediction) - np.asarray(data.values)[images]) * w
    return float(np.sum(r**2)), int(np.count_nonzero(w))


def predict_from_measured(
    model,
    theta: Float[Array, " n"],
    data: Dataset,
    target: Dataset | float | Sequence[float] | Float[ArrayLike, " k"],
    *,
    base: str = "auto",
    differences: list[dict] | None = None,
    differences_covariance: Float[ArrayLike, "m m"] | Sequence[Sequence[float | None]] | None = None,
) -> MeasuredPrediction:
    """The lobes of ``target``'s images predicted from the lobes measured in ``data`` and the scale law of
    ``model`` at ``theta`` (fitted to ``data``): seed Eq. 4.4 from the coarsest fitted scale ``μ_s ≤ μ`` of each
    target image, the measured lobe there widened by the law's ``ΔΣ(μ_s, μ)`` (module docstring).

    Args:
        model: a model with a scale law at any μ (:class:`fitting.AnisotropicLawModel`), or the per-scale
            :class:`fitting.AnisotropicModel` with ``differences``.
        theta: its fitted coordinates (``fitting.fit(model, data).theta``).
        data: the fitted Dataset: its images are the measured lobes, its finest scale the model's μ0.
        target: the images to predict — a Dataset (its values are not used), each image on the grid of a fitted
            image at a scale no finer than ``data``'s finest — or scales μ (a number or a sequence, in ``data``'s
            unit of μ), each predicted on the grids of ``data``'s images at its coarsest scale.
        base: ``"measured"`` (the measured lobe), ``"model"`` (the model's own prediction,
            ``model.predict_at``) or ``"auto"`` (the one that predicts ``data``'s coarsest scale better from the
            next finer one: module docstring; needs two fitted scales).
        differences: with the per-scale model only, its fit's ``FitResult.covariance_differences``: a width law
            fitted to them (:func:`fitting.law_from_differences`) carries ΔΣ beyond the measured scales, the model's
            base lobe is kept.
        differences_covariance: with ``differences``, their joint covariance (``FitResult.differences_covariance``
            of the same fit): the law is then fitted by generalised least squares and its ``p_value`` tests it.

    Returns:
        :class:`MeasuredPrediction`: the values, the base used, for ``"auto"`` the two χ²/n it chose by, and the
        law fitted to ``differences``.

    Raises:
        InvalidInputError: a model without a law at any μ (the per-scale model without ``differences``, or
            ``differences`` with a model of its own law; :func:`fitting.law_from_differences`' refusals); ``base``
            not one of :data:`BASES`; a target scale finer than μ0; a target image on a grid no fitted image at its
            source scale has; ``base="auto"`` where the two coarsest fitted scales' images lie on different grids;
            ``data`` not a Dataset; ``target`` neither a Dataset nor finite positive scales.
    """
    if not isinstance(data, Dataset):
        raise InvalidInputError(f"data must be a fitting.Dataset; got {type(data).__name__}.")
    if not isinstance(target, Dataset):
        target = _at_scales(data, target)
    if base not in BASES:
        raise InvalidInputError(f"base must be one of {', '.join(map(repr, BASES))}; got {base!r}.")
    scales = np.asarray(data.scales, dtype=float)
    for k_t in sorted(set(target.scale_of_image)):  # every refusal of the targets before any work
        _source_scale(scales, float(target.scales[k_t]))
    model, theta, law = _law_model(model, theta, data, differences, differences_covariance)
    theta = jnp.asarray(theta, dtype=jnp.asarray(data.values).dtype)
    validation = None
    if base == "auto":
        k = len(data.scales) - 1
        if k < 1:
            raise InvalidInputError("base='auto' needs two fitted scales (it validates on the coarsest); give base=.")
        images = list(data.images_of_scale(k))
        finer = _restricted(data, k - 1)
        if not any(_same_grid(data, i, j) for i in images for j in data.images_of_scale(k - 1)):
            raise InvalidInputError(
                f"base='auto' validates by predicting the coarsest fitted scale μ = {scales[k]:g} from the next finer "
                f"one, μ = {scales[k - 1]:g}, whose images lie on other pixel grids; give base='measured' or "
                "base='model'."
            )
        measured, _, _ = _predict(model, theta, finer, _restricted(data, k, images), "measured")
        own, _, _ = _predict(model, theta, data, _restricted(data, k, images), "model")
        chi_measured, n = _chi2(measured, data, images)
        chi_model, _ = _chi2(own, data, images)
        base = "measured" if chi_measured < chi_model else "model"
        validation = {
            "measured": chi_measured / n,
            "model": chi_model / n,
            "n": n,
            "scales": (float(data.scales[k - 1]), float(data.scales[k])),
        }
    values, mus, sources = _predict(model, theta, data, target, base)
    return MeasuredPrediction(values, base, mus, sources, target, validation, law)


def _at_scales(data: Dataset, scales) -> Dataset:
    """A target Dataset: every image of ``data``'s coarsest scale, at each of ``scales`` (sorted, distinct)."""
    try:
        mus = np.atleast_1d(np.asarray(scales, dtype=float))
    except (TypeError, ValueError):
        mus = np.array([np.nan])
    if mus.ndim != 1 or mus.size == 0 or not np.all(np.isfinite(mus)) or not np.all(mus > 0):
        raise InvalidInputError(
            f"target must be a fitting.Dataset or finite positive scales μ (a number or a sequence); got {scales!r}."
        )
    mus = np.unique(mus)
    source = []  # one image per distinct grid of the coarsest scale (replicates on one grid share a prediction)
    for i in data.images_of_scale(len(data.scales) - 1):
        if not any(_same_grid(data, i, j) for j in source):
            source.append(i)
    keep = jnp.asarray([i for _ in mus for i in source])
    return dataclasses.replace(
        data,
        offsets=data.offsets[keep],
        values=jnp.zeros_like(data.values[keep]),
        weight=data.weight[keep],
        scales=jnp.asarray(mus, dtype=data.scales.dtype),
        scale_of_image=tuple(k for k in range(len(mus)) for _ in source),
        image_sizes=tuple(data.image_sizes[int(i)] for i in keep),
        extents=tuple(data.extents[int(i)] for i in keep),
        topography=None,
    )


def _restricted(data: Dataset, k: int, images=None) -> Dataset:
    """``data`` with the scales up to ``k`` and, where ``images`` is given, only those images (all at scale
    ``k``): the layout :func:`_predict` reads (scales, images of a scale, grids, values, weights)."""
    keep = images if images is not None else [i for i, s in enumerate(data.scale_of_image) if s <= k]
    return dataclasses.replace(
        data,
        offsets=data.offsets[jnp.asarray(keep)],
        values=data.values[jnp.asarray(keep)],
        weight=data.weight[jnp.asarray(keep)],
        scales=data.scales[: k + 1],
        scale_of_image=tuple(data.scale_of_image[i] for i in keep),
        image_sizes=tuple(data.image_sizes[i] for i in keep),
        extents=tuple(data.extents[i] for i in keep),
        topography=None,
    )
