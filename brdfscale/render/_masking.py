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
from .._errors import InvalidInputError, MissingDependencyError
from ..exr import LobeTable
from ._material import scalar_table


N_S = 48
"""Nodes in ``s = √cosθ`` (0 … 1) of the masking tables."""

N_PHI = 49
"""Nodes in the azimuth φ (0 … 2π, the last repeating the first)."""


def masking_choice(masking):
    """``None`` (no masking) or a :class:`brdfscale.lobes.SmithMasking` from ``masking`` (True, False or a masking
    choice object)."""
    if masking is False or masking is None:
        return None
    smith, none = getattr(lobes, "SmithMasking", None), getattr(lobes, "NoMasking", None)
    if smith is None or none is None:  # until issue 32 item 4 (MASKING-API) is on main
        raise MissingDependencyError(
            "masking needs brdfscale.lobes.SmithMasking and stats.smith_lambda (issue 32 item 4), which this "
            "checkout does not have yet; pass masking=False."
        )
    if masking is True:
        return smith()
    if isinstance(masking, none):
        return None
    if isinstance(masking, smith):
        return masking
    raise InvalidInputError(
        "masking must be True (Smith, height-correlated), False (none), lobes.NoMasking() or "
        f"lobes.SmithMasking(correlated=...); got {masking!r}."
    )


def shapes(table: LobeTable) -> list:
    """The table's lobe shapes, one :class:`brdfscale.stats.Tabulated` per scale (negative values clipped to 0)."""
    return [stats.Tabulated(np.maximum(v, 0.0), extent=table.extent) for v in scalar_table(table)]


def directions(n_s: int = N_S, n_phi: int = N_PHI) -> np.ndarray:
    """Unit directions (n_s, n_phi, 3) at the nodes: ``cosθ = s²``, ``s = j/(n_s − 1)``, ``φ = 2πl/(n_phi − 1)``."""
    s = np.linspace(0.0, 1.0, n_s)
    phi = np.linspace(0.0, 2 * np.pi, n_phi)
    cos = s[:, None] ** 2 * np.ones_like(phi)
    sin = np.sqrt(np.maximum(1 - cos**2, 0.0))
    return np.stack([sin * np.cos(phi), sin * np.sin(phi), cos], axis=-1)


def g1_table(table: LobeTable, n_s: int = N_S, n_phi: int = N_PHI) -> np.ndarray:
    """``G₁(w)`` (k, n_s, n_phi) of every scale's lobe shape at :func:`directions` (0 at the horizon)."""
    w = directions(n_s, n_phi)
    above = w[1:]  # cosθ > 0
    out = np.zeros((len(table.scales), n_s, n_phi))
    for k, shape in enumerate(shapes(table)):
        lam = np.asarray(stats.smith_lambda(shape, jnp.asarray(above)))
        out[k, 1:] = 1.0 / (1.0 + lam)
    return out
