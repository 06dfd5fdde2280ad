"""Argument checks shared by the constructors.

Checks run on concrete values only: under ``jax.jit``/``vmap``/``grad`` the arguments are
tracers, their values are unknown and they pass through unchanged (the fitting code keeps
traced parameters on their valid domains by reparameterisation).
"""

import math
import operator

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
    """``x`` as a real array of shape (..., size); concrete values must be finite."""
    a = jnp.asarray(x)
    if a.ndim < 1 or a.shape[-1] != size:
        raise InvalidInputError(f"{name} must have shape (..., {size}); got shape {a.shape}.")
    if jnp.issubdtype(a.dtype, jnp.complexfloating) or a.dtype == bool:
        raise InvalidInputError(f"{name} must be real; got dtype {a.dtype}.")
    if is_concrete(a) and not np.all(np.isfinite(np.asarray(a))):
        raise InvalidInputError(f"{name} must be finite; got {np.count_nonzero(~np.isfinite(np.asarray(a)))} "
                                "NaN or infinite entries.")
    return a


def facet_size(mu, name: str = "mu"):
    """A facet size μ: one positive number (map over scales with ``jax.vmap``)."""
    a = positive(mu, name, "a positive facet size")
    if a.ndim != 0:
        raise InvalidInputError(f"{name} must be a single facet size (a scalar; map over scales with jax.vmap); "
                                f"got shape {a.shape}.")
    return a


# -- plain Python arguments (counts, seeds, tolerances, switches) ---------------------------
def integer(value, name: str, minimum: int) -> int:
    """``value`` as an int ≥ ``minimum`` (Python or NumPy integers; not bool, not float)."""
    try:
        if isinstance(value, (bool, np.bool_)):
            raise TypeError
        number = operator.index(value)
    except TypeError:
        raise InvalidInputError(f"{name} must be an integer ≥ {minimum}; got {type(value).__name__} {value!r}.") from None
    if number < minimum:
        raise InvalidInputError(f"{name} must be an integer ≥ {minimum}; got {value!r}.")
    return number


def real(value, name: str, *, minimum: float = -math.inf, strict: bool = False) -> float:
    """``value`` (a real scalar) as a finite float ≥ ``minimum`` (> ``minimum`` when ``strict``)."""
    bound = "" if minimum == -math.inf else f" {'>' if strict else '≥'} {minimum:g}"
    try:
        if isinstance(value, (bool, np.bool_, str, bytes)) or np.ndim(value) != 0 or np.iscomplexobj(value):
            raise TypeError
        x = float(value)
    except (TypeError, ValueError):
        raise InvalidInputError(
            f"{name} must be a finite real number{bound}; got {type(value).__name__} {value!r}.") from None
    if not math.isfinite(x) or x < minimum or (strict and x == minimum):
        raise InvalidInputError(f"{name} must be a finite number{bound}; got {value!r}.")
    return x


def flag(value, name: str) -> bool:
    """``value`` as a bool (Python or NumPy bool only)."""
    if not isinstance(value, (bool, np.bool_)):
        raise InvalidInputError(f"{name} must be True or False; got {type(value).__name__} {value!r}.")
    return bool(value)
