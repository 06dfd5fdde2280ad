"""The height-field container."""

import dataclasses
import functools
import math
import types
from collections.abc import Mapping
from typing import ClassVar

import equinox as eqx
import numpy as np
from jaxtyping import Bool, Float

from .. import stats
from .._errors import InvalidInputError
from .._measurement import boolean_mask
from .._show import Shown
from .._validation import flag, integer, pitch, real, real_array


MAX_GRID_BYTES = 2**31
"""The largest float64 grid synthesis allocates, in bytes: 2 GiB, i.e. 16384 × 16384 nodes.

It bounds the main array of each step — the height field of :func:`spectral_field`,
:func:`scratches` and :func:`blazed` (``8 n²`` bytes), the padded slope grid of
:func:`gonioreflectometer`, :func:`facet_statistics` and :func:`global_slopes` — and is
checked before anything is allocated (InvalidInputError). Peak memory is a small multiple of
it (FFT work arrays, histogram sums). To go beyond, synthesise smaller tiles, use fewer image
pixels or histogram bins, a coarser slope grid (a larger extent per node) or a narrower blur.
"""


def check_grid(side: float, what: str, advice: str) -> None:
    """Refuse a ``side × side`` float64 grid above :data:`MAX_GRID_BYTES` (before allocating it)."""
    needed = 8.0 * side * side
    if not needed <= MAX_GRID_BYTES:  # also NaN
        raise InvalidInputError(
            f"{what} would be a {side:.6g} × {side:.6g} float64 grid ({needed / 2**30:.3g} GiB), above "
            f"brdfscale.synth.MAX_GRID_BYTES = {MAX_GRID_BYTES} bytes ({math.isqrt(MAX_GRID_BYTES // 8)}² nodes); "
            f"{advice}."
        )


SLOPE_RANGE = (1e-30, 1e6)
"""The magnitudes a field's steepest pixel slope may have (dimensionless), unless it is 0 (a flat field).

Above 1e6 (a facet within 6e-5° of vertical) the heights are not a surface but a dropout,
a sentinel value or a wrong unit; below 1e-30 (a height change of 1e-30 m per metre, far
below any length a surface has) the second and fourth moments of the slopes that the facet
statistics and their standard errors are made of underflow float64 (heights in denormal
numbers). Either is refused by :class:`HeightField` with the steepest slope and where it is.
"""

MAX_PITCH_RATIO = 1e4
"""The largest ratio of a field's two pixel pitches: a facet window needs at least one pixel
along the coarser axis, so at this ratio its side along the finer one is 10 000 pixels."""


def check_micro(micro) -> stats.AbstractSlopeDensity:
    """The pixel facets' lobe: a :mod:`brdfscale.stats` probability density (not a plus-distribution)."""
    return stats.require_density(
        micro,
        "micro",
        other=" (Delta() for mirror facets)",
        use="Use plus.NearlySpecular(...) (mass 1) or plus.observe(plus.NearlySpecular(...), kernel).",
    )


_MIRROR = stats.Delta()  # the default micro lobe: mirror pixel facets
_NO_DESCRIPTION = types.MappingProxyType({})


@dataclasses.dataclass(frozen=True, eq=False, repr=False, init=False)
class HeightField(Shown):
    """A sampled height field — synthesised or measured — with the micro-facets' own lobe.

    Attributes:
        heights: ``h[j, k]`` at ``(x, y) = (k Δx, j Δy)`` (rows y, columns x), shape (ny, nx)
            with ny, nx ≥ 4, length units. Entries where ``mask`` is False are unmeasured:
            they are stored as 0 and never used.
        spacing: the pixel pitch ``(Δx, Δy)`` (length units, > 0); a single number means
            square pixels. A *pixel facet* is the plane through ``h[j, k]``, ``h[j, k+1]``
            and ``h[j+1, k]``: its height gradient is the forward difference along each axis
            with that axis's pitch. A facet at scale μ is a window of ``μ/Δy × μ/Δx`` pixel
            facets (:meth:`block`): μ × μ in length units, so non-square pixels are exact.
        micro: the lobe of one pixel facet in slope space (:mod:`brdfscale.stats` density):
            :class:`~brdfscale.stats.Delta` for mirror micro-facets (default), e.g.
            ``stats.Beckmann(0.01)`` for rough ones.
        spectrum: the power spectrum the heights were drawn from, when they were (it makes
            the analytic ``Σ(μ)`` of :class:`brdfscale.stats.GaussianSurface` available).
        description: JSON-serialisable provenance (generator, parameters, seed; for a
            measured field the file, format, instrument, channel and detrending —
            :mod:`brdfscale.topography`).
        mask: boolean (ny, nx), True where the height was measured, or None (all measured).
            A pixel facet is measured when its three nodes are; a facet window is used only
            when all its pixel facets are (windows touching unmeasured pixels are excluded).
        periodic: True for a field periodic with period ``(nx Δx, ny Δy)`` (synthesised
            fields: pixel facets and facets wrap around the edges); False for a measured
            field (``(ny − 1) × (nx − 1)`` pixel facets, facet windows placed without
            wrap-around).
        unit: the length unit of ``heights`` and ``spacing`` (``"m"`` for fields read by
            :mod:`brdfscale.topography`), or None for the dimensionless lengths of
            synthesised fields. Slopes are ratios of lengths and carry no unit.

    Slope convention (docs/conventions.md §1): the slope of a facet is the slope of its *normal*,
    ``m = (n_x/n_z, n_y/n_z) = −∇h``. A mirror facet of slope m reflects light into the
    half-vector slope ``m_s = m``.

    Raises InvalidInputError for heights that are not a real (ny, nx) array with ny, nx ≥ 4,
    finite where measured (complex, bool, text or None is refused, not cast); a spacing that
    is not a positive real number or pair; a mask of the wrong shape, not boolean or leaving
    no measured pixel facet; a ``micro`` that is not a probability density of facet slopes (a
    :class:`brdfscale.plus.PlusDistribution` has mass 0), a wrong ``spectrum``, a
    ``description`` that is not a mapping, a ``periodic`` that is not a bool or a ``unit``
    that is not a string or None.
    """

    # the fields hold the validated values; the constructor takes more (a single spacing, integer heights, any
    # mapping) and refuses the rest with InvalidInputError, so its arguments are unannotated (``object`` where a
    # default would otherwise make the type checker narrow what callers may pass to the default's type)
    SLOPE_RANGE: ClassVar[tuple[float, float]] = SLOPE_RANGE
    """The magnitudes the steepest pixel slope may have unless it is 0 (:data:`SLOPE_RANGE`)."""
    MAX_PITCH_RATIO: ClassVar[float] = MAX_PITCH_RATIO
    """The largest ratio of the two pitches (:data:`MAX_PITCH_RATIO`)."""
    LENGTH_TOLERANCE: ClassVar[float] = 1e-3
    """The relative tolerance within which two lengths of a field count as equal: the sides of
    a facet window (:meth:`block`; the window's side along y may differ from μ by this much when
    the pixels are not square) and, in :func:`brdfscale.topography.from_array`, two pitches
    that make square pixels."""

    heights: Float[np.ndarray, "ny nx"]
    spacing: tuple[float, float]
    micro: stats.AbstractSlopeDensity
    spectrum: stats.AbstractPowerSpectrum | None
    description: dict
    mask: Bool[np.ndarray, "ny nx"] | None
    periodic: bool
    unit: str | None

    def __init__(
        self,
        heights,
        spacing,
        micro: object = _MIRROR,
        spectrum=None,
        description: object = _NO_DESCRIPTION,
        mask=None,
        periodic=True,
        unit=None,
    ):
        mask = None if mask is None else boolean_mask(mask, "mask")
        raw = heights
        if mask is not None:
            raw = np.asarray(raw)
            if raw.shape != mask.shape:
                raise InvalidInputError(f"mask must have the shape of heights, {raw.shape}; got {mask.shape}.")
            if raw.dtype.kind in "fiu":
                raw = np.where(mask, raw, 0.0)
        h = real_array(raw, "heights")
        if h.ndim != 2 or min(h.shape) < 4:
            raise InvalidInputError(
                f"heights must be a 2-D (ny, nx) array with ny, nx ≥ 4 (rows y, columns x); got shape {h.shape}."
            )
        spacing = pitch(spacing)
        if not max(spacing) <= MAX_PITCH_RATIO * min(spacing):  # also an overflowing ratio
            raise InvalidInputError(
                f"the pixel pitches Δx = {spacing[0]:.6g} and Δy = {spacing[1]:.6g} differ by more than a factor "
                f"{MAX_PITCH_RATIO:g} (HeightField.MAX_PITCH_RATIO): no facet window holds whole "
                "pixels along both axes; check the pitches (and their units)."
            )
        check_micro(micro)
        if spectrum is not None and not isinstance(spectrum, stats.AbstractPowerSpectrum):
            raise InvalidInputError(
                f"spectrum must be a brdfscale.stats power spectrum; got {type(spectrum).__name__}."
            )
        if not isinstance(description, Mapping):
            raise InvalidInputError(
                f"description must be a dict (JSON-serialisable provenance); got {type(description).__name__}."
            )
        periodic = flag(periodic, "periodic")
        if unit is not None and not isinstance(unit, str):
            raise InvalidInputError(
                f"unit must be the name of a length unit (a string) or None; got {type(unit).__name__}."
            )
        if mask is not None and mask.all():
            mask = None
        object.__setattr__(self, "heights", h)
        object.__setattr__(self, "spacing", spacing)
        object.__setattr__(self, "micro", micro)
        object.__setattr__(self, "spectrum", spectrum)
        object.__setattr__(self, "description", dict(description))
        object.__setattr__(self, "mask", mask)
        object.__setattr__(self, "periodic", periodic)
        object.__setattr__(self, "unit", unit)
        if mask is not None:
            facets = self.pixel_facets
            assert facets is not None  # set whenever the mask is
            if not facets.any():
                raise InvalidInputError(
                    f"the mask leaves no measured pixel facet (a pixel facet needs its node and its right and lower "
                    f"neighbours measured); {int(mask.sum())} of {mask.size} pixels are measured."
                )
        self._check_slopes()

    def _check_slopes(self) -> None:
        """Refuse a steepest pixel slope outside :data:`SLOPE_RANGE` (0, a flat field, is measured)."""
        top, where = self._steepest
        low, high = SLOPE_RANGE
        if top == 0 or low <= top <= high:
            return
        unit = f" {self.unit}" if self.unit else ""
        j, k, axis = where
        what = (
            f"the steepest pixel slope is {top:.3g} (along {axis} at row {j}, column {k}), above {high:g}: "
            "a dropout or sentinel value that is not masked, or heights in another unit than the pitch; mask "
            "unmeasured pixels (NaN or mask=False) or give the heights' unit"
            if not top < low
            else f"the steepest pixel slope is {top:.3g}, below {low:g}: the slopes' second and fourth moments would "
            "underflow float64 (heights in denormal numbers, or in another unit than the pitch); give the heights' unit"
        )
        raise InvalidInputError(
            f"{what} (pitch {self.spacing[0]:.6g} × {self.spacing[1]:.6g}{unit}; accepted: a flat field or a steepest "
            f"slope from {low:g} to {high:g}, HeightField.SLOPE_RANGE)."
        )

    @functools.cached_property
    def _steepest(self) -> tuple[float, tuple[int, int, str]]:
        """The largest |component| of a measured pixel facet's normal slope, and where: (row, column, axis)."""
        (ny, nx), (fy, fx), h = self.shape, self.facet_grid, self.heights
        dx, dy = self.spacing
        valid = self.pixel_facets
        top, where = 0.0, (0, 0, "x")
        step = max(1, (1 << 21) // nx)  # rows per strip: ~16 MB per float64 work array
        for start in range(0, fy, step):
            stop = min(start + step, fy)
            strip = h[start:stop, :fx]
            right = np.roll(h[start:stop], -1, axis=1)[:, :fx]
            below = h[(np.arange(start, stop) + 1) % ny, :fx]
            for axis, d, other in (("x", dx, right), ("y", dy, below)):
                with np.errstate(over="ignore"):
                    m = np.abs(other - strip) / d
                if valid is not None:
                    m = np.where(valid[start:stop], m, 0.0)
                if not np.isfinite(m).all():
                    m = np.where(np.isfinite(m), m, np.inf)
                index = np.unravel_index(int(np.argmax(m)), m.shape)
                if m[index] > top:
                    top, where = float(m[index]), (start + int(index[0]), int(index[1]), axis)
        return top, where

    @property
    def steepest_slope(self) -> float:
        """The largest |component| of any measured pixel facet's normal slope (0 for a flat field)."""
        return self._steepest[0]

    # -- geometry ------------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        """``(ny, nx)``: rows (y) and columns (x) of ``heights``."""
        return self.heights.shape

    @property
    def size(self) -> int:
        """Pixels per side of a square field, n (a rectangular field has :attr:`shape` instead)."""
        ny, nx = self.shape
        if ny != nx:
            raise InvalidInputError(f"this field is rectangular, {ny} rows × {nx} columns; use field.shape.")
        return nx

    @property
    def facet_grid(self) -> tuple[int, int]:
        """Pixel facets per axis, ``(rows, cols)``: ``(ny, nx)`` when periodic, else ``(ny − 1, nx − 1)``."""
        ny, nx = self.shape
        return (ny, nx) if self.periodic else (ny - 1, nx - 1)

    @functools.cached_property
    def pixel_facets(self) -> Bool[np.ndarray, "rows cols"] | None:
        """Which pixel facets are measured (:attr:`facet_grid` shape), or None when all are."""
        if self.mask is None:
            return None
        m, (fy, fx) = self.mask, self.facet_grid
        right = np.roll(m, -1, axis=1)[:fy, :fx]
        below = np.roll(m, -1, axis=0)[:fy, :fx]
        return m[:fy, :fx] & right & below

    def block(self, mu: float) -> tuple[int, int]:
        """The facet window at scale μ, ``(rows, cols) = (round(μ/Δy), round(μ/Δx))`` pixel facets.

        Each side of the window, ``rows·Δy`` and ``cols·Δx``, must equal μ to
        :attr:`LENGTH_TOLERANCE` (relative), hold at least one pixel and at most
        :attr:`facet_grid` (InvalidInputError otherwise, naming the admissible scales). With
        square pixels that is a whole number of pixels; with rectangular ones a window whose
        two sides are equal to 0.1 % (``field.scales`` lists the admissible ones: every
        window whose side along y is within the tolerance of its side along x).
        """
        mu = real(mu, "mu")
        dx, dy = self.spacing
        fy, fx = self.facet_grid
        tol = self.LENGTH_TOLERANCE
        counts = []
        for d, top in ((dy, fy), (dx, fx)):
            b = mu / d
            nb = round(b) if math.isfinite(b) else 0
            if not (abs(nb * d - mu) <= tol * abs(mu) and 1 <= nb <= top):
                unit = f" {self.unit}" if self.unit else ""
                square = math.isclose(dx, dy, rel_tol=1e-12)
                whole = (
                    "a whole number of pixels"
                    if square
                    else f"a whole number of pixels along both axes (Δx = {dx:.6g}{unit}, Δy = {dy:.6g}{unit})"
                )
                raise InvalidInputError(
                    f"scale mu={mu!r} must be {whole}, to a relative {tol:g}, between {max(dx, dy):.6g}{unit} and "
                    f"{min(fx * dx, fy * dy):.6g}{unit} (the field's {fy} × {fx} pixel facets); "
                    f"field.scales(count) lists admissible ones."
                )
            counts.append(int(nb))
        return counts[0], counts[1]

    @functools.cached_property
    def _windows(self) -> tuple[np.ndarray, np.ndarray]:
        """Every admissible window: its x side μ = cols·Δx (ascending) and ``(rows, cols)``."""
        dx, dy = self.spacing
        fy, fx = self.facet_grid
        cols = np.arange(1, fx + 1)
        rows = np.rint(cols * dx / dy).astype(int)
        ok = (rows >= 1) & (rows <= fy) & (np.abs(rows * dy - cols * dx) <= self.LENGTH_TOLERANCE * cols * dx)
        return cols[ok] * dx, np.stack((rows[ok], cols[ok]), axis=-1)

    def scales(self, count: int = 8, *, smallest: int = 1, largest: int | None = None) -> list[float]:
        """Up to ``count`` admissible facet sizes μ, log-spaced, from the admissible windows.

        A window is admissible when its sides are equal to :attr:`LENGTH_TOLERANCE` (every
        whole number of pixels for square pixels; for rectangular ones also windows that are
        not exact common multiples of the two pitches, e.g. 37 × 15 pixels of 127.7 × 314.6 nm);
        μ is its side along x. ``smallest`` and ``largest`` count the *unit window* — the
        smallest admissible one (one pixel for square pixels) — and bound μ to
        ``[smallest, largest] ×`` its size. The default largest is half the shorter side,
        reduced until at least 4 windows lie wholly on measured pixels (at most 2 × 2 fit at
        half the side). Each of ``count`` log-spaced sizes is replaced by the admissible size
        nearest to it and repeats are dropped, so fewer than ``count`` may come back at small
        ranges.
        """
        count = integer(count, "count", 1)
        smallest = integer(smallest, "smallest", 1)
        sizes, blocks = self._windows
        if len(sizes) == 0:
            dx, dy = self.spacing
            raise InvalidInputError(
                f"no facet window of this {self.facet_grid[0]} × {self.facet_grid[1]} field has sides equal to a "
                f"relative {self.LENGTH_TOLERANCE:g} with pitches Δx = {dx:.6g} and Δy = {dy:.6g}; resample the field "
                "onto square pixels (brdfscale.topography.resample)."
            )
        unit = float(sizes[0])
        fy, fx = self.facet_grid
        top = int(min(fx * self.spacing[0], fy * self.spacing[1]) / unit * (1 + 1e-12))
        if largest is None:
            largest = max(1, top // 2)
            while largest > 1 and self._measured_windows(self._window_at(largest * unit)) < 4:
                largest -= max(1, largest // 16)
        else:
            largest = min(integer(largest, "largest", smallest), max(top, 1))
        if smallest > largest:
            raise InvalidInputError(
                f"smallest={smallest} exceeds the largest admissible window, {largest} unit windows."
            )
        inside = sizes[(sizes >= smallest * unit * (1 - 1e-12)) & (sizes <= largest * unit * (1 + 1e-12))]
        if len(inside) == 0:
            raise InvalidInputError(f"no admissible window lies between {smallest} and {largest} unit windows.")
        targets = np.geomspace(smallest, largest, count) * unit
        picked = np.unique(inside[np.argmin(np.abs(inside[None, :] - targets[:, None]), axis=1)])
        return [float(mu) for mu in picked]

    def _window_at(self, mu: float) -> tuple[int, int]:
        """The admissible window whose x side is nearest ``mu``, ``(rows, cols)``."""
        sizes, blocks = self._windows
        k = int(np.argmin(np.abs(sizes - mu)))
        return int(blocks[k][0]), int(blocks[k][1])

    def _measured_windows(self, block: tuple[int, int]) -> int:
        """How many whole windows of ``block`` (rows, cols) pixel facets are measured throughout."""
        (fy, fx), (by, bx) = self.facet_grid, block
        nby, nbx = fy // by, fx // bx
        if self.pixel_facets is None:
            return nby * nbx
        return int(self.pixel_facets[: nby * by, : nbx * bx].reshape(nby, by, nbx, bx).all(axis=(1, 3)).sum())

    def __add__(self, other: "HeightField") -> "HeightField":
        """Superpose two fields of equal shape, pitch and periodicity (heights add; masks
        combine; micro lobe and unit of ``self``). The sum has no single power spectrum, so
        ``spectrum`` is dropped."""
        if not isinstance(other, HeightField):
            return NotImplemented
        same = (
            other.shape == self.shape
            and other.periodic == self.periodic
            and all(math.isclose(a, b, rel_tol=1e-12) for a, b in zip(other.spacing, self.spacing))
        )
        if not same or other.unit != self.unit:
            raise InvalidInputError(
                f"can only add fields of equal shape, spacing, periodicity and unit; got {self.shape}@{self.spacing} "
                f"(periodic={self.periodic}, unit={self.unit}) and {other.shape}@{other.spacing} "
                f"(periodic={other.periodic}, unit={other.unit})."
            )
        if self.mask is None or other.mask is None:
            mask = self.mask if other.mask is None else other.mask
        else:
            mask = self.mask & other.mask
        return HeightField(
            self.heights + other.heights,
            self.spacing,
            micro=self.micro,
            description={"generator": "sum", "terms": [self.description, other.description]},
            mask=mask,
            periodic=self.periodic,
            unit=self.unit,
        )

    def _show_items(self):
        ny, nx = self.shape
        dx, dy = self.spacing
        unit = f" {self.unit}" if self.unit else ""
        items = [
            ("shape", f"{ny} × {nx}"),
            ("spacing", f"{dx:.4g} × {dy:.4g}{unit}" if dx != dy else f"{dx:.4g}{unit}"),
            ("periodic", self.periodic),
        ]
        if self.mask is not None:
            items.append(("unmeasured", f"{int(np.count_nonzero(~self.mask))} of {self.mask.size} px"))
        source = self.description.get("file") or self.description.get("generator") or self.description.get("name")
        if source:
            items.append(("source", source))
        if "detrend" in self.description:
            items.append(("detrend", self.description["detrend"]))
        items.append(("micro", type(self.micro).__name__))
        return items


def parameter_record(obj) -> dict:
    """An equinox module (density, spectrum) as ``{"type": name, field: value}`` with JSON values."""
    record = {"type": type(obj).__name__}
    for name, value in vars(obj).items():
        record[name] = _value_record(value)
    return record


def _value_record(value):
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, eqx.Module):
        return parameter_record(value)
    if isinstance(value, (tuple, list)):
        return [_value_record(v) for v in value]
    if callable(value):
        return getattr(value, "__name__", repr(value))
    return np.asarray(value, dtype=float).tolist()
