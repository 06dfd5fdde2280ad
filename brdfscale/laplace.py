"""The Laplace approximation of a least-squares fit and what its data determine — one policy for every fit.

A fit that minimises ``½‖r(θ)‖²`` over whitened residuals r (data rows ``(model − y)/σ``
and any prior rows) has at its optimum θ̂ the Gaussian (Laplace, Gauss–Newton) approximation
of the posterior with precision — the Fisher information —

    F = Jᵀ J,   J = ∂r/∂θ (θ̂),

and what the data determine is read from its eigen-decomposition ``F = V Λ Vᵀ`` (never from
an explicit inverse, which a nearly singular F turns into noise):

* a direction ``v_i`` is *numerically null* when ``λ_i ≤ 1e-12 λ_max``, and *undetermined*
  when it is null or its standard deviation ``1/√λ_i`` exceeds ``undetermined_std``
  (∞ switches the second criterion off: coordinates of unlike units). Undetermined
  directions are named as combinations of the coordinates, e.g. ``"0.71·log mu_c − 0.70·log exponent"``;
* the covariance of θ is the pseudo-inverse ``V Λ⁺ Vᵀ`` over the non-null directions;
* a quantity q with gradient g at θ̂ is *undetermined* — no standard deviation, no interval
  that would look like a measurement — when the undetermined directions would move it more
  than the determined ones, ``Σ_u (g·v_u)²/λ_u > 9 Σ_d (g·v_d)²/λ_d`` (λ floored at 1e-12 λ_max);
  otherwise its variance is ``Σ_d (g·v_d)²/λ_d`` plus the undetermined directions'
  linearised share (at most a ninth). A quantity whose gradient is not finite (NaN or ±∞) is
  undetermined.

"Undetermined" has one representation in the project: ``None`` — for a standard deviation,
an interval or quantiles the data do not determine, in Python results (:meth:`Laplace.std`,
``fitting.FitResult.std``/``quantiles``, ``brdfscale.plus.StrengthFit``'s σ fields) and
``null`` in JSON; never NaN, which arithmetic would carry on silently.

Both fits of the project use it: :func:`fitting.fit` (the multi-scale lobe fits) and
:func:`brdfscale.plus.fit_strengths` (nearly-specular strengths). Tested in
tests/test_laplace.py against a linear-Gaussian model whose posterior is exact.
"""

import dataclasses

import numpy as np
from jaxtyping import Float

from ._errors import InvalidInputError
from ._show import Shown, Table


__all__ = ["NULL", "Laplace", "combination", "laplace"]

NULL = 1e-12
"""Eigenvalues of ``JᵀJ`` at or below ``NULL · λ_max`` are numerically zero (no information)."""

_MOVES_MORE = 9.0  # a quantity is undetermined when the undetermined directions' variance is above 9× the determined


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class Laplace(Shown):
    """The Laplace approximation at an optimum and its identifiability analysis (module docstring).

    Attributes:
        names: the coordinates of θ.
        eigenvalues: ``λ`` of ``JᵀJ``, ascending (d,).
        eigenvectors: ``V`` (d, d), column i belonging to ``λ_i``.
        covariance: ``V Λ⁺ Vᵀ`` over the non-null directions (d, d).
        undetermined_mask: which eigen-directions are undetermined (d,).
        undetermined: one record per undetermined direction: ``combination`` (text),
            ``fisher_eigenvalue`` and ``std`` (``1/√λ``, None when null).
        undetermined_std: the threshold used.
    """

    names: tuple[str, ...]
    eigenvalues: Float[np.ndarray, " d"]
    eigenvectors: Float[np.ndarray, "d d"]
    covariance: Float[np.ndarray, "d d"]
    undetermined_mask: np.ndarray
    undetermined: list[dict]
    undetermined_std: float

    @property
    def null_mask(self) -> np.ndarray:
        """The numerically null directions (``λ ≤ NULL · λ_max``)."""
        return self.eigenvalues <= NULL * max(float(self.eigenvalues[-1]), 1e-300)

    @property
    def determined(self) -> bool:
        return not self.undetermined

    def determined_basis(self) -> Float[np.ndarray, "d k"]:
        """``V_d Λ_d^{-1/2}``: maps k standard normals onto a draw of θ − θ̂ along the determined directions."""
        keep = ~self.undetermined_mask
        return self.eigenvectors[:, keep] / np.sqrt(self.eigenvalues[keep])

    def _whitened(self, gradients) -> np.ndarray:
        """``g V Λ_f^{-1/2}`` (q, d): the gradients in the eigen-directions, each divided by its standard
        deviation ``1/√λ`` (λ floored at ``NULL · λ_max``: a null direction's contribution is large, not
        infinite) — the one policy behind :meth:`variances` and :meth:`covariance_of`."""
        g = np.atleast_2d(np.asarray(gradients, dtype=float))
        floor = np.maximum(self.eigenvalues, NULL * max(float(self.eigenvalues[-1]), 1e-300))
        with np.errstate(invalid="ignore", over="ignore"):  # a non-finite gradient: NaN, not determined
            return (g @ self.eigenvectors) / np.sqrt(floor)

    def variances(self, gradients: Float[np.ndarray, "q d"]) -> tuple[np.ndarray, np.ndarray]:
        """The linearised variances of quantities with these gradients: (determined part, undetermined part)."""
        whitened = self._whitened(gradients)
        with np.errstate(invalid="ignore", over="ignore"):  # as in _whitened: NaN or inf, not determined
            projected = whitened**2
        return projected[:, ~self.undetermined_mask].sum(axis=1), projected[:, self.undetermined_mask].sum(axis=1)

    def covariance_of(self, gradients: Float[np.ndarray, "q d"]) -> Float[np.ndarray, "q q"]:
        """The linearised joint covariance of quantities with these gradients, ``g V Λ_f⁻¹ Vᵀ gᵀ`` (q, q): its
        diagonal is the sum of :meth:`variances`' two parts (the same floor of the null directions), its
        off-diagonal the correlations that the standard errors alone leave out (used by
        :func:`fitting.law_from_differences` through ``FitResult.differences_covariance``)."""
        w = self._whitened(gradients)
        with np.errstate(invalid="ignore", over="ignore"):
            return w @ w.T

    def quantity_is_determined(self, gradients: Float[np.ndarray, "q d"]) -> np.ndarray:
        """True for each quantity whose gradient is finite and whose variance is finite and at most
        a tenth from the undetermined directions (module docstring). A gradient holding NaN or ±∞
        (a quantity not differentiable at θ̂) is not determined: no comparison with it is made."""
        g = np.atleast_2d(np.asarray(gradients, dtype=float))
        determined, undetermined = self.variances(g)
        return (
            np.all(np.isfinite(g), axis=1)
            & np.isfinite(determined + undetermined)
            & (undetermined <= _MOVES_MORE * determined)
        )

    def std(self, gradients: Float[np.ndarray, "q d"]) -> list[float | None]:
        """Linearised standard deviations of quantities, one per row of ``gradients``: a float,
        or None where the quantity is undetermined (:meth:`quantity_is_determined`)."""
        determined, undetermined = self.variances(gradients)
        out = np.sqrt(determined + undetermined)
        return [float(s) if ok else None for s, ok in zip(out, self.quantity_is_determined(gradients))]

    def _show_items(self):
        return [
            ("coordinates", len(self.names)),
            ("undetermined", "; ".join(u["combination"] for u in self.undetermined) or "none"),
        ]

    def _show_tables(self):
        rows = [(u["combination"], u["fisher_eigenvalue"], u["std"]) for u in self.undetermined]
        return (
            [Table("combinations the data do not determine", ("combination", "Fisher eigenvalue", "std"), rows)]
            if rows
            else []
        )


def laplace(jacobian: Float[np.ndarray, "m d"], names, *, undetermined_std: float = 1.0) -> Laplace:
    """The Laplace approximation of a fit from the Jacobian of its whitened residuals at the optimum.

    Args:
        jacobian: ``J = ∂r/∂θ`` at θ̂, shape (m, d), finite.
        names: d coordinate names (for the undetermined combinations).
        undetermined_std: directions with ``1/√λ`` above this are undetermined (> 0; ``np.inf``:
            only numerically null ones).

    Raises InvalidInputError for a Jacobian that is not a finite (m, d) array, names of the
    wrong length or a threshold that is not positive.
    """
    J = np.asarray(jacobian, dtype=float)
    names = tuple(str(n) for n in names)
    if J.ndim != 2 or J.shape[1] != len(names) or J.shape[1] == 0:
        raise InvalidInputError(f"jacobian must be (m, d) with d = len(names) = {len(names)} ≥ 1; got shape {J.shape}.")
    if not np.all(np.isfinite(J)):
        raise InvalidInputError(
            f"jacobian has {int(np.count_nonzero(~np.isfinite(J)))} non-finite entries; the "
            "residuals are not differentiable at this point (check σ, masks and the model)."
        )
    if not (isinstance(undetermined_std, (int, float)) and undetermined_std > 0):
        raise InvalidInputError(
            f"undetermined_std must be a positive number (np.inf allowed); got {undetermined_std!r}."
        )
    lam, V = np.linalg.eigh(J.T @ J)
    lam_max = max(float(lam[-1]), 1e-300)
    null = lam <= NULL * lam_max
    mask = null | (1.0 / np.sqrt(np.maximum(lam, 1e-300)) > undetermined_std)
    undetermined = [
        {
            "combination": combination(V[:, i], names),
            "fisher_eigenvalue": float(lam[i]),
            "std": None if null[i] else float(1 / np.sqrt(lam[i])),
        }
        for i in np.flatnonzero(mask)
    ]
    cov = (V[:, ~null] / lam[~null]) @ V[:, ~null].T
    return Laplace(names, lam, V, cov, mask, undetermined, float(undetermined_std))


def combination(vector: Float[np.ndarray, " d"], names, cutoff: float = 0.1) -> str:
    """A direction in θ as text, largest coefficient first and positive: ``"0.71·a − 0.70·b"``
    (coefficients below ``cutoff`` in magnitude left out)."""
    vector = np.asarray(vector, dtype=float)
    order = np.argsort(-np.abs(vector))
    if vector[order[0]] < 0:
        vector = -vector
    parts = [f"{vector[i]:+.2f}·{names[i]}" for i in order if abs(vector[i]) >= cutoff]
    return " ".join(parts).lstrip("+").replace("+", "+ ").replace("-", "− ")
