"""Arithmetic on the slope plane shared by the densities (:mod:`brdfscale.stats`), the
evolution operator and the plus-distributions: validated slopes, a norm with a finite gradient
at zero, the phase of a shift, the eigenvalues of 2×2 covariances, and the half-vector slope and
microfacet factor of validated directions (:mod:`brdfscale.geometry` validates, the lobes
evaluate many directions checked once). A private module of the
core (docs/architecture.md), so the model packages share it without importing each other's
private modules.
"""

import jax.numpy as jnp
from jaxtyping import Array

from ._validation import last_axis


def check_slopes(m, name: str = "m"):
    return last_axis(m, 2, name)


def safe_norm(v):
    """``|v|`` over the last axis with a zero (not NaN) gradient at ``v = 0``."""
    r2 = jnp.sum(v * v, axis=-1)
    positive = r2 > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, r2, 1.0)), 0.0)


def centred(m, offset, name: str = "m"):
    """Validated slopes ``m`` (..., 2) relative to ``offset`` (None: the origin)."""
    d = check_slopes(m, name)
    return d if offset is None else d - offset


def phase(W, offset):
    """``e^{−i W·offset}``, the transform of a shift by ``offset`` (1 when offset is None)."""
    if offset is None:
        return jnp.ones(jnp.shape(W)[:-1], dtype=jnp.result_type(W, 1j))
    return jnp.exp(-1j * jnp.sum(W * offset, axis=-1))


def shifted_cf(value, W, offset):
    """``value · e^{−i W·offset}`` as a complex array; no multiplication for a centred density."""
    if offset is None:
        return value.astype(jnp.result_type(value, 1j))
    return value * phase(W, offset)


def offset_norm(offset):
    return 0.0 if offset is None else jnp.linalg.norm(offset, axis=-1)


def add_offset(a, b):
    if a is None:
        return jnp.asarray(b)
    return a + jnp.asarray(b)


def eig2(cov):
    """The eigenvalues (smaller, larger) of symmetric 2×2 matrices ``cov`` (..., 2, 2)."""
    a, b, c = cov[..., 0, 0], cov[..., 0, 1], cov[..., 1, 1]
    mid, rad = (a + c) / 2, jnp.sqrt(((a - c) / 2) ** 2 + b**2)
    return mid - rad, mid + rad


def half_slope_of_valid(i: Array, o: Array) -> Array:
    """:func:`brdfscale.geometry.half_slope` of directions already validated (no second check)."""
    s = i + o
    return s[..., :2] / s[..., 2:3]


def microfacet_factor_of_valid(i: Array, o: Array) -> Array:
    """:func:`brdfscale.geometry.microfacet_factor` of directions already validated (no second check)."""
    s = i + o
    cos_h = s[..., 2] / jnp.linalg.norm(s, axis=-1)
    return 1.0 / (4.0 * o[..., 2] * cos_h**4)
