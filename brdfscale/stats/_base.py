"""The interface every slope density implements."""

import abc

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Complex, Float

from .._validation import last_axis
from ._grid import FrequencyGrid


class AbstractSlopeDensity(eqx.Module):
    """A probability density over 2D slope space (seed §4), with its transform.

    Subclasses represent the *facet-slope density* ``s(m)``: the density of the slope ``m``
    of a facet relative to the global orientation, i.e. what a histogram of facet slopes
    shows (DESIGN §2). The seed's ``q`` of Eq. 4.2 is its reflection, ``q(x) = s(−x)``, so
    the seed's ``Q(W) = S(−W)``; for centrally symmetric statistics the two coincide. The
    same classes describe the normalised *shape* of a BRDF lobe in slope space.

    Conventions: slopes ``m`` and frequencies ``W`` have shape ``(..., 2)`` (leading
    dimensions broadcast with the parameters); ``S(W) = ∫ s(m) e^{−i W·m} d²m`` so
    ``S(0) = 1``; densities are per unit slope area ``d²m`` (dimensionless slopes).
    """

    isotropic: eqx.AbstractVar[bool]
    """True when the density is radially symmetric about the origin (known structurally,
    not from parameter values)."""

    @abc.abstractmethod
    def density(self, m: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch"]:
        """The density ``s(m)`` per unit slope area."""

    @abc.abstractmethod
    def cf(self, W: Float[ArrayLike, "*batch 2"]) -> Complex[Array, "*batch"]:
        """The characteristic function ``S(W) = ∫ s(m) e^{−i W·m} d²m`` (complex)."""

    def cf_radial(self, k: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch"]:
        """``S`` at ``|W| = k`` for an isotropic density (real-valued)."""
        k = jnp.asarray(k)
        W = jnp.stack([k, jnp.zeros_like(k)], axis=-1)
        return jnp.real(self.cf(W))

    def cf_grid(self, grid: FrequencyGrid) -> Complex[Array, "n nx"]:
        """``S(W)`` at every node of a real-FFT frequency grid (rows ``W_y``, columns ``W_x``).

        The same values as :meth:`cf` at ``grid.nodes()``, computed with less work where the
        family allows: once per distinct radius for isotropic densities (this default),
        outer products of per-axis factors for diagonal Gaussians and shifts (overrides).
        For densities without batch dimensions (map batches with ``jax.vmap``).
        """
        if self.isotropic:
            return grid.radial(self.cf_radial).astype(jnp.result_type(grid.step, 1j))
        return self.cf(grid.nodes())

    @abc.abstractmethod
    def shifted(self, offset: Float[ArrayLike, "2"]) -> "AbstractSlopeDensity":
        """The same density translated by ``offset``: ``m ↦ s(m − offset)``."""

    @abc.abstractmethod
    def support_radius(self, tol: float) -> Float[Array, ""]:
        """A radius beyond which ``s(m) ≤ tol · max s`` (about the origin, shifts included).

        Used to choose the extent of slope grids so that periodic images (aliasing) stay
        below ``tol`` relative to the peak.
        """

    @abc.abstractmethod
    def bandwidth(self, tol: float) -> Float[Array, ""]:
        """A frequency beyond which ``|S(W)| ≤ tol`` (``inf`` when S does not decay)."""


def check_slopes(m, name: str = "m"):
    return last_axis(m, 2, name)


def safe_norm(v):
    """``|v|`` over the last axis with a zero (not NaN) gradient at ``v = 0``."""
    r2 = jnp.sum(v * v, axis=-1)
    positive = r2 > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, r2, 1.0)), 0.0)


def centred(m, offset, name: str = "m"):
    """Validated slopes ``m`` (..., 2) relative to ``offset`` (None: the origin)."""
    d = check_slopes(m, name)
    return d if offset is None else d - offset


def phase(W, offset):
    """``e^{−i W·offset}``, the transform of a shift by ``offset`` (1 when offset is None)."""
    if offset is None:
        return jnp.ones(jnp.shape(W)[:-1], dtype=jnp.result_type(W, 1j))
    return jnp.exp(-1j * jnp.sum(W * offset, axis=-1))


def shifted_cf(value, W, offset):
    """``value · e^{−i W·offset}`` as a complex array; no multiplication for a centred density."""
    if offset is None:
        return value.astype(jnp.result_type(value, 1j))
    return value * phase(W, offset)


def offset_norm(offset):
    return 0.0 if offset is None else jnp.linalg.norm(offset, axis=-1)


def add_offset(a, b):
    if a is None:
        return jnp.asarray(b)
    return a + jnp.asarray(b)
