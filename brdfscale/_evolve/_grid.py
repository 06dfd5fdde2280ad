"""The 2D-FFT grid path: ``G`` on an N × N real-FFT frequency grid over the slope half-width a.

:class:`Grid` owns the whole path (the pattern of lineax's solvers): it applies to any inputs;
its resolution from concrete values (:meth:`Grid.discretise`, what :func:`brdfscale.select`
returns), its evaluation at query offsets (:meth:`Grid.values`: direct inverse-DFT sums, or
a zero-padded inverse FFT onto a finer slope grid read off by 6 × 6-point Lagrange
interpolation), the lobe on its slope grid (:meth:`Grid.on_grid`) and :meth:`Grid.explain`.
Every choice is verified on the values it is made for:

* the side N and half-width a from the bandwidth and support radius (tol/2,
  :func:`._spectral.grid_size`; a capped grid relaxes the target by decades and reports the
  tolerance it honours);
* the zero-padded oversampling p doubled until 6 × 6-point Lagrange interpolation on the
  (pN)² slope grid, checked at every cell centre of the 2p grid, is within tol/2;
* the existence check for those values: ``|G| ≤ 1`` on the probe and no evolved value below
  −tol of the peak (the oversampled grid).

Offsets outside ``[−a, a)²`` evaluate to 0 (the lobe is below tol/2 of its peak there when a
is its support radius), never to a periodic image.
"""

import warnings
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._blocks import DEFAULT_BUDGET, in_blocks
from .._errors import InvalidInputError, ToleranceRelaxedWarning
from .._existence import negative_beyond, transform_exceeds_one, translated
from .._interpolate import interpolate, lagrange_stencil
from ..stats import Delta, FrequencyGrid
from ._method import (
    caller_stacklevel,
    check_budget,
    check_count,
    check_positive,
    lambda_note,
    number,
    optional_array,
    tol_note,
)
from ._spectral import (
    AbstractSpectralMethod,
    checked,
    concrete_support,
    grid_size,
    probe_checks,
)


MAX_GRID = 1024
"""The largest grid side chosen automatically."""
MAX_FINE_SIDE = 4096
"""The largest oversampled slope grid side of the grid path's table."""
GRID_POINTS = 6
"""Lagrange points per axis of the grid table (verified by :meth:`Grid.discretise`)."""


class Grid(AbstractSpectralMethod):
    """The 2D-FFT grid path: ``G`` on a ``size × size`` real-FFT frequency grid for the slope
    half-width ``extent``.

    Args:
        size: grid side (even); ``None`` for :func:`brdfscale.select` to choose.
        extent: slope half-width a of the grid; ``None``: the radius beyond which the lobe stays
            below ``tol/2`` of its peak (computed from the values, traced ones included).
            Offsets outside ``[−a, a)²`` evaluate to 0 (within tol when a is that radius;
            never a periodic image).
        oversample: the factor p of the zero-padded inverse FFT onto a slope grid of spacing
            ``h/p`` that 6 × 6-point Lagrange interpolation reads (set by
            :func:`brdfscale.select` after verifying it); ``None``: evaluate at the queries by
            direct sums.
        tol: the error the discretisation honours (set by :func:`brdfscale.select`; may be
            looser than asked when the size cap forbids the target, see ``evolve``).
        budget: bytes of temporaries an evaluation may hold at once (default 256 MiB).
    """

    size: int | None = eqx.field(static=True, default=None)
    extent: Float[Array, ""] | None = eqx.field(default=None, converter=optional_array)
    oversample: int | None = eqx.field(static=True, default=None)
    tol: float | None = eqx.field(static=True, default=None)
    error: Float[Array, ""] | None = eqx.field(default=None, converter=optional_array)  # verified interpolation error
    budget: int = eqx.field(static=True, default=DEFAULT_BUDGET)
    sign_check: bool = eqx.field(static=True, default=True)
    """Whether evaluations refuse values below −tol of the peak (off where a caller's explicit
    size or extent is too small for tol: its ringing and aliasing are no evidence about existence)."""
    regularisation: Float[Array, ""] | None = eqx.field(default=None, converter=optional_array)
    """The Tikhonov λ chosen with the discretisation (as :class:`~brdfscale.Radial`'s)."""
    regularisation_rule: str | None = eqx.field(static=True, default=None)
    regularisation_note: str | None = eqx.field(static=True, default=None)
    dtype: str | None = eqx.field(static=True, default=None)
    """The floating dtype of the evaluation it was resolved for (as :class:`~brdfscale.Radial`'s)."""
    asked: float | None = eqx.field(static=True, default=None)
    """The ``tol`` asked when the capped grid honours a looser one (``tol``); None otherwise."""

    size_argument = "size"

    def __check_init__(self):
        check_budget(self.budget)
        check_count("Grid(size=...)", self.size, 8)
        check_positive("Grid(extent=...)", self.extent, "a positive slope half-width")
        check_count("Grid(oversample=...)", self.oversample, 1)

    @property
    def resolution(self) -> int | None:
        return self.size

    @property
    def half_width(self) -> Float[Array, ""] | None:
        return self.extent

    @property
    def _resolved_size(self) -> int:
        """The side of a grid that evaluates: always resolved (``evaluate`` raises :meth:`unresolved`
        first; the planner's steps fix it)."""
        assert self.size is not None
        return self.size

    def show_sizes(self) -> list[tuple[str, Any]]:
        return [("size", self.size)] + ([] if self.extent is None else [("extent", self.extent)])

    def explain(self) -> str:
        if self.size is None:
            return "grid (2D FFT) path, not yet resolved"
        a = (
            "a from the support radius at run time"
            if self.extent is None
            else f"half-width a = {number(self.extent):.4g}"
        )
        if self.oversample is None:
            layout = "inverse DFT summed at the queries"
        else:
            verified = "not verified" if self.error is None else f"verified error {number(self.error):.2g} of the peak"
            layout = (
                f"zero-padded inverse FFT onto {self.size * self.oversample}² slope nodes, 6×6-point Lagrange "
                f"({verified}), direct at the queries when they are few"
            )
        return (
            f"grid (2D FFT) path: {self.size}×{self.size} frequencies, {a}; {layout}"
            f"{tol_note(self.tol, self.dtype, self.asked)}{lambda_note(self)}"
        )

    def sized(self, size, extent):
        if extent is not None:
            try:
                extent = float(extent)
            except TypeError:
                raise InvalidInputError(
                    "extent must be a concrete positive number (a discretisation choice), "
                    f"not a traced value; got {type(extent).__name__}."
                ) from None
            if not (np.isfinite(extent) and extent > 0):
                raise InvalidInputError(f"extent must be a positive slope half-width; got {extent}.")
        return Grid(size=None if size is None else int(size), extent=extent)

    # -- evaluation -------------------------------------------------------------------------------
    def spacing(self, density):
        """Slope-grid spacing h and half-width a = N h / 2 of ``density`` on this grid."""
        dtype = jnp.result_type(*jax.tree_util.tree_leaves(density.base), float)
        if self.extent is None:
            a = jax.lax.stop_gradient(density.support_radius(density.tol / 2))  # a discretisation choice
        else:
            a = jax.lax.stop_gradient(jnp.asarray(self.extent, dtype))
        return 2 * a / self._resolved_size, a

    def frequency_grid(self, h) -> FrequencyGrid:
        """The real-FFT frequencies of the ``size × size`` slope grid of spacing ``h``."""
        n = self._resolved_size
        return FrequencyGrid(n, 2 * jnp.pi / (n * h))

    def transform(self, density, grid: FrequencyGrid):
        """``G`` on ``grid`` and the existence predicate from the largest ``|G|``: on the grid
        itself, and on rays beyond its Nyquist frequency π/h (where the grid cannot see), 24
        frequencies per ray over three decades. ``None`` when nothing is divided (``s_to`` a
        point mass, |S_to| = 1): then G is a product of transforms of densities, |G| ≤ 1 holds
        by construction and there is nothing to check; and when the check is switched off
        (``check=False``)."""
        G = density.cf_grid(grid)
        if isinstance(density.s_to, Delta) or not density.check:
            return G, None
        G_fixed = jax.lax.stop_gradient(G)
        on_grid = jnp.sqrt(jnp.max(G_fixed.real**2 + G_fixed.imag**2))  # no per-node hypot
        beyond = jnp.max(density._probe(grid.step * (grid.size / 2))[1])  # from π/h
        return G, transform_exceeds_one(jnp.maximum(on_grid, beyond))

    def on_grid(self, density, oversample: int = 1):
        """``(u, values)``: nodes ``u`` (pN,) from −a to a − h/p and ``g_to`` on the pN × pN
        slope grid (rows u_y, columns u_x) by one real inverse FFT of the N × N spectrum,
        zero-padded by the factor ``p = oversample`` (the trigonometric interpolant of the
        N-grid sampled p times as densely)."""
        return _on_grid(density, oversample)

    def slope_table(self, density, h, p: int):
        """``g`` on the (pN)² slope grid and its existence predicates (|G| ≤ 1; no value
        below −tol of the grid's maximum)."""
        G, failed = self.transform(density, self.frequency_grid(h))
        values = _inverse_fft(G, h, self._resolved_size, p)
        negative = None
        if density._sign_check:
            fixed = jax.lax.stop_gradient(values)
            negative = negative_beyond(fixed, jnp.max(fixed), density.tol)
        return values, failed, negative

    def _on_grid(self, density, p: int):
        h, a = self.spacing(density)
        values, failed, negative = self.slope_table(density, h, p)
        u = -a + (h / p) * jnp.arange(self._resolved_size * p, dtype=h.dtype)
        return u, checked(values, failed, negative)

    def values(self, density, m):
        """Offsets inside ``[−a, a]²``: 6 × 6-point Lagrange interpolation on the oversampled
        slope grid (many queries, a verified oversampling) or the inverse DFT summed at each
        offset; outside: 0 (the lobe is below tol/2 of its peak there when a is its support
        radius)."""
        h, a = self.spacing(density)
        n = self._resolved_size
        size = jnp.dtype(m.dtype).itemsize
        inside = jnp.all(jnp.abs(m) <= a, axis=-1)
        q = m.shape[0]
        # direct sums cost ~4 N² per offset, the table ~5 (pN)² log₂(pN) once plus 36 reads per offset
        if self.oversample is not None and q > 16 * self.oversample**2 + 64:
            p = self.oversample
            table, failed, negative = self.slope_table(density, h, p)
            hp = h / p
            # the table's period is 2a: append its first row and column (the images of −a) so
            # that offsets up to +a interpolate without wrapping
            table = jnp.concatenate([table, table[:1]], axis=0)
            table = jnp.concatenate([table, table[:, :1]], axis=1)

            def read(rows):
                pos = (rows[:, ::-1] + a) / hp
                return interpolate(table, pos, points=GRID_POINTS)

            out = in_blocks(read, m, (8 + 4 * GRID_POINTS * (GRID_POINTS + 2)) * size, self.budget)
        else:
            grid = self.frequency_grid(h)
            G, failed = self.transform(density, grid)
            fx, fy = grid.wx, grid.wy
            weight = jnp.where((jnp.arange(fx.shape[0]) == 0) | (2 * jnp.arange(fx.shape[0]) == n), 1.0, 2.0)
            Gw = G * weight * ((2 * jnp.pi / (n * h)) ** 2 / (2 * jnp.pi) ** 2)

            def direct(rows):
                ex = jnp.exp(1j * rows[:, 0, None] * fx[None, :])  # (q, nx)
                ey = jnp.exp(1j * rows[:, 1, None] * fy[None, :])  # (q, ny)
                return jnp.real(jnp.einsum("qy,yx,qx->q", ey, Gw, ex))

            out = in_blocks(direct, m, 6 * n * 2 * size, self.budget)
            negative = None
            if density._sign_check:
                peak = jnp.sum(jnp.abs(jax.lax.stop_gradient(Gw)))
                negative = negative_beyond(out, peak, density.tol)
        return checked(jnp.where(inside, out, 0.0), failed, negative)

    # -- resolution (module docstring) ------------------------------------------------------------
    def discretise(self, density) -> "Grid":
        k, mag = density._probe()
        probe_checks(density, k, mag)
        sign_check = self.sign_check
        if self.size is None:
            size, truncation = grid_size(density, MAX_GRID, k, mag)
            honoured = max(density.tol, 2 * truncation)
            if honoured > density.tol:  # never silently (issue 31): warned here, stated by explain()
                warnings.warn(
                    f"tol={density.tol:g} was asked, but a {MAX_GRID}² grid (the largest chosen automatically) "
                    f"resolves this lobe to {honoured:g} of its peak only; evaluating to {honoured:g} (recorded in "
                    "result.shape.tol and its discretisation's explain()). Pass a larger size= (memory ∝ size²) "
                    "for the tol asked.",
                    ToleranceRelaxedWarning,
                    stacklevel=caller_stacklevel(),
                )
        else:
            size, honoured = self.size, density.tol
            try:
                needed, _ = grid_size(density, max(MAX_GRID, size), k, mag)
            except InvalidInputError as err:  # no automatic size resolves it: the caller's own size stands
                warnings.warn(
                    f"{err} Evaluating with size={size} as given: expect errors well above tol.",
                    stacklevel=caller_stacklevel(),
                )
                sign_check = False
            else:
                if size < needed:
                    warnings.warn(
                        f"size={size} is below the {needed} nodes per side that tol={density.tol:g} needs on this "
                        f"grid; expect errors well above tol (leave size=None to choose it).",
                        stacklevel=caller_stacklevel(),
                    )
                    sign_check = False
        support = float(concrete_support(density, honoured / 2))
        if self.extent is None:
            extent = support
        else:
            extent = float(self.extent)
            if extent < support:
                warnings.warn(
                    f"extent={extent:g} is inside the radius {support:.3g} beyond which the lobe is below tol/2 of its "
                    "peak: offsets outside the grid evaluate to 0 and the lobe's tail aliases into it; expect errors "
                    "above tol (leave extent=None to choose it).",
                    stacklevel=caller_stacklevel(),
                )
                sign_check = False
        d = density.with_discretisation(
            Grid(size=size, extent=extent, budget=self.budget, sign_check=sign_check), honoured
        )
        oversample, error = self.oversample, None
        if oversample is None:
            oversample, error = _oversampling(d, size, honoured / 2)
        values = d.on_grid(1)[1]  # the existence check on the grid (raises NoBRDFAtScaleError)
        del values
        dtype = jnp.dtype(jnp.result_type(*jax.tree_util.tree_leaves(density.base), float)).name
        return Grid(
            size=size,
            extent=extent,
            oversample=oversample,
            tol=honoured,
            error=error,
            budget=self.budget,
            sign_check=sign_check,
            dtype=dtype,
            asked=density.tol if honoured > density.tol else None,
        )


def _oversampling(density, size, half):
    """The smallest p (2, 4, …) whose (pN)² grid 6 × 6-point Lagrange interpolation reads
    within ``half`` of the peak, checked at every cell centre against the 2p grid; (None, None)
    when no p with 2pN ≤ MAX_FINE_SIDE does."""
    p = 2
    while 2 * p * size <= MAX_FINE_SIDE:
        coarse = np.asarray(density.on_grid(p)[1])
        fine = np.asarray(density.on_grid(2 * p)[1])
        n = coarse.shape[0]
        centres = np.arange(n - 1) + 0.5
        by, wy = lagrange_stencil(centres, n, GRID_POINTS, xp=np)
        stencil = by[:, None] + np.arange(GRID_POINTS)
        # separable: along x, then along y
        along_x = np.einsum("ysk,sk->ys", coarse[:, stencil], wy)
        guess = np.einsum("sky,sk->sy", along_x[stencil, :], wy)
        error = float(np.max(np.abs(guess - fine[1:-1:2, 1:-1:2][: n - 1, : n - 1])) / np.max(fine))
        if error <= half:
            return p, error
        p *= 2
    return None, None


def _inverse_fft(G, h, n: int, p: int):
    """``g`` on the (pN)² slope grid from ``−a`` with spacing ``h/p``: the N × N half-plane
    spectrum ``G`` zero-padded (its Nyquist row and column dropped: |G| < tol there by the
    grid's choice) and inverted by one real FFT. Nodes start at −a: the factor
    ``e^{+iW·a} = (−1)^{kx+ky}`` for a = N h/2; the 1/h² of the inverse DFT (for the fine
    spacing) is applied on the half-size frequency side."""
    if p == 1:
        sign = jnp.asarray(
            1.0 - 2.0 * ((np.arange(n)[:, None] + np.arange(n // 2 + 1)[None, :]) % 2), dtype=G.real.dtype
        )
        return jnp.fft.irfft2(G * (sign / h**2), s=(n, n))
    big = n * p
    half = n // 2
    fine = jnp.zeros((big, big // 2 + 1), G.dtype)
    fine = fine.at[:half, :half].set(G[:half, :half])
    fine = fine.at[big - half + 1 :, :half].set(G[half + 1 :, :half])
    rows = np.concatenate([np.arange(half), np.arange(big - half + 1, big)])
    # in G's precision: a float64 factor scattered into a complex64 spectrum is an unsafe cast
    sign = jnp.asarray(1.0 - 2.0 * ((rows[:, None] + np.arange(half)[None, :]) % 2), dtype=G.real.dtype)
    hp = h / p
    fine = fine.at[:half, :half].multiply(sign[:half] / hp**2)
    fine = fine.at[big - half + 1 :, :half].multiply(sign[half:] / hp**2)
    return jnp.fft.irfft2(fine, s=(big, big))


_on_grid = translated(eqx.filter_jit(lambda density, p: density.discretisation._on_grid(density, p)))
