"""Argument checks shared by the constructors.

Checks run on concrete values only: under ``jax.jit``/``vmap``/``grad`` the arguments are
tracers, their values are unknown and they pass through unchanged (the fitting code keeps
traced parameters on their valid domains by reparameterisation).

JAX is imported inside the checks that need it, so the host-side ones (numbers, NumPy arrays)
serve JAX-free paths such as ``brdfscale info`` on a measurement file.
"""

import math
import operator

import numpy as np

from ._errors import InvalidInputError


def is_concrete(x) -> bool:
    """True when ``x`` (and every leaf of it) holds actual values, not tracers."""
    import jax.core

    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(x))


def as_float_array(x, name: str):
    """``x`` as a floating JAX array (ints become the default float dtype)."""
    import jax.numpy as jnp

    if x is None:
        raise InvalidInputError(f"{name} is required.")
    if isinstance(x, (str, bytes)):
        raise InvalidInputError(f"{name} must be a real number or array; got the string {x!r}.")
    try:
        a = jnp.asarray(x)
    except (TypeError, ValueError) as err:
        raise InvalidInputError(f"{name} must be a real number or array; got {type(x).__name__}: {err}") from None
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
    import jax.numpy as jnp

    try:
        a = jnp.asarray(x)
    except (TypeError, ValueError) as err:
        raise InvalidInputError(
            f"{name} must be a real array of shape (..., {size}); got {type(x).__name__}: {err}"
        ) from None
    if a.ndim < 1 or a.shape[-1] != size:
        raise InvalidInputError(f"{name} must have shape (..., {size}); got shape {a.shape}.")
    if jnp.issubdtype(a.dtype, jnp.complexfloating) or a.dtype == bool:
        raise InvalidInputError(f"{name} must be real; got dtype {a.dtype}.")
    if is_concrete(a) and not np.all(np.isfinite(np.asarray(a))):
        raise InvalidInputError(
            f"{name} must be finite; got {np.count_nonzero(~np.isfinite(np.asarray(a)))} NaN or infinite entries."
        )
    return a


def facet_size(mu, name: str = "mu"):
    """A facet size μ: one positive number (map over scales with ``jax.vmap``)."""
    a = positive(mu, name, "a positive facet size")
    if a.ndim != 0:
        raise InvalidInputError(
            f"{name} must be a single facet size (a scalar; map over scales with jax.vmap); got shape {a.shape}."
        )
    return a


def real_array(x, name: str, ndim: int | None = None) -> np.ndarray:
    """``x`` as a finite float64 NumPy array, refusing what is not an array of real numbers.

    Integers are widened to float64; a bool, complex, string or object array (None, a
    ragged nest) is refused with InvalidInputError rather than cast (a complex value would
    lose its imaginary part, a bool become 0/1). ``ndim`` (when given) is checked too. The
    host-side (NumPy, float64 whatever ``jax_enable_x64`` says) counterpart of
    :func:`as_float_array`, for the containers that hold measured data.
    """
    try:
        a = np.asarray(x)
    except (TypeError, ValueError) as err:  # a ragged nest
        raise InvalidInputError(
            f"{name} must be an array of real numbers; got a {type(x).__name__} NumPy cannot read as one ({err})."
        ) from None
    if a.dtype.kind not in "fiu":
        what = {
            "c": "complex values are not cast to real",
            "b": "booleans are not numbers here",
            "O": "None or mixed objects",
            "U": "text",
            "S": "text",
        }.get(a.dtype.kind, "not numbers")
        raise InvalidInputError(f"{name} must be real numbers (float or int); got dtype {a.dtype} ({what}).")
    a = a.astype(float, copy=False)
    if ndim is not None and a.ndim != ndim:
        raise InvalidInputError(f"{name} must have {ndim} dimensions; got shape {a.shape}.")
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"{name} contains non-finite values ({np.count_nonzero(~np.isfinite(a))} NaN or inf).")
    return a


# -- plain Python arguments (counts, seeds, tolerances, switches) ---------------------------
RealNumber = float | np.floating | np.integer
"""The annotation of a real scalar argument that :func:`real` converts: a Python or NumPy real number
(Python ints included, by the numeric tower; NumPy's float32 or int64 are no Python floats)."""


def integer(value, name: str, minimum: int) -> int:
    """``value`` as an int ≥ ``minimum`` (Python or NumPy integers; not bool, not float)."""
    try:
        if isinstance(value, (bool, np.bool_)):
            raise TypeError
        number = operator.index(value)
    except TypeError:
        raise InvalidInputError(
            f"{name} must be an integer ≥ {minimum}; got {type(value).__name__} {value!r}."
        ) from None
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
            f"{name} must be a finite real number{bound}; got {type(value).__name__} {value!r}."
        ) from None
    if not math.isfinite(x) or x < minimum or (strict and x == minimum):
        raise InvalidInputError(f"{name} must be a finite number{bound}; got {value!r}.")
    return x


def flag(value, name: str) -> bool:
    """``value`` as a bool (Python or NumPy bool only)."""
    if not isinstance(value, (bool, np.bool_)):
        raise InvalidInputError(f"{name} must be True or False; got {type(value).__name__} {value!r}.")
    return bool(value)


def require_float64(what: str) -> None:
    """Refuse to run ``what`` unless JAX computes in float64 (``jax_enable_x64``).

    brdfscale changes no global JAX setting on import; work that needs float64 (the fits:
    optimistix refuses mixed float32/float64 structures, and σ-whitened residuals of
    well-measured lobes lose their precision in float32) calls this first.
    """
    import jax

    # jax.config's options are dynamic attributes, invisible to the type checker
    if not jax.config.jax_enable_x64:  # pyright: ignore[reportAttributeAccessIssue]
        raise InvalidInputError(
            f'{what} needs float64, and JAX is in float32 mode: add `jax.config.update("jax_enable_x64", True)` '
            "at the start of the script or notebook, before any JAX array is made (brdfscale changes no global "
            "setting itself)."
        )


def pitch(spacing) -> tuple[float, float]:
    """The pixel pitch ``(Δx, Δy)`` from one positive number or a pair of them."""
    if isinstance(spacing, (tuple, list, np.ndarray)) and np.ndim(spacing) == 1:
        if len(spacing) != 2:
            raise InvalidInputError(f"spacing must be one pixel pitch or a pair (dx, dy); got {len(spacing)} numbers.")
        return (
            real(spacing[0], "spacing dx", minimum=0, strict=True),
            real(spacing[1], "spacing dy", minimum=0, strict=True),
        )
    d = real(spacing, "spacing", minimum=0, strict=True)
    return (d, d)
