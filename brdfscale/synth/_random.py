"""Explicit random seeds: every generator of this package takes ``seed=`` and nothing else."""

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import InvalidInputError


def as_generator(seed) -> np.random.Generator:
    """A NumPy generator from an explicit seed.

    Accepted: a non-negative ``int`` (reproducible), a :class:`numpy.random.Generator`
    (used as is, so successive calls draw fresh numbers), or a JAX PRNG key (typed or raw
    ``uint32[2]``), whose bits seed a NumPy generator — the same key always gives the same
    field. Synthesis runs in NumPy because its FFTs and histograms on 4096² grids are
    memory-bound work that gains nothing from tracing.
    """
    if isinstance(seed, np.random.Generator):
        return seed
    if isinstance(seed, (bool, np.bool_)):
        raise InvalidInputError("seed must be an int ≥ 0, a numpy Generator or a JAX PRNG key; got a bool.")
    if isinstance(seed, (int, np.integer)):
        if seed < 0:
            raise InvalidInputError(f"seed must be ≥ 0; got {seed}.")
        return np.random.default_rng(int(seed))
    if isinstance(seed, jax.Array):
        data = jax.random.key_data(seed) if jnp.issubdtype(seed.dtype, jax.dtypes.prng_key) else seed
        words = np.asarray(data)
        if words.dtype != np.uint32 or words.ndim != 1:
            raise InvalidInputError(
                f"a JAX seed must be a single PRNG key; got an array of shape {words.shape}, dtype {words.dtype}."
            )
        return np.random.default_rng([int(w) for w in words])
    raise InvalidInputError(
        f"seed must be an int ≥ 0, a numpy.random.Generator or a JAX PRNG key; got {type(seed).__name__}."
    )


def seed_record(seed):
    """A JSON-friendly record of the seed for provenance metadata (None when not reproducible)."""
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
        return int(seed)
    if isinstance(seed, jax.Array):
        data = jax.random.key_data(seed) if jnp.issubdtype(seed.dtype, jax.dtypes.prng_key) else seed
        return {"jax_key": [int(w) for w in np.asarray(data)]}
    return None
