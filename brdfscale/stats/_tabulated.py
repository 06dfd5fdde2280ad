"""Slope densities tabulated on a regular grid (histograms, measurements): sums of tent functions."""

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._errors import InvalidInputError
from .._slopes import add_offset, centred, check_slopes, offset_norm, phase
from .._validation import as_float_array, is_concrete, positive, real_array, vector2
from ._base import AbstractSlopeDensity
from ._grid import axis_phase
from ._histogram import SlopeHistogram


def _sinc(x):
    """sin(x)/x with the limit 1 at 0."""
    safe = jnp.where(jnp.abs(x) < 1e-4, 1.0, x)
    return jnp.where(jnp.abs(x) < 1e-4, 1 - x**2 / 6 + x**4 / 120, jnp.sin(safe) / safe)


def grid_arguments(values, extent):
    """``values`` as a 2-D array of at least 2 × 2 nodes (rows m_y, columns m_x) and ``extent`` as the pair of the
    grid's half-widths (x, y): the checks of every density tabulated on nodes (:class:`Tabulated`,
    :class:`brdfscale.stats.PixelGaussians`)."""
    v = as_float_array(values, "values")
    if v.ndim != 2 or min(v.shape) < 2:
        raise InvalidInputError(
            f"values must be a 2D array (rows: m_y, columns: m_x) of at least 2×2; got shape {v.shape}."
        )
    e = positive(extent, "extent", "positive (the grid's half-width in slope units)")
    e = jnp.broadcast_to(e, (2,)) if e.ndim == 0 else e
    if e.shape != (2,):
        raise InvalidInputError(f"extent must be a scalar or a pair (x, y); got shape {e.shape}.")
    return v, e


class Tabulated(AbstractSlopeDensity):
    """A density given by its values on a regular slope grid: a sum of tent functions on the nodes.

    ``values[j, k]`` is the density at the node ``m_jk = center + (x_k, y_j)``, with ``x_k`` and
    ``y_j`` evenly spaced over ``[−extent_x, extent_x]`` and ``[−extent_y, extent_y]`` (spacings
    ``h_x = 2 extent_x/(n_x − 1)``, ``h_y = 2 extent_y/(n_y − 1)``; the first array axis is
    ``m_y``, the second ``m_x``, as in an image). The density is

        s(m) = Σ_jk v_jk Λ((d_x − x_k)/h_x) Λ((d_y − y_j)/h_y),   d = m − center,  Λ(t) = max(0, 1 − |t|):

    the bilinear interpolant between the nodes, falling linearly to zero over one spacing
    beyond the outermost nodes — as if the table were bordered by a ring of zero nodes — and
    zero beyond ``extent + spacing`` on each axis (a table whose border values are zero is the
    plain bilinear interpolant on ``[−extent, extent]``). Each tent integrates to ``h_x h_y``, so
    the values are rescaled to ``h_x h_y Σ_jk v_jk = 1``, and ``∫ s d²m = 1`` exactly.

    Its transform is exact for that density: ``S(W) = h_x h_y Σ_jk v_jk e^{−iW·m_jk}
    sinc²(W_x h_x/2) sinc²(W_y h_y/2)`` (the tent's transform is ``h sinc²(w h/2)``), so spectral
    evolution of a tabulated lobe introduces no further discretisation error.
    """

    values: Float[Array, "ny nx"]
    extent: Float[Array, "2"]
    center: Float[Array, "2"] | None
    isotropic: bool = eqx.field(static=True)

    def __init__(self, values, *, extent, center=None):
        v, e = grid_arguments(values, extent)
        if is_concrete(v) and np.any(np.asarray(v) < 0):
            raise InvalidInputError("values must be non-negative (a density); found negative entries.")
        hx, hy = 2 * e[0] / (v.shape[1] - 1), 2 * e[1] / (v.shape[0] - 1)
        total = hx * hy * jnp.sum(v)
        if is_concrete(total) and not float(total) > 0:
            raise InvalidInputError("values must have a positive sum.")
        self.values = v / total
        self.extent = e
        self.center = vector2(center, "center")
        self.isotropic = False

    @classmethod
    def from_samples(cls, samples, *, extent: float, bins: int = 129, weights=None, center=None):
        """Histogram slope samples of shape (n, 2) onto a ``bins × bins`` grid of nodes.

        The nodes span ``center + [−extent, extent]²``. Each sample is shared among the four
        surrounding nodes with bilinear weights (cloud in cell, :class:`SlopeHistogram`), so the
        tent sum of the node weights has exactly the total weight and the (weighted) mean of the
        samples inside the grid; samples outside it are dropped. The result is that tent sum,
        normalised (see :meth:`from_histogram`).
        """
        s = real_array(samples, "samples")
        if s.ndim != 2 or s.shape[1] != 2:
            raise InvalidInputError(f"samples must have shape (n, 2); got {s.shape}.")
        w = None if weights is None else real_array(weights, "weights")
        if w is not None and w.shape != (len(s),):
            raise InvalidInputError(
                f"weights must be {len(s)} finite real numbers, one per sample; got shape {w.shape}."
            )
        c = np.zeros(2) if center is None else real_array(center, "center", 1)
        if c.shape != (2,):
            raise InvalidInputError(f"center must have shape (2,); got {c.shape}.")
        hist = SlopeHistogram(extent, bins)
        hist.add(s[:, 0] - c[0], s[:, 1] - c[1], w)
        return cls.from_histogram(hist, center=center)

    @classmethod
    def from_histogram(cls, hist: SlopeHistogram, center=None) -> "Tabulated":
        """A :class:`SlopeHistogram` as a normalised density: node values ``counts / (h² Σ counts)``.

        The histogram's nodes, offset by ``center``, become the table's (``extent`` is the
        histogram's). By cloud-in-cell deposition the tent sum of the counts has the total
        weight and mean of the samples that fell inside the grid; normalising divides by the
        former, so the density is the distribution of those samples (per unit slope area).
        """
        if not isinstance(hist, SlopeHistogram):
            raise InvalidInputError(f"hist must be a brdfscale.stats.SlopeHistogram; got {type(hist).__name__}.")
        if not np.any(hist.counts > 0):
            raise InvalidInputError(f"no sample fell inside the grid of half-width {hist.extent}.")
        return cls(hist.node_counts(), extent=hist.extent, center=center)

    @property
    def spacing(self) -> Float[Array, "2"]:
        ny, nx = self.values.shape
        return jnp.stack([2 * self.extent[0] / (nx - 1), 2 * self.extent[1] / (ny - 1)])

    def nodes(self) -> tuple[Float[Array, " nx"], Float[Array, " ny"]]:
        """Node coordinates ``(x, y)`` relative to ``center``."""
        ny, nx = self.values.shape
        return (jnp.linspace(-1.0, 1.0, nx) * self.extent[0], jnp.linspace(-1.0, 1.0, ny) * self.extent[1])

    def density(self, m):
        # Bilinear interpolation on the table bordered by a ring of zero nodes, one spacing
        # beyond [−extent, extent]: the tent sum, which is zero outside the bordered grid.
        d = centred(m, self.center)
        v = jnp.pad(self.values, 1)
        ny, nx = v.shape
        h = self.spacing
        g = (d + self.extent + h) / h
        inside = jnp.all((g >= 0) & (g <= jnp.array([nx - 1, ny - 1])), axis=-1)
        i0 = jnp.clip(jnp.floor(g), 0, jnp.array([nx - 2, ny - 2])).astype(jnp.int32)
        f = g - i0
        ix, iy = i0[..., 0], i0[..., 1]
        fx, fy = f[..., 0], f[..., 1]
        val = (
            v[iy, ix] * (1 - fx) * (1 - fy)
            + v[iy, ix + 1] * fx * (1 - fy)
            + v[iy + 1, ix] * (1 - fx) * fy
            + v[iy + 1, ix + 1] * fx * fy
        )
        return jnp.where(inside, val, 0.0)

    def cf(self, W):
        W = check_slopes(W, "W")
        x, y = self.nodes()
        h = self.spacing
        ex = jnp.exp(-1j * W[..., 0, None] * x)  # (..., nx)
        ey = jnp.exp(-1j * W[..., 1, None] * y)  # (..., ny)
        total = jnp.einsum("...y,yx,...x->...", ey, self.values.astype(ex.dtype), ex)
        hat = (_sinc(W[..., 0] * h[0] / 2) * _sinc(W[..., 1] * h[1] / 2)) ** 2
        return h[0] * h[1] * total * hat * phase(W, self.center)

    def cf_grid(self, grid):
        # the node sum factorises: Σ_jk v_jk e^{−iW_x x_k} e^{−iW_y y_j} = E_y V E_xᵀ (two
        # matmuls); hat transforms and the shift by ``center`` are per-axis factors
        x, y = self.nodes()
        h = self.spacing
        ex = jnp.exp(-1j * x[:, None] * grid.wx[None, :])  # (nodes x, nx)
        ey = jnp.exp(-1j * grid.wy[:, None] * y[None, :])  # (n, nodes y)
        cx, cy = (None, None) if self.center is None else (self.center[0], self.center[1])
        factors = grid.separable(
            lambda w: h[0] * _sinc(w * h[0] / 2) ** 2 * axis_phase(w, cx),
            lambda w: h[1] * _sinc(w * h[1] / 2) ** 2 * axis_phase(w, cy),
        )
        return factors * (ey @ self.values.astype(ex.dtype) @ ex)

    def shifted(self, offset):
        return Tabulated(self.values, extent=self.extent, center=add_offset(self.center, offset))

    def support_radius(self, tol):
        # the outermost tents reach one spacing beyond the grid: s = 0 outside center + [−e − h, e + h]
        return jnp.linalg.norm(self.extent + self.spacing) + offset_norm(self.center)

    def bandwidth(self, tol):
        # With h_x h_y Σ v = 1 and |sinc x| ≤ min(1, 1/|x|): |S| ≤ min(1, 4/(W_x h_x)²) min(1, 4/(W_y h_y)²).
        # Some |W_i| ≥ |W|/√2, so |S| ≤ 8/(|W| h_min)² < tol beyond 3/(h_min √tol).
        return jnp.max(3 / (self.spacing * math.sqrt(tol)))
