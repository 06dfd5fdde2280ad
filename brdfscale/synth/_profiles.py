"""Non-Gaussian micro-structure: sparse scratches and blazed (sawtooth) gratings."""

import math

import numpy as np

from .. import stats
from .._errors import InvalidInputError
from .._validation import integer, real
from ._random import as_generator, seed_record
from ._spectral import _check_size
from ._surface import check_micro, HeightField


def _positive(value, name: str) -> float:
    return real(value, name, minimum=0, strict=True)


def blazed(
    *,
    size: int,
    spacing: float = 1.0,
    period: int,
    slopes: tuple[float, float] = (0.03, -0.07),
    angle: float = 0.0,
    micro: stats.AbstractSlopeDensity | None = None,
) -> HeightField:
    """A blazed (sawtooth) grating: facets of two normal slopes, zero mean slope.

    Along the direction ``(cos angle, sin angle)`` the facet normal slope is ``slopes[0]``
    over a fraction ``f`` of each period and ``slopes[1]`` over the rest, with
    ``f = −s₁/(s₀ − s₁)`` so that the mean slope vanishes (the profile is periodic). The
    default gives docs/conventions.md §2's skewed example: 70 % of the facets at slope +0.03, 30 % at
    −0.07. Slopes are normal slopes, ``m = −∇h``.

    ``period`` is in pixels and must divide ``size``; ``angle`` must be 0 (grooves along y)
    or π/2 (grooves along x) so that the grating stays periodic on the square grid. With
    ``f · period`` a whole number, every pixel facet has exactly one of the two slopes.

    Raises InvalidInputError for ``size`` not an integer ≥ 4 or above
    :data:`MAX_GRID_BYTES` (n × n float64 heights), a ``period`` that is not an integer ≥ 2
    dividing it, ``slopes`` that are not two real numbers of opposite sign, a ``spacing``
    that is not a positive real number, another ``angle``, or a ``micro`` that is not a
    probability density of facet slopes.
    """
    n = _check_size(size)
    if isinstance(period, bool) or not isinstance(period, (int, np.integer)) or period < 2 or n % period:
        raise InvalidInputError(f"period must be an integer ≥ 2 (pixels) dividing size={n}; got {period!r}.")
    try:
        if isinstance(slopes, (str, bytes)):
            raise TypeError
        first, second = slopes
    except (TypeError, ValueError):
        raise InvalidInputError(f"slopes must be two finite normal slopes of opposite sign; got {slopes!r}.") from None
    s0, s1 = real(first, "slopes[0]"), real(second, "slopes[1]")
    if not s0 * s1 < 0:
        raise InvalidInputError(f"slopes must be two finite normal slopes of opposite sign; got {slopes!r}.")
    spacing = _positive(spacing, "spacing")
    angle = real(angle, "angle")
    if angle not in (0.0, math.pi / 2):
        raise InvalidInputError(f"angle must be 0 or π/2 (a grating periodic on the grid); got {angle!r}.")
    micro = stats.Delta() if micro is None else check_micro(micro)
    f = -s1 / (s0 - s1)
    # The height h = −∫ m dx: it falls with slope s0 over [0, f p), rises back over [f p, p).
    x = (np.arange(n) % period) * spacing
    p = period * spacing
    profile = np.where(x < f * p, -s0 * x, -s0 * f * p - s1 * (x - f * p))
    heights = np.array(np.broadcast_to(profile[None, :] if angle == 0.0 else profile[:, None], (n, n)))
    return HeightField(
        heights,
        spacing,
        micro=micro,
        description={
            "generator": "blazed",
            "size": n,
            "spacing": spacing,
            "period": int(period),
            "slopes": [s0, s1],
            "fraction": f,
            "angle": float(angle),
        },
    )


def scratches(
    *,
    size: int,
    spacing: float = 1.0,
    count: int,
    depth: float,
    width: float,
    length: float,
    seed,
    micro: stats.AbstractSlopeDensity | None = None,
) -> HeightField:
    """Sparse straight V-shaped scratches on a flat, periodic surface.

    ``count`` segments of length ``length`` with uniformly random centres and orientations
    are cut ``depth`` deep into the surface with a V cross-section ``width`` wide
    (``h = −depth · max(0, 1 − 2 d/width)`` at distance d from the segment; overlapping
    scratches take the deeper cut). Their walls have normal slopes of modulus
    ``2 depth/width``: facet statistics with a δ at 0 and a ring of outliers, far from
    Gaussian. Lengths in length units; scratches wrap around the periodic boundary.

    Raises InvalidInputError for ``size`` not an integer ≥ 4 or above
    :data:`MAX_GRID_BYTES` (n × n float64 heights), ``count`` not an integer ≥ 0, a
    ``spacing``, ``depth``, ``width`` or ``length`` that is not a positive real number,
    ``length + width`` not below the field's side, a bad seed, or a ``micro`` that is not a
    probability density of facet slopes.
    """
    n = _check_size(size)
    spacing = _positive(spacing, "spacing")
    count = integer(count, "count", 0)
    micro = stats.Delta() if micro is None else check_micro(micro)
    depth, width, length = (_positive(v, name) for v, name in ((depth, "depth"), (width, "width"), (length, "length")))
    if length + width > n * spacing:
        raise InvalidInputError(f"length + width must be below the field size {n * spacing}; got {length + width}.")
    rng = as_generator(seed)
    heights = np.zeros((n, n))
    half = 0.5 * (length + width)
    reach = int(math.ceil(half / spacing)) + 1
    offsets = np.arange(-reach, reach + 1)
    for _ in range(count):
        centre = rng.uniform(0, n * spacing, 2)
        theta = rng.uniform(0, np.pi)
        direction = np.array([math.cos(theta), math.sin(theta)])
        ic = np.floor(centre / spacing).astype(int)
        xs = (ic[0] + offsets) * spacing - centre[0]
        ys = (ic[1] + offsets) * spacing - centre[1]
        dx, dy = np.meshgrid(xs, ys, indexing="xy")
        along = np.clip(dx * direction[0] + dy * direction[1], -length / 2, length / 2)
        dist = np.hypot(dx - along * direction[0], dy - along * direction[1])
        cut = -depth * np.maximum(0.0, 1 - 2 * dist / width)
        rows = (ic[1] + offsets) % n
        cols = (ic[0] + offsets) % n
        block = heights[np.ix_(rows, cols)]
        heights[np.ix_(rows, cols)] = np.minimum(block, cut)
    return HeightField(
        heights,
        spacing,
        micro=micro,
        description={
            "generator": "scratches",
            "size": n,
            "spacing": spacing,
            "count": count,
            "depth": depth,
            "width": width,
            "length": length,
            "seed": seed_record(seed),
        },
    )
