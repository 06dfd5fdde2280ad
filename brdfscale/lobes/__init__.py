"""BRDF lobes at one observation scale (seed §2, §4; docs/conventions.md §2).

In the nearly-flat approximation the microscopic BRDF of a facet tilted by ``m∞`` is, for
fixed directions, ``ρ(i, o, m∞) = A · F(i, o) · g(m_s(i, o) − m∞)``: an amplitude ``A``
times a *lobe* ``g`` in slope space around the specular (half-vector) slope ``m_s``, with
the mirror-microfacet factor ``F = 1/(4 cosθ_o cos⁴θ_h)`` of
:func:`brdfscale.geometry.microfacet_factor`. The lobe shape is a normalised slope density
(``∫ g d²u = 1``), so every :mod:`brdfscale.stats` family can serve as a lobe, and the
amplitude ``A`` is the lobe's integral over half-vector slope offsets ``u = m_s − m∞``.
A mirror gives ``g = δ``.

Masking and shadowing (beyond the seed; docs/masking.md): :meth:`AbstractLobe.evaluate` takes
``masking=`` — :class:`NoMasking` (the seed's ``G = 1``, the default ``brdfscale.choices.MASKING``)
or :class:`SmithMasking`, whose ``G₂(i, o)`` uses the lobe's own shape as the facet-slope density
(:func:`brdfscale.stats.smith_lambda`), so an evolved lobe is masked by its shape at its scale.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Complex, Float

from .. import stats
from .._errors import InvalidInputError
from .._show import derived, Shown
from .._slopes import half_slope_of_valid, microfacet_factor_of_valid
from .._validation import as_float_array, is_concrete
from ..geometry import validate_directions
from ._masking import AbstractMasking, as_masking, NoMasking, SmithMasking


__all__ = [
    "AbstractLobe",
    "Lobe",
    "Mirror",
    "Beckmann",
    "GGX",
    "Tabulated",
    "AbstractMasking",
    "NoMasking",
    "SmithMasking",
    "as_masking",
]


class AbstractLobe(Shown, eqx.Module):
    """A lobe ``A · g(u)`` over half-vector slope offsets ``u = m_s − m∞`` (shape (..., 2))."""

    shape: eqx.AbstractVar[stats.AbstractSlopeDensity]
    amplitude: eqx.AbstractVar[Float[Array, ""]]

    def _show_items(self):
        return [("shape", self.shape), ("amplitude", self.amplitude)]

    def plot(self, **options):
        """A figure of the lobe on the slope-offset plane with slices (and, given ``incident=``,
        the BRDF over outgoing directions): :func:`brdfscale.plot.lobe` (options as there);
        returns a ``matplotlib.figure.Figure``."""
        from .._figures import draw

        return draw("lobe", self, **options)

    def density(self, u: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch"]:
        """``A · g(u)``: the lobe per unit slope area at offsets ``u``."""
        return self.amplitude * self.shape.density(u)

    def cf(self, W: Float[ArrayLike, "*batch 2"]) -> Complex[Array, "*batch"]:
        """``A · G(W)`` with ``G(W) = ∫ g(u) e^{−iW·u} d²u``."""
        return self.amplitude * self.shape.cf(W)

    def evaluate(
        self,
        i: Float[ArrayLike, "#*batch 3"],
        o: Float[ArrayLike, "#*batch 3"],
        m_inf: Float[ArrayLike, "#*batch 2"] | None = None,
        *,
        masking: "AbstractMasking | str | None" = None,
    ) -> Float[Array, "*batch"]:
        """``ρ(i, o, m∞) = A · F(i, o) · g(m_s(i, o) − m∞)`` (seed §2: ρ = β cosθ_i), times ``G₂``.

        ``i``, ``o``: unit directions (..., 3) towards light and detector, z > 0.
        ``m_inf``: global facet slope (..., 2), default flat. Units: 1/sr.
        ``masking``: None (the library default, ``brdfscale.choices.MASKING``: ``"none"``), a
        name of ``choices.MASKING`` or a :class:`AbstractMasking`; the masked ρ is the unmasked
        one times ``masking.factor(self.shape, i, o, m_inf)`` — Smith's ``G₂``, or ``G₂/E(i)`` with
        multiply scattered light (``"smith_ms"``; docs/masking.md). :class:`NoMasking` returns the
        unmasked ρ itself.

        Accurate to grazing angles (θ = 89.9°: relative error ≤ 1e-13 in float64 against
        mpmath, experiments/stability.py). The lobe's relative error grows with the half-vector
        slope as ``ε (1 + |m_s|²/α²)`` (the argument of its exponential or power), and in float32
        values below its smallest normal number (1.2e-38, e.g. a Beckmann lobe far from its peak)
        are subnormal or 0.
        """
        masking = as_masking(masking)
        i = validate_directions(i, "i")
        o = validate_directions(o, "o")
        u = half_slope_of_valid(i, o)
        if m_inf is not None:
            u = u - jnp.asarray(m_inf)
        rho = self.density(u) * microfacet_factor_of_valid(i, o)
        if isinstance(masking, NoMasking):
            return rho
        return rho * masking.factor(self.shape, i, o, m_inf)


def _amplitude(a):
    """A lobe's amplitude: a real number ≥ 0 (its integral over slope offsets)."""
    a = as_float_array(a, "amplitude")
    if is_concrete(a) and not np.all(np.asarray(a) >= 0):
        raise InvalidInputError(f"amplitude must be ≥ 0 (a lobe's integral); got {np.asarray(a)!r}.")
    return a


class Lobe(AbstractLobe):
    """A lobe with any slope density as its shape (e.g. the result of :func:`brdfscale.evolve`)."""

    shape: stats.AbstractSlopeDensity
    amplitude: Float[Array, ""]

    def _show_items(self):
        # an evolved shape (brdfscale.evolve) shows its factors and discretisation in the lobe's summary
        if getattr(self.shape, "_show_in_lobe", False):
            return [("shape", type(self.shape).__name__), *self.shape._show_items(), ("amplitude", self.amplitude)]
        return super()._show_items()

    def __init__(self, shape: stats.AbstractSlopeDensity, amplitude: Float[ArrayLike, ""] = 1.0):
        self.shape = stats.require_density(
            shape, "shape", use="Use lobes.Lobe(plus.observe(plus.NearlySpecular(...), kernel))."
        )
        self.amplitude = _amplitude(amplitude)


class Mirror(AbstractLobe):
    """A perfect mirror: ``g = δ`` (seed §2, ``ρ_mirror = A δ(n − n_s)``)."""

    shape: stats.Delta
    amplitude: Float[Array, ""]

    def __init__(self, amplitude: Float[ArrayLike, ""] = 1.0):
        self.shape = stats.Delta()
        self.amplitude = _amplitude(amplitude)

    def _show_items(self):
        return [("amplitude", self.amplitude)]


class Beckmann(AbstractLobe):
    """Beckmann lobe: ``g`` Gaussian with per-axis variance ``α²/2`` (isotropic or α_x, α_y)."""

    shape: stats.Gaussian
    amplitude: Float[Array, ""]

    def __init__(self, alpha=None, *, alpha_x=None, alpha_y=None, amplitude=1.0):
        self.shape = stats.Beckmann(alpha, alpha_x=alpha_x, alpha_y=alpha_y)
        self.amplitude = _amplitude(amplitude)

    def _show_items(self):
        # α per axis is √2 σ of the Gaussian shape; one number where both axes agree
        alpha = dict(self.shape._show_items()).get("alpha")
        if alpha is None:
            alpha = derived(self.shape.cov, lambda c: (2 * c[..., (0, 1), (0, 1)]) ** 0.5)
        return [("alpha", alpha), ("amplitude", self.amplitude)] + (
            [("mean", self.shape.mean)] if self.shape.mean is not None else []
        )


class GGX(AbstractLobe):
    """GGX / Trowbridge–Reitz lobe (isotropic ``alpha`` or anisotropic ``alpha_x, alpha_y``)."""

    shape: stats.GGX
    amplitude: Float[Array, ""]

    def __init__(self, alpha=None, *, alpha_x=None, alpha_y=None, amplitude=1.0):
        self.shape = stats.GGX(alpha, alpha_x=alpha_x, alpha_y=alpha_y)
        self.amplitude = _amplitude(amplitude)

    def _show_items(self):
        return self.shape._show_items()[:1] + [("amplitude", self.amplitude)] + self.shape._show_items()[1:]


class Tabulated(AbstractLobe):
    """A lobe tabulated on a regular grid of offsets ``u`` (e.g. a measurement).

    ``values`` (rows: u_y, columns: u_x, nodes spanning ``center + [−extent, extent]``) are the
    lobe itself, ``A · g``, at the nodes, with the one meaning of :class:`brdfscale.stats.Tabulated`:
    a sum of tent functions on the nodes (bilinear between nodes, falling linearly to zero over
    one spacing beyond the outermost ones). The amplitude ``A = h_x h_y Σ values`` is then
    exactly the integral of the lobe, and the shape is the normalised
    :class:`brdfscale.stats.Tabulated` of the same values (``∫ g d²u = 1``).
    """

    shape: stats.Tabulated
    amplitude: Float[Array, ""]

    def __init__(self, values, *, extent, center=None):
        values = as_float_array(values, "values")
        self.shape = stats.Tabulated(values, extent=extent, center=center)
        h = self.shape.spacing
        self.amplitude = h[0] * h[1] * jnp.sum(values)

    def _show_items(self):
        items = [("values", self.shape.values), ("extent", self.shape.extent), ("amplitude", self.amplitude)]
        return items + ([("center", self.shape.center)] if self.shape.center is not None else [])
