"""Engine export: per-texel, per-mip anisotropic roughness as an EXR mip chain (issue 33 item 2).

Rasterisers take a normal (mean slope) and a roughness per texel and mip level, not a BRDF of the scale. What every
texel of level ℓ (``2^ℓ × 2^ℓ`` texels of level 0) needs is its lobe's first and second moments:

* from a height field (:class:`brdfscale.synth.HeightField`; level 0 = one pixel facet): the mean slope
  ``B = E[m]`` and the raw second moments ``M = E[m mᵀ] + C_micro`` of the pixel facets it covers (``m = −∇h``,
  :func:`brdfscale.synth.pixel_slopes`, square or rectangular pixels; ``C_micro`` the covariance of the field's
  micro lobe) — linear in the pixels, so each level is the 2×2 mean of the one below (LEAN mapping, Olano & Baker 2010);
* from statistics (a scale law or a FitResult, with ``base_lobe`` and ``mu0``): the lobe at ``μ_ℓ = μ0 · 2^ℓ``
  evolved as :func:`brdfscale.render.lobe_table` does, its moments in closed form where the evolved lobes are
  Gaussian (a Gaussian/Beckmann base lobe and Gaussian statistics: covariances add), else the trapezoid sums of the
  lobe sampled on ``size²`` nodes — the same at every texel (``resolution`` texels on a side at level 0); of an
  evolved :class:`brdfscale.exr.LobeTable`, those of the tent sum it defines (what the plugin renders).

The texel lobe's covariance ``Σ = M − B Bᵀ`` becomes the engine's numbers in the convention named in the file
(:data:`CONVENTIONS`, stated word for word in each part's header).
"""

import math

import numpy as np
import OpenEXR

from .. import stats
from .._errors import InvalidInputError
from .._validation import flag, integer
from ..files import atomic_write
from ._material import ACCEPTED, as_scale_law, evolved_lobes, gaussian_parameters, lobe_table, scalar_table, tabulate


_ALPHA = (
    "alpha_x = sqrt(2 S_xx), alpha_y = sqrt(2 S_yy) — alpha itself, not alpha squared — and rho = S_xy / "
    "sqrt(S_xx S_yy), where S is the covariance of the texel lobe's normal slopes (n_x/n_z, n_y/n_z); the lobe's "
    "principal axes need not be x and y: rho carries the tilt. Axes: x along the texture's u (columns), y along v "
    "(rows; row 0 of the file is v = 0). slope_x, slope_y: the texel's mean normal slope E[m] (a normal map: "
    "n proportional to (slope_x, slope_y, 1))."
)

CONVENTIONS = {
    "beckmann_alpha": "Beckmann roughness: the lobe exp(-(m/alpha)^2)/(pi alpha^2) per axis has variance alpha^2/2; "
    + _ALPHA,
    "ggx_alpha": "GGX / Trowbridge-Reitz roughness alpha given the Beckmann alpha of the same second moments (the "
    "same peak density 1/(pi alpha_x alpha_y)); GGX slopes have no finite variance, so any GGX alpha from moments "
    "is a convention — this one. Engines whose 'roughness' r has alpha = r^2 (Disney, Unreal, Filament) take "
    "r = sqrt(alpha). " + _ALPHA,
    "lean_moments": "LEAN mapping moments (Olano & Baker 2010): B_x, B_y = E[m] and M_xx, M_yy, M_xy = E[m m^T] "
    "(the micro lobe's covariance included) of the normal slopes m = (n_x/n_z, n_y/n_z); the lobe covariance is "
    "M - B B^T; all five are linear in the texels (a coarser level is the mean of the finer). Axes: x along u "
    "(columns), y along v (rows; row 0 is v = 0).",
}
"""The conventions :func:`export_roughness` writes, as stated in each file."""

CHANNELS = {
    "beckmann_alpha": ("alpha_x", "alpha_y", "rho", "slope_x", "slope_y"),
    "ggx_alpha": ("alpha_x", "alpha_y", "rho", "slope_x", "slope_y"),
    "lean_moments": ("B_x", "B_y", "M_xx", "M_yy", "M_xy"),
}

KIND = "roughness_mip_chain"


def _micro_covariance(micro) -> np.ndarray:
    if isinstance(micro, stats.Delta):
        return np.zeros((2, 2))
    cov = getattr(micro, "cov", None)
    if cov is None:
        raise InvalidInputError(
            f"the field's micro lobe {type(micro).__name__} has no finite second moments (a Gaussian/Beckmann or a "
            "mirror, stats.Delta, has); engines' roughness comes from second moments."
        )
    return np.broadcast_to(np.asarray(cov, float), (2, 2))


def field_moments(field, levels: int | None) -> list[tuple[np.ndarray, np.ndarray]]:
    """``[(B, M), …]`` per level: B (h, w, 2), M (h, w, 2, 2) (module docstring; the field cropped to whole
    level-(levels−1) blocks)."""
    from .. import synth

    slopes = synth.pixel_slopes(field)  # square or rectangular pixels alike
    if not np.all(np.isfinite(slopes)):
        raise InvalidInputError("the field has unmeasured pixels (mask); export needs a fully measured field.")
    h, w = slopes.shape[:2]
    top = int(math.floor(math.log2(min(h, w))))
    levels = top + 1 if levels is None else integer(levels, "levels", 1)
    if levels > top + 1:
        raise InvalidInputError(f"levels must be at most {top + 1} for a {h}×{w} field (down to one texel).")
    block = 2 ** (levels - 1)
    slopes = slopes[: h // block * block, : w // block * block]
    b = slopes
    m = slopes[..., :, None] * slopes[..., None, :] + _micro_covariance(field.micro)
    out = [(b, m)]
    for _ in range(levels - 1):
        b = 0.25 * (b[0::2, 0::2] + b[1::2, 0::2] + b[0::2, 1::2] + b[1::2, 1::2])
        m = 0.25 * (m[0::2, 0::2] + m[1::2, 0::2] + m[0::2, 1::2] + m[1::2, 1::2])
        out.append((b, m))
    return out


DEFAULT_STATISTICS_LEVELS = 9
"""Mip levels of statistics when ``levels`` is not given (fewer where measured statistics end sooner)."""


def _statistics_levels(law, mu0: float, levels) -> int:
    """The mip levels ``μ0 · 2^ℓ`` of a scale law: ``levels``, or :data:`DEFAULT_STATISTICS_LEVELS`; for statistics
    measured up to a largest scale (``law.mu``), at most the levels within it."""
    measured = getattr(law, "mu", None)
    top = None
    if measured is not None:
        hi = float(np.max(np.asarray(measured, float)))
        top = int(math.floor(math.log2(hi / mu0) * (1 + 1e-12))) + 1 if hi >= mu0 else 0
    if levels is None:
        return DEFAULT_STATISTICS_LEVELS if top is None else max(1, min(DEFAULT_STATISTICS_LEVELS, top))
    levels = integer(levels, "levels", 1)
    if top is not None and levels > max(top, 1):
        raise InvalidInputError(
            f"levels must be at most {max(top, 1)}: level ℓ is the lobe at μ0 · 2^ℓ from μ0 = {mu0:g}, and the "
            f"statistics are measured up to μ = {hi:g}."
        )
    return levels


def _check_octaves(scales: np.ndarray) -> None:
    """A mip chain halves its texels per level, so the scale must double per level."""
    ratios = scales[1:] / scales[:-1]
    if not np.allclose(ratios, 2.0, rtol=1e-6, atol=0):
        raise InvalidInputError(
            "a mip chain's scale doubles per level (its texels halve), and the LobeTable's scales "
            f"{', '.join(f'{s:g}' for s in scales)} do not: tabulate at μ0 · 2^ℓ "
            "(brdfscale.render.lobe_table(base_lobe, statistics, mu0=mu0, scales=mu0 * 2.0 ** np.arange(levels)))."
        )


def _check_finite_variance(density, what: str) -> None:
    """Refuse a density without finite second moments (GGX, Student-t with ν ≤ 2, mixtures with such a part), whose
    exported roughness would depend on the table's extent, not on the lobe: its transform's curvature at W = 0,
    ``(1 − Re S(W))/|W|²``, tends to a constant as |W| → 0 only when the second moments are finite (it grows like
    ``ln(1/|W|)`` for GGX). Compared on three directions at the radius r where ``1 − Re S`` first falls below 10⁻⁶
    (halving from |W| = 1) and at r/4: equal within 1 % for finite moments."""
    directions = np.array([[1.0, 0.0], [0.0, 1.0], [math.sqrt(0.5), math.sqrt(0.5)]])

    def curvature(radius):
        return (1.0 - np.real(np.asarray(density.cf(radius * directions)))) / radius**2

    r = 1.0
    for _ in range(200):
        if np.all(curvature(r) * r * r < 1e-6):
            break
        r /= 2
    near, nearer = curvature(r), curvature(r / 4)
    if not np.all(np.isfinite(nearer)) or np.any(np.abs(nearer - near) > 1e-2 * np.abs(near) + 1e-300):
        raise InvalidInputError(
            f"{what} ({type(density).__name__}) has no finite second moments (GGX slopes, Student-t with ν ≤ 2), "
            "and engines' roughness comes from second moments: its exported alpha would be the table's truncation. "
            "Give a base lobe and statistics with finite variance (Beckmann/Gaussian, Student-t with ν > 2)."
        )


def gaussian_moments(params: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(B, M)`` of Gaussian lobes in closed form from :func:`gaussian_parameters`' rows ``[A, c_x, c_y, Σ_xx, Σ_xy,
    Σ_yy]``: ``B = c``, ``M = Σ + c cᵀ`` (exact: no table)."""
    out = []
    for _, cx, cy, sxx, sxy, syy in np.asarray(params, float):
        b = np.array([cx, cy])
        out.append((b, np.array([[sxx, sxy], [sxy, syy]]) + np.outer(b, b)))
    return out


def table_moments(table, tent: bool = True) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(B, M)`` of each scale's tabulated lobe: with ``tent``, exact for the tent sum the plugin renders (a tent of
    pitch h adds h²/6 per axis: a LobeTable's own lobe); without, the node sums alone — the trapezoid rule for the
    moments of the lobe the nodes sample (an evolved lobe's, without the interpolant's h²/6)."""
    values = np.maximum(scalar_table(table), 0.0)
    n = values.shape[-1]
    x = np.linspace(-table.extent, table.extent, n)
    h = x[1] - x[0]
    out = []
    for v in values:
        p = v / v.sum()
        bx, by = (p.sum(axis=0) * x).sum(), (p.sum(axis=1) * x).sum()
        spread = h * h / 6 if tent else 0.0
        mxx = (p.sum(axis=0) * x**2).sum() + spread
        myy = (p.sum(axis=1) * x**2).sum() + spread
        mxy = (p * x[None, :] * x[:, None]).sum()
        out.append((np.array([bx, by]), np.array([[mxx, mxy], [mxy, myy]])))
    return out


def convert(b: np.ndarray, m: np.ndarray, convention: str) -> dict[str, np.ndarray]:
    """The channels of ``convention`` from the moments ``B`` (..., 2) and ``M`` (..., 2, 2)."""
    if convention == "lean_moments":
        return {"B_x": b[..., 0], "B_y": b[..., 1], "M_xx": m[..., 0, 0], "M_yy": m[..., 1, 1], "M_xy": m[..., 0, 1]}
    cov = m - b[..., :, None] * b[..., None, :]
    sxx, syy = np.maximum(cov[..., 0, 0], 0.0), np.maximum(cov[..., 1, 1], 0.0)
    denominator = np.sqrt(sxx * syy)
    rho = np.where(denominator > 0, cov[..., 0, 1] / np.where(denominator > 0, denominator, 1.0), 0.0)
    return {
        "alpha_x": np.sqrt(2 * sxx),
        "alpha_y": np.sqrt(2 * syy),
        "rho": np.clip(rho, -1.0, 1.0),
        "slope_x": b[..., 0],
        "slope_y": b[..., 1],
    }


def export_roughness(
    source,
    path,
    *,
    convention: str = "ggx_alpha",
    levels: int | None = None,
    base_lobe=None,
    mu0: float | None = None,
    resolution: int = 1,
    size: int = 128,
    overwrite: bool = False,
) -> list[dict[str, np.ndarray]]:
    """Write per-texel, per-mip anisotropic roughness as a multi-part OpenEXR file (part ℓ = mip level ℓ).

    Args:
        source: a :class:`brdfscale.synth.HeightField` (per-texel moments of its pixel facets; level 0 = one pixel
            facet), or statistics as for :func:`brdfscale.render.bsdf` (a scale law with ``base_lobe`` and
            ``mu0``, or a FitResult with ``base_lobe``, μ0 then the fit's own: level ℓ is the lobe at ``μ0 · 2^ℓ``,
            uniform over ``resolution >> ℓ`` texels; base lobe and statistics must have finite second moments), or
            an evolved :class:`brdfscale.exr.LobeTable` (level ℓ its ℓ-th scale; its scales must double per
            level).
        path: the .exr file (written atomically; an existing file only with ``overwrite``).
        convention: ``"ggx_alpha"``, ``"beckmann_alpha"`` or ``"lean_moments"`` (:data:`CONVENTIONS`; the text is
            each part's ``brdfscale.convention_text`` attribute, the name ``brdfscale.convention``).
        levels: mip levels (default: a field down to one texel; statistics 9, or as many as measured statistics
            reach — a FitResult's fitted scales, a :class:`brdfscale.stats.MeasuredScaleLaw`'s range; a LobeTable
            all its scales).

    Each part: float32 channels (:data:`CHANNELS`), ``brdfscale.kind = "roughness_mip_chain"``,
    ``brdfscale.mip_level``, ``brdfscale.mu`` (the level's scale, double; for a field ``2^ℓ`` pixel pitches in its
    length unit — for rectangular pixels Δx × Δy, ``2^ℓ √(Δx Δy)``, the side of the square of the texel's area).
    Returns the channels per level. Raises InvalidInputError for a convention or source of another kind
    (naming those accepted), :class:`brdfscale.OutputWriteError` when the file cannot be written.
    """
    if convention not in CONVENTIONS:
        raise InvalidInputError(f"convention must be one of {', '.join(map(repr, CONVENTIONS))}; got {convention!r}.")
    overwrite = flag(overwrite, "overwrite")
    from .. import synth
    from ..exr import LobeTable

    if isinstance(source, synth.HeightField):
        if base_lobe is not None or mu0 is not None:
            raise InvalidInputError(
                "base_lobe= and mu0= are for statistics; a height field's texels carry its own facets and micro lobe: "
                "omit them."
            )
        moments = field_moments(source, levels)
        pitch = math.sqrt(source.spacing[0] * source.spacing[1])  # the side of a square of the pixel's area
        mus = [pitch * 2**k for k in range(len(moments))]
    else:
        resolution = integer(resolution, "resolution", 1)
        if isinstance(source, LobeTable):
            if base_lobe is not None or mu0 is not None:
                raise InvalidInputError(
                    "base_lobe= and mu0= are for statistics; a LobeTable is already evolved: omit them."
                )
            table = lobe_table(None, source)
            scales = np.asarray(table.scales, float)
            n_levels = len(scales) if levels is None else integer(levels, "levels", 1)
            if n_levels > len(scales):
                raise InvalidInputError(
                    f"levels must be at most {len(scales)}: the LobeTable has {len(scales)} scales."
                )
            scales = scales[:n_levels]
            _check_octaves(scales)
            table_levels = table_moments(table)[:n_levels]
        elif base_lobe is None:
            raise InvalidInputError(
                f"source must be a synth.HeightField, or {ACCEPTED} (statistics with base_lobe= and mu0=); got "
                f"{type(source).__name__}" + (" without base_lobe." if callable(getattr(source, "at", None)) else ".")
            )
        else:
            law, mu0 = as_scale_law(source, mu0)  # a FitResult's μ0 is its own
            n_levels = _statistics_levels(law, mu0, levels)
            scales = mu0 * 2.0 ** np.arange(n_levels)
            for what, density in (
                ("base_lobe", getattr(base_lobe, "shape", None)),
                (f"the statistics at μ0 = {mu0:g}", law.at(mu0)),
                (f"the statistics at μ = {scales[-1]:g}", law.at(float(scales[-1]))),
            ):
                if density is not None:
                    _check_finite_variance(density, what)
            ladder, evolved, mu0, _, _ = evolved_lobes(base_lobe, source, mu0=mu0, scales=scales, levels=n_levels)
            params = gaussian_parameters(evolved)
            if params is None:
                table = tabulate(ladder, evolved, mu0=mu0, size=integer(size, "size", 4))
                table_levels = table_moments(table, tent=False)  # the evolved lobe's, not the interpolant's
            else:
                table_levels = gaussian_moments(params)
        mus = [float(s) for s in scales]
        moments = []
        for k, (b, m) in enumerate(table_levels):
            side = max(1, resolution >> k)
            moments.append((np.broadcast_to(b, (side, side, 2)), np.broadcast_to(m, (side, side, 2, 2))))
    images = [convert(b, m, convention) for b, m in moments]
    _write(path, images, mus, convention, overwrite)
    return images


def _write(path, images, mus, convention, overwrite):
    height, width = images[0][next(iter(images[0]))].shape
    parts = []
    for level, (image, mu) in enumerate(zip(images, mus)):
        h, w = image[next(iter(image))].shape
        header = {
            "compression": OpenEXR.ZIP_COMPRESSION,
            "type": OpenEXR.scanlineimage,
            "displayWindow": (np.array([0, 0], np.int32), np.array([width - 1, height - 1], np.int32)),
            "dataWindow": (np.array([0, 0], np.int32), np.array([w - 1, h - 1], np.int32)),
            "brdfscale.kind": KIND,
            "brdfscale.convention": convention,
            "brdfscale.convention_text": CONVENTIONS[convention],
            "brdfscale.mip_level": level,
            "brdfscale.mip_levels": len(images),
            "brdfscale.mu": np.array([mu], dtype=np.float64),
        }
        channels = {name: np.ascontiguousarray(a, dtype=np.float32) for name, a in image.items()}
        parts.append(OpenEXR.Part(header, channels, name=f"mip{level}"))
    atomic_write(path, lambda tmp: OpenEXR.File(parts).write(tmp), overwrite=overwrite, foreign=(RuntimeError,))
