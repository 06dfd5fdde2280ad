"""The interfaces of distributions over slope space: probability densities and generalised functions.

:class:`AbstractDistribution` is the transform interface both share;
:class:`AbstractSlopeDensity` (mass 1, a pointwise density) and
:class:`AbstractGeneralisedDensity` (mass 0, an action on test functions) say which a value is.
"""

import abc

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Complex, Float

from .._errors import SingularDensityError
from .._show import Shown
from ._grid import FrequencyGrid


class AbstractDistribution(Shown, eqx.Module):
    """A distribution over 2D slope space known through its transform (seed §4).

    The common interface of :class:`AbstractSlopeDensity` (probability densities, mass 1) and
    :class:`AbstractGeneralisedDensity` (generalised functions of mass 0 such as the
    plus-distributions ``h_n``): the transform ``S(W) = ⟨s, e^{−i W·m}⟩`` (``∫ s(m) e^{−i W·m} d²m``
    for a density), its evaluation on FFT grids, translation and a bandwidth. Whether ``s`` is
    a probability density is its type: code that needs one (a lobe's shape, the statistics of
    :func:`brdfscale.evolve`, a micro lobe) tests ``isinstance(s, AbstractSlopeDensity)``.

    Conventions: slopes ``m`` and frequencies ``W`` have shape ``(..., 2)`` (leading
    dimensions broadcast with the parameters); slopes are dimensionless, frequencies in
    radians per unit slope.
    """

    isotropic: eqx.AbstractVar[bool]
    """True when the distribution is radially symmetric about the origin (known structurally,
    not from parameter values)."""

    def plot(self, **options):
        """A figure of the density and its transform: :func:`brdfscale.plot.statistics` (options
        as there); returns a ``matplotlib.figure.Figure``."""
        from .._figures import draw

        return draw("statistics", self, **options)

    @abc.abstractmethod
    def cf(self, W: Float[ArrayLike, "*batch 2"]) -> Complex[Array, "*batch"]:
        """The transform ``S(W) = ⟨s, e^{−i W·m}⟩`` (complex)."""

    def cf_radial(self, k: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch"]:
        """``S`` at ``|W| = k`` for an isotropic distribution (real-valued)."""
        k = jnp.asarray(k)
        W = jnp.stack([k, jnp.zeros_like(k)], axis=-1)
        return jnp.real(self.cf(W))

    def cf_grid(self, grid: FrequencyGrid) -> Complex[Array, "n nx"]:
        """``S(W)`` at every node of a real-FFT frequency grid (rows ``W_y``, columns ``W_x``).

        The same values as :meth:`cf` at ``grid.nodes()``, computed with less work where the
        family allows: once per distinct radius for isotropic distributions (this default),
        outer products of per-axis factors for diagonal Gaussians, tables and shifts
        (overrides). For distributions without batch dimensions (map batches with ``jax.vmap``).
        """
        if self.isotropic:
            return grid.radial(self.cf_radial).astype(jnp.result_type(grid.step, 1j))
        return self.cf(grid.nodes())

    @abc.abstractmethod
    def shifted(self, offset: Float[ArrayLike, "2"]) -> "AbstractDistribution":
        """The same distribution translated by ``offset``: ``m ↦ s(m − offset)``, ``S ↦ S e^{−iW·offset}``."""

    @abc.abstractmethod
    def bandwidth(self, tol: float) -> Float[Array, ""]:
        """A frequency beyond which ``|S(W)| ≤ tol`` (``inf`` when S does not decay)."""


class AbstractSlopeDensity(AbstractDistribution):
    """A probability density over 2D slope space (seed §4), with its transform.

    Subclasses represent the *facet-slope density* ``s(m)``: the density of the slope ``m``
    of a facet relative to the global orientation, i.e. what a histogram of facet slopes
    shows (docs/conventions.md §2). The seed's ``q`` of Eq. 4.2 is its reflection, ``q(x) = s(−x)``, so
    the seed's ``Q(W) = S(−W)``; for centrally symmetric statistics the two coincide. The
    same classes describe the normalised *shape* of a BRDF lobe in slope space.

    ``s ≥ 0`` with mass 1: ``S(W) = ∫ s(m) e^{−i W·m} d²m`` so ``S(0) = 1``; densities are per
    unit slope area ``d²m`` (dimensionless slopes). Point masses (:class:`Delta`, and mixtures
    with one) are probability measures without a pointwise density: their :meth:`density`
    raises :class:`brdfscale.SingularDensityError`.
    """

    @abc.abstractmethod
    def density(self, m: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch"]:
        """The density ``s(m)`` per unit slope area."""

    @abc.abstractmethod
    def shifted(self, offset: Float[ArrayLike, "2"]) -> "AbstractSlopeDensity":
        """The same density translated by ``offset``: ``m ↦ s(m − offset)``."""

    @abc.abstractmethod
    def support_radius(self, tol: float) -> Float[Array, ""]:
        """A radius beyond which ``s(m) ≤ tol · max s`` (about the origin, shifts included).

        Used to choose the extent of slope grids so that periodic images (aliasing) stay
        below ``tol`` relative to the peak.
        """


class AbstractGeneralisedDensity(AbstractDistribution):
    """A generalised function over 2D slope space of mass 0, with no pointwise density.

    Defined by its action ``⟨h, ψ⟩`` on smooth test functions ψ and by its transform
    ``H(W) = ⟨h, e^{−i W·m}⟩`` with ``H(0) = 0`` (it integrates to zero against constants),
    e.g. the regularised plus-distributions ``h_n`` of :class:`brdfscale.plus.PlusDistribution`.
    It is not a probability density — not a facet-slope statistic, a lobe shape or a micro
    lobe by itself — but a term of one: ``a δ + Σ c_n h_n + w s_smooth``
    (:class:`brdfscale.plus.NearlySpecular`, mass 1) is an :class:`AbstractSlopeDensity`.
    """

    @abc.abstractmethod
    def apply(self, psi) -> Float[Array, ""]:
        """``⟨h, ψ⟩`` for a test function ``psi`` mapping slopes (..., 2) to values (...)
        (implementations may add keyword options, e.g. their quadrature's settings)."""

    @abc.abstractmethod
    def support_radius(self, tol: float) -> Float[Array, ""]:
        """A radius (about the origin, shifts included) outside which ``h`` vanishes: ``⟨h, ψ⟩ = 0``
        for every ψ supported there (``tol``: the tolerance of a tail, as for
        :meth:`AbstractSlopeDensity.support_radius`; compact supports ignore it)."""

    def density(self, m: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch"]:
        """Always raises :class:`brdfscale.SingularDensityError`: there is no pointwise value."""
        raise SingularDensityError(
            f"{type(self).__name__} is a generalised function of mass 0 with no pointwise density; use "
            ".apply(psi) for its action on a test function or .cf(W) for its transform."
        )
