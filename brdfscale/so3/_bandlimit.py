"""Band limits from a lobe's width and an error target.

A lobe whose degree-J content decays like ``a_J`` (e.g. a Gaussian of angular standard
deviation σ per axis: ``a_J = exp(−σ² J(J+1)/2)``, the heat kernel of SO(3)) and is
truncated to J < B has, relative to its peak, the error

    ε(B) = Σ_{J≥B} (2J+1)² a_J / Σ_{J≥0} (2J+1)² a_J,

an exact bound for an isotropic (class-function) lobe with a_J ≥ 0 — its value at the
identity is Σ (2J+1)² a_J / 8π² and |χ_J| ≤ 2J+1 elsewhere — and the working estimate for
anisotropic lobes, with a_J the decay along the narrowest axis. :func:`band_limit` returns
the smallest B with ε(B) ≤ tol; the benchmark measures the error actually reached.
"""

from collections.abc import Callable

import numpy as np

from .._errors import InvalidInputError
from ._grid import MAX_BAND_LIMIT


__all__ = ["band_limit", "truncation_error", "gaussian_spectrum"]

_J_MAX = 100_000


def gaussian_spectrum(width: float) -> Callable[[np.ndarray], np.ndarray]:
    """``a_J = exp(−σ² J(J+1)/2)`` for a Gaussian lobe of angular std σ = ``width`` (radians)."""
    if not (isinstance(width, (int, float, np.floating)) and np.isfinite(width) and width > 0):
        raise InvalidInputError(f"width must be a positive angle in radians; got {width!r}.")
    return lambda J: np.exp(-(width**2) * J * (J + 1) / 2)


def _spectrum(lobe):
    if callable(lobe):
        return lobe
    return gaussian_spectrum(lobe)


def _weights(spectrum):
    J = np.arange(_J_MAX, dtype=float)
    w = (2 * J + 1) ** 2 * np.abs(np.asarray(spectrum(J), dtype=float))
    if not np.all(np.isfinite(w)) or w.sum() <= 0:
        raise InvalidInputError("the lobe's spectrum must be finite and not identically zero.")
    return w


def truncation_error(lobe, B: int) -> float:
    """``ε(B)`` for a lobe given by its angular width σ (radians) or a spectrum ``a(J)``.

    ``B``: the band limit (degrees J < B kept), an integer in [0, 100000] (ε(0) = 1); the
    spectrum is summed over J < 100000.
    """
    if isinstance(B, bool) or not isinstance(B, (int, np.integer)) or not 0 <= B <= _J_MAX:
        raise InvalidInputError(f"B must be an integer band limit in [0, {_J_MAX}] (degrees J < B kept); got {B!r}.")
    w = _weights(_spectrum(lobe))
    return float(w[B:].sum() / w.sum())


def band_limit(lobe, tol: float = 1e-8) -> tuple[int, float]:
    """The smallest band limit B with ``ε(B) ≤ tol``, and ``ε(B)``.

    Args:
        lobe: the angular width σ in radians (a Gaussian lobe) or a callable spectrum
            ``a(J)`` — e.g. :meth:`AnisotropicMicrofacetLobe.spectrum`.
        tol: the error target relative to the lobe's peak, in (0, 1).

    Raises:
        InvalidInputError: tol outside (0, 1), or the lobe too narrow for B ≤ MAX_BAND_LIMIT.
    """
    if not 0 < tol < 1:
        raise InvalidInputError(f"tol must lie in (0, 1); got {tol!r}.")
    w = _weights(_spectrum(lobe))
    tail = np.cumsum(w[::-1])[::-1] / w.sum()  # tail[B] = ε(B)
    ok = np.nonzero(tail <= tol)[0]
    B = int(max(1, ok[0])) if ok.size else _J_MAX
    if B > MAX_BAND_LIMIT:
        raise InvalidInputError(
            f"the lobe needs band limit B = {B} > {MAX_BAND_LIMIT} for tol = {tol}; widen the lobe, "
            "relax tol, or use the slope-space path (brdfscale.evolve) for such narrow lobes."
        )
    return B, float(tail[B])
