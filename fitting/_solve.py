"""One least-squares solve with optimistix: the solver by name or as an optimistix object, the
solve from one start, its result code by name through optimistix's public ``RESULTS``.

The solve minimises ``½‖r(θ)‖²`` over the unconstrained coordinates θ of a model, ``r`` the
whitened residual rows of :class:`fitting.Problem` (or its :class:`~fitting._problem.Rows`).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from brdfscale import choices, InvalidInputError


__all__ = ["RESULT_NAMES", "SOLVERS", "make_solver", "solve", "solve_rows", "solver_name"]

SOLVERS = tuple(choices.SOLVERS)
"""The solvers by name (:data:`brdfscale.choices.SOLVERS`): Levenberg–Marquardt (default),
Gauss–Newton, dogleg, BFGS (a minimiser of ½‖r‖²)."""

_SOLVER_CLASSES = {
    "lm": optx.LevenbergMarquardt,
    "gauss_newton": optx.GaussNewton,
    "dogleg": optx.Dogleg,
    "bfgs": optx.BFGS,
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
RESULT_NAMES = tuple(name for name, _ in _RESULT_ITEMS)
"""The name of every code :func:`solve_rows` returns (``RESULT_NAMES[0] == "successful"``)."""


def result_name(code: int) -> str:
    """The optimistix result name of a code of :func:`solve_rows` (``"unknown"`` for −1)."""
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
    return _SOLVER_CLASSES[solver](rtol=rtol, atol=atol, norm=optx.rms_norm)


def _residuals(theta, rows):
    # module-level, so optimistix sees the same function object on every call (no recompilation);
    # ``rows`` is a Problem or its Rows (fitting.fit_many)
    return rows.residuals(theta)


def _code(result) -> jax.Array:
    """The index in :data:`RESULT_NAMES` of an optimistix result (traced; −1 if none matches)."""
    matches = jnp.stack([result == item for _, item in _RESULT_ITEMS])
    return jnp.where(jnp.any(matches), jnp.argmax(matches), -1).astype(jnp.int32)


@eqx.filter_jit
def solve(problem, y0, solver, max_steps):
    """One least-squares solve from ``y0``: θ̂, result code, steps, χ² and the Jacobian at θ̂."""
    return solve_rows(problem, y0, solver, max_steps)


def solve_rows(rows, y0, solver, max_steps):
    """The solve itself (traced; :func:`fitting.fit` jits it per start, :func:`fitting.fit_many`
    vmaps it over materials × starts): θ̂, result code (:data:`RESULT_NAMES`), steps,
    χ²(θ̂) and ``∂r/∂θ(θ̂)``.

    The Gauss–Newton family (LM, dogleg) carries ``r`` and ``J`` in its state (``f_info``: the
    linearisation at the last accepted point, which is θ̂), so they are read from there
    rather than evaluated once more; other solvers evaluate them."""
    sol = optx.least_squares(_residuals, solver, y0, args=rows, max_steps=max_steps, throw=False)
    info = getattr(sol.state, "f_info", None)
    if isinstance(info, optx.FunctionInfo.ResidualJac):
        residuals, jac = info.residual, info.jac.as_matrix()
    else:
        residuals, jac = rows.residuals(sol.value), jax.jacfwd(rows.residuals)(sol.value)
    return sol.value, _code(sol.result), sol.stats["num_steps"], rows.chi2_of_residuals(residuals), jac
