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

GENERIC_ADVICE = (
    " Towards a finer scale (s_to wider than s_from: a deconvolution) choose a coarser target scale or set "
    "regularisation > 0; towards a coarser scale the lobe and the statistics are not consistent (noise, "
    "statistics that do not nest): regularise (regularisation='auto' searches for a λ at which the lobe "
    "exists) or loosen tol."
)
"""The advice of a check attached to traced values, where the direction is not known; a concrete
failure in :func:`brdfscale.evolve` replaces it by :func:`advice` for its direction and λ."""

TRANSFORM_ABOVE_ONE = (
    NO_BRDF + ": the evolved lobe's transform exceeds 1 in modulus, which no non-negative lobe has." + GENERIC_ADVICE
)
NEGATIVE_LOBE = (
    NO_BRDF + ": the evolved lobe takes negative values beyond its error target (below −tol of its peak; e.g. "
    "point-mass components in the statistics, or noise in a tabulated lobe)." + GENERIC_ADVICE
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


def direction(s_from, s_to) -> str | None:
    """``"finer"`` when ``s_to`` is wider than ``s_from`` (Eq. 4.4 then divides by the faster-decaying
    transform: a deconvolution), ``"coarser"`` when narrower, ``"same"`` when neither, None for traced
    values. Measured on the transforms, which every density has (heavy tails included): the mean of
    ``|S_to| − |S_from|`` over 4 directions × 16 frequencies ``k ∈ [10⁻², 10]/R``, ``R`` the larger
    support radius at 10⁻³ (``|S|`` is larger for the narrower density; coarser facets are narrower,
    seed §3). Verified in ``tests/test_regularisation.py``."""
    if not is_concrete((s_from, s_to)):
        return None
    radius = max(float(s_from.support_radius(1e-3)), float(s_to.support_radius(1e-3)))
    if not np.isfinite(radius) or radius <= 0:
        return "same"
    k = np.logspace(-2.0, 1.0, 16) / radius
    angles = np.arange(4) * np.pi / 4
    W = jnp.asarray(np.stack([np.outer(k, np.cos(angles)), np.outer(k, np.sin(angles))], axis=-1))
    diff = float(np.mean(np.abs(np.asarray(s_to.cf(W))) - np.abs(np.asarray(s_from.cf(W)))))
    if abs(diff) <= 1e-12:
        return "same"
    return "coarser" if diff > 0 else "finer"


def regularisation_text(lam, note: str | None = None) -> str:
    """The regularisation in force, as :func:`advice` states it."""
    if lam is None:
        return "none (λ = 0)"
    value = float(np.asarray(lam))
    if value == 0:
        return "none (λ = 0)"
    return f"Tikhonov λ = {value:.3g}" + ("" if note is None else f" ({note})")


def advice(message: str, way: str | None, in_force: str) -> str:
    """``message`` (one of the checks' texts) with its generic advice replaced by the advice for
    the evolution's direction ``way`` (:func:`direction`) and the regularisation in force."""
    head = message.replace(GENERIC_ADVICE, "")
    if way == "finer":
        tail = (
            " The evolution goes towards a finer scale (s_to is wider than s_from): a deconvolution, which has a "
            f"non-negative solution only where the data support it. Regularisation in force: {in_force}. Choose a "
            "coarser target scale, or regularise (regularisation='auto' searches for a λ at which the lobe exists, "
            "or pass a larger λ)."
        )
    elif way in ("coarser", "same"):
        what = "a coarser scale (s_to is narrower than s_from)" if way == "coarser" else "the same scale"
        tail = (
            f" The evolution goes towards {what}, a blur for statistics that nest (s_from = s_to ∗ a density); "
            "these are not consistent with the lobe (noise in a tabulated lobe, measured statistics that do not "
            f"nest exactly). Regularisation in force: {in_force}. Pass regularisation='auto' (it searches for a λ at "
            "which the lobe exists), a larger tol (values below −tol of the peak are refused), or smoother "
            "statistics (a fitted or measured scale law)."
        )
    else:
        return message
    return head + tail


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
