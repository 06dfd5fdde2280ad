"""The analysis of a fit's starts: the best start, its Laplace covariance and identifiability, the summaries.

The fit minimises ``½‖r(θ)‖²`` over the unconstrained coordinates θ of a model, with the
whitened residuals ``r = ((prediction − data)/σ, prior rows)`` — computed on the dataset's
distinct points (:meth:`Dataset.points`), which gives the per-pixel χ² up to a constant
and the same ``JᵀJ``. At the optimum θ̂ the
Laplace approximation of the posterior is Gaussian with precision (Fisher information)

    F = Jᵀ J,   J = ∂r/∂θ (θ̂)   (``jax.jacfwd``; optimistix exposes no Jacobian),

and identifiability is read from its eigen-decomposition ``F = V Λ Vᵀ`` by
:func:`brdfscale.laplace.laplace` (the one policy of every fit in the project): a direction
``v_i`` is *undetermined* when its standard deviation ``1/√λ_i`` exceeds
``undetermined_std`` (default 1: in log-parameters, the combination is not known to within
a factor e) or when ``λ_i`` is numerically zero (``λ_i ≤ 1e-12 λ_max``). Undetermined
combinations are reported by name (e.g. ``"0.71·log mu_c − 0.70·log exponent"``), and a
quantity q with gradient g is reported as undetermined (no standard deviation, no
quantiles) when the undetermined directions would move it more than the determined ones,
``Σ_u (g·v_u)²/λ_u > 9 Σ_d (g·v_d)²/λ_d`` (λ floored at 1e-12 λ_max), instead of with a
fake precision (docs/conventions.md §2). The covariance of θ is the pseudo-inverse ``V Λ⁺ Vᵀ`` over the
numerically non-zero directions. The quantities' standard deviations and 5/50/95 %
quantiles come from 4000 draws of that Gaussian along the *determined* directions pushed
through the model's quantities (draws along an undetermined direction, with standard
deviations up to 1e6 in θ, would overflow any exponential and say nothing about the data),
widened by the linearised contribution ``Σ_u (g·v_u)²/λ_u`` of the undetermined directions
(at most 1/9 of the determined variance for a quantity that is reported at all): the
variance is added, the quantiles are stretched about the median by the same factor.
"""

import numpy as np

from brdfscale import InvalidInputError
from brdfscale.laplace import combination, laplace

from ._derived import (
    evaluate,
    evaluate_many,
    quantity_names,
    ratio_frequencies,
    ratio_names,
    summarise_covariance_differences,
)
from ._problem import stack_trees
from ._result import FitResult
from ._solve import result_name, RESULT_NAMES, solver_name


__all__ = ["result_of_starts", "results_of_starts"]

_LAPLACE_DRAWS = 4000


def result_of_starts(problem, values, codes, steps, chi2s, jacobians, options) -> FitResult:
    """The :class:`FitResult` of the solves from every start (arrays with the start first): the
    best start, the Laplace analysis at it, the quantities and ratios (module docstring)."""
    stage = _Analysis(problem, values, codes, steps, chi2s, jacobians, options)
    return stage.finish(*map(np.asarray, evaluate(problem.model, *stage.inputs())))


def results_of_starts(problems, values, codes, steps, chi2s, jacobians, options) -> list:
    """:func:`result_of_starts` of many materials of one structure (arrays with the material
    first, then the start): the host-side analysis of each, and the quantities and ratios of
    all of them at their optima and Laplace draws in one vmapped program
    (:func:`fitting.fit_many`'s buckets). A material whose every start is non-finite gets its
    :class:`~brdfscale.InvalidInputError` in its slot."""
    stages = []
    for i, problem in enumerate(problems):
        try:
            stages.append(_Analysis(problem, values[i], codes[i], steps[i], chi2s[i], jacobians[i], options))
        except InvalidInputError as err:
            stages.append(err)
    live = [k for k, st in enumerate(stages) if isinstance(st, _Analysis)]
    if live:
        inputs = [stages[k].inputs() for k in live]
        models = stack_trees([problems[k].model for k in live])
        evaluated = tuple(map(np.asarray, evaluate_many(models, *(stack_trees(list(x)) for x in zip(*inputs)))))
        names = quantity_names(problems[live[0]].model)  # one structure: the same quantities
        for j, k in enumerate(live):
            stages[k] = stages[k].finish(*(e[j] for e in evaluated), names_of_quantities=names)
    return stages


class _Analysis:
    """:func:`result_of_starts` in three stages: the host-side analysis of the starts (best
    start, Laplace analysis by :func:`brdfscale.laplace.laplace`, the draws), the arrays the
    compiled evaluation needs (:meth:`inputs`, for :func:`fitting._derived.evaluate` of one material or
    :func:`fitting._derived.evaluate_many` of a bucket), and the :class:`FitResult` from what it returns
    (:meth:`finish`)."""

    def __init__(self, problem, values, codes, steps, chi2s, jacobians, options):
        model = problem.model
        ok = (codes == RESULT_NAMES.index("successful")) & np.isfinite(chi2s)
        pool = np.flatnonzero(ok) if ok.any() else np.flatnonzero(np.isfinite(chi2s))
        if pool.size == 0:
            raise InvalidInputError(
                "every start produced a non-finite χ²; check the data (σ, masks) and the model choice."
            )
        best = int(pool[np.argmin(chi2s[pool])])
        self.problem, self.options, self.chi2 = problem, options, float(chi2s[best])
        self.theta = theta = np.asarray(values[best])
        self.start_info = [
            {
                "chi2": float(c),
                "result": result_name(int(k)),
                "steps": int(s),
                "at_best": bool(np.isfinite(c) and abs(c - chi2s[best]) <= 1e-6 * max(1.0, chi2s[best])),
            }
            for c, k, s in zip(chi2s, codes, steps)
        ]
        self.status = "converged" if ok[best] else result_name(int(codes[best]))
        lo, hi = np.asarray(problem.lower), np.asarray(problem.upper)
        self.at_bounds = [
            n for n, t, a, b in zip(model.names, theta, lo, hi) if t <= a + 1e-6 * (b - a) or t >= b - 1e-6 * (b - a)
        ]
        # the optimum reported is θ clipped to the prior box: Problem clips θ before every prediction, so the
        # residuals and χ² are the clipped point's, and every estimate lies inside the prior range printed beside it
        self.theta = theta = np.clip(theta, lo, hi)
        # brdfscale.laplace: the one policy
        self.analysis = laplace(np.asarray(jacobians[best]), model.names, undetermined_std=options.undetermined_std)
        # quantities: Laplace draws along the determined directions only (module docstring); a
        # quantity the undetermined directions move more than the determined ones gets no interval
        rng = np.random.default_rng(options.seed + 1)
        basis = self.analysis.determined_basis()
        self.draws = theta + rng.standard_normal((_LAPLACE_DRAWS, basis.shape[1])) @ basis.T
        # what the data determine whatever the parametrisation: the ratios S(μ0)/S(μ_k) at these |W|
        self.W = ratio_frequencies(problem.data)

    def inputs(self) -> tuple:
        """θ̂, the Laplace draws, the ratios' |W| and the scales: the arguments of
        :func:`fitting._derived.evaluate` after the model."""
        return self.theta, self.draws, self.W, np.asarray(self.problem.data.scales)

    def finish(self, q_hat, grads, q_draws, r_hat, r_grads, r_draws, names_of_quantities=None) -> FitResult:
        """The :class:`FitResult` from :func:`fitting._derived.evaluate`'s arrays;
        ``names_of_quantities``: those of ``model.quantities`` where the caller knows them (a
        bucket's models share them)."""
        model, data, analysis = self.problem.model, self.problem.data, self.analysis
        names = model.names
        if names_of_quantities is None:
            names_of_quantities = quantity_names(model)
        estimates, std, quantiles = _summaries(analysis, names_of_quantities, q_hat, grads, q_draws)
        W, scales = self.W, np.asarray(data.scales)
        r_est, r_std, r_q = _summaries(analysis, ratio_names(data, W), r_hat, r_grads, r_draws)
        ratios = {
            name: {
                "estimate": r_est[name] if np.isfinite(r_est[name]) else None,  # 0/0: undefined (_summaries)
                "std": r_std[name],
                "quantiles_5_50_95": r_q[name],
                "mu0": float(scales[0]),
                "mu": float(scales[1 + i // len(W)]),
                "W": float(W[i % len(W)]),
            }
            for i, name in enumerate(r_est)
        }
        keep = ~analysis.undetermined_mask
        combinations = [
            {
                "combination": combination(analysis.eigenvectors[:, i], names),
                "value": float(_signed(analysis.eigenvectors[:, i]) @ self.theta),
                "std": float(1 / np.sqrt(analysis.eigenvalues[i])),
            }
            for i in np.flatnonzero(keep)[::-1]
        ]
        differences, differences_covariance = summarise_covariance_differences(
            model, np.clip(self.theta, self.problem.lower, self.problem.upper), scales, analysis
        )
        return FitResult(
            names=names,
            theta=self.theta,
            covariance=analysis.covariance,
            chi2=self.chi2,
            n_data=data.n_data,
            status=self.status,
            starts=self.start_info,
            estimates=estimates,
            std=std,
            quantiles=quantiles,
            eigenvalues=analysis.eigenvalues,
            undetermined=analysis.undetermined,
            notes=list(model.identifiability_notes),
            solver=solver_name(self.options.solver),
            at_bounds=self.at_bounds,
            eigenvectors=analysis.eigenvectors,
            ratios=ratios,
            combinations=combinations,
            covariance_differences=differences,
            differences_covariance=differences_covariance,
        )


def _summaries(analysis, names, values, grads, draws):
    """Estimate, standard deviation and widened 5/50/95 % quantiles of quantities from their
    Laplace draws along the determined directions (module docstring); None where undetermined."""
    _, var_undetermined = analysis.variances(grads)
    determined = analysis.quantity_is_determined(grads)
    estimates, std, quantiles = {}, {}, {}
    for idx, name in enumerate(names):
        estimates[name] = float(values[idx])
        # not a number at θ̂, in its gradient or at a draw (a ratio S(W, μ0)/S(W, μk) = 0/0 in float64): no std
        finite = np.isfinite(values[idx]) and np.all(np.isfinite(grads[idx])) and np.all(np.isfinite(draws[:, idx]))
        if not determined[idx] or not finite:
            std[name], quantiles[name] = None, None
            continue
        spread = float(np.var(draws[:, idx]))
        widen = np.sqrt(1 + var_undetermined[idx] / spread) if spread > 0 else 1.0
        std[name] = float(np.sqrt(spread + var_undetermined[idx]))
        q = np.percentile(draws[:, idx], [5, 50, 95])
        quantiles[name] = (q[1] + widen * (q - q[1])).tolist()
    return estimates, std, quantiles


def _signed(vector):
    """The eigenvector with the sign :func:`brdfscale.laplace.combination` prints it with."""
    return vector if vector[np.argmax(np.abs(vector))] >= 0 else -vector
