"""Closed-form convolution and deconvolution of slope densities, where the families allow it.

Rules (exact): δ is the identity (a shifted δ shifts); Gaussians add (subtract)
covariances and means; mixtures distribute over components. Everything else returns
``None`` and is left to the spectral paths.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._errors import NoBRDFAtScaleError
from .._existence import NEGATIVE_VARIANCE
from .._slopes import eig2
from .._validation import is_concrete
from ..stats import AbstractSlopeDensity, Delta, Gaussian, Mixture


def _neg(offset):
    return None if offset is None else -offset


def _sum_means(a, b):
    if a is None:
        return b
    if b is None:
        return a
    return a + b


def _gaussian(cov, mean, isotropic: bool) -> Gaussian:
    """A Gaussian that keeps the structural isotropy of its inputs (so that later evolutions
    of it can take the radial path)."""
    if isotropic:
        return Gaussian(sigma=jnp.sqrt(cov[..., 0, 0]), mean=mean)
    return Gaussian(cov=cov, mean=mean)


def convolve(a: AbstractSlopeDensity, b: AbstractSlopeDensity) -> AbstractSlopeDensity | None:
    """``a ∗ b`` in closed form, or None."""
    if isinstance(a, Delta):
        return b if a.mean is None else b.shifted(a.mean)
    if isinstance(b, Delta):
        return convolve(b, a)
    if isinstance(a, Gaussian) and isinstance(b, Gaussian):
        return _gaussian(a.cov + b.cov, _sum_means(a.mean, b.mean), a.isotropic and b.isotropic)
    for mix, other in ((a, b), (b, a)):
        if isinstance(mix, Mixture):
            parts = [convolve(c, other) for c in mix.components]
            if all(p is not None for p in parts):
                return Mixture(mix.weights, parts)
    return None


def has_closed_form(lobe: AbstractSlopeDensity, s_from: AbstractSlopeDensity, s_to: AbstractSlopeDensity) -> bool:
    """Whether :func:`convolve` and :func:`deconvolve` handle these families (structure only,
    never values: the same answer under ``jax.jit``)."""
    a = convolve(lobe, s_from)
    if a is None:
        return False
    if isinstance(s_to, Delta):
        return True
    if not isinstance(s_to, Gaussian):
        return False
    return isinstance(a, Gaussian) or (isinstance(a, Mixture) and all(isinstance(c, Gaussian) for c in a.components))


def deconvolve(a: AbstractSlopeDensity, b: AbstractSlopeDensity, check: bool = True) -> AbstractSlopeDensity | None:
    """``c`` with ``c ∗ b = a`` in closed form, or None; raises when no density ``c`` exists
    (``check=False``: traced values are not checked; see :func:`brdfscale.evolve`)."""
    if isinstance(b, Delta):
        return a if b.mean is None else a.shifted(-b.mean)
    if isinstance(a, Gaussian) and isinstance(b, Gaussian):
        cov = a.cov - b.cov
        lo, _ = eig2(cov)
        if is_concrete(lo):
            if not np.all(np.asarray(lo) > 0):
                raise NoBRDFAtScaleError(NEGATIVE_VARIANCE + f" (smallest eigenvalue {float(np.min(lo)):.6g})")
        elif check:
            cov = eqx.error_if(cov, jnp.any(lo <= 0), NEGATIVE_VARIANCE)
        return _gaussian(cov, _sum_means(a.mean, _neg(b.mean)), a.isotropic and b.isotropic)
    if isinstance(a, Mixture) and isinstance(b, Gaussian):
        parts = [deconvolve(c, b, check) if isinstance(c, Gaussian) else None for c in a.components]
        if all(p is not None for p in parts):
            return Mixture(a.weights, parts)
    return None
