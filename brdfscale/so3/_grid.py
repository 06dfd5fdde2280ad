"""The Kostelec–Rockmore sampling grid on SO(3) and its exact β quadrature.

For band limit B (degrees J < B) the grid has 2B × 2B × 2B Euler angles

    α_j = γ_j = π j / B,   β_k = π (2k + 1) / (4B),   j, k = 0 … 2B − 1,

and the weights (Kostelec & Rockmore 2008, Eq. 2.13)

    w_B(k) = (2/B) sin β_k Σ_{l<B} sin((2l + 1) β_k) / (2l + 1),

which integrate ``∫₀^π f(β) sin β dβ = Σ_k w_B(k) f(β_k)`` exactly for every product
``d^J_{MM'} d^{J'}_{MM'}`` with J, J' < B (they sum to 2). The Haar measure is
``dΓ = sin β dα dβ dγ`` with total volume 8π².
"""

import functools

import numpy as np
from jaxtyping import Float

from .._errors import InvalidInputError


__all__ = ["grid", "quadrature_weights", "MAX_BAND_LIMIT"]

MAX_BAND_LIMIT = 512
"""Largest band limit accepted (the grid alone has (2B)³ points)."""


def check_band_limit(B, name: str = "B") -> int:
    if isinstance(B, bool) or not isinstance(B, (int, np.integer)) or not 1 <= B <= MAX_BAND_LIMIT:
        raise InvalidInputError(f"{name} must be an integer band limit in [1, {MAX_BAND_LIMIT}]; got {B!r}.")
    return int(B)


def grid(B: int) -> tuple[Float[np.ndarray, " n"], Float[np.ndarray, " n"], Float[np.ndarray, " n"]]:
    """The grid's Euler angles ``(α_j, β_k, γ_j)``, each of length ``n = 2B`` (float64, radians).

    Samples for :func:`forward` are ``f(α_a, β_k, γ_g)`` in an array indexed ``[..., a, k, g]``.
    """
    B = check_band_limit(B)
    ag = np.pi * np.arange(2 * B) / B
    beta = np.pi * (2 * np.arange(2 * B) + 1) / (4 * B)
    return ag.copy(), beta, ag.copy()


@functools.lru_cache(maxsize=32)
def _weights(B: int) -> np.ndarray:
    _, beta, _ = grid(B)
    l = np.arange(B)
    w = (2.0 / B) * np.sin(beta) * (np.sin(np.outer(beta, 2 * l + 1)) / (2 * l + 1)).sum(axis=1)
    w.setflags(write=False)
    return w


def quadrature_weights(B: int) -> Float[np.ndarray, " n"]:
    """The exact β weights ``w_B(k)``, k < n = 2B, of the Kostelec–Rockmore grid (float64; they sum to 2)."""
    return _weights(check_band_limit(B)).copy()
