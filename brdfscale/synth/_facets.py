"""Facet statistics of a height field at a scale μ (seed §3–4, docs/conventions.md §2).

A facet at scale μ is a block of ``b × b`` pixels, ``b = μ/Δ``, of a :class:`HeightField`.
Its slope is the block average of the pixel facets' normal slopes ``m = −∇h`` (forward
differences), which telescopes to the height differences across the block: the box-window
average of the gradient of :class:`brdfscale.stats.GaussianSurface` with ``window="box"``
(exact along x; along y the rows are summed, a Dirichlet kernel that equals the box's sinc
up to ``O((kΔ)²)``).

* The between-facet statistics ``s(·, μ)`` are the histogram of the facet slopes.
* The within-facet lobe ``g_μ`` is the histogram of the pixel slopes relative to the slope of
  the facet that contains them, pooled over all facets, convolved with the pixel facets'
  own lobe (δ for mirror micro-facets). It is the lobe a gonioreflectometer sees when it
  measures one facet of size μ in that facet's own frame, averaged over facets, and
  ``g_∞ = g_μ ∗ s(·, μ)`` (seed Eq. 3.1) holds only when the within-facet residuals are
  independent of the facet slope; experiments/consistency.py measures its violation.
"""

import dataclasses
import math

import equinox as eqx
import numpy as np
from jaxtyping import Float

from .. import stats
from .._errors import InvalidInputError
from .._validation import integer, real, real_array
from ..stats._histogram import SlopeHistogram
from ._surface import HeightField, check_grid

_PIXELS_PER_CHUNK = 1 << 21  # pixels per strip: ~16 MB per float64 work array
_TAIL = 1e-6  # kernel tails below this fraction of their peak may be cut or wrapped


@dataclasses.dataclass(frozen=True, eq=False)
class FacetStatistics:
    """Slope statistics of one height field at one scale.

    Attributes:
        mu: the scale (facet size, length units); ``block = μ/Δ`` pixels per side.
        slopes: ``s(·, μ)``, the density of the facets' normal slopes (histogram).
        lobe: ``g_μ``, the within-facet lobe in slope space (histogram ⊛ micro lobe).
        mean, covariance: sample mean (2,) and covariance (2, 2) of the facet slopes,
            the latter to compare with ``GaussianSurface(spectrum, window="box")`` Σ(μ).
        count: the number of facets, ``(n // block)²``.
    """

    mu: float
    block: int
    slopes: stats.Tabulated
    lobe: stats.Tabulated
    mean: Float[np.ndarray, "2"]
    covariance: Float[np.ndarray, "2 2"]
    count: int


def check_field(field) -> HeightField:
    if not isinstance(field, HeightField):
        raise InvalidInputError(f"field must be a brdfscale.synth.HeightField; got {type(field).__name__}.")
    return field


def check_scales(scales) -> list[float]:
    """Facet sizes μ: one real number or a 1-D sequence of them, at least one."""
    a = real_array(scales, "scales")
    if a.ndim > 1:
        raise InvalidInputError(f"scales must be a facet size or a 1-D sequence of them; got shape {a.shape}.")
    if a.size == 0:
        raise InvalidInputError("scales must list at least one facet size.")
    return [float(mu) for mu in np.atleast_1d(a)]


def facet_slopes(field: HeightField, mu: float) -> Float[np.ndarray, "nb nb 2"]:
    """Normal slopes of the facets at scale μ, shape ``(n // b, n // b, 2)`` with ``b = μ/Δ``.

    Facet ``[J, K]`` covers rows ``J b … J b + b − 1`` and columns ``K b … K b + b − 1``; the
    pixels beyond the last whole facet (when b does not divide n) are left out.
    Cost: two passes over the heights, ``O(n²/b)`` memory.
    """
    check_field(field)
    return np.stack(_facet_slope_components(field, field.block(mu)), axis=-1)


def _facet_slope_components(field: HeightField, b: int) -> tuple[np.ndarray, np.ndarray]:
    n, h, d = field.size, field.heights, field.spacing
    nb = n // b
    edges = (np.arange(nb + 1) * b) % n
    row_sums = h[: nb * b].reshape(nb, b, n).sum(axis=1)  # (nb, n): Σ over each facet's rows
    col_sums = h[:, : nb * b].reshape(n, nb, b).sum(axis=2)  # (n, nb)
    mx = -np.diff(row_sums[:, edges], axis=1) / (b * b * d)
    my = -np.diff(col_sums[edges], axis=0) / (b * b * d)
    return mx, my


def _pixel_strips(field: HeightField, block: int):
    """Yield ``(rows, mx, my)`` for strips of whole facet rows: the pixel facets' normal slopes."""
    n, h, d = field.size, field.heights, field.spacing
    nb = n // block
    width = nb * block
    step = block * max(1, _PIXELS_PER_CHUNK // (width * block))
    for start in range(0, width, step):
        stop = min(start + step, width)
        below = (np.arange(start, stop) + 1) % n
        strip = h[start:stop, :width]
        right = h[start:stop, 1 : width + 1] if width < n else np.roll(h[start:stop], -1, axis=1)
        mx = -(right - strip) / d
        my = -(h[below, :width] - strip) / d
        yield start, stop, mx, my


def offset_histogram(field: HeightField, mu: float | None, hist: SlopeHistogram, incident=None) -> SlopeHistogram:
    """Accumulate pixel slopes relative to their facet at scale μ (all pixels when μ is None).

    With ``incident`` (a unit vector towards the light) every pixel facet is weighted by the
    light it intercepts relative to a flat one, ``max(0, 1 + m·i_xy / i_z)`` (its area
    ``√(1+|m|²)`` times ``n·i``); without it every pixel counts once, the seed's nearly-flat
    approximation (docs/conventions.md §2, seed footnote 1).
    """
    block = 1 if mu is None else field.block(mu)
    facets = None if mu is None else _facet_slope_components(field, block)
    for start, stop, mx, my in _pixel_strips(field, block):
        weights = None
        if incident is not None:
            weights = np.maximum(0.0, 1 + (mx * incident[0] + my * incident[1]) / incident[2])
        if facets is not None:
            fx, fy = (f[start // block : stop // block, :, None] for f in facets)  # (r, nb, 1)
            r, nb = fx.shape[:2]
            mx = (mx.reshape(r, block, nb, block) - fx[:, None]).reshape(mx.shape)
            my = (my.reshape(r, block, nb, block) - fy[:, None]).reshape(my.shape)
        hist.add(mx, my, weights)
    return hist


def steepest_slope(field: HeightField) -> float:
    """The largest |component| of any pixel facet's normal slope (sizes slope grids)."""
    check_field(field)
    top = 0.0
    for _, _, mx, my in _pixel_strips(field, 1):
        top = max(top, float(np.max(np.abs(mx))), float(np.max(np.abs(my))))
    return top


def kernel_padding(micro: stats.AbstractSlopeDensity, resolution: float, spacing: float, nodes: int = 0,
                   what: str = "the slope grid", advice: str = "use fewer nodes or a coarser grid") -> int:
    """Grid nodes to add on each side so a blur by ``micro`` ⊛ N(0, resolution²) is not cut.

    The padded grid, ``nodes + 2·pad`` per side, is checked against :data:`MAX_GRID_BYTES`
    (InvalidInputError naming ``what`` and ``advice``) before anything is allocated.
    """
    radius = 0.0
    if not _is_mirror(micro):
        radius += float(micro.support_radius(_TAIL))
    if resolution > 0:
        radius += resolution * math.sqrt(2 * math.log(1 / _TAIL))
    pad = 0.0 if radius == 0 else radius / spacing if spacing > 0 else math.inf
    check_grid(nodes + 2.0 * math.ceil(pad) if math.isfinite(pad) else math.inf, what,
               f"{advice} (the grid is padded by {pad:.6g} nodes per side for the micro lobe's support and the blur)")
    return math.ceil(pad)


def _is_mirror(micro) -> bool:
    return isinstance(micro, stats.Delta) and micro.mean is None


@eqx.filter_jit
def _transform(density: stats.AbstractSlopeDensity, w):
    return density.cf(w)


def blur(values: np.ndarray, spacing: float, micro: stats.AbstractSlopeDensity, resolution: float = 0.0) -> np.ndarray:
    """Convolve node values on a grid of pitch ``spacing`` with ``micro`` and a Gaussian.

    The product of the DFT with ``S_micro(W) · exp(−resolution² |W|²/2)`` (the transforms
    of the micro lobe and of an isotropic Gaussian of standard deviation ``resolution`` per
    axis, docs/conventions.md §1's sign convention) is transformed back: a circular convolution, so the
    grid must carry :func:`kernel_padding` empty nodes on each side. Results below zero by
    round-off are set to zero.
    """
    if _is_mirror(micro) and resolution == 0:
        return values
    ny, nx = values.shape
    wy = 2 * np.pi * np.fft.fftfreq(ny, spacing)
    wx = 2 * np.pi * np.fft.rfftfreq(nx, spacing)
    w = np.stack(np.broadcast_arrays(wx[None, :], wy[:, None]), axis=-1)
    kernel = np.ones(w.shape[:-1], dtype=complex)
    if not _is_mirror(micro):
        kernel = kernel * np.asarray(_transform(micro, w), dtype=complex)
    if resolution > 0:
        kernel = kernel * np.exp(-0.5 * resolution**2 * np.sum(w**2, axis=-1))
    out = np.fft.irfft2(np.fft.rfft2(values) * kernel, s=values.shape)
    return np.maximum(out, 0.0)


def facet_statistics(field: HeightField, scales, *, bins: int = 129, extent: float | None = None) -> tuple[FacetStatistics, ...]:
    """Between-facet statistics ``s(·, μ)`` and within-facet lobes ``g_μ`` at each scale.

    Args:
        field: the surface.
        scales: facet sizes μ (length units), each a whole number of pixels.
        bins: nodes per axis of the tabulated densities.
        extent: half-width of the grids (slope units). Default: the largest pixel slope
            component plus the largest facet slope component, so that no sample falls
            outside (lobe grids are widened further for a rough micro lobe).

    Cost: one pass over the pixels per scale, ``O(n²)`` time, constant memory per strip.
    The grids (``bins`` nodes per side, widened for a rough micro lobe) must fit
    :data:`MAX_GRID_BYTES` (2**31 bytes of float64 nodes): a larger one is refused before it
    is allocated — use fewer bins or a larger extent.

    Raises:
        InvalidInputError: ``field`` not a :class:`HeightField`; ``scales`` not real numbers
            (each a whole number of pixels between Δ and nΔ); ``bins`` not an integer ≥ 2;
            ``extent`` not a positive real number or None; a grid above MAX_GRID_BYTES.
    """
    check_field(field)
    scales = check_scales(scales)
    bins = integer(bins, "bins", 2)
    if extent is not None:
        extent = real(extent, "extent", minimum=0, strict=True)
    check_grid(bins, f"bins={bins}", "use fewer bins")
    for mu in scales:
        field.block(mu)
    steepest = steepest_slope(field) if extent is None else None
    results = []
    for mu in scales:
        b = field.block(mu)
        samples = facet_slopes(field, mu).reshape(-1, 2)
        top = float(np.max(np.abs(samples)))
        s_extent = extent if extent is not None else max(top, 1e-12) * (1 + 1e-9) + 1e-12
        s_hist = SlopeHistogram(s_extent, bins)
        s_hist.add(samples[:, 0], samples[:, 1])
        slopes = stats.Tabulated.from_histogram(s_hist)
        g_extent = extent if extent is not None else (steepest + top) * (1 + 1e-9) + 1e-12
        h = 2 * g_extent / (bins - 1)
        pad = kernel_padding(field.micro, 0.0, h, bins, f"the within-facet lobe grid at mu={mu}",
                             "use fewer bins or a larger extent")
        hist = offset_histogram(field, mu, SlopeHistogram(g_extent + pad * h, bins + 2 * pad))
        lobe = stats.Tabulated(blur(hist.node_counts(), h, field.micro), extent=g_extent + pad * h)
        cov = np.cov(samples.T, bias=False) if len(samples) > 1 else np.zeros((2, 2))
        results.append(FacetStatistics(mu, b, slopes, lobe, samples.mean(axis=0), cov, len(samples)))
    return tuple(results)


def global_slopes(field: HeightField, *, bins: int = 129, extent: float | None = None) -> stats.Tabulated:
    """The global slope distribution: the density of all pixel facets' normal slopes.

    For mirror micro-facets this is the lobe at the coarsest scale, ``g_∞`` (seed §6,
    Harvey's relation ``R(W, μ) = Q(W, μ0)``). Default extent: the steepest pixel slope.

    Raises InvalidInputError for a ``field`` that is not a :class:`HeightField`, ``bins``
    not an integer ≥ 2 or above :data:`MAX_GRID_BYTES` (``8 bins²`` bytes), or an
    ``extent`` that is not a positive real number or None.
    """
    check_field(field)
    bins = integer(bins, "bins", 2)
    check_grid(bins, f"bins={bins}", "use fewer bins")
    if extent is not None:
        extent = real(extent, "extent", minimum=0, strict=True)
    if extent is None:
        extent = steepest_slope(field) * (1 + 1e-9) + 1e-12
    return stats.Tabulated.from_histogram(offset_histogram(field, None, SlopeHistogram(extent, bins)))
