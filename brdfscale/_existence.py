"""The existence check of an evolved BRDF: its predicate, its messages and their translation.

One place for what every evolution (slope space, the planner's steps, SO(3)) checks before it
hands back a lobe (seed Eq. 4.4 read backwards: going finer is a deconvolution, which has a
non-negative solution only for data that support it):

* a non-negative lobe ``g`` of mass 1 has ``|G(W)| ≤ G(0) = 1`` for every W
  (:func:`transform_exceeds_one`, with the float64 slack :data:`CF_EXCESS`);
* and its values are ``≥ 0`` — evolved values below ``−tol`` of the lobe's peak (the error the
  evaluation honours) mean no non-negative lobe exists, even where ``|G| ≤ 1`` holds, e.g. with
  δ components in mixture statistics (:func:`negative_beyond`);
* a deconvolution that overflows (SO(3) blocks) has no finite answer (:func:`not_finite`).

Where the values are concrete the check raises :class:`brdfscale.NoBRDFAtScaleError` at once
(:func:`require`). Where they are traced (inside ``jax.jit``, ``grad``, ``vmap``) it is attached
to the result with ``equinox.error_if`` (:func:`attach`) and fires when the program runs: inside
the library's own compiled evaluations :func:`translated` turns it back into
``NoBRDFAtScaleError``; inside a *user's* ``jax.jit`` JAX offers no way to raise a chosen
exception type from a running program, so it reaches the user as the exception JAX raises for a failed run-time check
(``equinox.EquinoxRuntimeError``, ``jax.errors.JaxRuntimeError``, or — JAX 0.10 on the CPU, at
``block_until_ready`` — a ``ValueError`` from its callback) whose text holds the library's
message, starting with :data:`NO_BRDF`.
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._errors import NoBRDFAtScaleError
from ._validation import is_concrete


CF_EXCESS = 1e-6
"""Slack of the test ``|G| ≤ 1``: float64 evaluation of a quotient of transforms that is
exactly 1 at W = 0 can exceed 1 by rounding."""

NO_BRDF = "no BRDF exists at the requested scale"
"""How every existence message starts (and how :func:`translated` recognises them)."""

TRANSFORM_ABOVE_ONE = (
    NO_BRDF + ": the evolved lobe's transform exceeds 1 in modulus, which no non-negative "
    "lobe has (evolving towards a finer scale than the data support). Choose a coarser target "
    "scale or set regularisation > 0."
)
NEGATIVE_LOBE = (
    NO_BRDF + ": the evolved lobe takes negative values beyond its error target (the deconvolution "
    "towards a finer scale has no non-negative solution, e.g. with point-mass components in the "
    "statistics). Choose a coarser target scale or set regularisation > 0."
)
NEGATIVE_VARIANCE = (
    NO_BRDF + ": evolving this Gaussian lobe would need a covariance that is not positive definite "
    "(a negative variance). The target statistics are wider than the lobe and source statistics "
    "together; choose a coarser target scale, or a lobe measured at a finer scale."
)
NOT_FINITE = NO_BRDF + ": dividing out the statistics at μ gives non-finite values"


def transform_exceeds_one(peak):
    """``|G|``'s largest value found exceeds 1 (or is NaN): no non-negative lobe."""
    excess = peak - 1
    return (excess > CF_EXCESS) | jnp.isnan(excess)


def negative_beyond(values, peak, tol: float):
    """Some value lies below ``−tol · peak``."""
    return jnp.min(values) < -tol * peak


def not_finite(values):
    return ~jnp.all(jnp.isfinite(values))


def attach(value, failed, message: str):
    """``value`` with the check attached: raises ``message`` when ``failed`` holds at run time
    (no check when ``failed`` is None)."""
    if failed is None:
        return value
    return eqx.error_if(value, failed, message)


def require(value, failed, message: str):
    """:func:`attach` for traced values; for concrete ones, raise at once."""
    if failed is None:
        return value
    if is_concrete(failed):
        if bool(np.any(np.asarray(failed))):
            raise NoBRDFAtScaleError(message)
        return value
    return eqx.error_if(value, failed, message)


_RUNTIME_ERRORS = (eqx.EquinoxRuntimeError, jax.errors.JaxRuntimeError, ValueError)  # ValueError: JAX's CPU callback


def message_of(err: BaseException) -> str | None:
    """The library's existence message carried by an equinox/JAX runtime error, or None."""
    text = str(err)
    start = text.find(NO_BRDF)
    if start < 0:
        return None
    for known in (TRANSFORM_ABOVE_ONE, NEGATIVE_LOBE, NEGATIVE_VARIANCE):
        if text.startswith(known, start):
            return known
    return text[start:].split("\n", 1)[0].strip()


def translated(fn):
    """Wrap a compiled evaluation: outside any trace, its run-time existence check becomes
    :class:`NoBRDFAtScaleError` (with the library's message, not JAX's traceback)."""

    @functools.wraps(fn)
    def call(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except _RUNTIME_ERRORS as err:
            message = message_of(err)
            if message is None:
                raise
            raise NoBRDFAtScaleError(message) from None

    return call
