"""Rotations as z-y-z Euler angles and 3×3 matrices (seed Eq. 5.1–5.2, docs/conventions.md §3).

``Γ(α, β, γ) = U(α) A(β) U(γ)``: *active* rotations, ``U`` about z and ``A`` about y,

    U(α) = [[cos α, −sin α, 0], [sin α, cos α, 0], [0, 0, 1]],
    A(β) = [[cos β, 0, sin β], [0, 1, 0], [−sin β, 0, cos β]],

with ``0 ≤ α, γ < 2π`` and ``0 ≤ β ≤ π``. A facet's orientation Γ maps the facet frame to
the global frame: its columns are the facet's tangent, bitangent and normal ``n = Γ ẑ``,
whose polar angle is β and azimuth α.
"""

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._errors import InvalidInputError
from .._validation import as_float_array, is_concrete


__all__ = ["euler_to_matrix", "matrix_to_euler", "check_rotation", "ROTATION_TOLERANCE"]


def _rot_z(t):
    c, s = jnp.cos(t), jnp.sin(t)
    o, z = jnp.ones_like(t), jnp.zeros_like(t)
    return jnp.stack([jnp.stack([c, -s, z], -1), jnp.stack([s, c, z], -1), jnp.stack([z, z, o], -1)], -2)


def _rot_y(t):
    c, s = jnp.cos(t), jnp.sin(t)
    o, z = jnp.ones_like(t), jnp.zeros_like(t)
    return jnp.stack([jnp.stack([c, z, s], -1), jnp.stack([z, o, z], -1), jnp.stack([-s, z, c], -1)], -2)


def euler_to_matrix(
    alpha: Float[ArrayLike, "*#batch"], beta: Float[ArrayLike, "*#batch"], gamma: Float[ArrayLike, "*#batch"]
) -> Float[Array, "*batch 3 3"]:
    """``Γ(α, β, γ) = U(α) A(β) U(γ)`` (seed Eq. 5.1–5.2); angles in radians, broadcast."""
    alpha = as_float_array(alpha, "alpha")
    beta = as_float_array(beta, "beta")
    gamma = as_float_array(gamma, "gamma")
    alpha, beta, gamma = jnp.broadcast_arrays(alpha, beta, gamma)
    return _rot_z(alpha) @ _rot_y(beta) @ _rot_z(gamma)


ROTATION_TOLERANCE = 1e-6
"""Largest ``max |ΓᵀΓ − I|`` accepted of a concrete rotation matrix (entries of a rotation are ≤ 1
in modulus, so this is a relative tolerance)."""


def check_rotation(rotation, name: str = "rotation") -> Float[Array, "*batch 3 3"]:
    """``rotation`` as a floating array of shape (..., 3, 3), validated when concrete: finite,
    orthogonal to :data:`ROTATION_TOLERANCE` and with determinant +1 (a proper rotation).
    Traced values pass through unchecked."""
    r = as_float_array(rotation, name)
    if r.ndim < 2 or r.shape[-2:] != (3, 3):
        raise InvalidInputError(f"{name} must have shape (..., 3, 3); got {r.shape}.")
    if is_concrete(r) and r.size:
        a = np.asarray(r, dtype=np.float64)
        residual = np.abs(np.swapaxes(a, -1, -2) @ a - np.eye(3)).max(axis=(-2, -1))
        det = np.linalg.det(a)
        bad = (residual > ROTATION_TOLERANCE) | (det < 0)
        if np.any(bad):
            err = float(residual.max())
            first = tuple(int(k) for k in np.argwhere(bad)[0])
            at = f" (first offending matrix at index {first})" if first else ""
            raise InvalidInputError(
                f"{name} must be a proper rotation matrix: orthogonal (max |ΓᵀΓ − I| ≤ {ROTATION_TOLERANCE:g}) with "
                f"determinant +1; got max |ΓᵀΓ − I| = {err:.3g}{at}, min det = {float(det.min()):.3g}."
            )
    return r


def matrix_to_euler(
    rotation: Float[ArrayLike, "*batch 3 3"],
) -> tuple[Float[Array, "*batch"], Float[Array, "*batch"], Float[Array, "*batch"]]:
    """z-y-z Euler angles ``(α, β, γ)`` of rotation matrices, the inverse of :func:`euler_to_matrix`.

    ``β = atan2(√(Γ₁₃² + Γ₂₃²), Γ₃₃) ∈ [0, π]``, ``α = atan2(Γ₂₃, Γ₁₃)``, ``γ = atan2(Γ₃₂, −Γ₃₁)``,
    with α, γ in [0, 2π). At the poles (β = 0 or π) only α ± γ is defined; there γ = 0.
    Raises :class:`InvalidInputError` for concrete inputs that are not proper rotations
    (:func:`check_rotation`: tolerance 1e-6).
    """
    r = check_rotation(rotation, "rotation")
    sin_b = jnp.hypot(r[..., 0, 2], r[..., 1, 2])
    beta = jnp.arctan2(sin_b, r[..., 2, 2])
    two_pi = 2 * jnp.pi
    pole = sin_b < 1e-12
    safe = jnp.where(pole, 1.0, 0.0)
    alpha_gen = jnp.arctan2(r[..., 1, 2], r[..., 0, 2] + safe)  # + safe: no 0/0 (nor NaN gradient) at a pole
    gamma_gen = jnp.arctan2(r[..., 2, 1], -r[..., 2, 0] + safe)
    # at a pole Γ = U(α ± γ) (β = 0) or U(α) A(π) U(γ) = U(α − γ) A(π): put everything into α, γ = 0
    alpha_pole = jnp.where(
        r[..., 2, 2] > 0, jnp.arctan2(r[..., 1, 0], r[..., 0, 0]), jnp.arctan2(-r[..., 1, 0], -r[..., 0, 0])
    )
    alpha = jnp.where(pole, alpha_pole, alpha_gen)
    gamma = jnp.where(pole, 0.0, gamma_gen)
    return jnp.mod(alpha, two_pi), beta, jnp.mod(gamma, two_pi)
