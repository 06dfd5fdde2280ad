"""Convolution on SO(3) as per-degree block products, and the normalisations involved.

With ``f^J = (2J+1)/(8π²) ∫ f D^{J*} dΓ`` (seed §5) the convolution

    (f ⋆ g)(Γ∞) = ∫ f(Γ) g(Γ⁻¹ Γ∞) dΓ        has coefficients   (8π²/(2J+1)) f^J g^J.

The seed (below Eq. 5.3) writes ``f^J g^J`` and drops the factor 8π²/(2J+1) (docs/conventions.md §3).
In *operator normalisation* ``f̃^J = (8π²/(2J+1)) f^J`` a δ at the identity has
``f̃^J = I`` and convolution with g is ``f^J g̃^J``: the form used by the evolution.

Reflection. The seed's statistic q (``p(Γ∞, Γ) = q(Γ⁻¹Γ∞)``) and the density s of a facet's
orientation Δ = Γ∞⁻¹Γ relative to the global one (what users histogram) are related by
``q(Δ⁻¹) = s(Δ)``, hence ``q^J = (s^J)†`` for real s (docs/conventions.md §3; tested on a skewed s).
"""

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Complex, Shaped

from .._errors import InvalidInputError
from ._transform import _coefficients


__all__ = ["convolve", "to_operator", "from_operator", "reflect"]


def _scale(B, dtype):
    return jnp.asarray(8 * np.pi**2 / (2 * np.arange(B) + 1), dtype)


def to_operator(coefficients: Shaped[ArrayLike, "*batch B rows cols"]) -> Complex[Array, "*batch B rows cols"]:
    """``f̃^J = (8π²/(2J+1)) f^J`` (δ at the identity ↦ identity blocks). Pads stay zero."""
    c, B, _, _ = _coefficients(coefficients)
    return c * _scale(B, jnp.finfo(c.dtype).dtype)[:, None, None]


def from_operator(operator: Shaped[ArrayLike, "*batch B rows cols"]) -> Complex[Array, "*batch B rows cols"]:
    """The inverse of :func:`to_operator`: ``f^J = ((2J+1)/(8π²)) f̃^J``."""
    c, B, _, _ = _coefficients(operator)
    return c / _scale(B, jnp.finfo(c.dtype).dtype)[:, None, None]


def convolve(
    f: Shaped[ArrayLike, "*#batch B rows inner"], g: Shaped[ArrayLike, "*#batch B inner cols"]
) -> Complex[Array, "*batch B rows cols"]:
    """Coefficients of ``(f ⋆ g)(Γ∞) = ∫ f(Γ) g(Γ⁻¹Γ∞) dΓ``: ``(8π²/(2J+1)) f^J g^J`` per block.

    The inner orders must match (f's column bound = g's row bound = K); the product is
    exact when they cover every |k| ≤ J, i.e. K = B − 1, or when f vanishes beyond K.
    """
    f, B, _, K = _coefficients(f)
    g, Bg, Kg, _ = _coefficients(g)
    if B != Bg or K != Kg:
        raise InvalidInputError(
            f"convolve needs equal band limits and matching inner orders: f has shape {f.shape} "
            f"(B = {B}, column bound {K}), g has shape {g.shape} (B = {Bg}, row bound {Kg})."
        )
    return (f @ g) * _scale(B, jnp.finfo(f.dtype).dtype)[:, None, None]


def reflect(coefficients: Shaped[ArrayLike, "*batch B n n"]) -> Complex[Array, "*batch B n n"]:
    """Coefficients of ``Γ ↦ s(Γ⁻¹)`` for a real function s: ``(s^J)†`` per block.

    Turns a facet-orientation density s into the seed's q (and back).
    """
    c, _, L, N = _coefficients(coefficients)
    if L != N:
        raise InvalidInputError(f"reflect needs square blocks (equal row and column bounds); got shape {c.shape}.")
    return jnp.conj(jnp.swapaxes(c, -1, -2))
