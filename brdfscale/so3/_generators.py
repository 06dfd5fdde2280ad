"""Angular momentum in the spin-J representation and rotational-diffusion generators.

Matrices act on ``|J M⟩``, M = −J … J, in the convention of :mod:`._wigner`:
``J_z = diag(M)``, ``J₊|J M⟩ = c_M |J M+1⟩`` with ``c_M = √(J(J+1) − M(M+1))``,
``J_x = (J₊ + J₋)/2``, ``J_y = (J₊ − J₋)/(2i)``, so that ``D^J(rotation by θ about n) =
exp(−iθ n·J)`` and ``d^J(β) = exp(−iβ J_y)``.

Rotational diffusion with coefficients (D_x, D_y, D_z) about the facet's own axes has the
generator ``G = D_x J_x² + D_y J_y² + D_z J_z²`` (real, symmetric, positive semi-definite):
the density that starts as δ at the identity has operator-normalised coefficients
``exp(−τ G^J)`` after "time" τ (units: rad² per unit τ per D). Isotropic diffusion
(D_x = D_y = D_z = D) gives ``exp(−τ D J(J+1)) I``, the heat kernel of SO(3); each tilt
axis then has, for small τD, angular variance 2Dτ. ``G`` is pentadiagonal:

    G_{MM} = (D_x + D_y)/2 · (J(J+1) − M²) + D_z M²,   G_{M+2,M} = G_{M,M+2} = (D_x − D_y)/4 · c_{M+1} c_M.
"""

import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np
from jaxtyping import Array, ArrayLike, Complex, Float

from .._errors import InvalidInputError
from .._validation import as_float_array, is_concrete
from ._grid import check_band_limit
from ._wigner import check_degree


__all__ = ["angular_momentum", "diffusion_generator", "diffusion_operator"]

DiffusionCoefficients = Float[ArrayLike, ""] | Float[ArrayLike, "3"] | Sequence[Float[ArrayLike, ""]]
"""What a diffusion argument ``D`` may be (:func:`check_diffusion`): a real scalar (isotropic
diffusion) or the three coefficients (D_x, D_y, D_z), as an array or a sequence of reals."""


def angular_momentum(J: int) -> tuple[Complex[np.ndarray, "n n"], ...]:
    """``(J_x, J_y, J_z)`` for degree J as complex NumPy matrices (rows/cols M = −J … J: n = 2J+1)."""
    J = check_degree(J)
    M = np.arange(-J, J + 1)
    raise_op = np.diag(np.sqrt(J * (J + 1) - M[:-1] * (M[:-1] + 1.0)), -1).astype(complex)
    lower = raise_op.T.copy()
    return (raise_op + lower) / 2, (raise_op - lower) / 2j, np.diag(M).astype(complex)


def check_diffusion(D: DiffusionCoefficients) -> Float[Array, "3"]:
    d = as_float_array(D, "D")
    d = jnp.broadcast_to(d, (3,)) if d.ndim == 0 else d
    if d.shape != (3,):
        raise InvalidInputError(f"D must be a scalar (isotropic) or (D_x, D_y, D_z); got shape {d.shape}.")
    if is_concrete(d) and np.any(np.asarray(d) < 0):
        raise InvalidInputError(f"diffusion coefficients must be ≥ 0; got {np.asarray(d)!r}.")
    return d


def _generator_bands(B: int):
    """Per degree (padded to 2B−1): ``J(J+1) − M²``, ``M²`` and ``c_{M+1} c_M / 4`` on |M| ≤ J."""
    J = np.arange(B)[:, None]
    M = np.arange(-(B - 1), B)[None, :]
    inside = np.abs(M) <= J
    tilt = np.where(inside, J * (J + 1) - M**2, 0.0)
    twist = np.where(inside, M**2, 0.0)
    c = lambda k: np.sqrt(np.maximum(J * (J + 1) - k * (k + 1.0), 0.0))
    off = np.where(inside & (M + 2 <= J), c(M + 1) * c(M) / 4, 0.0)[:, :-2]  # (M+2, M) entries
    return tilt, twist, off


def diffusion_generator(B: int, D: DiffusionCoefficients) -> Float[Array, "B 2*B-1 2*B-1"]:
    """Blocks ``G^J = D_x J_x² + D_y J_y² + D_z J_z²`` for J < B, zero-padded to (2B−1)².

    ``D``: a scalar (isotropic) or (D_x, D_y, D_z), ≥ 0; differentiable in D.
    """
    B = check_band_limit(B)
    d = check_diffusion(D)
    tilt, twist, off = (jnp.asarray(x, d.dtype) for x in _generator_bands(B))
    diag = (d[0] + d[1]) / 2 * tilt + d[2] * twist
    band = (d[0] - d[1]) * off
    idx = np.arange(2 * B - 1)
    G = jnp.zeros((B, 2 * B - 1, 2 * B - 1), d.dtype).at[:, idx, idx].set(diag)
    G = G.at[:, idx[2:], idx[:-2]].set(band).at[:, idx[:-2], idx[2:]].set(band)
    return G


def diffusion_operator(B: int, D: DiffusionCoefficients, tau: Float[ArrayLike, ""]) -> Float[Array, "B 2*B-1 2*B-1"]:
    """``exp(−τ G^J)`` per degree (identity on the padding), by ``jax.scipy.linalg.expm``.

    The operator-normalised coefficients of the rotational-diffusion density after time τ
    (a real symmetric matrix per block, so the density is inversion-symmetric: s = q).
    """
    t = as_float_array(tau, "tau")
    if is_concrete(t) and float(t) < 0:
        raise InvalidInputError(f"tau must be ≥ 0 (a diffusion time); got {float(t)}.")
    return block_expm(-t * diffusion_generator(B, D))


def block_expm(A: Float[ArrayLike, "B 2*B-1 2*B-1"]) -> Float[Array, "B 2*B-1 2*B-1"]:
    """``exp(A^J)`` per degree by ``jax.scipy.linalg.expm`` (Padé with scaling and squaring;
    absolute accuracy ~1e-11 on the blocks met here). Zero padding maps to the identity.

    The blocks go through ``lax.map``, not a batched call: batching turns expm's
    data-dependent branches into selects, so every block would pay for the maximal number
    of squarings."""
    return _block_expm(jnp.asarray(A))


@jax.jit
def _block_expm(A):
    return jax.lax.map(functools.partial(jsl.expm, max_squarings=48), A)
