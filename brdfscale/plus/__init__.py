"""Nearly-specular reflection: regularised plus-distributions and their strengths (seed §6, docs/conventions.md §4).

* :func:`plus_transform` — the transforms ``H_n`` (n = 0…6) to float64 rounding;
* :class:`PlusDistribution` — ``h_n = (1/2π)[θ(x0 − |m|) logⁿ(|m|/x0)/|m|²]₊``, a generalised function of
  mass 0 (:class:`brdfscale.stats.AbstractGeneralisedDensity`), a term of a statistic, not one;
* :class:`NearlySpecular` — ``a δ + Σ c_n h_n + w s_smooth`` (mass ``a + w = 1``);
* :func:`observe` / :class:`ObservedDensity` — what an instrument of finite angular
  resolution sees, with a check that it is non-negative;
* :func:`fit_strengths` — least-squares fit of ``c_n`` and ``x0`` with Laplace uncertainties.
"""

from ._distribution import PlusDistribution
from ._fit import fit_strengths, StrengthFit
from ._nearly_specular import MAX_POINTS, NearlySpecular, observe, ObservedDensity
from ._transform import MAX_ORDER, plus_transform


__all__ = [
    "MAX_ORDER",
    "plus_transform",
    "PlusDistribution",
    "NearlySpecular",
    "ObservedDensity",
    "observe",
    "MAX_POINTS",
    "StrengthFit",
    "fit_strengths",
]
