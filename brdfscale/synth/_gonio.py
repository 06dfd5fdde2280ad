"""A synthetic gonioreflectometer: lobe images of a height field at several scales."""

import dataclasses
import functools
import warnings
from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

from .. import stats
from .._choices import WEIGHTINGS
from .._errors import InvalidInputError, LobeCutWarning
from .._measurement import LobeImage, MeasurementSet
from .._validation import integer, real, real_array, RealNumber
from ..geometry import validate_directions
from ..stats import SlopeHistogram
from ._facets import (
    _is_mirror,
    blur,
    check_field,
    check_scales,
    facet_samples,
    kernel_padding,
    offset_histogram,
    offset_moments,
)
from ._random import as_generator, seed_record
from ._surface import HeightField, parameter_record


MAX_EXPECTED_COUNT = 1e18
"""The largest expected count ``v · exposure`` :class:`PoissonNoise` draws from. NumPy's
Poisson sampler returns int64 and refuses ``lam`` within 10 standard deviations of the
int64 maximum (about 9.22e18); 1e18 stays clear of that. No detector counts that many
photons per pixel; at such counts the noise is negligible (relative σ ≤ 1e-9), so measure
without noise (``noise=None``) or with :class:`GaussianNoise` instead."""


@dataclasses.dataclass(frozen=True, init=False)
class PoissonNoise:
    """Photon-counting noise: ``exposure`` counts per unit lobe value, plus optional read noise.

    A pixel of true value v reads ``(N + r·ε) / exposure`` with ``N ~ Poisson(v · exposure)``,
    ``ε ~ Normal(0, 1)`` and ``r = read_noise`` (counts). Its reported standard deviation is
    the model's, at the truth:

    * ``read_noise > 0``: ``√(v · exposure + r²) / exposure`` — exactly the standard deviation
      of the reading, so at the truth ``E[((reading − v)/σ)²] = 1`` in every pixel and χ²/dof
      of a correct model is ≈ 1 however dark the lobe is (the detector model of a CCD/CMOS
      camera: shot noise plus Gaussian read noise);
    * ``read_noise = 0`` (default): ``√max(v · exposure, 1) / exposure`` — pure counts, with a
      floor of one count that keeps σ positive where the lobe is dark. That floor is larger
      than the true spread of a pixel whose expected count is below 1 (an exact 0 almost
      always), so χ²/dof of a correct model falls below 1 when many pixels are dark.

    ``exposure`` must be a positive real number ≤ :data:`MAX_EXPECTED_COUNT` (1e18),
    ``read_noise`` a real number ≥ 0; an expected count ``v · exposure`` above the cap when
    sampling is refused too (NumPy's Poisson sampler cannot draw it; the normal
    approximation is not substituted). InvalidInputError otherwise. The χ² claim is tested in
    tests/test_synth.py.
    """

    # the fields hold Python floats (JSON-ready in the metadata); the constructor takes NumPy numbers too
    exposure: float
    read_noise: float

    def __init__(self, exposure: RealNumber, read_noise: RealNumber = 0.0):
        counts = real(exposure, "exposure")
        if not 0 < counts <= MAX_EXPECTED_COUNT:
            raise InvalidInputError(
                f"exposure must be a positive number of counts per unit value, at most MAX_EXPECTED_COUNT = "
                f"{MAX_EXPECTED_COUNT:g} (NumPy's Poisson sampler cannot draw larger counts); got {exposure!r}."
            )
        object.__setattr__(self, "exposure", counts)
        object.__setattr__(self, "read_noise", real(read_noise, "read_noise", minimum=0))

    def sample(self, values: Float[np.ndarray, "..."], rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        expected = real_array(values, "values") * self.exposure
        if np.any(expected < 0):
            raise InvalidInputError(
                f"Poisson noise needs values ≥ 0; the smallest is {np.min(expected) / self.exposure:.6g}."
            )
        peak = float(np.max(expected, initial=0.0))
        if not peak <= MAX_EXPECTED_COUNT:
            raise InvalidInputError(
                f"the largest expected count, {peak:.4g} (value {peak / self.exposure:.4g} × exposure "
                f"{self.exposure:g}), exceeds MAX_EXPECTED_COUNT = {MAX_EXPECTED_COUNT:g}, beyond NumPy's Poisson "
                f"sampler; use exposure ≤ {MAX_EXPECTED_COUNT / peak * self.exposure:.4g}, "
                "or noise=None or GaussianNoise."
            )
        counts = rng.poisson(expected).astype(np.float64)
        if self.read_noise == 0:
            return counts / self.exposure, np.sqrt(np.maximum(expected, 1.0)) / self.exposure
        counts += self.read_noise * rng.standard_normal(expected.shape)
        return counts / self.exposure, np.sqrt(expected + self.read_noise**2) / self.exposure

    def record(self) -> dict:
        return {"type": "poisson", "exposure": self.exposure, "read_noise": self.read_noise}


@dataclasses.dataclass(frozen=True, init=False)
class GaussianNoise:
    """Additive Gaussian noise with per-pixel ``σ = √((relative · v)² + floor²)`` for true value v.

    ``floor`` must be a positive real number, ``relative`` a real number ≥ 0 (InvalidInputError
    otherwise, also for a string, None, bool or complex).
    """

    # the fields hold Python floats (JSON-ready in the metadata); the constructor takes NumPy numbers too
    floor: float
    relative: float

    def __init__(self, floor: RealNumber, relative: RealNumber = 0.0):
        sigma = real(floor, "floor")
        if not sigma > 0:
            raise InvalidInputError(f"floor must be a positive standard deviation; got {floor!r}.")
        object.__setattr__(self, "floor", sigma)
        object.__setattr__(self, "relative", real(relative, "relative", minimum=0))

    def sample(self, values: Float[np.ndarray, "..."], rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        sigma = np.sqrt((self.relative * values) ** 2 + self.floor**2)
        return values + sigma * rng.standard_normal(values.shape), sigma

    def record(self) -> dict:
        return {"type": "gaussian", "floor": self.floor, "relative": self.relative}


EXTENT_QUANTILE = 0.99
"""The quantile of the pixel facets' slope deviations :func:`robust_extent` starts from."""
EXTENT_FACTOR = 1.5
"""The factor :func:`robust_extent` multiplies that quantile by."""


LIGHT_INSIDE = 0.95
"""The share of a lobe's light an image of :func:`gonioreflectometer` must hold; below it, LobeCutWarning."""


def robust_extent(field: HeightField, *, quantile: float = EXTENT_QUANTILE, factor: float = EXTENT_FACTOR) -> float:
    """A half-width for :func:`gonioreflectometer`'s images from robust slope quantiles:
    ``factor × quantile_q |m − m̄|`` over the measured pixel facets' normal slopes m (the finest
    facets the field has; m̄ their mean), by default ``1.5 ×`` the 99th percentile.

    The lobes are densities of slope offsets ``u = m − m_facet``, which spread at most about as
    far as the pixel slopes about their mean; for Gaussian slopes of standard deviation σ per
    axis the 99th percentile of ``|m − m̄|`` is ``3.03 σ``, so the default extent is ``4.55 σ``
    (light beyond the grid ≈ 5e-6 per axis) and a coarse-scale lobe's rms width is about
    ``(pixels − 1)/9.1`` image pixels (7 at 65 pixels). A quantile ignores the few outliers of a
    measured file — a spike of one steep pixel (slope 0.84 on a surface of rms slope 0.0037)
    would otherwise set the extent (``1.05 ×`` :func:`steepest_slope`, the rule of earlier
    releases) and put every lobe into one image pixel (both tested in tests/test_adequacy.py).

    Raises:
        InvalidInputError: ``field`` is not a :class:`HeightField`, ``quantile`` not in (0, 1],
            ``factor`` not positive, or the field is flat (its lobe is its facets' own lobe: none for
            mirror facets; for others, its extent is the caller's to give).
    """
    check_field(field)
    q, f = real(quantile, "quantile"), real(factor, "factor")
    if not 0 < q <= 1 or not f > 0:
        raise InvalidInputError(f"quantile must lie in (0, 1] and factor be > 0; got quantile={q!r}, factor={f!r}.")
    slopes, _ = facet_samples(field, (1, 1))
    deviation = np.hypot(*(slopes - slopes.mean(axis=0)).T)
    extent = f * float(np.quantile(deviation, q))
    if not extent > 0:
        flat = f"the field's pixel slopes do not vary (the {q:g} quantile of |m − m̄| is 0): a flat field's lobe is"
        if isinstance(field.micro, stats.Delta):
            raise InvalidInputError(
                f"{flat} its facets' own, here mirror facets' (micro=stats.Delta(), a measured file's default): a "
                "spike at one slope, no lobe to image."
            )
        raise InvalidInputError(
            f"{flat} its facets' own ({type(field.micro).__name__}): give its extent explicitly (extent=)."
        )
    return extent


@eqx.filter_jit
def _box_covariance(law: stats.GaussianSurface, mu):
    return law.slope_covariance(mu)


def gonioreflectometer(
    field: HeightField,
    scales,
    incident: Float[ArrayLike, "*k 3"] | Sequence[float] | Sequence[Sequence[float]],
    *,
    extent: float,
    pixels: int = 64,
    noise: PoissonNoise | GaussianNoise | None = None,
    resolution: float = 0.0,
    albedo=1.0,
    weighting: str = WEIGHTINGS.default,
    seed=None,
) -> MeasurementSet:
    """Measure the lobes of ``field`` at each scale μ and incident direction i.

    Each image is the lobe a facet of size μ shows in its own frame, averaged over the
    facets: the density of half-vector slope offsets ``u = m_s − m∞`` (docs/conventions.md §6) of the
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

    Memory: each image is computed on a grid of ``pixels + 2·pad`` nodes per side, the pad
    covering the micro lobe's support and the resolution blur (``pad ≈ (support +
    5.3·resolution) / pitch``, pitch ``2·extent/(pixels − 1)``); that float64 grid must fit
    :data:`MAX_GRID_BYTES` (2**31 bytes, 16384² nodes) and is refused before it is allocated
    otherwise — use fewer pixels, a smaller resolution or a larger extent (a coarser pitch).

    Returns:
        A :class:`brdfscale.MeasurementSet` with one image per (μ, i), scales outermost; its
        ``metadata`` records the surface, the instrument and the truth (the pixel facets' slope
        covariance, facet-slope mean and covariance per scale, the covariance of the offsets each scale's
        images hold, ``offset_covariance`` (:func:`offset_moments`, before the micro lobe's and the resolution's
        blur; the lobe's widening between two scales, :func:`fitting.covariance_truth`), and the analytic ``Σ(μ)`` of
        :class:`brdfscale.stats.GaussianSurface` with a box window and 256 quadrature
        nodes in k when the field has a spectrum).

    Warns:
        LobeCutWarning: an image holds less than :data:`LIGHT_INSIDE` of its lobe's light (the node sum of the
            cropped lobe density times the pitch², the density being per sample added: the share of the facet
            offsets, blurred by the micro lobe, that land on the image) — the extent is too small; the message
            names the worst scale and its share (``tests/test_synth.py``).

    Raises:
        InvalidInputError: checked before any work, for a ``field`` that is not a
            :class:`HeightField`; ``scales`` that are not real numbers or not whole numbers
            of pixels; ``incident`` not real unit vectors with z > 0 (complex is refused);
            ``extent`` not a positive real number; ``pixels`` not an integer ≥ 2;
            ``resolution`` not a real number ≥ 0; ``albedo`` not a positive scalar or RGB
            triple; an unknown ``weighting``; a wrong ``noise`` or a missing/bad ``seed``;
            an image grid above :data:`MAX_GRID_BYTES`. Also when a Poisson expected count
            exceeds :data:`MAX_EXPECTED_COUNT` (see :class:`PoissonNoise`).
    """
    check_field(field)
    scales = check_scales(scales)
    for mu in scales:
        field.block(mu)
    directions = np.atleast_2d(real_array(incident, "incident"))
    validate_directions(directions, "incident")
    extent = real(extent, "extent")
    if not extent > 0:
        raise InvalidInputError(f"extent must be a positive slope half-width; got {extent!r}.")
    pixels = integer(pixels, "pixels", 2)
    resolution = real(resolution, "resolution")
    if not resolution >= 0:
        raise InvalidInputError(f"resolution must be a slope standard deviation ≥ 0; got {resolution!r}.")
    albedo = real_array(albedo, "albedo")
    if albedo.shape not in ((), (3,)) or not np.all(albedo > 0):
        raise InvalidInputError(f"albedo must be a positive scalar or an RGB triple; got {albedo!r}.")
    WEIGHTINGS.check(weighting)
    if noise is not None and not isinstance(noise, (PoissonNoise, GaussianNoise)):
        raise InvalidInputError(f"noise must be PoissonNoise, GaussianNoise or None; got {type(noise).__name__}.")
    if noise is not None and seed is None:
        raise InvalidInputError("a noisy measurement needs an explicit seed= (int, NumPy Generator or JAX key).")
    sample = None if noise is None else functools.partial(noise.sample, rng=as_generator(seed))  # None: noiseless

    h = 2 * extent / (pixels - 1)
    pad = kernel_padding(
        field.micro,
        resolution,
        h,
        pixels,
        f"the image grid (pixels={pixels}, resolution={resolution:g})",
        "use fewer pixels, a smaller resolution or a larger extent (a coarser pitch)",
    )
    crop = slice(pad, pad + pixels)
    images, inside = [], []
    truth = {"facet_slope_mean": [], "facet_slope_covariance": [], "offset_covariance": []}
    law = None if field.spectrum is None else stats.GaussianSurface(field.spectrum, window="box", n_k=256)
    pixel, _ = facet_samples(field, (1, 1))  # the measured pixel facets' own normal slopes
    truth["pixel_slope_covariance"] = np.cov(pixel.T).tolist()
    if law is not None:
        truth["analytic_facet_slope_covariance"] = []
    for mu in scales:
        samples, _ = facet_samples(field, field.block(mu))
        if len(samples) == 0:
            raise InvalidInputError(
                f"no facet window of mu={mu:g} lies wholly on measured pixels; use a smaller scale."
            )
        truth["facet_slope_mean"].append(samples.mean(axis=0).tolist())
        truth["facet_slope_covariance"].append(
            np.cov(samples.T).tolist() if len(samples) > 1 else [[0.0, 0.0], [0.0, 0.0]]
        )
        truth["offset_covariance"].append(offset_moments(field, mu)[1].tolist())
        if law is not None:
            truth["analytic_facet_slope_covariance"].append(np.asarray(_box_covariance(law, jnp.asarray(mu))).tolist())
        lobe = None
        for i in directions:
            if lobe is None or weighting == "projected_area":
                hist = SlopeHistogram(extent + pad * h, pixels + 2 * pad)
                offset_histogram(field, mu, hist, incident=i if weighting == "projected_area" else None)
                lobe = blur(hist.density(), h, field.micro, resolution)[crop, crop]
                inside.append((float(lobe.sum()) * h * h, mu))
            clean = lobe[..., None] * albedo if albedo.ndim else lobe * albedo
            values, sigma = (clean, None) if sample is None else sample(clean)
            images.append(LobeImage(mu=mu, incident=i, extent=extent, values=values, sigma=sigma))
    share, worst = min(inside)
    if share < LIGHT_INSIDE:
        warnings.warn(
            f"the image at μ = {worst:g} holds only {100 * share:.0f} % of its lobe's light (extent {extent:.4g}): "
            "the lobe is wider than the image ("
            + (
                "the pixel facets' offsets from their facet's slope spread beyond it"
                if _is_mirror(field.micro)
                else f"a rough micro-facet lobe's tails: {type(field.micro).__name__}"
            )
            + "); give a larger extent (extent=, brdfscale synth --extent) for the images to hold at least "
            f"{100 * LIGHT_INSIDE:.0f} %.",
            LobeCutWarning,
            stacklevel=2,
        )
    metadata = {
        "generator": "brdfscale.synth.gonioreflectometer",
        "surface": field.description,
        "spacing": field.spacing[0] if field.spacing[0] == field.spacing[1] else list(field.spacing),
        "shape": list(field.shape),
        "periodic": field.periodic,
        "unit": field.unit,
        "unmeasured": 0 if field.mask is None else int(np.count_nonzero(~field.mask)),
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
