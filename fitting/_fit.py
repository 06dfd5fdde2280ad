"""The fit of one material: :func:`fit` and its checked options (:class:`FitOptions`).

The chain, a module per job: the residual rows (:mod:`fitting._problem`), one optimistix solve
per start (:mod:`fitting._solve`), the analysis of the starts — best start, Laplace covariance,
identifiability (:mod:`fitting._analysis`) — with the quantities and ratios at θ̂ and the
Laplace draws (:mod:`fitting._derived`), the :class:`~fitting.FitResult` (:mod:`fitting._result`).
"""

import dataclasses

import jax.numpy as jnp
import numpy as np

from brdfscale import InvalidInputError
from brdfscale.checks import integer, real
from brdfscale.choices import FIT

from ._analysis import result_of_starts
from ._data import Dataset
from ._model import AbstractModel
from ._problem import check_pair, Problem, starting_points
from ._result import FitResult
from ._solve import check_solver, make_solver, resolve_solver, solve


__all__ = ["FitOptions", "fit", "resolve_starts"]


@dataclasses.dataclass(frozen=True)
class FitOptions:
    """The options of :func:`fit` (and :func:`fitting.fit_many`), checked when made.

    ``solver`` a name of :data:`fitting.SOLVERS` or an optimistix solver object; ``starts``,
    ``max_steps`` integers ≥ 1 (:meth:`for_models` resolves ``"auto"`` of both); ``spread`` finite ≥ 0;
    ``seed`` an integer ≥ 0; ``rtol``, ``atol`` finite ≥ 0, not both 0; ``undetermined_std`` finite > 0 — else
    :class:`~brdfscale.InvalidInputError` naming the option.
    """

    solver: object = FIT.solver
    starts: int = FIT.model_starts
    max_steps: int = FIT.max_steps
    spread: float = FIT.spread
    seed: int = FIT.seed
    rtol: float = FIT.rtol
    atol: float = FIT.atol
    undetermined_std: float = FIT.undetermined_std

    def __post_init__(self):
        checked = {
            "solver": check_solver(self.solver),
            "starts": integer(self.starts, "starts", 1),
            "max_steps": integer(self.max_steps, "max_steps", 1),
            "spread": real(self.spread, "spread", minimum=0.0),
            "seed": integer(self.seed, "seed", 0),
            "rtol": real(self.rtol, "rtol", minimum=0.0),
            "atol": real(self.atol, "atol", minimum=0.0),
            "undetermined_std": real(self.undetermined_std, "undetermined_std", minimum=0.0, strict=True),
        }
        if checked["rtol"] == 0 and checked["atol"] == 0:
            raise InvalidInputError("rtol and atol must not both be 0: no step could ever meet the convergence test.")
        for name, value in checked.items():
            object.__setattr__(self, name, value)

    @classmethod
    def for_models(cls, models, *, solver, starts, **options) -> "FitOptions":
        """The options for fitting ``models``, ``"auto"`` resolved: the solver by
        :func:`fitting.resolve_solver`, the starts by :func:`resolve_starts`; the rest checked as
        :class:`FitOptions` checks them."""
        return cls(solver=resolve_solver(solver, models), starts=resolve_starts(starts, models), **options)

    def optimiser(self):
        """The optimistix solver object of these options (:func:`fitting._solve.make_solver`)."""
        return make_solver(self.solver, self.rtol, self.atol)


def resolve_starts(starts, models) -> int:
    """``starts`` itself, or for ``"auto"`` the most any of ``models`` prefers (their
    ``preferred_starts``: ``brdfscale.choices.FIT.model_starts`` = 8, 1 for the anisotropic
    non-parametric model; one number serves a batch). Anything else is checked by :class:`FitOptions`."""
    if isinstance(starts, str):
        if starts != "auto":
            raise InvalidInputError(f"starts must be an integer ≥ 1 or 'auto' (the model's own count); got {starts!r}.")
        return max((getattr(m, "preferred_starts", FIT.model_starts) for m in models), default=FIT.model_starts)
    return starts


def fit(
    model: AbstractModel,
    data: Dataset,
    *,
    solver=FIT.solver,
    starts: int | str = FIT.starts,
    spread: float = FIT.spread,
    seed: int = FIT.seed,
    max_steps: int = FIT.max_steps,
    rtol: float = FIT.rtol,
    atol: float = FIT.atol,
    undetermined_std: float = FIT.undetermined_std,
) -> FitResult:
    """Maximum-likelihood fit of ``model`` to ``data`` from several starting points.

    Args:
        model, data: what to fit to what.
        solver: ``"auto"`` (default: the model's ``preferred_solver`` — ``"lm_normal"`` for the
            anisotropic models, ``"gauss_newton_edm"`` for the anisotropic non-parametric one, ``"lm"``
            for the others; the result records which),
            ``"lm"`` (Levenberg–Marquardt), ``"lm_normal"`` (its steps by the
            normal equations: faster for many rows, e.g. the anisotropic models),
            ``"gauss_newton"``, ``"gauss_newton_edm"`` (line-searched, the undetermined directions
            left out, stopped on the expected distance to the minimum: fitting._gauss_newton),
            ``"dogleg"`` or ``"bfgs"`` (a minimiser of ½‖r‖²), or an
            optimistix least-squares solver or minimiser object (e.g.
            ``optimistix.LevenbergMarquardt(rtol=1e-8, atol=1e-8)``),
            used as it is: its own tolerances and norm apply, not ``rtol``/``atol``; the
            result's ``solver`` is then its class name.
        starts: number of starts, or ``"auto"`` (default: the model's ``preferred_starts``,
            :func:`resolve_starts` — 8, 1 for :class:`~fitting.AnisotropicNonParametricModel`): the
            model's data-driven start plus ``starts − 1`` jittered copies (normal, standard
            deviation ``spread`` in θ), all clipped to the prior box. They share one compiled solve.
        seed: seed of the jitter.
        max_steps, rtol, atol: optimistix settings: a start has converged when an accepted
            step changes θ by less than ``atol + rtol·|θ_i|`` and the residuals by less than
            ``atol + rtol·|r_i|``, both in the root-mean-square over components (the
            residuals normalised to a root-mean-square of 1 at the start, which makes the fit
            independent of σ's overall scale — fitting._solve — and 1e-6 far below the noise;
            Levenberg–Marquardt converges quadratically, so the last step bounds the error). Tighter settings
            or a max-norm only add steps at the rounding level (experiments/bench_fit.py
            checks the optimum against SciPy).
        undetermined_std: threshold of the identifiability analysis (module docstring).

    Returns:
        A :class:`FitResult`; inspect ``status`` and ``undetermined`` before trusting it
        (``"converged"`` only at a finite θ̂ that is not an unmoved, non-stationary start:
        fitting._solve names the other outcomes).

    Raises:
        InvalidInputError: ``model``/``data`` of the wrong type or not belonging together
            (:class:`Problem`); an unknown ``solver``; ``starts``, ``max_steps`` not integers
            ≥ 1, ``seed`` not an integer ≥ 0; ``spread``, ``rtol``, ``atol`` not finite and
            ≥ 0 (``rtol``, ``atol`` not both 0), ``undetermined_std`` not finite and > 0;
            every start ending with a non-finite χ².
    """
    check_pair(model, data, "fit(model, data)")
    options = FitOptions.for_models(
        [model],
        solver=solver,
        starts=starts,
        max_steps=max_steps,
        spread=spread,
        seed=seed,
        rtol=rtol,
        atol=atol,
        undetermined_std=undetermined_std,
    )
    problem = Problem(model, data)
    optimiser = options.optimiser()
    y0 = jnp.asarray(starting_points(problem, options), dtype=jnp.float64)
    # one compiled solve, called per start (vmapping the solve compiles ~2.5× longer here)
    runs = [solve(problem, y, optimiser, options.max_steps) for y in y0]
    values, codes, steps, chi2s, jacobians = (np.stack([np.asarray(run[i]) for run in runs]) for i in range(5))
    return result_of_starts(problem, values, codes, steps, chi2s, jacobians, options)
