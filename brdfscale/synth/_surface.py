"""The height-field container."""

import dataclasses
import math
from collections.abc import Mapping

import equinox as eqx
import numpy as np
from jaxtyping import Float

from .. import stats
from .._errors import InvalidInputError
from .._validation import real, real_array

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
            f"brdfscale.synth.MAX_GRID_BYTES = {MAX_GRID_BYTES} bytes ({math.isqrt(MAX_GRID_BYTES // 8)}² nodes); {advice}."
        )


def check_micro(micro) -> stats.AbstractSlopeDensity:
    """The pixel facets' lobe: a :mod:`brdfscale.stats` probability density (not a plus-distribution)."""
    if isinstance(micro, stats.AbstractGeneralisedDensity):
        raise InvalidInputError(
            f"micro must be a probability density of facet slopes (mass 1); got {type(micro).__name__}, "
            "a generalised function of mass 0 with no pointwise density (a plus-distribution h_n). Use "
            "plus.NearlySpecular(...) (mass 1) or plus.observe(plus.NearlySpecular(...), kernel).")
    if not isinstance(micro, stats.AbstractSlopeDensity):
        raise InvalidInputError(
            f"micro must be a brdfscale.stats density (Delta() for mirror facets); got {type(micro).__name__}."
        )
    return micro


@dataclasses.dataclass(frozen=True, eq=False)
class HeightField:
    """A periodic height field sampled on a square grid, with the micro-facets' own lobe.

    Attributes:
        heights: ``h[j, k]`` at ``(x, y) = (k Δ, j Δ)`` (rows y, columns x), shape (n, n),
            length units; the field is periodic with period ``n Δ`` on both axes.
        spacing: the pixel pitch Δ (length units, > 0). A *pixel facet* is the plane
            through ``h[j, k]``, ``h[j, k+1]`` and ``h[j+1, k]``: its height gradient is the
            forward difference. Facets at scale μ are blocks of ``μ/Δ × μ/Δ`` pixels.
        micro: the lobe of one pixel facet in slope space (:mod:`brdfscale.stats` density):
            :class:`~brdfscale.stats.Delta` for mirror micro-facets (default), e.g.
            ``stats.Beckmann(0.01)`` for rough ones.
        spectrum: the power spectrum the heights were drawn from, when they were (it makes
            the analytic ``Σ(μ)`` of :class:`brdfscale.stats.GaussianSurface` available).
        description: JSON-serialisable provenance (generator, parameters, seed).

    Slope convention (docs/conventions.md §1): the slope of a facet is the slope of its *normal*,
    ``m = (n_x/n_z, n_y/n_z) = −∇h``. A mirror facet of slope m reflects light into the
    half-vector slope ``m_s = m``.

    Raises InvalidInputError for heights that are not a finite real (n, n) array with n ≥ 4
    (complex, bool, text or None is refused, not cast), a spacing that is not a positive
    real number, a ``micro`` that is not a probability density of facet slopes (a
    :class:`brdfscale.plus.PlusDistribution` has mass 0), a wrong ``spectrum`` or a
    ``description`` that is not a mapping.
    """

    heights: Float[np.ndarray, "n n"]
    spacing: float
    micro: stats.AbstractSlopeDensity = dataclasses.field(default_factory=stats.Delta)
    spectrum: stats.AbstractPowerSpectrum | None = None
    description: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        h = real_array(self.heights, "heights")
        if h.ndim != 2 or h.shape[0] != h.shape[1] or h.shape[0] < 4:
            raise InvalidInputError(f"heights must be a square (n, n) array with n ≥ 4; got shape {h.shape}.")
        spacing = real(self.spacing, "spacing", minimum=0, strict=True)
        check_micro(self.micro)
        if self.spectrum is not None and not isinstance(self.spectrum, stats.AbstractPowerSpectrum):
            raise InvalidInputError(f"spectrum must be a brdfscale.stats power spectrum; got {type(self.spectrum).__name__}.")
        if not isinstance(self.description, Mapping):
            raise InvalidInputError(f"description must be a dict (JSON-serialisable provenance); got {type(self.description).__name__}.")
        object.__setattr__(self, "heights", h)
        object.__setattr__(self, "spacing", spacing)
        object.__setattr__(self, "description", dict(self.description))

    @property
    def size(self) -> int:
        """Pixels per side, n."""
        return self.heights.shape[0]

    def __add__(self, other: "HeightField") -> "HeightField":
        """Superpose two fields of equal size and pitch (heights add; micro lobe of ``self``).

        The sum has no single power spectrum, so ``spectrum`` is dropped.
        """
        if not isinstance(other, HeightField):
            return NotImplemented
        if other.size != self.size or not math.isclose(other.spacing, self.spacing, rel_tol=1e-12):
            raise InvalidInputError(
                f"can only add fields of equal size and spacing; got {self.size}@{self.spacing} and {other.size}@{other.spacing}."
            )
        return HeightField(
            self.heights + other.heights,
            self.spacing,
            micro=self.micro,
            description={"generator": "sum", "terms": [self.description, other.description]},
        )

    def block(self, mu: float) -> int:
        """The facet size μ in pixels; μ must be a whole number of pixels between 1 and n."""
        b = real(mu, "mu") / self.spacing
        nb = round(b) if math.isfinite(b) else 0
        if not (abs(b - nb) <= 1e-9 * max(1.0, b) and 1 <= nb <= self.size):
            raise InvalidInputError(
                f"scale mu={mu!r} must be a whole number of pixels (spacing {self.spacing}) between "
                f"{self.spacing} and {self.size * self.spacing}."
            )
        return nb


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
