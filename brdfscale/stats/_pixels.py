"""A lobe image's pixels as a slope density: a mixture of equal Gaussians on the pixel nodes.

What the measurement-set forward model's masking (docs/masking.md) needs from an image: a density
of facet slopes whose Smith Λ costs one closed form per pixel, not the generic path's transform
quadrature (1024 transform evaluations of n² terms per direction, for n² directions).
"""

import math

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._errors import InvalidInputError
from .._slopes import add_offset, centred, check_slopes, offset_norm, phase
from .._validation import is_concrete, vector2
from ._base import AbstractSlopeDensity
from ._tabulated import grid_arguments


__all__ = ["PixelGaussians"]


class PixelGaussians(AbstractSlopeDensity):
    """``s(m) = Σ_jk w_jk N(m; center + (x_k, y_j), s² I)``: the nodes of an ``n_y × n_x`` image
    (rows m_y, columns m_x, spanning ``[−extent, extent]`` on each axis as
    :class:`Tabulated`'s), each a Gaussian of the variance of :class:`Tabulated`'s tent on that
    node, ``s² = (h_x² + h_y²)/12`` per axis (a tent of half-width h has variance h²/6; the two
    axes' mean), with weights ``w ∝ max(values, 0)`` summing to 1.

    It has the mean of :class:`Tabulated` of the same values and, for square pixels, its
    covariance; Smith's Λ is a mixture of Gaussian closed forms
    (:func:`brdfscale.stats.smith_lambda`, module docstring of its module). Negative values (noise
    around zero) count as zero.
    """

    values: Float[Array, "ny nx"]
    extent: Float[Array, "2"]
    center: Float[Array, "2"] | None
    isotropic: bool = eqx.field(static=True)

    def __init__(self, values, *, extent, center=None):
        v, e = grid_arguments(values, extent)
        v = jnp.maximum(v, 0.0)
        total = jnp.sum(v)
        if is_concrete(total) and not float(total) > 0:
            raise InvalidInputError("values must have a positive part (a lobe): all are ≤ 0.")
        self.values = v / total
        self.extent = e
        self.center = vector2(center, "center")
        self.isotropic = False

    @property
    def spacing(self) -> Float[Array, "2"]:
        ny, nx = self.values.shape
        return jnp.stack([2 * self.extent[0] / (nx - 1), 2 * self.extent[1] / (ny - 1)])

    @property
    def variance(self) -> Float[Array, ""]:
        """``s²``, each node's variance per axis."""
        return jnp.sum(self.spacing**2) / 12

    def nodes(self) -> Float[Array, "ny nx 2"]:
        """The node slopes relative to ``center``."""
        ny, nx = self.values.shape
        x = jnp.linspace(-1.0, 1.0, nx, dtype=self.extent.dtype) * self.extent[0]
        y = jnp.linspace(-1.0, 1.0, ny, dtype=self.extent.dtype) * self.extent[1]
        return jnp.stack(jnp.broadcast_arrays(x[None, :], y[:, None]), axis=-1)

    def density(self, m):
        d = centred(m, self.center)[..., None, None, :] - self.nodes()
        s2 = self.variance
        kernel = jnp.exp(-0.5 * jnp.sum(d**2, axis=-1) / s2) / (2 * jnp.pi * s2)
        return jnp.sum(self.values * kernel, axis=(-2, -1))

    def cf(self, W):
        W = check_slopes(W, "W")
        nodes = self.nodes()
        sums = jnp.einsum("...k,yxk->...yx", W, nodes)
        total = jnp.sum(self.values * jnp.exp(-1j * sums), axis=(-2, -1))
        return total * jnp.exp(-0.5 * self.variance * jnp.sum(W**2, axis=-1)) * phase(W, self.center)

    def shifted(self, offset):
        return PixelGaussians(self.values, extent=self.extent, center=add_offset(self.center, offset))

    def support_radius(self, tol):
        return jnp.linalg.norm(self.extent) + jnp.sqrt(2 * self.variance * math.log(1 / tol)) + offset_norm(self.center)

    def bandwidth(self, tol):
        return jnp.sqrt(2 * math.log(1 / tol) / self.variance)

    def centroid(self) -> Float[Array, "2"]:
        """``Σ w_jk node_jk`` (+ center)."""
        m = jnp.einsum("yx,yxk->k", self.values, self.nodes())
        return m if self.center is None else m + self.center
