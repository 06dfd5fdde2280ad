"""Engine export: per-texel, per-mip anisotropic roughness as an EXR mip chain (issue 33 item 2).

Rasterisers take a normal (mean slope) and a roughness per texel and mip level, not a BRDF of the scale. What every
texel of level ℓ (``2^ℓ × 2^ℓ`` texels of level 0) needs is its lobe's first and second moments:

* from a height field (:class:`brdfscale.synth.HeightField`; level 0 = one pixel facet): the mean slope
  ``B = E[m]`` and the raw second moments ``M = E[m mᵀ] + C_micro`` of the pixel facets it covers (``m = −∇h``,
  :func:`brdfscale.synth.pixel_slopes`, square or rectangular pixels; ``C_micro`` the covariance of the field's
  micro lobe) — linear in the pixels, so each level is the 2×2 mean of the one below (LEAN mapping, Olano & Baker 2010);
* from statistics (a scale law or a FitResult, with ``base_lobe`` and ``mu0``): the lobe at ``μ_ℓ = μ0 · 2^ℓ``
  evolved as :func:`brdfscale.render.lobe_table` does. Its moments are in closed form where base lobe and
  statistics have known ones (:func:`cumulants`: Gaussian/Beckmann, Student-t, disk, table and mixtures of these —
  seed Eq. 4.4 multiplies transforms, so cumulants add, :func:`evolved_moments`), else the node sums of the lobe
  sampled on ``size²`` nodes; densities without finite second moments (GGX, Student-t with ν ≤ 2) are refused. The
  same at every texel (``resolution`` texels on a side at level 0). Of an evolved :class:`brdfscale.exr.LobeTable`:
  those of the tent sum it defines (what the plugin renders).

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
from ._material import ACCEPTED, as_scale_law, evolved_lobes, lobe_table, scalar_table, tabulate


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
        lo, hi = float(np.min(np.asarray(measured, float))), float(np.max(np.asarray(measured, float)))
        if not lo * (1 - 1e-12) <= mu0 <= hi * (1 + 1e-12):
            raise InvalidInputError(
                f"mu0 = {mu0:g} is outside the range the statistics are measured over, [{lo:g}, {hi:g}]."
            )
        top = int(math.floor(math.log2(hi / mu0) * (1 + 1e-12))) + 1
    if levels is None:
        return DEFAULT_STATISTICS_LEVELS if top is None else min(DEFAULT_STATISTICS_LEVELS, top)
    levels = integer(levels, "levels", 1)
    if top is not None and levels > top:
        raise InvalidInputError(
            f"levels must be at most {top}: level ℓ is the lobe at μ0 · 2^ℓ from μ0 = {mu0:g}, and the "
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


def _infinite(density) -> InvalidInputError:
    return InvalidInputError(
        f"{type(density).__name__} slopes have no finite second moments (GGX; Student-t with ν ≤ 2), and engines' "
        "roughness comes from second moments: exported from a table it would be the table's truncation. Give a "
        "base lobe and statistics of finite variance (Beckmann/Gaussian, Student-t with ν > 2, a disk, a table)."
    )


def cumulants(density) -> tuple[np.ndarray, np.ndarray] | None:
    """``(mean, covariance)`` of a slope density in closed form — :class:`stats.Delta`, :class:`stats.Gaussian`,
    :class:`stats.StudentT` (``Σ ν/(ν − 2)``), :class:`stats.Disk` (``r²/4`` per axis), :class:`stats.Tabulated`
    (its nodes' tent sum: node sums plus ``h²/6`` per axis) and :class:`stats.Mixture` of these — None for a density
    of another kind. InvalidInputError for one without finite second moments (GGX, Student-t with ν ≤ 2)."""
    mean = None if isinstance(density, stats.Mixture) else getattr(density, "mean", None)
    centre = np.zeros(2) if mean is None else np.asarray(mean, float)
    if centre.shape != (2,):
        return None  # a batch of densities
    if isinstance(density, stats.Delta):
        return centre, np.zeros((2, 2))
    if isinstance(density, stats.Gaussian):
        cov = np.asarray(density.cov, float)
        return (centre, cov) if cov.shape == (2, 2) else None  # None: a batch
    if isinstance(density, stats.GGX):
        raise _infinite(density)
    if isinstance(density, stats.StudentT):
        nu = float(density.nu)
        if nu <= 2:
            raise _infinite(density)
        return centre, np.asarray(density.cov, float) * nu / (nu - 2)
    if isinstance(density, stats.Disk):
        return centre, np.eye(2) * float(density.radius) ** 2 / 4
    if isinstance(density, stats.Tabulated):
        x, y = (np.asarray(a, float) for a in density.nodes())
        h = np.asarray(density.spacing, float)
        p = np.asarray(density.values, float)
        p = p / p.sum()
        b = np.array([(p.sum(axis=0) * x).sum(), (p.sum(axis=1) * y).sum()])
        dx, dy = x - b[0], y - b[1]
        cxx = (p.sum(axis=0) * dx**2).sum() + h[0] ** 2 / 6
        cyy = (p.sum(axis=1) * dy**2).sum() + h[1] ** 2 / 6
        cxy = (p * dx[None, :] * dy[:, None]).sum()
        centre = b if density.center is None else b + np.asarray(density.center, float)
        return centre, np.array([[cxx, cxy], [cxy, cyy]])
    if isinstance(density, stats.Mixture):
        parts = []
        for component in density.components:
            part = cumulants(component)
            if part is None:
                return None
            parts.append(part)
        w = np.asarray(density.weights, float)
        b = np.zeros(2)
        raw = np.zeros((2, 2))
        for wk, (m, c) in zip(w, parts):
            b = b + wk * m
            raw = raw + wk * (c + np.outer(m, m))
        return b, raw - np.outer(b, b)
    return None


def evolved_moments(base, first, at) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """``(B, M)`` of the base lobe evolved from the statistics ``first`` (at μ0) to each of ``at`` (seed Eq. 4.4:
    the transforms multiply, ``G(μ) = G(μ0) S(μ0)/S(μ)``, so cumulants add): ``B = b0 + m(μ0) − m(μ)``,
    ``M = C0 + Σ(μ0) − Σ(μ) + B Bᵀ`` — None where a density's moments are not known in closed form."""
    known = []
    for density in (base, first, *at):
        moments = None if density is None else cumulants(density)
        if moments is None:
            return None
        known.append(moments)
    (b0, c0), (m_first, s_first) = known[0], known[1]
    out = []
    for m, s in known[2:]:
        b = b0 + m_first - m
        out.append((b, c0 + s_first - s + np.outer(b, b)))
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
    size = integer(size, "size", 4)
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
            shape = getattr(base_lobe, "shape", None)
            table_levels = evolved_moments(shape, law.at(mu0), [law.at(float(mu)) for mu in scales])
            mirror = isinstance(shape, stats.Delta)
            if mirror and table_levels is None:
                raise InvalidInputError(
                    "a mirror base lobe evolved by statistics of this kind has no closed-form moments at μ0, where it "
                    "is a spike no table holds; give statistics of known moments (Gaussian, Student-t, disk, table) "
                    "or a base lobe with a width."
                )
            evolving = scales[1:] if mirror else scales  # a mirror's μ0 level is the mirror itself
            if len(evolving):  # the evolution itself: its existence (NoBRDFAtScaleError), else its sampled lobes
                ladder, evolved, mu0, _, _ = evolved_lobes(base_lobe, source, mu0=mu0, scales=evolving, levels=n_levels)
                if table_levels is None:  # the evolved lobes' node sums, not the interpolant's (no tent term)
                    table_levels = table_moments(tabulate(ladder, evolved, mu0=mu0, size=size), tent=False)
            assert table_levels is not None  # a mirror of unknown moments is refused above, other lobes sampled
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
