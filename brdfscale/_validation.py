"""Argument checks shared by the constructors.

Checks run on concrete values only: under ``jax.jit``/``vmap``/``grad`` the arguments are
tracers, their values are unknown and they pass through unchanged (the fitting code keeps
traced parameters on their valid domains by reparameterisation).
"""

import jax
import jax.numpy as jnp
import numpy as np

from ._errors import InvalidInputError


def is_concrete(x) -> bool:
    """True when ``x`` (and every leaf of it) holds actual values, not tracers."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(x))


def as_float_array(x, name: str):
    """``x`` as a floating JAX array (ints become the default float dtype)."""
    if x is None:
        raise InvalidInputError(f"{name} is required.")
    a = jnp.asarray(x)
    if not jnp.issubdtype(a.dtype, jnp.floating):
        if jnp.issubdtype(a.dtype, jnp.complexfloating) or a.dtype == bool:
            raise InvalidInputError(f"{name} must be real; got dtype {a.dtype}.")
        a = a.astype(jnp.result_type(float))
    if is_concrete(a) and not np.all(np.isfinite(np.asarray(a))):
        raise InvalidInputError(f"{name} must be finite; got {np.asarray(a)!r}.")
    return a


def positive(x, name: str, what: str = "a positive number"):
    a = as_float_array(x, name)
    if is_concrete(a) and not np.all(np.asarray(a) > 0):
        raise InvalidInputError(f"{name} must be {what}; got {np.asarray(a)!r}.")
    return a


def vector2(x, name: str):
    """A 2-vector (slope or offset) with shape (..., 2); None means the origin."""
    if x is None:
        return None
    a = as_float_array(x, name)
    if a.ndim < 1 or a.shape[-1] != 2:
        raise InvalidInputError(f"{name} must have shape (..., 2); got shape {a.shape}.")
    return a


def last_axis(x, size: int, name: str):
    a = jnp.asarray(x)
    if a.ndim < 1 or a.shape[-1] != size:
        raise InvalidInputError(f"{name} must have shape (..., {size}); got shape {a.shape}.")
    return a
