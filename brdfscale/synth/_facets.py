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
from .._show import Shown
from .._validation import integer, real, real_array
from ..stats import SlopeHistogram
from ._surface import check_grid, HeightField


_PIXELS_PER_CHUNK = 1 << 21  # pixels per strip: ~16 MB per float64 work array
_TAIL = 1e-6  # kernel tails below this fraction of their peak may be cut or wrapped


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class FacetStatistics(Shown):
    """Slope statistics of one height field at one scale.

    Attributes:
        mu: the scale (facet size, length units): a window of ``block = (μ/Δy, μ/Δx)``
            pixel facets (rows, cols).
        block: that window, ``(rows, cols)``.
        slopes: ``s(·, μ)``, the density of the facets' normal slopes (histogram).
        lobe: ``g_μ``, the within-facet lobe in slope space (histogram ⊛ micro lobe).
        mean, covariance: sample mean (2,) and covariance (2, 2) of the facet slopes (the
            unbiased ``1/(N − 1)`` estimate), ``Σ(μ)`` — to compare with
            ``GaussianSurface(spectrum, window="box")`` for a synthesised field.
        covariance_error: the standard error of each entry of ``covariance`` (2, 2):
            ``√(Var(z_ab) · τ_ab / N)`` for the centred products ``z_ab = (m_a − m̄_a)(m_b − m̄_b)``
            of the N facets, with ``τ_ab`` the sum of the products' autocorrelation over the
            facet lattice (neighbouring facets of a surface correlated beyond μ are not
            independent). The fourth moments are the data's, floored by the Gaussian value
            (:func:`covariance_error`). ∞ with fewer than 2 facets.
        count: the number of facets used: whole windows placed without wrap-around on a
            measured field (with wrap-around on a periodic one), less those touching an
            unmeasured pixel.
        excluded: the windows left out because they touch an unmeasured pixel.
        independent: the effective number of independent facets, ``N / max_ab τ_ab`` (≤ count).
        rms_slope: ``√⟨|m|²⟩`` over the facets (not centred); at the pixel scale of a measured
            field it is SurfaceTopography's ``rms_gradient()`` of the same heights.
        window: the window's physical sides ``(cols·Δx, rows·Δy)``: μ and, with rectangular
            pixels, a side along y equal to μ within :attr:`HeightField.LENGTH_TOLERANCE`.
    """

    mu: float
    block: tuple[int, int]
    slopes: stats.Tabulated
    lobe: stats.Tabulated
    mean: Float[np.ndarray, "2"]
    covariance: Float[np.ndarray, "2 2"]
    count: int
    covariance_error: Float[np.ndarray, "2 2"] = dataclasses.field(default_factory=lambda: np.full((2, 2), np.inf))
    independent: float = 0.0
    excluded: int = 0
    rms_slope: float = 0.0
    window: tuple[float, float] = (0.0, 0.0)

    def _show_items(self):
        sd = np.sqrt(np.diag(self.covariance))
        return [
            ("mu", self.mu),
            ("block", "×".join(map(str, self.block))),
            ("facets", self.count),
            ("independent", round(self.independent, 1)),
            ("excluded", self.excluded),
            ("σ_x, σ_y", f"{sd[0]:.4g}, {sd[1]:.4g}"),
            ("Σ error", f"{self.covariance_error[0, 0]:.2g}, {self.covariance_error[1, 1]:.2g}"),
        ]


def check_field(field) -> HeightField:
    if not isinstance(field, HeightField):
        raise InvalidInputError(
            f"field must be a brdfscale.synth.HeightField (brdfscale.topography.read or "
            f"from_array make one of a measured surface); got {type(field).__name__}."
        )
    return field


def check_scales(scales) -> list[float]:
    """Facet sizes μ: one real number or a 1-D sequence of them, at least one."""
    a = real_array(scales, "scales")
    if a.ndim > 1:
        raise InvalidInputError(f"scales must be a facet size or a 1-D sequence of them; got shape {a.shape}.")
    if a.size == 0:
        raise InvalidInputError("scales must list at least one facet size.")
    return [float(mu) for mu in np.atleast_1d(a)]


def facet_slopes(field: HeightField, mu: float) -> Float[np.ndarray, "rows cols 2"]:
    """Normal slopes of the facets at scale μ, shape ``(F_y // b_y, F_x // b_x, 2)``.

    ``(b_y, b_x) = field.block(μ)`` and ``(F_y, F_x) = field.facet_grid``. Facet ``[J, K]``
    covers pixel facets ``J b_y … J b_y + b_y − 1`` (rows) and ``K b_x … K b_x + b_x − 1``
    (columns); the pixel facets beyond the last whole window are left out. Windows touching an
    unmeasured pixel are NaN (:attr:`HeightField.mask`). Cost: two passes over the heights,
    ``O(n²/b)`` memory.
    """
    check_field(field)
    return _block_slopes(field, field.block(mu))


def pixel_slopes(field: HeightField) -> Float[np.ndarray, "rows cols 2"]:
    """Normal slopes of the pixel facets, shape ``field.facet_grid + (2,)``: :func:`facet_slopes` of the one-pixel
    window (whatever the pitches, square or not); NaN where a pixel facet touches an unmeasured pixel."""
    return _block_slopes(check_field(field), (1, 1))


def _block_slopes(field: HeightField, block: tuple[int, int]) -> np.ndarray:
    mx, my = _facet_slope_components(field, block)
    valid = _window_validity(field, block)
    if valid is not None:
        mx, my = np.where(valid, mx, np.nan), np.where(valid, my, np.nan)
    return np.stack((mx, my), axis=-1)


def _facet_slope_components(field: HeightField, block: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The mean pixel-facet slope of every whole window, telescoped to the heights on its edges."""
    (ny, nx), (fy, fx), h = field.shape, field.facet_grid, field.heights
    (dx, dy), (by, bx) = field.spacing, block
    nby, nbx = fy // by, fx // bx
    cols = (np.arange(nbx + 1) * bx) % nx
    rows = (np.arange(nby + 1) * by) % ny
    row_sums = h[: nby * by].reshape(nby, by, nx).sum(axis=1)  # (nby, nx): Σ over each facet's rows
    col_sums = h[:, : nbx * bx].reshape(ny, nbx, bx).sum(axis=2)  # (ny, nbx)
    mx = -np.diff(row_sums[:, cols], axis=1) / (by * bx * dx)
    my = -np.diff(col_sums[rows], axis=0) / (by * bx * dy)
    return mx, my


def _window_validity(field: HeightField, block: tuple[int, int]) -> np.ndarray | None:
    """Which whole windows have every pixel facet measured (None: all of them)."""
    valid = field.pixel_facets
    if valid is None:
        return None
    (fy, fx), (by, bx) = field.facet_grid, block
    nby, nbx = fy // by, fx // bx
    return np.asarray(valid[: nby * by, : nbx * bx].reshape(nby, by, nbx, bx).all(axis=(1, 3)))


def facet_samples(field: HeightField, block: tuple[int, int]) -> tuple[np.ndarray, np.ndarray | None]:
    """The measured windows' slopes ``(N, 2)`` and the window validity grid (None: all valid)."""
    mx, my = _facet_slope_components(field, block)
    valid = _window_validity(field, block)
    if valid is None:
        return np.stack((mx.ravel(), my.ravel()), axis=-1), None
    return np.stack((mx[valid], my[valid]), axis=-1), valid


def _pixel_strips(field: HeightField, block: tuple[int, int] | None):
    """Yield ``(start, stop, mx, my, valid)`` for strips of whole facet rows: the pixel facets'
    normal slopes in the whole windows (all pixel facets when ``block`` is None) and which of
    them count (None: all) — a pixel facet counts when its window is measured throughout."""
    (ny, nx), (fy, fx), h = field.shape, field.facet_grid, field.heights
    dx, dy = field.spacing
    by, bx = (1, 1) if block is None else block
    height, width = (fy // by) * by, (fx // bx) * bx
    windows = None if block is None else _window_validity(field, block)
    pixels = field.pixel_facets
    step = by * max(1, _PIXELS_PER_CHUNK // (width * by))
    for start in range(0, height, step):
        stop = min(start + step, height)
        below = (np.arange(start, stop) + 1) % ny
        strip = h[start:stop, :width]
        right = h[start:stop, 1 : width + 1] if width < nx else np.roll(h[start:stop], -1, axis=1)
        mx = -(right - strip) / dx
        my = -(h[below, :width] - strip) / dy
        if windows is not None:
            valid = np.repeat(np.repeat(windows[start // by : stop // by], by, axis=0), bx, axis=1)
        elif block is None and pixels is not None:
            valid = pixels[start:stop, :width]
        else:
            valid = None
        yield start, stop, mx, my, valid


def _offsets(field: HeightField, mu: float | None, incident=None):
    """Yield ``(u_x, u_y, weights)`` chunk by chunk: the pixel facets' normal slopes relative to the slope
    of their facet at scale μ (the pixel slopes themselves when μ is None) and their weights (None: each
    counts once) — the samples of :func:`offset_histogram` and :func:`offset_moments`.

    Only pixel facets in measured windows count (measured pixel facets when μ is None). With
    ``incident`` (a unit vector towards the light) every pixel facet is weighted by the
    light it intercepts relative to a flat one, ``max(0, 1 + m·i_xy / i_z)`` (its area
    ``√(1+|m|²)`` times ``n·i``); without it every pixel counts once, the seed's nearly-flat
    approximation (docs/conventions.md §2, seed footnote 1).
    """
    block = None if mu is None else field.block(mu)
    facets = None if block is None else _facet_slope_components(field, block)
    for start, stop, mx, my, valid in _pixel_strips(field, block):
        weights = None
        if incident is not None:
            weights = np.maximum(0.0, 1 + (mx * incident[0] + my * incident[1]) / incident[2])
        if block is not None and facets is not None:  # both set when μ is
            by, bx = block
            fx, fy = (f[start // by : stop // by, :, None] for f in facets)  # (r, nb, 1)
            r, nb = fx.shape[:2]
            mx = (mx.reshape(r, by, nb, bx) - fx[:, None]).reshape(mx.shape)
            my = (my.reshape(r, by, nb, bx) - fy[:, None]).reshape(my.shape)
        if valid is not None:
            mx, my = mx[valid], my[valid]
            weights = None if weights is None else weights[valid]
        if mx.size:
            yield mx.ravel(), my.ravel(), None if weights is None else weights.ravel()


def offset_histogram(field: HeightField, mu: float | None, hist: SlopeHistogram, incident=None) -> SlopeHistogram:
    """Accumulate pixel slopes relative to their facet at scale μ (all pixels when μ is None) into
    ``hist`` (the samples and weights of :func:`_offsets`)."""
    for mx, my, weights in _offsets(field, mu, incident):
        hist.add(mx, my, weights)
    return hist


def offset_moments(field: HeightField, mu: float) -> tuple[Float[np.ndarray, "2"], Float[np.ndarray, "2 2"]]:
    """The mean (2,) and covariance (2, 2) of the pixel slopes' offsets from their facet's slope at scale μ —
    the first and second moments of the lobe :func:`offset_histogram` accumulates (every pixel facet of a measured
    window counts once: the nearly-flat weighting), before the micro lobe's and the resolution's blur. The
    covariance is the population one (divided by N, not N − 1).

    It is what :func:`brdfscale.synth.gonioreflectometer`'s image at μ holds, and for a field measured
    throughout whose windows tile the same pixels at every scale it is the law of total variance's
    ``Cov(pixel slopes) − C(μ)``: the difference of two scales' offset covariances is the facet statistics'
    ``C(μ0) − C(μ_k)``. Where the pixel population changes with μ (unmeasured pixels: a coarser facet is
    measured in fewer places; the pixels past the last whole window) the two differ — even in sign on frt-1 of
    tests/data (tests/test_covariance_truth.py). Sums are accumulated chunk by chunk about the first chunk's
    mean (no cancellation, constant memory)."""
    check_field(field)
    field.block(mu)  # a scale that is not a whole number of pixels is refused here
    total, first, second, shift = 0, np.zeros(2), np.zeros((2, 2)), None
    for mx, my, _ in _offsets(field, mu):
        u = np.stack((mx, my), axis=-1)
        if shift is None:
            shift = u.mean(axis=0)
        d = u - shift
        total += len(d)
        first += d.sum(axis=0)
        second += d.T @ d
    if shift is None:
        raise InvalidInputError(f"no pixel facet lies in a measured window of mu={mu:g}; use a smaller scale.")
    mean = first / total
    return shift + mean, second / total - np.outer(mean, mean)


def covariance_error(
    samples: np.ndarray, valid: np.ndarray | None, lattice: tuple[int, int]
) -> tuple[np.ndarray, float]:
    """Standard errors of the sample covariance of facet slopes and the effective facet count.

    For each entry ab the centred products ``z = (m_a − m̄_a)(m_b − m̄_b)`` of the N facets
    give ``Var(Σ̂_ab) ≈ Var(z) τ / N`` with ``τ = Σ_lag ρ_z(lag)``, the autocorrelation of z
    on the facet lattice summed over lags ``|ℓ_x|, |ℓ_y| ≤ L``, ``L = min(rows, cols) // 4``
    (at most 8; windows that are unmeasured are left out of every lag's average), and
    ``τ ≥ 1``. The error is never below the Gaussian value ``√((Σ_aa Σ_bb + Σ_ab²)/(N_eff − 1))``
    with ``N_eff = N / max τ``: with few facets the empirical fourth moment is unreliable (two
    facets give identical centred squares, ``Var(z) = 0``). Returns the (2, 2) errors and
    ``N_eff``.
    """
    n = len(samples)
    if n < 2:
        return np.full((2, 2), np.inf), float(n)
    rows, cols = lattice
    present = np.ones(lattice, bool) if valid is None else valid
    centred = samples - samples.mean(axis=0)
    lag = min(rows, cols, 32) // 4  # at most 8
    errors, taus = np.zeros((2, 2)), []
    for a, b in ((0, 0), (0, 1), (1, 1)):
        z = centred[:, a] * centred[:, b]
        zc = z - z.mean()
        var = float(np.mean(zc**2))
        tau = 1.0
        if lag > 0 and var > 0:
            grid = np.zeros(lattice)
            grid[present] = zc
            tau = _lattice_tau(grid, present.astype(float), lag, var)
        taus.append(tau)
        errors[a, b] = errors[b, a] = math.sqrt(var * tau / n)
    independent = n / max(taus)
    cov = np.cov(samples.T)
    gaussian = np.sqrt((np.outer(np.diag(cov), np.diag(cov)) + cov**2) / max(independent - 1, 1))
    return np.maximum(errors, gaussian), independent


def _lattice_tau(grid: np.ndarray, present: np.ndarray, lag: int, var: float) -> float:
    """``max(1, Σ_{|ℓ|≤lag} ρ(ℓ))`` of a lattice series (zero where absent), by FFT products."""
    rows, cols = grid.shape
    shape = (2 * rows, 2 * cols)
    f, p = np.fft.rfft2(grid, shape), np.fft.rfft2(present, shape)
    products = np.fft.irfft2(f * np.conj(f), shape)
    pairs = np.fft.irfft2(p * np.conj(p), shape)
    ly = np.r_[0 : lag + 1, -lag:0] % shape[0]
    lx = np.r_[0 : lag + 1, -lag:0] % shape[1]
    num, cnt = products[np.ix_(ly, lx)], np.rint(pairs[np.ix_(ly, lx)])
    rho = np.where(cnt > 0, num / np.maximum(cnt, 1) / var, 0.0)
    return max(1.0, float(rho.sum()))


def steepest_slope(field: HeightField) -> float:
    """The largest |component| of any measured pixel facet's normal slope (sizes slope grids);
    0 for a flat field. :class:`HeightField` computes it once, when it is made, and refuses a
    field whose steepest slope lies outside ``HeightField.SLOPE_RANGE`` (a dropout, denormal heights)."""
    return check_field(field).steepest_slope


def kernel_padding(
    micro: stats.AbstractSlopeDensity,
    resolution: float,
    spacing: float,
    nodes: int = 0,
    what: str = "the slope grid",
    advice: str = "use fewer nodes or a coarser grid",
) -> int:
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
    check_grid(
        nodes + 2.0 * math.ceil(pad) if math.isfinite(pad) else math.inf,
        what,
        f"{advice} (the grid is padded by {pad:.6g} nodes per side for the micro lobe's support and the blur)",
    )
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


def facet_statistics(
    field: HeightField, scales, *, bins: int = 129, extent: float | None = None
) -> tuple[FacetStatistics, ...]:
    """Between-facet statistics ``s(·, μ)`` and within-facet lobes ``g_μ`` at each scale.

    Args:
        field: the surface.
        scales: facet sizes μ (length units), each a whole number of pixels.
        bins: nodes per axis of the tabulated densities.
        extent: half-width of the grids (slope units). Default: the largest pixel slope
            component plus the largest facet slope component, so that no sample falls
            outside (lobe grids are widened further for a rough micro lobe).

    Facets are the whole μ × μ windows of :func:`facet_slopes` (without wrap-around on a
    measured field); windows touching an unmeasured pixel are excluded (counted in
    ``excluded``), and so are their pixel facets from ``g_μ``. Each result carries the facet
    count, the effective number of independent facets and the standard error of ``Σ(μ)``
    (:class:`FacetStatistics`).

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
    steepest = steepest_slope(field) if extent is None else 0.0  # only an automatic extent uses it
    results = []
    for mu in scales:
        block = field.block(mu)
        samples, valid = facet_samples(field, block)
        (fy, fx), (by, bx) = field.facet_grid, block
        lattice = (fy // by, fx // bx)
        if len(samples) == 0:
            raise InvalidInputError(
                f"no facet window of mu={mu:g} ({block[0]} × {block[1]} pixel facets) lies wholly on measured pixels; "
                "use a smaller scale (field.scales lists admissible ones)."
            )
        top = float(np.max(np.abs(samples)))
        s_extent = extent if extent is not None else max(top, 1e-12) * (1 + 1e-9) + 1e-12
        s_hist = SlopeHistogram(s_extent, bins)
        s_hist.add(samples[:, 0], samples[:, 1])
        slopes = stats.Tabulated.from_histogram(s_hist)
        g_extent = extent if extent is not None else (steepest + top) * (1 + 1e-9) + 1e-12
        h = 2 * g_extent / (bins - 1)
        pad = kernel_padding(
            field.micro, 0.0, h, bins, f"the within-facet lobe grid at mu={mu}", "use fewer bins or a larger extent"
        )
        hist = offset_histogram(field, mu, SlopeHistogram(g_extent + pad * h, bins + 2 * pad))
        lobe = stats.Tabulated(blur(hist.node_counts(), h, field.micro), extent=g_extent + pad * h)
        cov = np.cov(samples.T, bias=False) if len(samples) > 1 else np.zeros((2, 2))
        error, independent = covariance_error(samples, valid, lattice)
        results.append(
            FacetStatistics(
                mu,
                block,
                slopes,
                lobe,
                samples.mean(axis=0),
                cov,
                len(samples),
                covariance_error=error,
                independent=independent,
                excluded=lattice[0] * lattice[1] - len(samples),
                rms_slope=float(np.sqrt(np.mean(np.sum(samples**2, axis=1)))),
                window=(block[1] * field.spacing[0], block[0] * field.spacing[1]),
            )
        )
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
