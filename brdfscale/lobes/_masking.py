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

**A tilted patch.** ``m_inf`` is the slope of the patch's mean plane (the lobe's ``m∞``): the
directions are expressed in that plane's frame — the rotation about ``z × n∞`` that takes
``z`` to the plane's normal ``n∞ = (m∞, 1)/√(1 + |m∞|²)`` — and ``G₂ = 0`` where ``i`` or
``o`` lies on or below that plane (the patch neither is lit nor seen).
"""

import abc

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .. import stats
from .._choices import MASKING
from .._errors import InvalidInputError
from .._show import Shown
from .._validation import flag
from ..geometry import validate_directions, validate_slopes


__all__ = ["AbstractMasking", "NoMasking", "SmithMasking", "as_masking"]


class AbstractMasking(Shown, eqx.Module):
    """A masking–shadowing choice: the factor ``G₂(i, o)`` by which a lobe's ρ is multiplied
    (:meth:`brdfscale.lobes.AbstractLobe.evaluate`) and its one-direction factor ``G₁(w)``."""

    name: eqx.AbstractClassVar[str]
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


class NoMasking(AbstractMasking):
    """``G = 1``: every facet is lit and seen (the seed's assumption, its footnote 1)."""

    name = "none"

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
    name = "smith"

    def __check_init__(self):
        flag(self.correlated, "correlated")

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


_BY_NAME = {"none": NoMasking, "smith": SmithMasking}


def as_masking(masking: "AbstractMasking | str | None" = None) -> AbstractMasking:
    """The masking choice ``masking`` names: None → the library default (``brdfscale.choices.MASKING``),
    a name of ``choices.MASKING`` (``"none"``, ``"smith"``: height-correlated) → its object, an
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
