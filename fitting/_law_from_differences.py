"""A scale law fitted to a per-scale model's ΔΣ estimates: what carries :class:`fitting.AnisotropicModel`'s fit to
scales it has not measured (:func:`law_from_differences`).

The per-scale model determines ``ΔΣ_k = Σ(μ0) − Σ(μ_k)`` at the measured scales only (its coordinates are one
increment per scale). To predict a coarser, unmeasured scale μ, something must say how Σ goes on beyond μ_K: a
scale law. This module fits one to the estimates themselves — a second stage on the fit, nothing refitted to the
images — by weighted least squares over the determined entries of every ``ΔΣ(μ0, μ_k)``,

    χ²(φ, p) = Σ_k Σ_{ab ∈ xx, xy, yy} ((ΔΣ_law(μ0, μ_k; φ, p)_ab − ΔΣ_k,ab) / std_k,ab)²,

with ``ΔΣ_law`` that of :class:`fitting.AnisotropicLawModel`'s law (principal axes at a free angle φ, each principal
variance a :class:`fitting.Width` law unless another is given). The standard errors are the fit's (``FitResult``'s
``covariance_differences``). With their joint covariance ``C`` (``covariance=FitResult.differences_covariance``: the
Laplace covariance of θ propagated linearly, the components of one scale and of different scales correlated through
the shared coordinates) the sum is the generalised least squares'

    χ²(φ, p) = rᵀ C⁺ r,   r = ΔΣ_law − ΔΣ over the determined components,

(``C⁺`` the pseudo-inverse over the eigen-directions of the components' correlation matrix above ``1e-10`` of its
largest; the others, and the law's coordinates, taken from the degrees of freedom), a calibrated test of the law:
``p_value`` is χ²'s survival function at ``dof`` (Gaussian errors, a law linear enough near its optimum). Without
it the components are taken as independent and χ² is only a guide (``p_value`` None). An entry without a standard
error (undetermined, or fixed by an isotropic model) is left out. The law's coordinates are kept inside their prior
box (``Law.bounds``) by a logistic map.

The result is an :class:`fitting.AnisotropicLawModel` with the per-scale model's base lobe (amplitude, C0, centre,
tail index) and the fitted law, and its θ: :func:`fitting.predict_from_measured` then predicts any coarser scale —
from the measured lobe widened by the law's ΔΣ between the coarsest fitted scale and the target, the law's own
increments between measured scales matching the per-scale estimates to their standard errors where the law fits.

Verified in tests/test_measured_prediction.py: ΔΣ_k made by a known width law are recovered and extrapolated to a
coarser scale to 1e-6 of the law's own, also over hypothesis-drawn orientations, anisotropy ratios and axis laws;
with a correlated covariance, χ² against a hand-written ``rᵀ C⁻¹ r`` at the law's optimum and ``p_value`` against
SciPy's χ² distribution (uniform over draws); components whose standard errors differ by 10⁶ all kept; refusals
(models, entries, covariances, too few of them); in tests/test_anisotropic.py a fit's ``differences_covariance``
against ``J Cov(θ) Jᵀ`` with J by finite differences.
"""

import dataclasses
import math
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Float

from brdfscale import InvalidInputError
from brdfscale.choices import ADEQUACY

from ._anisotropic import AnisotropicModel
from ._anisotropic_law import AnisotropicLawModel, Law
from ._data import Dataset
from ._derived import DIFFERENCE_COMPONENTS


__all__ = ["LawFromDifferences", "law_from_differences"]

_ENTRIES = DIFFERENCE_COMPONENTS
_RANK = 1e-10
"""Eigen-directions of the components' correlation matrix below this fraction of its largest eigenvalue are left out
of the generalised χ² (and of its degrees of freedom)."""
_SOLVER = optx.LevenbergMarquardt(rtol=1e-10, atol=1e-12)
_MAX_STEPS = 2000
_PHI_STARTS = (0.0, math.pi / 4, -math.pi / 4, math.pi / 2)
"""The starts of φ, offsets from the principal axis of the coarsest ΔΣ estimate (the best start is kept)."""


@dataclasses.dataclass(frozen=True)
class LawFromDifferences:
    """What :func:`law_from_differences` returns: ``model`` (:class:`fitting.AnisotropicLawModel`, the per-scale
    model's base lobe and the fitted law) and its ``theta``; ``chi2`` and ``dof`` of the law against the ΔΣ
    entries it was fitted to (``dof``: determined entries — with a covariance, its eigen-directions kept — − the
    law's coordinates − 1 for φ); ``scales`` the measured scales (μ0 first); ``converged`` the solve's outcome;
    ``correlated`` whether χ² is the generalised one (the components' joint covariance given): only then is
    :attr:`p_value` a test."""

    model: AnisotropicLawModel
    theta: Float[Array, " n"]
    chi2: float
    dof: int
    scales: tuple[float, ...]
    converged: bool = True
    correlated: bool = False

    @staticmethod
    def scales_needed(law: str | Law = "width") -> int:
        """The fewest measured scales (μ0 included) whose ΔΣ estimates determine ``law``: its coordinates and φ
        need as many components, three (xx, xy, yy) per coarser scale."""
        return 1 + math.ceil(_n_coordinates(AnisotropicLawModel(law, scales=(1.0, 2.0))) / len(_ENTRIES))

    @property
    def p_value(self) -> float | None:
        """The probability of a χ² at least this large were the law true (χ²'s survival function at ``dof``):
        None where the components were taken as independent (``correlated`` False: χ² is then a guide, not a
        test) or no degree of freedom is left."""
        if not self.correlated or self.dof < 1:
            return None
        from scipy import stats  # here, not at import (as fitting._adequacy)

        return float(stats.chi2.sf(self.chi2, self.dof))

    @property
    def p_text(self) -> str | None:
        """``p = …`` for a line (``p < 1e-300`` where it underflows to 0), None where there is no p."""
        p = self.p_value
        if p is None:
            return None
        return "p < 1e-300" if p == 0 else f"p = {p:.2g}"

    def inadequate_because(self, thresholds=None) -> str | None:
        """One line saying why the law does not describe the ΔΣ estimates it was fitted to, or None: by the rule of
        :func:`fitting.assess` (``thresholds``: :data:`brdfscale.choices.ADEQUACY` unless given) — χ²/dof above
        ``max_reduced_chi2`` and ``p_value`` below its ``p_value``. Only a generalised χ² (``correlated``) is
        tested: without the covariance None."""
        thresholds = ADEQUACY if thresholds is None else thresholds
        p = self.p_value
        if p is None or self.chi2 / self.dof <= thresholds.max_reduced_chi2 or p >= thresholds.p_value:
            return None
        return (
            f"the {type(self.model.law).__name__.lower()} law fitted to the per-scale ΔΣ estimates does not describe "
            f"them (generalised χ²/dof = {self.chi2:.3g}/{self.dof}, {self.p_text} < {thresholds.p_value:g}): "
            "predictions beyond the measured scales extrapolate through it"
        )

    def to_json(self) -> dict:
        """``{"law", "fitted_to", "chi2", "dof", "p_value", "converged", "theta": {name: value}}`` (a report's or a
        file's record; ``fitted_to`` says whether by the joint covariance or the standard errors alone)."""
        return {
            "law": type(self.model.law).__name__.lower(),
            "fitted_to": "the per-scale model's covariance_differences ("
            + ("their joint covariance: generalised least squares" if self.correlated else "their standard errors")
            + ")",
            "chi2": self.chi2,
            "dof": self.dof,
            "p_value": self.p_value,
            "converged": self.converged,
            "theta": {n: float(v) for n, v in zip(self.model.names, np.asarray(self.theta))},
        }

    def __repr__(self) -> str:
        law = type(self.model.law).__name__
        p = "" if self.p_text is None else f", {self.p_text}"
        return (
            f"LawFromDifferences({law} law on {len(self.scales)} scales, χ²/dof = {self.chi2:.3g}/{self.dof}{p}, "
            f"φ = {float(self.theta[self.model.names.index('phi')]):.3g} rad)"
        )


def _n_coordinates(law_model: AnisotropicLawModel) -> int:
    """The coordinates :func:`law_from_differences` fits: the law's and φ."""
    return len(law_model.law.names) + 1


def _matrix(x, what: str) -> np.ndarray | None:
    """A 2 × 2 array of floats (None entries: NaN) of an entry's ``value`` or ``std``; None for None."""
    if x is None:
        return None
    try:
        m = np.array([[np.nan if c is None else float(c) for c in row] for row in x], dtype=float)
    except (TypeError, ValueError):
        m = np.zeros(0)
    if m.shape != (2, 2):
        raise InvalidInputError(
            f"{what} must be a 2 × 2 matrix of numbers (None where not determined); got {x!r:.200}."
        )
    return m


def _entries(differences, scales: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(index (k, a, b), value, std, row)`` of every determined ΔΣ component, flattened; ``row`` its row in
    ``FitResult.differences_covariance`` (``3(k − 1) + c``, c the component's place in :data:`_ENTRIES`)."""
    if not isinstance(differences, (list, tuple)) or len(differences) != len(scales) - 1:
        raise InvalidInputError(
            f"differences must be the fit's covariance_differences: one entry per coarser scale ({len(scales) - 1} "
            f"for these data), as FitResult.covariance_differences gives; got {differences!r:.200}."
        )
    index, value, std, row = [], [], [], []
    for k, entry in enumerate(differences, start=1):
        try:
            mu, v, s = float(entry["mu"]), entry["value"], entry["std"]
        except (TypeError, KeyError, ValueError):
            raise InvalidInputError(
                f"differences[{k - 1}] must hold 'mu', 'value' and 'std' (FitResult.covariance_differences); "
                f"got {entry!r:.200}."
            ) from None
        mu0 = entry.get("mu0", scales[0]) if isinstance(entry, dict) else scales[0]
        for name, got, want in (("μ", mu, scales[k]), ("μ0", mu0, scales[0])):
            if not (isinstance(got, (int, float)) and math.isclose(float(got), float(want), rel_tol=1e-9)):
                raise InvalidInputError(
                    f"differences[{k - 1}] has {name} = {got!r}, the data's {name} = {float(want):g} there: give the "
                    "covariance_differences of the fit to these data."
                )
        v, s = _matrix(v, f"differences[{k - 1}]['value']"), _matrix(s, f"differences[{k - 1}]['std']")
        if v is None or s is None:
            continue
        for c, (a, b) in enumerate(_ENTRIES):
            if math.isfinite(v[a, b]) and math.isfinite(s[a, b]) and s[a, b] > 0:
                index.append((k, a, b))
                value.append(float(v[a, b]))
                std.append(float(s[a, b]))
                row.append(len(_ENTRIES) * (k - 1) + c)
    return (
        np.asarray(index, int).reshape(-1, 3),
        np.asarray(value, float),
        np.asarray(std, float),
        np.asarray(row, int),
    )


def _whitening(covariance, rows: np.ndarray, std: np.ndarray, n_scales: int) -> np.ndarray:
    """``W`` with ``χ² = |W r|²``: ``diag(1/std)`` without a covariance; with one, ``Λ^{-1/2} Uᵀ D⁻¹`` of the
    eigen-decomposition ``U Λ Uᵀ`` of the used components' *correlation* matrix ``D⁻¹ C D⁻¹`` (``D = diag(std)``:
    which directions count does not depend on the components' units), the directions below :data:`_RANK` of its
    largest eigenvalue left out. The covariance is checked against the entries it claims to describe (its diagonal
    their squared std; symmetric to 1e-9 of ``std_i std_j``, then symmetrised)."""
    if covariance is None:
        return np.diag(1.0 / std)
    m = len(_ENTRIES) * (n_scales - 1)
    try:
        c = np.asarray(covariance, dtype=float)  # fit.json's nested lists: null (None) becomes NaN
    except (TypeError, ValueError):
        c = np.zeros(0)
    if c.shape != (m, m):
        raise InvalidInputError(
            f"covariance must be the differences' joint covariance, FitResult.differences_covariance: {m} × {m} "
            f"(xx, xy, yy per coarser scale); got shape {c.shape}."
        )
    used = c[np.ix_(rows, rows)]
    scale = np.outer(std, std)
    if not np.all(np.isfinite(used)) or np.any(np.abs(used - used.T) > 1e-9 * scale):
        raise InvalidInputError(
            "covariance must be finite and symmetric over the determined entries of differences (the fit's "
            "FitResult.differences_covariance, NaN only where an entry has no std)."
        )
    if not np.allclose(np.sqrt(np.diag(used)), std, rtol=1e-6, atol=0.0):
        raise InvalidInputError(
            "covariance's diagonal is not the square of differences' standard errors: give the "
            "differences_covariance of the same fit as the covariance_differences."
        )
    correlation = (used + used.T) / (2 * scale)
    eigenvalues, vectors = np.linalg.eigh(correlation)
    if eigenvalues[0] < -1e-9 * eigenvalues[-1]:
        raise InvalidInputError(
            f"covariance is not positive semi-definite over the determined entries (its correlation matrix has the "
            f"eigenvalue {eigenvalues[0]:.3g}): give the fit's FitResult.differences_covariance."
        )
    keep = eigenvalues > _RANK * eigenvalues[-1]
    return vectors[:, keep].T / np.sqrt(eigenvalues[keep])[:, None] / std[None, :]


@eqx.filter_jit
def _solve(model, base, tail, lo, hi, scales, index, value, whiten, z0):
    def theta_of(z):
        p = lo + (hi - lo) * jax.nn.sigmoid(z[1:])
        return jnp.concatenate([base, z[:1], p, tail])

    def residuals(z, _):
        delta = model.covariance_differences(theta_of(z), scales)
        return whiten @ (delta[index[:, 0], index[:, 1], index[:, 2]] - value)

    solution = optx.least_squares(residuals, _SOLVER, z0, max_steps=_MAX_STEPS, throw=False)
    r = residuals(solution.value, None)
    return theta_of(solution.value), jnp.sum(r**2), solution.result == optx.RESULTS.successful


def law_from_differences(
    model: AnisotropicModel,
    theta: Float[ArrayLike, " n"],
    differences: list[dict],
    data: Dataset,
    *,
    law: str | Law = "width",
    covariance: Float[ArrayLike, "m m"] | Sequence[Sequence[float | None]] | None = None,
) -> LawFromDifferences:
    """A scale law fitted to the per-scale model's ΔΣ estimates (module docstring): the
    :class:`fitting.AnisotropicLawModel` of the same base lobe whose law's ΔΣ(μ0, μ_k) best matches
    ``differences`` by their standard errors, or by their joint ``covariance`` (generalised least squares: then
    ``p_value`` tests the law).

    Args:
        model: the fitted :class:`fitting.AnisotropicModel` (per-scale ΔΣ_k, not the isotropic case; any shape).
        theta: its fitted coordinates.
        differences: the fit's ``covariance_differences`` (``FitResult.covariance_differences``: per coarser scale
            ``{"mu", "value", "std"}``).
        data: the fitted Dataset (its scales; the law's prior box).
        law: ``"width"`` (default) or ``"spline"`` (:class:`fitting.AnisotropicLawModel`'s laws), or a
            :class:`fitting.Law`.
        covariance: the differences' joint covariance, ``FitResult.differences_covariance`` of the same fit
            (3(K − 1) rows: xx, xy, yy per coarser scale; NaN where an entry has no std); None: the components
            taken as independent (χ² a guide only).

    Returns:
        :class:`LawFromDifferences`: the law model, its θ and the law's χ² against the entries.

    Raises:
        InvalidInputError: ``model`` not an anisotropic :class:`fitting.AnisotropicModel`; ``theta`` not of its length;
            ``differences`` not one entry per coarser scale of ``data`` at its scales; fewer determined entries than
            the law has coordinates (φ included); ``data`` not a Dataset; ``covariance`` not of that shape, not
            finite and symmetric over the determined entries, its diagonal not their squared std, or not positive
            semi-definite.
    """
    if not isinstance(model, AnisotropicModel):
        raise InvalidInputError(
            "model must be the per-scale fitting.AnisotropicModel whose ΔΣ_k the law is fitted to; got "
            f"{type(model).__name__} (a fitting.AnisotropicLawModel carries its own law: use it as it is)."
        )
    if model.isotropic:
        raise InvalidInputError(
            "model is the isotropic AnisotropicModel (one ΔΣ number per scale): the anisotropic law's two axes and "
            "orientation are not determined by it; fit AnisotropicModel(n_scales) (isotropic=False) or "
            "AnisotropicLawModel instead."
        )
    if not isinstance(data, Dataset):
        raise InvalidInputError(f"data must be a fitting.Dataset; got {type(data).__name__}.")
    try:
        theta = np.asarray(theta, dtype=float)
    except (TypeError, ValueError):
        theta = np.full(0, np.nan)
    if theta.shape != (len(model.names),) or not np.all(np.isfinite(theta)):
        raise InvalidInputError(
            f"theta must be the model's {len(model.names)} finite coordinates (FitResult.theta); got shape "
            f"{theta.shape}{'' if np.all(np.isfinite(theta)) else ' with non-finite values'}."
        )
    scales = np.asarray(data.scales, dtype=float)
    index, value, std, rows = _entries(differences, scales)
    law_model = AnisotropicLawModel(
        law, scales=scales, centred=model.centred, shape=model.shape, increments=model.increments
    )
    n_law = _n_coordinates(law_model)
    if len(value) < n_law:
        raise InvalidInputError(
            f"the {type(law_model.law).__name__} law has {n_law} coordinates (φ included) and the differences only "
            f"{len(value)} determined components: it needs the estimates of at least "
            f"{LawFromDifferences.scales_needed(law_model.law)} measured scales, each ΔΣ determined."
        )
    whiten = _whitening(covariance, rows, std, len(scales))
    n_kept = whiten.shape[0]
    if n_kept < n_law:
        raise InvalidInputError(
            f"covariance leaves {n_kept} independent directions of the {len(value)} determined components, fewer "
            f"than the {n_law} coordinates of the {type(law_model.law).__name__} law (φ included)."
        )
    lo, hi = (np.asarray(b, float) for b in law_model.law.bounds(data))
    delta = np.zeros((len(scales), 2, 2))
    for (k, a, b), x in zip(index, value):
        delta[k, a, b] = delta[k, b, a] = x
    floor = 1e-3 * max(float(np.abs(delta).max()), 1e-300)  # an axis without change starts just above none
    phi0, _ = law_model.law_start(scales, delta, floor)
    tail = theta[len(theta) - len(model.tail_names) :]  # the increments' tail and ν, as the law's model has them
    args = [jnp.asarray(x) for x in (theta[: law_model.n_base], tail, lo, hi, scales, index, value, whiten)]
    best = None
    for offset in _PHI_STARTS:
        phi, p0 = law_model.law_start(scales, delta, floor, phi0 + offset)
        p0 = np.clip(np.asarray(p0, float), lo + 1e-6 * (hi - lo), hi - 1e-6 * (hi - lo))
        z0 = np.concatenate([[phi], np.log((p0 - lo) / (hi - p0))])
        fitted, chi2, ok = _solve(law_model, *args, jnp.asarray(z0))  # pyright: ignore[reportCallIssue]
        finite = np.all(np.isfinite(np.asarray(fitted))) and math.isfinite(float(chi2))
        if finite and (best is None or float(chi2) < best[1]):
            best = (fitted, float(chi2), bool(ok))
    if best is None:
        raise InvalidInputError(
            "the width law's fit to the ΔΣ estimates is not finite from any start (the estimates or their standard "
            "errors out of any law's reach); predict from a fitting.AnisotropicLawModel fitted to the images instead."
        )
    fitted = np.array(best[0])
    i = law_model.names.index("phi")
    fitted[i] = (fitted[i] + math.pi / 2) % math.pi - math.pi / 2  # ΔΣ is periodic in φ with period π
    scales_ = tuple(float(s) for s in scales)
    return LawFromDifferences(
        law_model, jnp.asarray(fitted), best[1], n_kept - n_law, scales_, best[2], correlated=covariance is not None
    )
