"""Finite mixtures of slope densities."""

from typing import cast

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._errors import InvalidInputError
from .._slopes import check_slopes
from .._validation import as_float_array, is_concrete
from ._base import AbstractSlopeDensity
from ._require import require_density


def _weighted_sum(weights, values) -> Array:
    """``Σ_k w_k v_k`` over a mixture's components (never empty: ``sum``'s start 0 is never the result)."""
    return cast(Array, sum(w * v for w, v in zip(weights, values)))


class Mixture(AbstractSlopeDensity):
    """``s(m) = Σ_k w_k s_k(m)`` with non-negative weights normalised to sum to 1.

    Components may be of different families, including :class:`Delta` point masses, so
    sawtooth or blazed micro-structure (facets at a few discrete slopes) is
    ``Mixture(weights=[0.7, 0.3], components=[Delta(mean=[0.03, 0]), Delta(mean=[-0.07, 0])])``:
    zero mean, but skewed. ``S(W) = Σ_k w_k S_k(W)``. Components must be probability
    densities (:class:`AbstractSlopeDensity`), so the mixture is one; plus-distributions
    (mass 0) enter a statistic through :class:`brdfscale.plus.NearlySpecular`.
    """

    weights: Float[Array, " k"]
    components: tuple[AbstractSlopeDensity, ...]
    isotropic: bool = eqx.field(static=True)

    def __init__(self, weights, components):
        components = require_density(
            tuple(components),
            "components",
            each=True,
            other=" (a non-empty sequence)",
            use="The mixture would not have mass 1. Use brdfscale.plus.NearlySpecular(a, [c_0, …], x0, smooth=..., "
            "smooth_weight=w) for a δ + Σ c_n h_n + w s_smooth.",
        )
        w = as_float_array(weights, "weights")
        if w.shape != (len(components),):
            raise InvalidInputError(f"weights must have shape ({len(components)},), one per component; got {w.shape}.")
        if is_concrete(w):
            wn = np.asarray(weights, dtype=np.result_type(np.asarray(weights), np.float64))
            if np.any(wn < 0) or not np.any(wn > 0):
                raise InvalidInputError(f"weights must be non-negative with a positive sum; got {wn!r}.")
            wn = wn / wn.max()  # first to the largest: the sum neither under- nor overflows
            self.weights = jnp.asarray(wn / wn.sum(), dtype=w.dtype)
        else:
            self.weights = w / jnp.sum(w)
        self.components = components
        self.isotropic = all(c.isotropic for c in components)

    def density(self, m):
        m = check_slopes(m, "m")
        return _weighted_sum(self.weights, (c.density(m) for c in self.components))

    def cf(self, W):
        W = check_slopes(W, "W")
        return _weighted_sum(self.weights, (c.cf(W) for c in self.components))

    def cf_grid(self, grid):
        return _weighted_sum(self.weights, (c.cf_grid(grid) for c in self.components))

    def shifted(self, offset):
        return Mixture(self.weights, [c.shifted(offset) for c in self.components])

    def support_radius(self, tol):
        return jnp.max(jnp.stack([c.support_radius(tol) for c in self.components]))

    def bandwidth(self, tol):
        return jnp.max(jnp.stack([c.bandwidth(tol) for c in self.components]))
