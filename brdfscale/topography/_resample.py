"""A height field onto square pixels: separable cubic convolution (one place for resampling)."""

import math

import numpy as np

from .._errors import InvalidInputError
from .._validation import real
from ..synth import HeightField, MAX_GRID_BYTES


INTERPOLATION = "separable cubic convolution (Keys 1981, a = −1/2)"

_A = -0.5  # Keys' parameter: the only one for which the interpolant reproduces quadratics (third order)


def _keys(s: np.ndarray) -> np.ndarray:
    """Keys' cubic convolution kernel ``w(s)`` (R. Keys, IEEE Trans. ASSP 29, 1153 (1981), Eq. 15)."""
    s = np.abs(s)
    inner = (_A + 2) * s**3 - (_A + 3) * s**2 + 1
    outer = _A * s**3 - 5 * _A * s**2 + 8 * _A * s - 4 * _A
    return np.where(s <= 1, inner, np.where(s < 2, outer, 0.0))


def _axis(n: int, old: float, new: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Taps ``(count, 4)`` and weights of the new nodes along one axis, and the first node's position.

    Unchanged pitch: every node kept (identity taps). Otherwise the new nodes are ``x₀ + k·new``
    from ``x₀ = old`` while the four taps ``⌊u⌋ − 1 … ⌊u⌋ + 2`` of ``u = x/old`` lie on the grid.
    """
    if new == old:
        index = np.arange(n)[:, None] + np.array([[0, 0, 0, 0]])
        return index, np.array([[1.0, 0.0, 0.0, 0.0]]).repeat(n, axis=0), 0.0
    count = math.floor(((n - 2) * old - old) / new * (1 + 1e-12)) + 1 if n >= 4 else 0
    u = 1.0 + np.arange(max(count, 0)) * new / old
    base = np.minimum(np.floor(u).astype(int), n - 3)  # u = n − 2 exactly: taps n − 4 … n − 1
    t = u - base
    index = base[:, None] + np.arange(-1, 3)[None, :]
    weights = _keys(t[:, None] - np.arange(-1, 3)[None, :])
    return index, weights, old


def _apply(values: np.ndarray, index: np.ndarray, weights: np.ndarray, axis: int) -> np.ndarray:
    moved = np.moveaxis(values, axis, -1)
    out = np.einsum("...ck,ck->...c", moved[..., index], weights)
    return np.moveaxis(out, -1, axis)


def resample(field: HeightField, pitch: float | None = None) -> HeightField:
    """The field on square pixels of side ``pitch`` (default: the finer of its two pitches).

    Interpolation: separable cubic convolution, Keys' kernel with ``a = −1/2`` (R. Keys,
    *Cubic convolution interpolation for digital image processing*, IEEE Trans. ASSP 29,
    1153 (1981)): along each axis whose pitch changes, the height at ``x`` is
    ``Σ_{i=⌊u⌋−1}^{⌊u⌋+2} h_i w(u − i)`` with ``u = x/Δ``; it passes through the nodes and
    reproduces polynomials up to degree 2, so its error on a smooth surface is ``O(Δ³)``
    (tests/test_topography_robustness.py checks both on an analytic surface). An axis whose
    pitch is already ``pitch`` is copied. New nodes start one old pixel in (``x₀ = Δx``,
    ``y₀ = Δy`` on the resampled axes) and end where the four taps still lie on the grid, so
    the resampled field covers the old one less about one pixel at each edge; a new node is
    measured when every tap with a non-zero weight is. The result is not periodic; it keeps
    ``micro`` and ``unit``, drops ``spectrum``, and records the pitches, the interpolation and
    the origin in ``description`` (the old description under ``"source"``).

    Note that interpolation smooths: slopes at the pixel scale of a resampled field are those
    of the interpolant; at facet sizes of a few old pixels and more the facet statistics are
    the old field's (to ``O(Δ³)`` in the heights).

    Raises InvalidInputError for a ``field`` that is not a HeightField, a ``pitch`` that is not a
    positive real number, or a result smaller than 4 × 4 pixels or above
    :data:`brdfscale.synth.MAX_GRID_BYTES`.
    """
    if not isinstance(field, HeightField):
        raise InvalidInputError(f"field must be a brdfscale.synth.HeightField; got {type(field).__name__}.")
    dx, dy = field.spacing
    new = min(dx, dy) if pitch is None else real(pitch, "pitch", minimum=0, strict=True)
    ny, nx = field.shape
    unit = f" {field.unit}" if field.unit else ""
    sizes = [(n - 3) * d / new + 1 if d != new else n for n, d in ((ny, dy), (nx, dx))]
    if not (min(sizes) >= 4 and 8.0 * sizes[0] * sizes[1] <= MAX_GRID_BYTES):
        raise InvalidInputError(
            f"pitch={new:.6g}{unit} would resample the {ny} × {nx} field of {dx:.6g} × {dy:.6g}{unit} pixels onto "
            f"about {sizes[0]:.6g} × {sizes[1]:.6g} pixels; a field needs at least 4 × 4 and at most "
            f"brdfscale.synth.MAX_GRID_BYTES = {MAX_GRID_BYTES} bytes of float64 nodes."
        )
    (iy, wy, y0), (ix, wx, x0) = _axis(ny, dy, new), _axis(nx, dx, new)
    measured = np.ones(field.shape) if field.mask is None else field.mask.astype(float)
    heights = np.where(measured > 0, field.heights, 0.0)
    heights = _apply(_apply(heights, ix, wx, 1), iy, wy, 0)
    missing = _apply(_apply(1.0 - measured, ix, np.abs(wx), 1), iy, np.abs(wy), 0)
    mask = missing == 0
    description = {
        "generator": "brdfscale.topography.resample",
        "interpolation": INTERPOLATION,
        "pitch_as_given": [dx, dy],
        "pitch": new,
        "origin": [x0, y0],  # the first new node's (x, y) on the old grid
        "source": field.description,
    }
    if not mask.any():
        raise InvalidInputError("no resampled node has all its interpolation taps measured.")
    return HeightField(
        heights,
        (new, new),
        micro=field.micro,
        description=description,
        mask=None if mask.all() else mask,
        periodic=False,
        unit=field.unit,
    )
