"""Masking and shadowing of a lobe: the choice objects (issue 32 item 4; docs/masking.md).

The seed's lobes assume every facet sees the light and the detector (no masking, no
shadowing: :class:`NoMasking`, the library's default until the instrument study decides,
``brdfscale.choices.MASKING``). :class:`SmithMasking` multiplies the lobe by Smith's
geometric attenuation of a surface whose microfacet slopes have the lobe's shape as density
(Smith 1967; Heitz 2014, "Understanding the masking-shadowing function"):

* ``G₁(w) = 1/(1 + Λ(w))`` — the fraction of the facets seen from ``w``
  (:func:`brdfscale.stats.smith_lambda`);
* height-correlated (``correlated=True``, the default): ``G₂(i, o) = 1/(1 + Λ(i) + Λ(o))``;
* separable (``correlated=False``): ``G₂(i, o) = G₁(i) G₁(o)`` (what Mitsuba's ``roughconductor``
  uses).

The facets that reflect ``i`` into ``o`` have the half vector ``h`` as normal and
``i·h = o·h > 0``, so Smith's back-facing indicators ``χ⁺(w·h)`` are 1 and do not appear.

**Multiple scattering** (``multiple_scattering=True``, name ``"smith_ms"``). Smith's ``G₂`` keeps
the light reflected once; what the facets reflect into other facets (and what they reflect below
the mean plane) is lost, ``1 − E(i)`` of it, where ``E(i)`` is the single-scattering directional
albedo of lossless mirror facets (:meth:`SmithMasking.albedo`). On a real surface that light is
reflected again and leaves: the ray-traced instrument with interreflection finds 4–9 % more light
than single scattering at 50–80° on rms slopes 0.2–0.3 (docs/masking.md). The compensation of
Turquin (2019, "A practical multiple scattering compensation for microfacet models", as used by
Filament and Unity) gives the multiply scattered light the shape of the single-scattered lobe and
the missing energy,

    factor(i, o) = G₂(i, o) · (1 + (1 − E(i))/E(i)) = G₂(i, o)/E(i),

so the lobe of lossless facets reflects all the light it receives (tests/test_masking.py integrates
it over the hemisphere). That the shape is right is an assumption, checked against the instrument
by the L1 error of its images (experiments/bench_instrument.py). A lobe amplitude below 1 (facets
that absorb) scales every order alike, where the k-th order is really weighted by the k-th power
of the facets' reflectance: the compensation then overestimates the extra light by at most the
absorbed fraction of it. The factor is not symmetric in ``i`` and ``o`` (the compensation depends
on ``i``, the instrument's fixed incidence): it is a model of a measurement at fixed incidence, not
a reciprocal BSDF, and the Mitsuba plugin (:mod:`brdfscale.render`) refuses it.

**A tilted patch.** ``m_inf`` is the slope of the patch's mean plane (the lobe's ``m∞``): the
directions are expressed in that plane's frame — the rotation about ``z × n∞`` that takes
``z`` to the plane's normal ``n∞ = (m∞, 1)/√(1 + |m∞|²)`` — and ``G₂ = 0`` where ``i`` or
``o`` lies on or below that plane (the patch neither is lit nor seen).
"""

import abc
import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .. import stats
from .._blocks import in_blocks
from .._choices import MASKING
from .._errors import InvalidInputError
from .._show import Shown
from .._validation import flag
from ..geometry import reflect, slope_to_direction, validate_directions, validate_slopes


__all__ = ["AbstractMasking", "NoMasking", "SmithMasking", "as_masking"]

ALBEDO_RADIAL = 96
"""Gauss–Legendre nodes in ``t ∈ (0, 1)``, ``r = s t/(1 − t)``, of :meth:`SmithMasking.albedo`'s polar rule for
densities without nodes of their own (``s`` the density's scale; the rule reaches to infinity)."""
ALBEDO_ANGULAR = 128
"""Azimuths (midpoints) of that polar rule."""


class AbstractMasking(Shown, eqx.Module):
    """A masking–shadowing choice: the factor ``G₂(i, o)`` by which a lobe's ρ is multiplied
    (:meth:`brdfscale.lobes.AbstractLobe.evaluate`) and its one-direction factor ``G₁(w)``."""

    @property
    @abc.abstractmethod
    def name(self) -> str:
        """The name of the choice in ``brdfscale.choices.MASKING`` (and of ``brdfscale fit --masking``)."""

    @abc.abstractmethod
    def g1(self, density: stats.AbstractSlopeDensity, w: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch"]:
        """``G₁(w)``: the fraction of the facets of slope density ``density`` visible from ``w``."""

    @abc.abstractmethod
    def g2(
        self,
        density: stats.AbstractSlopeDensity,
        i: Float[ArrayLike, "#*batch 3"],
        o: Float[ArrayLike, "#*batch 3"],
        m_inf: Float[ArrayLike, "#*batch 2"] | None = None,
    ) -> Float[Array, "*batch"]:
        """``G₂(i, o)``: the fraction of the facets reflecting ``i`` into ``o`` that are both lit
        and seen, on a patch whose mean plane has slope ``m_inf`` (default flat; module docstring)."""

    def factor(
        self,
        density: stats.AbstractSlopeDensity,
        i: Float[ArrayLike, "#*batch 3"],
        o: Float[ArrayLike, "#*batch 3"],
        m_inf: Float[ArrayLike, "#*batch 2"] | None = None,
    ) -> Float[Array, "*batch"]:
        """The factor by which the unmasked ρ (and a measurement set's lobe) is multiplied: ``G₂(i, o)``
        unless the choice adds multiply scattered light (:class:`SmithMasking` with
        ``multiple_scattering=True``: ``G₂/E(i)``, module docstring)."""
        return self.g2(density, i, o, m_inf)


class NoMasking(AbstractMasking):
    """``G = 1``: every facet is lit and seen (the seed's assumption, its footnote 1)."""

    @property
    def name(self) -> str:
        return "none"

    def g1(self, density, w):
        stats.require_density(density, "density")
        w = validate_directions(w, "w")
        return jnp.ones(w.shape[:-1], dtype=w.dtype)

    def g2(self, density, i, o, m_inf=None):
        stats.require_density(density, "density")
        i, o = validate_directions(i, "i"), validate_directions(o, "o")
        shape = jnp.broadcast_shapes(i.shape[:-1], o.shape[:-1])
        if m_inf is not None:
            shape = jnp.broadcast_shapes(shape, validate_slopes(m_inf, "m_inf").shape[:-1])
        return jnp.ones(shape, dtype=jnp.result_type(i, o))


class SmithMasking(AbstractMasking):
    """Smith's masking–shadowing with the facet-slope density's Λ (:func:`brdfscale.stats.smith_lambda`).

    ``correlated=True``: the height-correlated ``G₂ = 1/(1 + Λ(i) + Λ(o))``; ``False``: the
    separable ``G₁(i) G₁(o)``. Both are ≤ 1, symmetric in ``i`` and ``o`` (reciprocity) and 1 at
    normal incidence and exitance (tests/test_masking.py).
    """

    correlated: bool = eqx.field(static=True, default=True)
    multiple_scattering: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        flag(self.correlated, "correlated")
        flag(self.multiple_scattering, "multiple_scattering")

    @property
    def name(self) -> str:
        """``"smith"``, or ``"smith_ms"`` with multiply scattered light (``brdfscale.choices.MASKING``; the
        separable form has no name of its own)."""
        return "smith_ms" if self.multiple_scattering else "smith"

    def g1(self, density, w):
        return 1.0 / (1.0 + stats.smith_lambda(density, w))

    def g2(self, density, i, o, m_inf=None):
        density = stats.require_density(density, "density")
        i, o = validate_directions(i, "i"), validate_directions(o, "o")
        i, o = jnp.broadcast_arrays(i, o)
        above = jnp.ones(i.shape[:-1], dtype=bool)
        if m_inf is not None:
            m = validate_slopes(m_inf, "m_inf")
            i, o = _in_plane_frame(i, m), _in_plane_frame(o, m)
            above = (i[..., 2] > 0) & (o[..., 2] > 0)
        lam_i, lam_o = stats.smith_lambda(density, jnp.stack([_above_or_normal(w, above) for w in (i, o)]))
        g = 1.0 / (1.0 + (lam_i + lam_o)) if self.correlated else 1.0 / ((1.0 + lam_i) * (1.0 + lam_o))
        return jnp.where(above, g, 0.0)

    def factor(self, density, i, o, m_inf=None):
        g = self.g2(density, i, o, m_inf)
        if not self.multiple_scattering:
            return g
        i = validate_directions(i, "i")
        if m_inf is not None:
            i = _in_plane_frame(i, validate_slopes(m_inf, "m_inf"))
        below = i[..., 2] <= 0
        e = self.albedo(density, _above_or_normal(i, ~below))
        return jnp.where(below, 0.0, g / e)

    def albedo(self, density: stats.AbstractSlopeDensity, i: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch"]:
        """``E(i)``: the fraction of the light falling from ``i`` that lossless mirror facets of slope
        density ``density`` reflect once and that leaves (Smith's single-scattering directional albedo),

            E(i) = ∫ s(m) · (i·h)/(i_z h_z) · G₂(i, o(m)) d²m,     h = (m, 1)/√(1 + |m|²),  o = reflect(i, h),

        ``(i·h)/(i_z h_z) = 1 + m·i_xy/i_z`` the light a facet of slope m intercepts per unit area of
        the mean plane (0 where it faces away), ``G₂ = 0`` where ``o`` points into the surface, the
        slopes taken from the density's mean (:func:`brdfscale.stats.mean_slope`, Λ's reading) and
        ``G₂`` this choice's (height-correlated or separable). Without masking the integral is 1;
        ``1 − E(i)`` is the light single scattering loses. 1 at normal incidence for a narrow density,
        falling towards grazing.

        The rule: a :class:`brdfscale.stats.PixelGaussians` or :class:`~brdfscale.stats.Tabulated`
        density is summed over its own nodes (each node's mass at the node); any other over a polar
        rule about its mean, :data:`ALBEDO_RADIAL` Gauss–Legendre nodes in ``t``, ``r = s t/(1 − t)``
        to infinity (``s`` a third of the density's support radius at 1 %: its standard deviation for
        a Gaussian) × :data:`ALBEDO_ANGULAR` azimuths; the weights are normalised to mass 1. Verified in
        tests/test_masking.py against SciPy's quadrature of the definition (Beckmann and GGX).
        """
        density = stats.require_density(density, "density")
        i = validate_directions(i, "i")
        stats.smith_lambda(density, i)  # its refusals (a density without a first moment, …), before tracing
        return _albedo(SmithMasking(correlated=self.correlated), density, i)


_ALBEDO_BYTES_PER_NODE = 8 * 32
"""Temporaries of :func:`_albedo` per direction and node of its rule (float64: reflected directions, the lit
fraction, G₂ and its two Λ, with room to spare): its directions are taken in blocks of the library's budget."""


@eqx.filter_jit
def _albedo(masking: "SmithMasking", density: stats.AbstractSlopeDensity, i: Array) -> Array:
    """:meth:`SmithMasking.albedo` of validated directions (compiled once per density structure and batch shape),
    the directions in blocks (:func:`brdfscale._blocks.in_blocks`: memory bounded whatever their number)."""
    nodes, weights = _albedo_rule(density)
    d = nodes - stats.mean_slope(density).astype(nodes.dtype)
    h = slope_to_direction(d)  # (Q, 3)

    def block(rows: Array) -> Array:
        ii = rows[:, None, :]
        o = reflect(ii, h)
        lit = jnp.sum(ii * h, axis=-1) / (ii[..., 2] * h[..., 2])
        leaves = (o[..., 2] > 0) & (lit > 0)
        safe = _above_or_normal(o / jnp.linalg.norm(o, axis=-1, keepdims=True), leaves)
        g = masking.g2(density, jnp.broadcast_to(ii, safe.shape), safe)
        return jnp.sum(weights * jnp.where(leaves, lit * g, 0.0), axis=-1)

    flat = jnp.reshape(i, (-1, 3))
    return jnp.reshape(in_blocks(block, flat, _ALBEDO_BYTES_PER_NODE * h.shape[0]), i.shape[:-1])


def _albedo_rule(density: stats.AbstractSlopeDensity) -> tuple[Array, Array]:
    """``(nodes (Q, 2), weights (Q,))``, weights summing to 1, of ``∫ s(m) f(m) d²m`` (:meth:`SmithMasking.albedo`)."""
    if isinstance(density, stats.PixelGaussians):
        nodes = density.nodes().reshape(-1, 2)
        if density.center is not None:
            nodes = nodes + density.center
        weights = density.values.reshape(-1)
    elif isinstance(density, stats.Tabulated):
        x, y = density.nodes()
        nodes = jnp.stack(jnp.broadcast_arrays(x[None, :], y[:, None]), axis=-1).reshape(-1, 2)
        if density.center is not None:
            nodes = nodes + density.center
        weights = jnp.maximum(density.values, 0.0).reshape(-1)
    else:
        t, wt, phi = _polar_rule()
        mean = stats.mean_slope(density)
        scale = jax.lax.stop_gradient(jnp.asarray(density.support_radius(1e-2))) / 3.0
        r = scale * t / (1.0 - t)
        dr = scale / (1.0 - t) ** 2
        e = jnp.stack([jnp.cos(phi), jnp.sin(phi)], axis=-1)
        nodes = (mean + r[:, None, None] * e[None, :, :]).reshape(-1, 2)
        weights = (density.density(nodes).reshape(r.shape[0], -1) * (r * dr * wt)[:, None]).reshape(-1)
    return nodes, weights / jnp.sum(weights)


@functools.cache
def _polar_rule() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(t, w_t, φ)``: Gauss–Legendre nodes and weights on (0, 1) and midpoint azimuths (weights 2π/n folded
    into w_t)."""
    x, w = np.polynomial.legendre.leggauss(ALBEDO_RADIAL)
    phi = (np.arange(ALBEDO_ANGULAR) + 0.5) * (2 * math.pi / ALBEDO_ANGULAR)
    return (x + 1) / 2, w / 2 * (2 * math.pi / ALBEDO_ANGULAR), phi


def _above_or_normal(w: Array, above: Array) -> Array:
    """``w`` where it is above the plane, the plane's normal ``z`` elsewhere (masked by the caller)."""
    return jnp.where(above[..., None], w, jnp.array([0.0, 0.0, 1.0], dtype=w.dtype))


def _in_plane_frame(w: Array, m: Array) -> Array:
    """``Rᵀ w`` with R the rotation about ``z × n`` taking ``z`` to ``n = (m, 1)/√(1 + |m|²)``:
    w in the frame of the plane of normal slope m (its z component is ``n·w``)."""
    n = jnp.concatenate([m, jnp.ones(m.shape[:-1] + (1,), dtype=m.dtype)], axis=-1)
    n = n / jnp.linalg.norm(n, axis=-1, keepdims=True)
    nx, ny, nz = n[..., 0], n[..., 1], n[..., 2]
    wx, wy, wz = w[..., 0], w[..., 1], w[..., 2]
    q = 1.0 / (1.0 + nz)
    x = wx * (1 - nx**2 * q) - wy * nx * ny * q - wz * nx
    y = -wx * nx * ny * q + wy * (1 - ny**2 * q) - wz * ny
    z = nx * wx + ny * wy + nz * wz
    return jnp.stack(jnp.broadcast_arrays(x, y, z), axis=-1)


_BY_NAME = {
    "none": NoMasking,
    "smith": SmithMasking,
    "smith_ms": functools.partial(SmithMasking, multiple_scattering=True),
}


def as_masking(masking: "AbstractMasking | str | None" = None) -> AbstractMasking:
    """The masking choice ``masking`` names: None → the library default (``brdfscale.choices.MASKING``),
    a name of ``choices.MASKING`` (``"none"``, ``"smith"``: height-correlated, ``"smith_ms"``: with multiply
    scattered light) → its object, an
    :class:`AbstractMasking` → itself; :class:`brdfscale.InvalidInputError` otherwise."""
    if masking is None:
        masking = MASKING.default
    if isinstance(masking, AbstractMasking):
        return masking
    if isinstance(masking, str):
        return _BY_NAME[MASKING.check(masking)]()
    raise InvalidInputError(
        f"masking must be None (the default, {MASKING.default!r}), one of {', '.join(map(repr, MASKING.names))} or a "
        f"brdfscale.lobes.AbstractMasking; got {type(masking).__name__}."
    )
