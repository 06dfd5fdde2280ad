"""The masking term of the rendered lobe, tabulated per scale (issue 33 item 1; MASKING-API, issue 32 item 4).

Smith's masking of a surface whose facet slopes have the density ``g_μ`` (the evolved lobe's shape at each scale of
the ladder) is ``G₁(w) = 1/(1 + Λ(w))`` with Λ from :func:`brdfscale.stats.smith_lambda`; the height-correlated
masking–shadowing term is ``G₂ = 1/(1 + Λ(i) + Λ(o))`` and the uncorrelated one ``G₁(i) G₁(o)``
(:class:`brdfscale.lobes.SmithMasking`). Λ is computed once per scale here, in JAX, on a grid of directions, and
stored as ``G₁ ∈ [0, 1]`` (bounded, where Λ diverges at grazing angles) over ``(s, φ)`` with ``s = √cosθ`` (nodes
crowd towards the horizon, where G₁ falls fastest) and ``φ ∈ [0, 2π]`` (end node repeated); the plugin interpolates
it linearly in s, φ and ln μ and forms ``G₂`` from the two ``G₁``.
"""

import jax.numpy as jnp
import numpy as np

from .. import lobes, stats
from .._errors import InvalidInputError
from ..exr import LobeTable
from ._material import scalar_table


N_S = 48
"""Nodes in ``s = √cosθ`` (0 … 1) of the masking tables."""

N_PHI = 49
"""Nodes in the azimuth φ (0 … 2π, the last repeating the first)."""


def masking_choice(masking):
    """``None`` (no masking) or the :class:`brdfscale.lobes.SmithMasking` that ``masking`` asks for: True (Smith,
    height-correlated), False (none), or what :func:`brdfscale.lobes.as_masking` accepts (a masking choice object,
    ``"smith"``, ``"none"``, None for the library default ``brdfscale.choices.MASKING``)."""
    if masking is True:
        masking = "smith"  # height-correlated
    if masking is False:
        return None
    try:
        choice = lobes.as_masking(masking)
    except InvalidInputError:
        raise InvalidInputError(
            "masking must be True (Smith, height-correlated), False (none), lobes.SmithMasking(correlated=...), "
            f"lobes.NoMasking(), 'smith', 'none' or None (the library default); got {masking!r}."
        ) from None
    if isinstance(choice, lobes.NoMasking):
        return None
    if isinstance(choice, lobes.SmithMasking) and choice.multiple_scattering:
        raise InvalidInputError(
            "the Mitsuba plugin takes Smith's single-scattering G2 only: the multiple-scattering compensation "
            "(lobes.SmithMasking(multiple_scattering=True), 'smith_ms') depends on the incident direction alone and "
            "is not reciprocal (docs/masking.md); pass masking=True or 'smith'."
        )
    if isinstance(choice, lobes.SmithMasking):
        return choice
    raise InvalidInputError(
        f"the Mitsuba plugin tabulates Smith masking only (lobes.SmithMasking, lobes.NoMasking); got {masking!r}."
    )


def table_shapes(table: LobeTable) -> list:
    """A LobeTable's lobe shapes, one :class:`brdfscale.stats.Tabulated` per scale (negative values clipped to 0).
    Their Λ goes through :func:`brdfscale.stats.smith_lambda`'s generic quadrature, whose cost grows with the
    table's nodes (about a minute per scale for 64² nodes here): the evolved shapes themselves, where
    :func:`brdfscale.render.bsdf` has them, are much cheaper (closed forms for Gaussian evolutions)."""
    return [stats.Tabulated(np.maximum(v, 0.0), extent=table.extent) for v in scalar_table(table)]


def directions(n_s: int = N_S, n_phi: int = N_PHI) -> np.ndarray:
    """Unit directions (n_s, n_phi, 3) at the nodes: ``cosθ = s²``, ``s = j/(n_s − 1)``, ``φ = 2πl/(n_phi − 1)``."""
    s = np.linspace(0.0, 1.0, n_s)
    phi = np.linspace(0.0, 2 * np.pi, n_phi)
    cos = s[:, None] ** 2 * np.ones_like(phi)
    sin = np.sqrt(np.maximum(1 - cos**2, 0.0))
    return np.stack([sin * np.cos(phi), sin * np.sin(phi), cos], axis=-1)


def g1_table(shapes, n_s: int = N_S, n_phi: int = N_PHI) -> np.ndarray:
    """``G₁(w) = 1/(1 + Λ(w))`` (k, n_s, n_phi) of every scale's lobe shape at :func:`directions` (0 at the
    horizon)."""
    w = directions(n_s, n_phi)
    above = jnp.asarray(w[1:])  # cosθ > 0
    out = np.zeros((len(shapes), n_s, n_phi))
    for k, shape in enumerate(shapes):
        out[k, 1:] = 1.0 / (1.0 + np.asarray(stats.smith_lambda(shape, above)))
    return out
