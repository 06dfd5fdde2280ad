"""One least-squares solve with optimistix: the solver by name or as an optimistix object, the
solve from one start, its result code by name through optimistix's public ``RESULTS`` and the
two outcomes this module adds.

The solve minimises ``½‖r(θ)‖²`` over the unconstrained coordinates θ of a model, ``r`` the
whitened residual rows of :class:`fitting.Problem` (or its :class:`~fitting._problem.Rows`).

**Scale invariance.** Scaling every σ by one factor c scales ``r`` by 1/c and cannot move the
optimum, but an optimiser's own numbers are absolute: optimistix's convergence test compares
the change of ``r`` with ``atol + rtol·|r|`` (its first step compares ``r(θ₀)`` itself, so any
problem whose residuals are all below ``atol`` "converges" at its start), and
Levenberg–Marquardt's damping starts at λ = 1 against ``JᵀJ ∝ 1/c²``. With σ × 1e10 the default
fit stopped at its start, far from the optimum, and reported that as converged. So the solver sees the rows
normalised by the root-mean-square of the non-zero rows at the start,

    r̃(θ) = ν r(θ),   ν = √m₀ / ‖r(θ₀)‖   (m₀: rows ≠ 0 at θ₀; ν = 1 if ‖r(θ₀)‖ is 0 or not finite),

one constant per solve, the same for data rows, prior rows (the non-parametric model's
smoothness rows) and any appended rows, so their relative weights and the optimum are those of
``½‖r‖²``; ``r̃`` does not change when σ is scaled (ν → cν), nor when values and σ change units
together, and its rows are of order 1 at the start, as whitened rows of a sensible start are. χ²
and the Jacobian are returned for ``r`` (``J = J̃/ν``), so the Laplace covariance, the samplers'
posterior and every reported χ² are those of the problem itself. Padding rows (zero weight,
:func:`fitting.fit_many`) are zero and do not count in m₀, so a batched solve is normalised as
the single one. tests/test_scale_invariance.py checks the optimum under σ × c for c = 1e-30 …
1e30 (60 decades) to 1e-8, χ² · c² and the covariance / c² to 1e-8 relative.

**Outcomes.** Beyond optimistix's results (:data:`RESULT_NAMES`), a solve that optimistix
calls successful is reported as

* ``"nonfinite"`` when θ̂, χ²(θ̂) or the Jacobian there is not finite (whatever optimistix
  said: a non-finite estimate never passes as converged);
* ``"stopped_at_start"`` when θ̂ is the start itself and the start is not stationary: some
  coordinate strictly inside the prior box has a Jacobian column ``J_i`` whose cosine with the
  residual exceeds :data:`STATIONARY_COSINE`, ``|J_iᵀ r| > 1e-4 ‖J_i‖ ‖r‖`` —
  moving along it alone would lower χ² by more than 1e-8 of itself (a cosine: the same for
  every σ scale and every unit of θ). A loose solver object (``atol`` above the residuals)
  stops there; the named solvers, normalised as above, do not. For ``gauss_newton_edm`` a start
  that meets that solver's own stop (the expected distance to the minimum below 1e-3 of the reduced
  χ²: :mod:`fitting._gauss_newton`) is stationary too — it stops there by design.
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx

from brdfscale import choices, InvalidInputError

from ._gauss_newton import GaussNewtonEDM


__all__ = [
    "RESULT_NAMES",
    "SOLVERS",
    "STATIONARY_COSINE",
    "make_solver",
    "resolve_solver",
    "solve",
    "solve_rows",
    "solver_name",
]

SOLVERS = tuple(choices.SOLVERS)
"""The solvers by name (:data:`brdfscale.choices.SOLVERS`): ``auto`` (default: the model's
``preferred_solver``, :func:`resolve_solver`), Levenberg–Marquardt (its damped steps solved by
QR), Levenberg–Marquardt with normal-equation steps (``lm_normal``:
``JᵀJ + λI`` by Cholesky — one n × n system per step instead of a QR of the m × n Jacobian, the
difference experiments/bench_anisotropic.py ``--normal`` measures on the anisotropic model's
8-scale, 65² px fit; it squares the condition number, so it suits well-conditioned problems with
many rows), Gauss–Newton, Gauss–Newton stopped on the expected distance to the minimum
(``gauss_newton_edm``: :mod:`fitting._gauss_newton`), dogleg, BFGS (a minimiser of ½‖r‖²)."""

_SOLVER_CLASSES = {
    "lm": optx.LevenbergMarquardt,
    "lm_normal": functools.partial(optx.LevenbergMarquardt, linear_solver=lx.Normal(lx.Cholesky())),
    "gauss_newton": optx.GaussNewton,
    "dogleg": optx.Dogleg,
    "bfgs": optx.BFGS,
    "gauss_newton_edm": GaussNewtonEDM,
}

# optimistix's result names, in the order of the codes a solve returns (index = code); through the
# public API only: ``getattr(optx.RESULTS, name)`` and ``==`` (a name the installed optimistix
# lacks is left out). Code −1: a result not among them.
_KNOWN_RESULTS = (
    "successful",
    "max_steps_reached",
    "singular",
    "breakdown",
    "stagnation",
    "conlim",
    "nonfinite_input",
    "nonlinear_max_steps_reached",
    "nonlinear_divergence",
    "nonfinite",
)


def _result_items() -> tuple:
    items = []
    for name in _KNOWN_RESULTS:
        try:
            items.append((name, getattr(optx.RESULTS, name)))
        except (AttributeError, KeyError):
            pass
    return tuple(items)


_RESULT_ITEMS = _result_items()
_OWN_RESULTS = ("nonfinite", "stopped_at_start")  # this module's outcomes (module docstring)
RESULT_NAMES = tuple(name for name, _ in _RESULT_ITEMS) + tuple(
    name for name in _OWN_RESULTS if name not in dict(_RESULT_ITEMS)
)
"""The name of every code :func:`solve_rows` returns (``RESULT_NAMES[0] == "successful"``):
optimistix's results, then ``"nonfinite"`` (where the installed optimistix lacks it) and
``"stopped_at_start"`` (module docstring)."""

STATIONARY_COSINE = 1e-4
"""The largest ``|J_iᵀ r|/(‖J_i‖ ‖r‖)`` at which a solve that never left its start still counts
as converged (module docstring)."""


def result_name(code: int) -> str:
    """The name of a code of :func:`solve_rows` (``"unknown"`` for −1)."""
    return RESULT_NAMES[code] if 0 <= code < len(RESULT_NAMES) else "unknown"


def is_solver(solver) -> bool:
    """Whether ``solver`` is an optimistix least-squares solver or minimiser object."""
    return isinstance(solver, (optx.AbstractLeastSquaresSolver, optx.AbstractMinimiser))


def check_solver(solver):
    """``solver`` if it is a name of :data:`SOLVERS` or an optimistix solver object, else
    :class:`~brdfscale.InvalidInputError` naming both forms."""
    if (isinstance(solver, str) and solver in SOLVERS) or is_solver(solver):
        return solver
    got = repr(solver) if isinstance(solver, str) else type(solver).__name__
    raise InvalidInputError(
        f"solver must be one of {SOLVERS} or an optimistix least-squares solver or minimiser "
        f"object (e.g. optimistix.LevenbergMarquardt(rtol=1e-6, atol=1e-6)); got {got}."
    )


def resolve_solver(solver, models):
    """``solver`` itself, or for ``"auto"`` the models' ``preferred_solver`` (``"lm"`` unless every
    model prefers the same other one: one solver serves a batch)."""
    if solver != "auto":
        return solver
    preferred = {getattr(m, "preferred_solver", "lm") for m in models}
    return preferred.pop() if len(preferred) == 1 else "lm"


def solver_name(solver) -> str:
    """The name a result records: the name given, or the optimistix object's class name."""
    return solver if isinstance(solver, str) else type(solver).__name__


def make_solver(solver, rtol: float, atol: float):
    """The optimistix solver: a name of :data:`SOLVERS` with root-mean-square norms in the
    convergence test (a max-norm over the residual rows keeps taking rounding-level steps:
    rows of merged pixels have large ∂r/∂θ) and ``rtol``, ``atol``; an optimistix object as
    it is (its own tolerances and norm)."""
    solver = check_solver(solver)
    if is_solver(solver):
        return solver
    name = "lm" if solver == "auto" else solver  # "auto" without a model to ask (resolve_solver): lm
    return _SOLVER_CLASSES[name](rtol=rtol, atol=atol, norm=optx.rms_norm)


def _residuals(theta, rows):
    # ``rows`` is a Problem or its Rows (fitting.fit_many)
    return rows.residuals(theta)


def _normalised_residuals(theta, args):
    # module-level, so optimistix sees the same function object on every call (no recompilation);
    # ``args``: the rows (as _residuals) and the normalisation ν (module docstring)
    rows, scale = args
    return _residuals(theta, rows) * scale


def _code(result) -> jax.Array:
    """The index in :data:`RESULT_NAMES` of an optimistix result (traced; −1 if none matches)."""
    matches = jnp.stack([result == item for _, item in _RESULT_ITEMS])
    return jnp.where(jnp.any(matches), jnp.argmax(matches), -1).astype(jnp.int32)


def normalisation(r0: jax.Array) -> jax.Array:
    """``ν = √m₀/‖r₀‖`` of the residuals ``r₀`` at the start, 1 where ``‖r₀‖`` is 0 or not finite
    (module docstring; traced)."""
    big = jnp.max(jnp.abs(r0), initial=0.0)
    safe = jnp.where((big > 0) & jnp.isfinite(big), big, 1.0)
    norm = big * jnp.sqrt(jnp.sum((r0 / safe) ** 2))  # ‖r0‖ without overflowing where ‖r0‖² would
    count = jnp.count_nonzero(r0).astype(r0.dtype)
    usable = (norm > 0) & jnp.isfinite(norm)
    return jnp.where(usable, jnp.sqrt(count) / jnp.where(usable, norm, 1.0), 1.0)


def _stationary(rows, theta, residuals, jac) -> jax.Array:
    """Whether no coordinate strictly inside the prior box has a Jacobian column at a cosine above
    :data:`STATIONARY_COSINE` with the residual (module docstring; traced)."""
    lo, hi = jnp.asarray(rows.lower), jnp.asarray(rows.upper)
    inside = (theta > lo + 1e-6 * (hi - lo)) & (theta < hi - 1e-6 * (hi - lo))
    column = jnp.sqrt(jnp.sum(jac * jac, axis=0))
    cosine = jnp.abs(residuals @ jac) / jnp.maximum(column * jnp.sqrt(residuals @ residuals), jnp.finfo(jac.dtype).tiny)
    return ~jnp.any(inside & (cosine > STATIONARY_COSINE))


@eqx.filter_jit
def solve(problem, y0, solver, max_steps):
    """One least-squares solve from ``y0``: θ̂, result code, steps, χ² and the Jacobian at θ̂."""
    return solve_rows(problem, y0, solver, max_steps)


def solve_rows(rows, y0, solver, max_steps):
    """The solve itself (traced; :func:`fitting.fit` jits it per start, :func:`fitting.fit_many`
    vmaps it over materials × starts): θ̂, result code (:data:`RESULT_NAMES`), steps,
    χ²(θ̂) and ``∂r/∂θ(θ̂)``.

    The solver works on the normalised rows ``r̃ = ν r`` (module docstring); χ² and the Jacobian
    returned are those of ``r``. The Gauss–Newton family (LM, dogleg, gauss_newton_edm) carries ``r̃`` and ``J̃`` in
    its state (``f_info``: the linearisation at the last accepted point, which is θ̂), so they are
    read from there rather than evaluated once more; other solvers evaluate them."""
    scale = normalisation(rows.residuals(y0))
    sol = optx.least_squares(_normalised_residuals, solver, y0, args=(rows, scale), max_steps=max_steps, throw=False)
    info = getattr(sol.state, "f_info", None)
    if isinstance(info, optx.FunctionInfo.ResidualJac):
        residuals, jac = info.residual / scale, info.jac.as_matrix() / scale
    else:
        residuals, jac = rows.residuals(sol.value), jax.jacfwd(rows.residuals)(sol.value)
    chi2 = rows.chi2_of_residuals(residuals)
    code = _code(sol.result)
    successful = code == RESULT_NAMES.index("successful")
    at_start = jnp.all(sol.value == y0)
    stationary = _stationary(rows, sol.value, residuals, jac)
    if isinstance(solver, GaussNewtonEDM):  # a start that meets its stop is stationary by its own test
        stationary = stationary | solver.settled(sol.state)
    code = jnp.where(
        successful & at_start & ~stationary,
        RESULT_NAMES.index("stopped_at_start"),
        code,
    )
    finite = jnp.all(jnp.isfinite(sol.value)) & jnp.isfinite(chi2) & jnp.all(jnp.isfinite(jac))
    code = jnp.where(finite, code, RESULT_NAMES.index("nonfinite")).astype(jnp.int32)
    return sol.value, code, sol.stats["num_steps"], chi2, jac
