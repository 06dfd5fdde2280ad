"""Height maps from arrays: units, masks and detrending (one place for each)."""

import math
from collections.abc import Mapping

import numpy as np
from jaxtyping import ArrayLike, Bool, Float, Real

from .. import stats
from .._errors import InvalidInputError
from .._measurement import boolean_mask
from .._validation import pitch, real_array
from ..synth import HeightField


#: Length units accepted for heights and pitches, in metres (µ as U+00B5 or U+03BC, or "u").
UNITS: dict[str, float] = {
    "km": 1e3,
    "m": 1.0,
    "cm": 1e-2,
    "mm": 1e-3,
    "um": 1e-6,
    "\u00b5m": 1e-6,
    "\u03bcm": 1e-6,
    "nm": 1e-9,
    "\u00c5": 1e-10,
    "A": 1e-10,
    "pm": 1e-12,
}

#: The physical range of a pixel pitch, in metres: from 1 pm (below the spacing of atoms) to
#: 10 km. A pitch outside it is refused by :func:`from_array` (and so by :func:`read`):
#: a damaged header or a wrong unit, not a measurement.
PITCH_RANGE_M = (1e-12, 1e4)

#: The detrending modes: the polynomial in ``ξ = x/L_x, η = y/L_y`` removed by least squares
#: over the measured pixels (SurfaceTopography's ``detrend("height")`` and ``detrend("curvature")``).
DETRENDS: dict[str | None, tuple[str, ...]] = {
    None: (),
    "plane": ("1", "ξ", "η"),
    "curvature": ("1", "ξ", "η", "ξ²", "η²", "ξη"),
}


def is_length_unit(unit) -> bool:
    """Whether ``unit`` is one of :data:`UNITS` (SurfaceTopography gives some channels' units as tuples, e.g.
    ('µm', None))."""
    return isinstance(unit, str) and unit in UNITS


def metres_per(unit) -> float:
    """The size of one ``unit`` in metres (InvalidInputError naming the accepted units)."""
    if not is_length_unit(unit):
        raise InvalidInputError(f"unit must be one of {', '.join(repr(u) for u in UNITS)}; got {unit!r}.")
    return UNITS[unit]


def check_mode(mode) -> str | None:
    if mode is not None and (not isinstance(mode, str) or mode not in DETRENDS):
        raise InvalidInputError(f"detrend must be None, 'plane' or 'curvature'; got {mode!r}.")
    return mode


def detrend(
    heights: Real[ArrayLike, "ny nx"], mode: str | None = "plane", mask: Bool[ArrayLike, "ny nx"] | None = None
) -> tuple[Float[np.ndarray, "ny nx"], dict]:
    """Remove a plane or a quadratic from ``heights`` by least squares over the measured pixels.

    The trend is ``p(ξ, η) = Σ_t c_t t(ξ, η)`` over the terms of :data:`DETRENDS` in the
    normalised coordinates ``ξ = k/n_x``, ``η = j/n_y`` of pixel ``[j, k]`` — the
    parametrisation of SurfaceTopography's ``polyfit``, so the coefficients are its
    coefficients for the same heights (tests/test_topography.py). Detrending changes the
    heights, not the pitch: slopes change by the trend's gradient. Heights that are the trend
    to the fit's rounding (rms at most :data:`PLANE_ROUNDING` of the largest |height|) detrend to exactly 0.

    Returns the detrended heights (unmeasured entries 0) and a record ``{"mode", "terms",
    "coefficients"}`` for the field's provenance, the coefficients in the unit of the heights
    given (:func:`from_array` detrends after converting to metres, so its records are in metres).
    InvalidInputError for heights that are not a finite real 2-D array where measured, a bad
    mask or mode, or fewer measured pixels than coefficients.
    """
    mode = check_mode(mode)
    valid = None if mask is None else boolean_mask(mask, "mask")
    h = np.asarray(heights)
    if valid is not None and h.shape != valid.shape:
        raise InvalidInputError(f"mask must have the shape of heights, {h.shape}; got {valid.shape}.")
    if valid is not None and h.dtype.kind in "fiu":
        h = np.where(valid, h, 0.0)
    h = real_array(h, "heights", ndim=2)
    return _fit_trend(h, mode, np.ones(h.shape, bool) if valid is None else valid)


def _fit_trend(h: np.ndarray, mode: str | None, valid: np.ndarray) -> tuple[np.ndarray, dict]:
    record = {"mode": mode, "terms": list(DETRENDS[mode]), "coefficients": []}
    if mode is None:
        return np.where(valid, h, 0.0), record
    ny, nx = h.shape
    xi = (np.arange(nx) / nx)[None, :]
    eta = (np.arange(ny) / ny)[:, None]
    columns = [np.ones_like(h), np.broadcast_to(xi, h.shape), np.broadcast_to(eta, h.shape)]
    if mode == "curvature":
        columns += [np.broadcast_to(xi**2, h.shape), np.broadcast_to(eta**2, h.shape), xi * eta]
    design = np.stack([c[valid] for c in columns], axis=-1)
    if design.shape[0] < design.shape[1]:
        raise InvalidInputError(
            f"detrend={mode!r} fits {design.shape[1]} coefficients but only {design.shape[0]} pixels are measured."
        )
    # fitted to the heights less one measured height, which is exact: a flat field detrends to exactly 0
    reference = float(h[valid][0])
    coefficients, *_ = np.linalg.lstsq(design, h[valid] - reference, rcond=None)
    trend = sum(c * t for c, t in zip(coefficients, columns))
    record["coefficients"] = [float(c) + (reference if k == 0 else 0.0) for k, c in enumerate(coefficients)]
    residual = np.where(valid, (h - reference) - trend, 0.0)
    # heights that are the trend to the fit's rounding (a tilted plane, a test file's) detrend to exactly 0, as a
    # flat field does; else their rounding noise (~1e-16 of the heights) would pass for a texture of slopes ~1e-15
    size = float(np.max(np.abs(h[valid])))  # the rounding of each height given (and of the fit) scales with it
    if 0 < size < np.inf and np.sqrt(np.mean((residual[valid] / size) ** 2)) <= PLANE_ROUNDING:  # ratios: no underflow
        residual = np.zeros_like(residual)
    return residual, record


#: Detrended heights whose rms is at most this fraction of the largest |height| given (about 4500 float64
#: roundings of it) are the trend's rounding, not a texture: :func:`from_array` makes them exactly 0 (a plane,
#: or a quadratic with ``detrend="curvature"``, is then a flat field), whatever offset the heights sit on. Any
#: instrument's texture is above 1e-8 of its range (24-bit digitisers: 6e-8).
PLANE_ROUNDING = 1e-12


def square_pitch(dx: float, dy: float) -> tuple[tuple[float, float], dict | None]:
    """Pitches equal to :attr:`HeightField.LENGTH_TOLERANCE` (relative) made square, with the record.

    Two pitches with ``|Δx − Δy| ≤ 1e-3 max(Δx, Δy)`` become their geometric mean
    ``Δ = √(Δx Δy)`` along both axes (the pixel's area kept; each slope component changes by
    the factor ``Δ_a/Δ``, at most 0.05 %), and the record ``{"pitch_as_given": [Δx, Δy],
    "pitch": Δ, "relative_difference": |Δx − Δy|/max, "tolerance": 1e-3}`` goes into the
    field's provenance. Exactly square or farther apart: unchanged, record None.
    """
    difference = abs(dx - dy) / max(dx, dy)
    if difference == 0 or difference > HeightField.LENGTH_TOLERANCE:
        return (dx, dy), None
    d = math.sqrt(dx) * math.sqrt(dy)
    record = {
        "pitch_as_given": [dx, dy],
        "pitch": d,
        "relative_difference": difference,
        "tolerance": HeightField.LENGTH_TOLERANCE,
    }
    return (d, d), record


#: A height map is quantised when fewer than this fraction of its measured pixels hold distinct heights
#: (:func:`height_quantum`).
QUANTISED_DISTINCT = 0.5


def height_quantum(heights: Real[ArrayLike, "..."], mask: Bool[ArrayLike, "..."] | None = None) -> float | None:
    """The instrument's height step: the median gap between consecutive distinct measured heights, where the
    heights lie on a lattice — fewer than :data:`QUANTISED_DISTINCT` of the measured pixels hold distinct
    heights and 99 % of the gaps are whole multiples of that step (to 1 %); None otherwise (unquantised heights,
    or fewer than two distinct ones). In the unit of ``heights``; NaN entries and ``mask`` False are unmeasured.

    A quantised height map puts its pixel slopes on a lattice of one *slope quantum*, step/Δ per axis: the
    within-facet lobes of its facets are then combs of spikes one quantum apart (docs/results.md, study 5,
    "Height quantisation"), which ``brdfscale synth --topography`` blurs away by default (its ``--resolution``).
    :func:`from_array` records it in ``description["height_quantum"]`` (metres; before detrending, which moves
    the heights off the lattice but keeps the slopes' step). Verified on the files in tests/data (plu-1: 2⁻⁸ µm)
    and on rounded synthetic heights (tests/test_topography.py).

    Raises:
        InvalidInputError: heights that are not real numbers, or a mask of another shape.
    """
    try:
        h = np.asarray(heights, dtype=float)
    except (TypeError, ValueError) as err:
        raise InvalidInputError(f"heights must be an array of real numbers; got {type(heights).__name__} ({err}).")
    valid = np.isfinite(h)
    if mask is not None:
        m = boolean_mask(mask, "mask")
        if m.shape != h.shape:
            raise InvalidInputError(f"mask must have the shape of heights, {h.shape}; got {m.shape}.")
        valid &= m
    measured = h[valid]
    distinct = np.unique(measured)
    if len(distinct) < 2 or len(distinct) >= QUANTISED_DISTINCT * measured.size:
        return None
    gaps = np.diff(distinct)
    step = float(np.median(gaps))
    multiple = gaps / step
    if np.mean(np.abs(multiple - np.round(multiple)) <= 0.01) < 0.99:
        return None
    return step


def from_array(
    heights: Real[ArrayLike, "ny nx"],
    spacing,
    *,
    unit: str = "m",
    mask: Bool[ArrayLike, "ny nx"] | None = None,
    detrend: str | None = "plane",
    periodic: bool = False,
    micro=None,
    description: Mapping | None = None,
) -> HeightField:
    """A measured height map as a :class:`brdfscale.synth.HeightField` in metres.

    Args:
        heights: ``h[j, k]`` at ``(x, y) = (k Δx, j Δy)`` — rows y, columns x — in ``unit``.
            NaN entries and the masked entries of a :class:`numpy.ma.MaskedArray` are
            unmeasured.
        spacing: the pixel pitch, ``(Δx, Δy)`` or one number for square pixels, in ``unit``;
            each from 1 pm to 10 km (:data:`PITCH_RANGE_M`). Two pitches equal to a relative
            1e-3 (:attr:`HeightField.LENGTH_TOLERANCE`) are made square, their geometric mean,
            and the difference is recorded as ``description["square_pixels"]``
            (:func:`square_pitch`); :func:`resample` puts pixels farther from square onto a
            square grid.
        unit: the length unit of heights and spacing, one of :data:`UNITS`; the field is
            stored in metres.
        mask: boolean (ny, nx), True where measured (combined with NaN and a masked array's
            own mask), or None.
        detrend: ``"plane"`` (default: tilt removed), ``"curvature"`` (a quadratic removed)
            or None, by least squares over the measured pixels (:func:`detrend`); recorded
            in the provenance with its coefficients. Heights that are the trend to its fit's
            rounding (rms at most :data:`PLANE_ROUNDING` of the largest |height|: an exact plane,
            or quadratic) become exactly 0, a flat field without a slope quantum.
        periodic: True only for a height map that is periodic (a simulation's); then
            ``detrend`` must be None, since a removed plane is not periodic.
        micro: the pixel facets' own lobe (default mirror facets, ``stats.Delta()``).
        description: extra provenance to record (merged into ``field.description``).

    Raises InvalidInputError for heights that are not a real 2-D array of at least 4 × 4
    (infinite values are refused; NaN means unmeasured), a bad spacing (or one outside
    :data:`PITCH_RANGE_M`), unit, mask or detrend, ``periodic=True`` with detrending, a mask
    that leaves no measured pixel facet, or a steepest pixel slope outside
    ``HeightField.SLOPE_RANGE`` (a dropout or a wrong unit above 1e6, denormal heights
    below 1e-30; a flat field is accepted).
    """
    raw = heights
    masks = []
    if isinstance(raw, np.ma.MaskedArray):
        masks.append(~np.ma.getmaskarray(raw))
        raw = np.ma.getdata(raw)
    try:
        h = np.array(raw, copy=True)
    except (TypeError, ValueError) as err:
        raise InvalidInputError(
            f"heights must be an array of real numbers; got a {type(heights).__name__} NumPy "
            f"cannot read as one ({err})."
        ) from None
    if h.dtype.kind not in "fiu":
        raise InvalidInputError(f"heights must be real numbers (float or int); got dtype {h.dtype}.")
    h = h.astype(float)
    if h.ndim != 2:
        raise InvalidInputError(f"heights must be a 2-D (ny, nx) array, rows y and columns x; got shape {h.shape}.")
    if np.any(np.isinf(h)):
        raise InvalidInputError(
            f"heights contain {int(np.count_nonzero(np.isinf(h)))} infinite values; mark "
            "unmeasured pixels with NaN or mask=False instead."
        )
    masks.append(~np.isnan(h))
    if mask is not None:
        m = boolean_mask(mask, "mask")
        if m.shape != h.shape:
            raise InvalidInputError(f"mask must have the shape of heights, {h.shape}; got {m.shape}.")
        masks.append(m)
    valid = np.logical_and.reduce(masks)
    scale = metres_per(unit)
    dx, dy = pitch(spacing)
    low, high = PITCH_RANGE_M
    for axis, d in (("x", dx), ("y", dy)):
        if not low <= d * scale <= high:
            raise InvalidInputError(
                f"the pixel pitch Δ{axis} = {d:.6g} {unit} ({d * scale:.6g} m) is outside the physical range "
                f"{low:g} m to {high:g} m (topography.PITCH_RANGE_M): a damaged size or a wrong unit."
            )
    mode = check_mode(detrend)
    if not isinstance(periodic, (bool, np.bool_)):
        raise InvalidInputError(f"periodic must be True or False; got {type(periodic).__name__} {periodic!r}.")
    if periodic and mode is not None:
        raise InvalidInputError(
            f"periodic=True needs detrend=None: a removed {mode} is not periodic; got detrend={mode!r}."
        )
    if description is not None and not isinstance(description, Mapping):
        raise InvalidInputError(f"description must be a dict of provenance; got {type(description).__name__}.")
    if not valid.any():
        raise InvalidInputError("no height is measured: every entry is NaN or masked.")
    if min(h.shape) < 4:
        raise InvalidInputError(f"heights must be at least 4 × 4 pixels (rows y, columns x); got shape {h.shape}.")
    with np.errstate(over="ignore"):  # the lattice of the heights given, before detrending moves them off it
        quantum = height_quantum(h, valid)
    with np.errstate(over="ignore"):  # heights beyond float64 in metres are refused by HeightField
        h, trend = _fit_trend(np.where(valid, h, 0.0) * scale, mode, valid)
    if not np.all(np.isfinite(h)):
        raise InvalidInputError(
            f"heights in {unit} overflow float64 when converted to metres or detrended; they are not a surface's."
        )
    if mode is not None and not h.any():
        quantum = None  # a plane: its heights' lattice (the tilt's step) puts no slope of the detrended field on one
    spacing_m, square = square_pitch(dx * scale, dy * scale)
    provenance = {
        "generator": "brdfscale.topography.from_array",
        "input_unit": unit,  # the unit of the arrays given; the field, its spacing and the trend are in metres
        "detrend": mode,
        "trend": trend,
        "shape": list(h.shape),
        "spacing": list(spacing_m),
        **({"square_pixels": square} if square else {}),
        "unmeasured": int(np.count_nonzero(~valid)),
        "height_quantum": None if quantum is None else quantum * scale,  # metres; None: not quantised
        **(dict(description) if description else {}),
    }
    return HeightField(
        h,
        spacing_m,
        micro=stats.Delta() if micro is None else micro,
        description=provenance,
        mask=None if valid.all() else valid,
        periodic=bool(periodic),
        unit="m",
    )
