"""Point estimates with optimistix, multi-start, Laplace covariance and identifiability.

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

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float

from brdfscale import InvalidInputError
from brdfscale.laplace import combination, laplace
from brdfscale.show import Shown, Table

from brdfscale.checks import integer, real, require_float64
from ._data import Dataset, PointData
from ._model import AbstractModel, moments, require_dataset

__all__ = ["Problem", "FitResult", "fit", "SOLVERS"]

SOLVERS = ("lm", "gauss_newton", "dogleg", "bfgs")
_RESULT_NAMES = {int(item._value): name for name, item in optx.RESULTS._name_to_item.items()}
_LAPLACE_DRAWS = 4000


class Problem(Shown, eqx.Module):
    """A model paired with its data: the whitened residual vector ``r(θ)``.

    The data rows of ``r`` are ``√c_u (f_u(θ) − v̄_u)`` over the distinct points ``u`` of the
    dataset (grouped by radius for radially symmetric models, :meth:`Dataset.points`), then
    the model's prior rows; ``chi2(θ) = ‖r‖² + (within-group scatter)`` is the χ² over all
    valid pixels (plus the prior rows), exactly.

    θ is clipped to the model's prior box before the prediction, so no solver step can
    reach parameters where the forward model does not exist (e.g. a lobe width that
    underflows to 0); inside the box (where every reported optimum lies) the clip is the
    identity.

    Raises:
        InvalidInputError: ``model`` is not a fitting model, ``data`` not a
            :class:`~fitting.Dataset`, or the two do not belong together (a
            :class:`~fitting.NonParametricModel` built from data with another number of scales).
    """

    model: AbstractModel
    data: Dataset
    points: PointData
    lower: jax.Array
    upper: jax.Array

    def __init__(self, model: AbstractModel, data: Dataset):
        require_float64("fitting.Problem")
        if not isinstance(model, AbstractModel):
            raise InvalidInputError(f"Problem(model, data) needs a fitting model (ParametricModel or "
                                    f"NonParametricModel) as model; got {type(model).__name__}.")
        require_dataset(data, "Problem(model, data)")
        model.check_data(data)
        self.model, self.data = model, data
        self.points = data.points(model.radial)
        lo, hi = model.bounds(data)
        self.lower, self.upper = jnp.asarray(lo, jnp.float64), jnp.asarray(hi, jnp.float64)

    def _show_items(self):
        return [("model", self.model), ("data", self.data), ("coordinates", len(self.model.names))]

    def residuals(self, theta: Float[Array, " n"]) -> Float[Array, " m"]:
        return self.rows().residuals(theta)

    def rows(self) -> "Rows":
        """What the residuals depend on, without the dataset's layout (:class:`Rows`)."""
        return Rows(self.model, self.data.scales, self.points, self.lower, self.upper)

    def chi2(self, theta: Float[Array, " n"]) -> Float[Array, ""]:
        """χ² over every valid pixel plus the prior rows."""
        return self.chi2_of_residuals(self.residuals(theta))

    def chi2_of_residuals(self, r: Float[Array, " m"]) -> Float[Array, ""]:
        """χ² from the reduced residuals ``r`` (adds the within-group constant back)."""
        return self.rows().chi2_of_residuals(r)


class Rows(eqx.Module):
    """The whitened residual rows of a :class:`Problem` as a pure pytree of arrays: the model,
    the scales, the distinct points and the prior box — not the dataset, whose layout (image
    sizes, extents) is static and would make every dataset compile its own solve. One
    material of :func:`fitting.fit_many` is one ``Rows``; stacked along a leading axis they
    are a batch (``fitting._batch``)."""

    model: AbstractModel
    scales: jax.Array
    points: PointData
    lower: jax.Array
    upper: jax.Array

    def residuals(self, theta: Float[Array, " n"]) -> Float[Array, " m"]:
        """``(√c_u (f_u(θ) − v̄_u), prior rows)`` with θ clipped to the prior box (:class:`Problem`)."""
        theta = jnp.clip(theta, self.lower, self.upper)
        p = self.points
        fitted = self.model.predict_points(theta, self.scales, p.points)
        return jnp.concatenate([((fitted - p.mean) * p.weight).ravel(), self.model.penalty(theta)])

    def chi2_of_residuals(self, r: Float[Array, " m"]) -> Float[Array, ""]:
        """χ² from the reduced residuals ``r`` (adds the within-group constant back)."""
        return r @ r + self.points.chi2_offset

    def chi2(self, theta: Float[Array, " n"]) -> Float[Array, ""]:
        """χ² over every valid pixel plus the prior rows (:meth:`Problem.chi2`)."""
        return self.chi2_of_residuals(self.residuals(theta))


def check_fit(problem, fit, what: str) -> None:
    """Raise :class:`~brdfscale.InvalidInputError` unless ``fit`` is a :class:`FitResult` of
    ``problem``'s model (same θ coordinates); ``what`` names the caller in the message."""
    if not isinstance(problem, Problem):
        raise InvalidInputError(f"{what} needs a fitting.Problem as problem; got {type(problem).__name__}.")
    if not isinstance(fit, FitResult):
        raise InvalidInputError(f"{what} needs the FitResult of fitting.fit as fit; got {type(fit).__name__}.")
    names = tuple(problem.model.names)
    theta, cov = np.asarray(fit.theta), np.asarray(fit.covariance)
    if tuple(fit.names) != names or theta.shape != (len(names),) or cov.shape != (len(names), len(names)):
        def brief(n):
            return f"{len(n)} coordinates ({', '.join(n[:3])}{', …' if len(n) > 3 else ''})"
        raise InvalidInputError(
            f"{what}: fit is the result for {brief(tuple(fit.names))}, but the problem's model has "
            f"{brief(names)}; pass the fit of this model and data (fitting.fit(problem.model, problem.data))."
        )


def _residuals(theta, rows):
    # module-level, so optimistix sees the same function object on every call (no recompilation);
    # ``rows`` is a Problem or its Rows (fitting.fit_many)
    return rows.residuals(theta)


def _make_solver(name: str, rtol: float, atol: float):
    # root-mean-square norms in the convergence test (fit's docstring): a max-norm over the
    # residual rows keeps taking rounding-level steps (rows of merged pixels have large ∂r/∂θ)
    options = dict(rtol=rtol, atol=atol, norm=optx.rms_norm)
    if name == "lm":
        return optx.LevenbergMarquardt(**options)
    if name == "gauss_newton":
        return optx.GaussNewton(**options)
    if name == "dogleg":
        return optx.Dogleg(**options)
    if name == "bfgs":
        return optx.BFGS(**options)
    raise InvalidInputError(f"solver must be one of {SOLVERS}; got {name!r}.")


@eqx.filter_jit
def _solve(problem, y0, solver, max_steps):
    """One least-squares solve from ``y0``: θ̂, result code, steps, χ² and the Jacobian at θ̂."""
    return solve_rows(problem, y0, solver, max_steps)


def solve_rows(rows, y0, solver, max_steps):
    """The solve itself (traced; :func:`fit` jits it per start, :func:`fitting.fit_many` vmaps
    it over materials × starts): θ̂, result code, steps, χ²(θ̂) and ``∂r/∂θ(θ̂)``.

    The Gauss–Newton family (LM, dogleg) carries ``r`` and ``J`` in its state (``f_info``: the
    linearisation at the last accepted point, which is θ̂), so they are read from there
    rather than evaluated once more; other solvers evaluate them."""
    sol = optx.least_squares(_residuals, solver, y0, args=rows, max_steps=max_steps, throw=False)
    info = getattr(sol.state, "f_info", None)
    if isinstance(info, optx.FunctionInfo.ResidualJac):
        residuals, jac = info.residual, info.jac.as_matrix()
    else:
        residuals, jac = rows.residuals(sol.value), jax.jacfwd(rows.residuals)(sol.value)
    return sol.value, sol.result._value, sol.stats["num_steps"], rows.chi2_of_residuals(residuals), jac


@dataclasses.dataclass(repr=False)
class FitResult(Shown):
    """Outcome of :func:`fit` (all NumPy / Python values; ``to_json()`` for reports).

    ``status`` is ``"converged"`` when the best start's solver reported success, else the
    optimistix result name of the best start (e.g. ``"nonlinear_max_steps_reached"``).
    ``estimates``/``std``/``quantiles`` are keyed by quantity name; ``std`` and
    ``quantiles`` hold None for quantities that the data do not determine. ``at_bounds``
    lists coordinates that ended on the prior box's edge (there the residuals are flat in
    that coordinate, so it also shows up as undetermined).
    """

    names: tuple[str, ...]
    theta: np.ndarray
    covariance: np.ndarray
    chi2: float
    n_data: int
    status: str
    starts: list[dict]
    estimates: dict[str, float]
    std: dict[str, float | None]
    quantiles: dict[str, list[float] | None]
    eigenvalues: np.ndarray
    undetermined: list[dict]
    notes: list[str]
    solver: str
    at_bounds: list[str]
    eigenvectors: np.ndarray | None = None  # V of the Fisher matrix's eigen-decomposition, columns by eigenvalue
    ratios: dict = dataclasses.field(default_factory=dict)  # S(μ0)/S(μk) at reference |W| (ratio_frequencies)
    combinations: list = dataclasses.field(default_factory=list)  # determined Fisher eigen-directions: value ± std

    @property
    def dof(self) -> int:
        return max(self.n_data - len(self.names), 1)

    @property
    def determined(self) -> bool:
        return not self.undetermined

    def _estimate_text(self, name: str) -> str:
        std = self.std.get(name)
        return f"{self.estimates[name]:.4g} ± {std:.2g}" if std is not None else f"{self.estimates[name]:.4g} (undetermined)"

    def _show_items(self):
        items = [("status", self.status), ("solver", self.solver),
                 ("chi2/dof", f"{self.chi2:.4g}/{self.dof} = {self.chi2 / self.dof:.4g}")]
        items += [(name, self._estimate_text(name)) for name in self.estimates]
        if self.undetermined:
            items.append(("undetermined", "; ".join(u["combination"] for u in self.undetermined)))
        if self.at_bounds:
            items.append(("at_bounds", ", ".join(self.at_bounds)))
        return items

    def _show_tables(self):
        rows = []
        for name, value in self.estimates.items():
            q = self.quantiles.get(name) or (None, None, None)
            rows.append((name, value, self.std.get(name), *q))
        tables = [Table("parameters (Laplace: estimate, standard deviation, 5/50/95 % quantiles; — where the data "
                        "do not determine it)", ("quantity", "estimate", "std", "5 %", "50 %", "95 %"), rows)]
        if self.ratios:
            tables.append(Table("what the data determine: ratios S(W, μ0)/S(W, μk) (Laplace)",
                                ("ratio", "estimate", "std", "5 %", "95 %"),
                                [(n, r["estimate"], r["std"], *((r["quantiles_5_50_95"] or [None] * 3)[::2]))
                                 for n, r in self.ratios.items()]))
        if self.combinations:
            tables.append(Table("determined combinations of θ (Fisher eigen-directions)", ("combination", "value", "std"),
                                [(c["combination"], c["value"], c["std"]) for c in self.combinations]))
        if self.undetermined:
            tables.append(Table("combinations the data do not determine", ("combination", "Fisher eigenvalue", "std"),
                                [(u["combination"], u["fisher_eigenvalue"], u["std"]) for u in self.undetermined]))
        return tables

    def plot(self, problem: "Problem", **options):
        """Data, fit and whitened residuals per scale: :func:`fitting.plot_fit` (``problem`` is
        the fit's, options as there); returns a ``matplotlib.figure.Figure``."""
        from ._plot import plot_fit

        return plot_fit(problem, self, **options)

    def to_json(self) -> dict:
        return {
            "solver": self.solver,
            "status": self.status,
            "chi2": self.chi2,
            "n_data": self.n_data,
            "dof": self.dof,
            "reduced_chi2": self.chi2 / self.dof,
            "starts": self.starts,
            "at_prior_bounds": self.at_bounds,
            "theta_names": list(self.names),
            "theta": self.theta.tolist(),
            "estimates": self.estimates,
            "std": self.std,
            "quantiles_5_50_95": self.quantiles,
            "identifiability": {
                "fisher_eigenvalues": self.eigenvalues.tolist(),
                "determined_combinations": self.combinations,
                "undetermined_combinations": self.undetermined,
                "notes": self.notes,
            },
            "ratios": self.ratios,
        }


def starting_points(problem, options) -> np.ndarray:
    """The model's data-driven start and ``starts − 1`` jittered copies, clipped to the box."""
    lo, hi = np.asarray(problem.lower), np.asarray(problem.upper)
    theta0 = np.clip(problem.model.initial(problem.data), lo, hi)
    rng = np.random.default_rng(options["seed"])
    jitter = rng.normal(0.0, options["spread"], (options["starts"] - 1, theta0.size))
    return np.clip(np.vstack([theta0, theta0 + jitter]), lo, hi)


def fit(
    model: AbstractModel,
    data: Dataset,
    *,
    solver: str = "lm",
    starts: int = 8,
    spread: float = 0.5,
    seed: int = 0,
    max_steps: int = 256,
    rtol: float = 1e-6,
    atol: float = 1e-6,
    undetermined_std: float = 1.0,
) -> FitResult:
    """Maximum-likelihood fit of ``model`` to ``data`` from several starting points.

    Args:
        model, data: what to fit to what.
        solver: ``"lm"`` (Levenberg–Marquardt, default), ``"gauss_newton"``, ``"dogleg"`` or
            ``"bfgs"`` (a minimiser of ½‖r‖²).
        starts: number of starts: the model's data-driven start plus ``starts − 1`` jittered
            copies (normal, standard deviation ``spread`` in θ), all clipped to the prior box.
            They share one compiled solve.
        seed: seed of the jitter.
        max_steps, rtol, atol: optimistix settings: a start has converged when an accepted
            step changes θ by less than ``atol + rtol·|θ_i|`` and the residuals by less than
            ``atol + rtol·|r_i|``, both in the root-mean-square over components (residuals
            are in units of σ, so 1e-6 is far below the noise; Levenberg–Marquardt
            converges quadratically, so the last step bounds the error). Tighter settings
            or a max-norm only add steps at the rounding level (experiments/bench_fit.py
            checks the optimum against SciPy).
        undetermined_std: threshold of the identifiability analysis (module docstring).

    Returns:
        A :class:`FitResult`; inspect ``status`` and ``undetermined`` before trusting it.

    Raises:
        InvalidInputError: ``model``/``data`` of the wrong type or not belonging together
            (:class:`Problem`); an unknown ``solver``; ``starts``, ``max_steps`` not integers
            ≥ 1, ``seed`` not an integer ≥ 0; ``spread``, ``rtol``, ``atol`` not finite and
            ≥ 0 (``rtol``, ``atol`` not both 0), ``undetermined_std`` not finite and > 0;
            every start ending with a non-finite χ².
    """
    check_pair(model, data, "fit(model, data)")
    options = fit_options(solver=solver, starts=starts, max_steps=max_steps, spread=spread, seed=seed, rtol=rtol,
                          atol=atol, undetermined_std=undetermined_std)
    problem = Problem(model, data)
    optimiser = _make_solver(solver, options["rtol"], options["atol"])
    y0 = jnp.asarray(starting_points(problem, options), dtype=jnp.float64)
    # one compiled solve, called per start (vmapping the solve compiles ~2.5× longer here)
    runs = [_solve(problem, y, optimiser, options["max_steps"]) for y in y0]
    values, codes, steps, chi2s, jacobians = (np.stack([np.asarray(run[i]) for run in runs]) for i in range(5))
    return result_of_starts(problem, values, codes, steps, chi2s, jacobians, options)


def check_pair(model, data, what: str) -> None:
    """InvalidInputError naming ``what`` unless ``model`` is a fitting model and ``data`` a Dataset."""
    if not isinstance(model, AbstractModel) or not isinstance(data, Dataset):
        raise InvalidInputError(
            f"{what} needs a fitting model (ParametricModel or NonParametricModel) and a fitting.Dataset "
            f"(fitting.Dataset.from_measurements); got {type(model).__name__} and {type(data).__name__}.")


def fit_options(*, solver, starts, max_steps, spread, seed, rtol, atol, undetermined_std) -> dict:
    """The options of :func:`fit` (and :func:`fitting.fit_many`) checked and normalised."""
    if not isinstance(solver, str) or solver not in SOLVERS:
        raise InvalidInputError(f"solver must be one of {SOLVERS}; got {solver!r}.")
    options = dict(solver=solver, starts=integer(starts, "starts", 1), max_steps=integer(max_steps, "max_steps", 1),
                   spread=real(spread, "spread", minimum=0.0), seed=integer(seed, "seed", 0),
                   rtol=real(rtol, "rtol", minimum=0.0), atol=real(atol, "atol", minimum=0.0),
                   undetermined_std=real(undetermined_std, "undetermined_std", minimum=0.0, strict=True))
    if options["rtol"] == 0 and options["atol"] == 0:
        raise InvalidInputError("rtol and atol must not both be 0: no step could ever meet the convergence test.")
    return options


def result_of_starts(problem, values, codes, steps, chi2s, jacobians, options) -> "FitResult":
    """The :class:`FitResult` of the solves from every start (arrays with the start first): the
    best start, the Laplace analysis at it, the quantities and ratios (module docstring)."""
    stage = _Analysis(problem, values, codes, steps, chi2s, jacobians, options)
    return stage.finish(*map(np.asarray, _evaluate(problem.model, *stage.inputs())))


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
        models = _stack_trees([problems[k].model for k in live])
        evaluated = tuple(map(np.asarray, _evaluate_many(models, *(_stack_trees(list(x)) for x in zip(*inputs)))))
        names = _quantity_names(problems[live[0]].model)  # one structure: the same quantities
        for j, k in enumerate(live):
            stages[k] = stages[k].finish(*(e[j] for e in evaluated), quantity_names=names)
    return stages


def _stack_trees(trees):
    """Pytrees of one structure stacked leaf by leaf along a new leading axis (NumPy on the host)."""
    return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *trees)


class _Analysis:
    """:func:`result_of_starts` in three stages: the host-side analysis of the starts (best
    start, Laplace analysis by :func:`brdfscale.laplace.laplace`, the draws), the arrays the
    compiled evaluation needs (:meth:`inputs`, for :func:`_evaluate` of one material or
    :func:`_evaluate_many` of a bucket), and the :class:`FitResult` from what it returns
    (:meth:`finish`)."""

    def __init__(self, problem, values, codes, steps, chi2s, jacobians, options):
        model = problem.model
        ok = (codes == optx.RESULTS.successful._value) & np.isfinite(chi2s)
        pool = np.flatnonzero(ok) if ok.any() else np.flatnonzero(np.isfinite(chi2s))
        if pool.size == 0:
            raise InvalidInputError("every start produced a non-finite χ²; check the data (σ, masks) and the model choice.")
        best = int(pool[np.argmin(chi2s[pool])])
        self.problem, self.options, self.chi2 = problem, options, float(chi2s[best])
        self.theta = theta = np.asarray(values[best])
        self.start_info = [
            {"chi2": float(c), "result": _RESULT_NAMES.get(int(k), str(int(k))), "steps": int(s),
             "at_best": bool(np.isfinite(c) and abs(c - chi2s[best]) <= 1e-6 * max(1.0, chi2s[best]))}
            for c, k, s in zip(chi2s, codes, steps)
        ]
        self.status = "converged" if ok[best] else _RESULT_NAMES.get(int(codes[best]), "failed")
        lo, hi = np.asarray(problem.lower), np.asarray(problem.upper)
        self.at_bounds = [n for n, t, a, b in zip(model.names, theta, lo, hi)
                          if t <= a + 1e-6 * (b - a) or t >= b - 1e-6 * (b - a)]
        # brdfscale.laplace: the one policy
        self.analysis = laplace(np.asarray(jacobians[best]), model.names, undetermined_std=options["undetermined_std"])
        # quantities: Laplace draws along the determined directions only (module docstring); a
        # quantity the undetermined directions move more than the determined ones gets no interval
        rng = np.random.default_rng(options["seed"] + 1)
        basis = self.analysis.determined_basis()
        self.draws = theta + rng.standard_normal((_LAPLACE_DRAWS, basis.shape[1])) @ basis.T
        # what the data determine whatever the parametrisation: the ratios S(μ0)/S(μ_k) at these |W|
        self.W = ratio_frequencies(problem.data)

    def inputs(self) -> tuple:
        """θ̂, the Laplace draws, the ratios' |W| and the scales: the arguments of :func:`_evaluate` after the model."""
        return self.theta, self.draws, self.W, np.asarray(self.problem.data.scales)

    def finish(self, q_hat, grads, q_draws, r_hat, r_grads, r_draws, quantity_names=None) -> "FitResult":
        """The :class:`FitResult` from :func:`_evaluate`'s arrays; ``quantity_names``: those of
        ``model.quantities`` where the caller knows them (a bucket's models share them)."""
        problem, model, data, analysis = self.problem, self.problem.model, self.problem.data, self.analysis
        names = model.names
        quantity_names = _quantity_names(model) if quantity_names is None else quantity_names
        estimates, std, quantiles = _summaries(analysis, quantity_names, q_hat, grads, q_draws)
        W, scales = self.W, np.asarray(data.scales)
        r_est, r_std, r_q = _summaries(analysis, ratio_names(data, W), r_hat, r_grads, r_draws)
        ratios = {name: {"estimate": r_est[name], "std": r_std[name], "quantiles_5_50_95": r_q[name],
                         "mu0": float(scales[0]), "mu": float(scales[1 + i // len(W)]),
                         "W": float(W[i % len(W)])}
                  for i, name in enumerate(r_est)}
        keep = ~analysis.undetermined_mask
        combinations = [{"combination": combination(analysis.eigenvectors[:, i], names),
                         "value": float(_signed(analysis.eigenvectors[:, i]) @ self.theta),
                         "std": float(1 / np.sqrt(analysis.eigenvalues[i]))}
                        for i in np.flatnonzero(keep)[::-1]]
        return FitResult(
            names=names, theta=self.theta, covariance=analysis.covariance, chi2=self.chi2, n_data=data.n_data,
            status=self.status, starts=self.start_info, estimates=estimates, std=std, quantiles=quantiles,
            eigenvalues=analysis.eigenvalues, undetermined=analysis.undetermined, notes=list(model.identifiability_notes),
            solver=self.options["solver"], at_bounds=self.at_bounds, eigenvectors=analysis.eigenvectors, ratios=ratios,
            combinations=combinations,
        )


def _quantity_names(model) -> list:
    """The names of ``model.quantities``, in its order (from an abstract evaluation: no
    computation; not from ``eval_shape``'s output, a dict that comes back with sorted keys)."""
    names = []

    def capture(t):
        quantities = model.quantities(t)
        names.extend(quantities)
        return jnp.stack(list(quantities.values()))

    jax.eval_shape(capture, jax.ShapeDtypeStruct((len(model.names),), jnp.float64))
    return names


def _summaries(analysis, names, values, grads, draws):
    """Estimate, standard deviation and widened 5/50/95 % quantiles of quantities from their
    Laplace draws along the determined directions (module docstring); None where undetermined."""
    _, var_undetermined = analysis.variances(grads)
    determined = analysis.quantity_is_determined(grads)
    estimates, std, quantiles = {}, {}, {}
    for idx, name in enumerate(names):
        estimates[name] = float(values[idx])
        if not determined[idx]:
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


RATIO_FREQUENCIES = (0.5, 1.0, 2.0)
"""The frequencies |W| at which the ratios ``S(W, μ0)/S(W, μ_k)`` are reported, in units of
``1/α``, α the half-maximum width of the widest (coarsest-scale) images: there every scale's
lobe transform is still well above the noise (``≈ e^{−1/16}, e^{−1/4}, e^{−1}`` of its peak for
a Beckmann lobe), so the ratio ``G(W, μ_k)/G(W, μ0)`` is what the images measure."""


def ratio_frequencies(data: Dataset) -> np.ndarray:
    """The reported ratios' frequencies |W| for this dataset (:data:`RATIO_FREQUENCIES` / α)."""
    _, width2 = moments(data)
    return np.asarray(RATIO_FREQUENCIES) / np.sqrt(max(float(np.max(width2)), 1e-300))


def ratio_names(data: Dataset, W) -> list[str]:
    """``"S(μ0)/S(μk) @ |W|=w"`` for every coarser scale k and frequency w."""
    return [f"S(μ0)/S(μ{k}) @ |W|={w:.4g}" for k in range(1, len(data.scales)) for w in np.asarray(W)]


def _evaluation(model, theta, draws, W, scales):
    """The quantities and the ratios ``S(W, μ0)/S(W, μ_k)``, k ≥ 1 (flattened), each at θ̂, their
    Jacobian there, and at every Laplace draw: what :class:`_Analysis` summarises."""
    def quantities(t):
        return jnp.stack(list(model.quantities(t).values()))

    def ratios(t):
        return model.relative_statistics(t, W, scales)[1:].ravel()

    return (quantities(theta), jax.jacfwd(quantities)(theta), jax.vmap(quantities)(draws),
            ratios(theta), jax.jacfwd(ratios)(theta), jax.vmap(ratios)(draws))


_evaluate = eqx.filter_jit(_evaluation)
_evaluate_many = eqx.filter_jit(jax.vmap(_evaluation))
