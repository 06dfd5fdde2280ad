"""Directions, slopes and half vectors.

Conventions (docs/conventions.md §1; seed §2 and §4):

* Global frame: ``z`` is the macroscopic surface normal. ``i`` points from the surface to
  the light and ``o`` from the surface to the detector; both are unit vectors with z > 0.
* The slope of a normal ``n`` (``n_z > 0``) is ``m(n) = (n_x/n_z, n_y/n_z)``; this is the
  seed's ``m = n/(n·z) − z`` (§4) without its zero z-component. Slopes are dimensionless.
* The half-vector slope is ``m_s(i, o) = m(h)`` with ``h = (i + o)/|i + o|``: the slope of
  the mirror facet that reflects ``i`` into ``o``.
* Area elements: ``d²m = dω_n / cos³θ_n``. A normal distribution ``D`` normalised as
  ``∫ D cosθ dω = 1`` and its slope density are related by ``P22(m) = D(n) cos⁴θ_n``.

All functions are pure, jit-compatible and differentiable; inputs broadcast over leading
dimensions. The ``validate_*`` helpers check concrete (non-traced) inputs and raise
:class:`~brdfscale.InvalidInputError`; under ``jax.jit`` they pass values through.
"""

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._errors import InvalidInputError
from ._slopes import half_slope_of_valid, microfacet_factor_of_valid
from ._validation import is_concrete, last_axis


__all__ = [
    "direction_to_slope",
    "slope_to_direction",
    "half_vector",
    "half_slope",
    "solid_angle_per_slope_area",
    "microfacet_factor",
    "reflect",
    "validate_directions",
    "validate_slopes",
]


def validate_directions(v: ArrayLike, name: str = "direction", atol: float = 1e-6):
    """Check that ``v`` has shape (..., 3) (unit vectors in the surface frame, z = the
    macroscopic normal), is real, finite, unit length and points upwards.

    Returns ``v`` as a JAX array. Raises :class:`InvalidInputError` otherwise.
    """
    v = last_axis(v, 3, name)  # shape, real, finite
    if is_concrete(v):
        a = np.asarray(v)
        norm = np.linalg.norm(a, axis=-1)
        if np.any(np.abs(norm - 1) > max(atol, 1e2 * np.finfo(a.dtype).eps if a.dtype.kind == "f" else atol)):
            raise InvalidInputError(f"{name} must be unit vectors; got norms in [{norm.min():.6g}, {norm.max():.6g}].")
        if np.any(a[..., 2] <= 0):
            raise InvalidInputError(
                f"{name} must lie in the upper hemisphere (z > 0, z = macroscopic normal); "
                f"smallest z component is {a[..., 2].min():.6g}."
            )
    return v


def validate_slopes(m: ArrayLike, name: str = "slopes"):
    """Check that ``m`` has shape (..., 2) (slope components m_x, m_y), is real and finite;
    return it as a JAX array."""
    return last_axis(m, 2, name)


def direction_to_slope(n: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 2"]:
    """Slope ``m = (n_x/n_z, n_y/n_z)`` of a unit direction in the upper hemisphere (seed §4)."""
    n = validate_directions(n, "n")
    return n[..., :2] / n[..., 2:3]


def slope_to_direction(m: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch 3"]:
    """Unit normal with slope ``m``, the inverse of :func:`direction_to_slope`: ``(m, 1)/√(1+|m|²)``."""
    m = validate_slopes(m, "m")
    one = jnp.ones(m.shape[:-1] + (1,), dtype=m.dtype)
    v = jnp.concatenate([m, one], axis=-1)
    return v / jnp.linalg.norm(v, axis=-1, keepdims=True)


def half_vector(i: Float[ArrayLike, "#*batch 3"], o: Float[ArrayLike, "#*batch 3"]) -> Float[Array, "*batch 3"]:
    """``h = (i + o)/|i + o|``, the normal of the mirror facet reflecting ``i`` into ``o``
    (unit directions in the upper hemisphere)."""
    s = validate_directions(i, "i") + validate_directions(o, "o")
    return s / jnp.linalg.norm(s, axis=-1, keepdims=True)


def half_slope(i: Float[ArrayLike, "#*batch 3"], o: Float[ArrayLike, "#*batch 3"]) -> Float[Array, "*batch 2"]:
    """Half-vector slope ``m_s(i, o) = m(h)``; the normalisation of ``h`` cancels."""
    return half_slope_of_valid(validate_directions(i, "i"), validate_directions(o, "o"))


def solid_angle_per_slope_area(m: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch"]:
    """Jacobian ``dω_n / d²m = cos³θ_n = (1 + |m|²)^{−3/2}``."""
    m = jnp.asarray(m)
    return (1.0 + jnp.sum(m**2, axis=-1)) ** -1.5


def reflect(i: Float[ArrayLike, "#*batch 3"], n: Float[ArrayLike, "#*batch 3"]) -> Float[Array, "*batch 3"]:
    """Mirror reflection of ``i`` (pointing away from the surface) about the normal ``n``."""
    i = jnp.asarray(i)
    n = jnp.asarray(n)
    return 2 * jnp.sum(i * n, axis=-1, keepdims=True) * n - i


def microfacet_factor(i: Float[ArrayLike, "#*batch 3"], o: Float[ArrayLike, "#*batch 3"]) -> Float[Array, "*batch"]:
    """Geometric factor ``1 / (4 cosθ_o cos⁴θ_h)`` that turns a slope-space lobe into ``ρ``.

    Mirror microfacets with normal distribution D (``∫ D cosθ dω = 1``), no masking and
    Fresnel factor 1 give ``f = D(h) / (4 cosθ_i cosθ_o)``: the facets with normals in dω_h
    have area ``D dω_h`` per unit macro-area, intercept ``(i·h)`` of the beam and send it into
    ``dω_o = 4 (h·o) dω_h``, and ``i·h = h·o``. With the seed's ``ρ = β cosθ_i`` (§2) and
    ``D = P22 / cos⁴θ_h`` this is ``ρ(i, o) = P22(m_s) · microfacet_factor(i, o)``.
    """
    return microfacet_factor_of_valid(validate_directions(i, "i"), validate_directions(o, "o"))
