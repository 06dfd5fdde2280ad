"""A synthetic gonioreflectometer: lobe images of a height field at several scales."""

import dataclasses
import math
from typing import Literal

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

from .. import stats
from .._errors import InvalidInputError
from .._measurement import LobeImage, MeasurementSet
from ..geometry import validate_directions
from ._facets import blur, facet_slopes, kernel_padding, offset_histogram
from ..stats._histogram import SlopeHistogram
from ._random import as_generator, seed_record
from ._surface import HeightField, parameter_record


@dataclasses.dataclass(frozen=True)
class PoissonNoise:
    """Photon-counting noise: ``exposure`` counts per unit lobe value.

    A pixel of true value v reads ``N / exposure`` with ``N ~ Poisson(v · exposure)``; its
    reported standard deviation is ``√max(v · exposure, 1) / exposure`` (the model's, at the
    truth; the floor of one count keeps σ positive where the lobe is dark).
    """

    exposure: float

    def __post_init__(self):
        if not (math.isfinite(self.exposure) and self.exposure > 0):
            raise InvalidInputError(f"exposure must be a positive number of counts per unit value; got {self.exposure!r}.")

    def sample(self, values: Float[np.ndarray, "..."], rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        expected = values * self.exposure
        return rng.poisson(expected) / self.exposure, np.sqrt(np.maximum(expected, 1.0)) / self.exposure

    def record(self) -> dict:
        return {"type": "poisson", "exposure": self.exposure}


@dataclasses.dataclass(frozen=True)
class GaussianNoise:
    """Additive Gaussian noise with per-pixel ``σ = √((relative · v)² + floor²)`` for true value v."""

    floor: float
    relative: float = 0.0

    def __post_init__(self):
        if not (math.isfinite(self.floor) and self.floor > 0):
            raise InvalidInputError(f"floor must be a positive standard deviation; got {self.floor!r}.")
        if not (math.isfinite(self.relative) and self.relative >= 0):
            raise InvalidInputError(f"relative must be ≥ 0; got {self.relative!r}.")

    def sample(self, values: Float[np.ndarray, "..."], rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        sigma = np.sqrt((self.relative * values) ** 2 + self.floor**2)
        return values + sigma * rng.standard_normal(values.shape), sigma

    def record(self) -> dict:
        return {"type": "gaussian", "floor": self.floor, "relative": self.relative}


@eqx.filter_jit
def _box_covariance(law: stats.GaussianSurface, mu):
    return law.slope_covariance(mu)


Weighting = Literal["nearly_flat", "projected_area"]


def gonioreflectometer(
    field: HeightField,
    scales,
    incident: Float[ArrayLike, "*k 3"],
    *,
    extent: float,
    pixels: int = 64,
    noise: PoissonNoise | GaussianNoise | None = None,
    resolution: float = 0.0,
    albedo=1.0,
    weighting: Weighting = "nearly_flat",
    seed=None,
) -> MeasurementSet:
    """Measure the lobes of ``field`` at each scale μ and incident direction i.

    Each image is the lobe a facet of size μ shows in its own frame, averaged over the
    facets: the density of half-vector slope offsets ``u = m_s − m∞`` (DESIGN §6) of the
    light its pixel facets reflect, per unit slope area and per unit of light falling on
    the flat surface, times ``albedo`` — i.e. ``A·g_μ(u)`` of
    :func:`facet_statistics` with ``A = albedo`` (a mirror pixel facet of normal slope m
    reflects into ``m_s = m``). Images sample ``u`` on ``pixels × pixels`` nodes over
    ``[−extent, extent]²`` (rows u_y, columns u_x); light beyond the grid is not renormalised
    into it.

    Args:
        field: the surface (its ``micro`` lobe blurs every pixel facet's reflection).
        scales: facet sizes μ, whole numbers of pixels (length units).
        incident: unit direction(s) towards the light, shape (3,) or (k, 3), z > 0.
        extent: half-width of the image grid (slope units).
        pixels: nodes per image axis (≥ 2).
        noise: :class:`PoissonNoise`, :class:`GaussianNoise` or None (exact images, no σ).
        resolution: the instrument's angular resolution as the standard deviation of an
            isotropic Gaussian blur in slope space (0: none).
        albedo: the amplitude A, a scalar (Y images) or an RGB triple (R, G, B images).
        weighting: ``"nearly_flat"`` — every pixel facet reflects the same light, the seed's
            approximation, so the lobe does not depend on i; ``"projected_area"`` — each
            pixel facet reflects the light it intercepts, ``max(0, 1 + m·i_xy/i_z)`` relative
            to a flat one (no masking or shadowing by other facets).
        seed: int / NumPy Generator / JAX key for the noise (required when noise is set).

    Returns:
        A :class:`brdfscale.MeasurementSet` with one image per (μ, i), scales outermost; its
        ``metadata`` records the surface, the instrument and the truth (facet-slope mean and
        covariance per scale, and the analytic ``Σ(μ)`` of
        :class:`brdfscale.stats.GaussianSurface` with a box window and 256 quadrature
        nodes in k when the field has a spectrum).
    """
    if not isinstance(field, HeightField):
        raise InvalidInputError(f"field must be a brdfscale.synth.HeightField; got {type(field).__name__}.")
    scales = [float(mu) for mu in np.atleast_1d(np.asarray(scales, dtype=float))]
    if not scales:
        raise InvalidInputError("scales must list at least one facet size.")
    for mu in scales:
        field.block(mu)
    directions = np.atleast_2d(np.asarray(incident, dtype=float))
    validate_directions(directions, "incident")
    if not (math.isfinite(extent) and extent > 0):
        raise InvalidInputError(f"extent must be a positive slope half-width; got {extent!r}.")
    if isinstance(pixels, bool) or not isinstance(pixels, (int, np.integer)) or pixels < 2:
        raise InvalidInputError(f"pixels must be an integer ≥ 2; got {pixels!r}.")
    if not (math.isfinite(resolution) and resolution >= 0):
        raise InvalidInputError(f"resolution must be a slope standard deviation ≥ 0; got {resolution!r}.")
    albedo = np.asarray(albedo, dtype=float)
    if albedo.shape not in ((), (3,)) or not np.all(np.isfinite(albedo) & (albedo > 0)):
        raise InvalidInputError(f"albedo must be a positive scalar or an RGB triple; got {albedo!r}.")
    if weighting not in ("nearly_flat", "projected_area"):
        raise InvalidInputError(f"weighting must be 'nearly_flat' or 'projected_area'; got {weighting!r}.")
    if noise is not None and not isinstance(noise, (PoissonNoise, GaussianNoise)):
        raise InvalidInputError(f"noise must be PoissonNoise, GaussianNoise or None; got {type(noise).__name__}.")
    if noise is not None and seed is None:
        raise InvalidInputError("a noisy measurement needs an explicit seed= (int, NumPy Generator or JAX key).")
    rng = None if noise is None else as_generator(seed)

    h = 2 * extent / (pixels - 1)
    pad = kernel_padding(field.micro, resolution, h)
    crop = slice(pad, pad + pixels)
    images, truth = [], {"facet_slope_mean": [], "facet_slope_covariance": []}
    law = None if field.spectrum is None else stats.GaussianSurface(field.spectrum, window="box", n_k=256)
    if law is not None:
        truth["analytic_facet_slope_covariance"] = []
    for mu in scales:
        samples = facet_slopes(field, mu).reshape(-1, 2)
        truth["facet_slope_mean"].append(samples.mean(axis=0).tolist())
        truth["facet_slope_covariance"].append(np.cov(samples.T).tolist() if len(samples) > 1 else [[0.0, 0.0], [0.0, 0.0]])
        if law is not None:
            truth["analytic_facet_slope_covariance"].append(np.asarray(_box_covariance(law, jnp.asarray(mu))).tolist())
        lobe = None
        for i in directions:
            if lobe is None or weighting == "projected_area":
                hist = SlopeHistogram(extent + pad * h, pixels + 2 * pad)
                offset_histogram(field, mu, hist, incident=i if weighting == "projected_area" else None)
                lobe = blur(hist.density(), h, field.micro, resolution)[crop, crop]
            clean = lobe[..., None] * albedo if albedo.ndim else lobe * albedo
            values, sigma = (clean, None) if noise is None else noise.sample(clean, rng)
            images.append(LobeImage(mu=mu, incident=i, extent=extent, values=values, sigma=sigma))
    metadata = {
        "generator": "brdfscale.synth.gonioreflectometer",
        "surface": field.description,
        "spacing": field.spacing,
        "size": field.size,
        "micro": parameter_record(field.micro),
        "scales": scales,
        "pixels": int(pixels),
        "extent": float(extent),
        "noise": None if noise is None else noise.record(),
        "resolution": float(resolution),
        "albedo": albedo.tolist(),
        "weighting": weighting,
        "seed": seed_record(seed),
        "truth": truth,
    }
    return MeasurementSet(tuple(images), metadata)
