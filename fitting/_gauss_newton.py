"""A Gauss–Newton solver that stops when the statistics are settled: line-searched Gauss–Newton
steps with the undetermined directions left out, stopped on the expected distance to the minimum
(the solver ``"gauss_newton_edm"`` of :data:`fitting.SOLVERS`; docs/fitting.md, "Solvers").

The solve minimises ``½‖r(θ)‖²`` (``r`` the whitened residual rows, normalised as
:mod:`fitting._solve` says). At an accepted point with Jacobian ``J`` and gradient ``g = Jᵀr``,

    δ = −(JᵀJ)⁺ g,   (JᵀJ)⁺ = Σ_{λ_i > ρ λ_max} v_i v_iᵀ / λ_i   (ρ = :data:`RCOND`),

the Gauss–Newton step on the eigen-decomposition of ``JᵀJ`` with the eigenvalues below ρ times the
largest left out: the directions the data do not determine (e.g. the anisotropic non-parametric
model's base-lobe nodes where the lobe is below the noise at every scale: their derivative is the
lobe itself, ≈ 0, and ``JᵀJ`` is singular there — experiments/nonparametric_solvers.py) are not
moved, where Levenberg–Marquardt keeps damping them. The step is scaled by a backtracking line search
(Armijo: halved until ``½‖r‖²`` falls by at least 1e-4 of the decrease the linearisation predicts).

**Stop.** The expected distance to the minimum of ``½χ²`` (MINUIT's EDM; −log-likelihood units),

    EDM = −½ gᵀδ = ½ gᵀ(JᵀJ)⁺g,

the decrease the full step predicts, is compared with the reduced χ²: the solve stops when

    EDM ≤ τ · χ²/m   (τ = :data:`EDM_TOLERANCE`, m the non-zero rows),

or when optimistix's own test (``rtol``/``atol`` on θ and on the residuals, as for the other named
solvers) is met. For an adequate model (χ²/m ≈ 1) that is EDM ≤ 1e-3: θ̂ lies within about
√(2 EDM) ≈ 0.045 standard errors of the optimum along every determined direction — what the
uncertainties need, where optimistix's test asks for the rounding level and the 470-parameter fit of
experiments/nonparametric_solvers.py takes 256 Levenberg–Marquardt steps without reaching it. For an
inadequate model the test loosens with χ²/m, as the standard errors scaled by √(χ²/m) do. The test is
the same in normalised and in raw units (both sides scale by ν²), so it keeps the solve's scale
invariance (tests/test_gauss_newton_edm.py).

Each iteration materialises ``J`` once (forward mode, one pass per parameter) and decomposes the n × n
matrix ``JᵀJ`` (n the parameters): meant for problems with many more rows than parameters.
"""

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax.flatten_util as jfu
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from jaxtyping import Array, Bool, Float, PyTree


__all__ = ["EDM_TOLERANCE", "GaussNewtonEDM", "RCOND"]

EDM_TOLERANCE = 1e-3
"""τ: the solve stops when the expected distance to the minimum is at most τ times the reduced χ²
(module docstring)."""

RCOND = 1e-9
"""ρ: eigenvalues of ``JᵀJ`` below ρ times the largest are left out of the step (module docstring)."""


class _DescentState(eqx.Module):
    step: PyTree
    edm: Float[Array, ""]
    result: optx.RESULTS


class _TruncatedNewtonDescent(optx.AbstractDescent):
    """The truncated Gauss–Newton step and its EDM at a linearisation (module docstring)."""

    rcond: float

    def init(self, y, f_info_struct) -> _DescentState:
        del f_info_struct
        return _DescentState(y, jnp.array(jnp.inf), optx.RESULTS.successful)

    def query(self, y, f_info, state) -> _DescentState:
        del state
        flat, unravel = jfu.ravel_pytree(y)
        jac = lx.materialise(f_info.jac).as_matrix()  # m × n
        residual, _ = jfu.ravel_pytree(f_info.residual)
        gradient = jac.T @ residual
        values, vectors = jnp.linalg.eigh(jac.T @ jac)
        keep = values > self.rcond * values[-1]
        newton = vectors @ jnp.where(keep, (vectors.T @ gradient) / jnp.where(keep, values, 1.0), 0.0)
        finite = jnp.all(jnp.isfinite(newton))
        result = optx.RESULTS.where(finite, optx.RESULTS.successful, optx.RESULTS.nonlinear_divergence)
        edm = 0.5 * gradient @ newton
        return _DescentState(unravel(newton.astype(flat.dtype)), jnp.where(finite, edm, jnp.inf), result)

    def step(self, step_size, state: _DescentState):
        flat, unravel = jfu.ravel_pytree(state.step)
        return unravel(-step_size * flat), state.result


class GaussNewtonEDM(optx.AbstractGaussNewton):
    """Line-searched, truncated Gauss–Newton stopped on the expected distance to the minimum
    (module docstring; ``fitting.fit(..., solver="gauss_newton_edm")``).

    Args:
        rtol, atol, norm: optimistix's convergence test on θ and the residuals (also stops).
        rcond: eigenvalues of ``JᵀJ`` below ``rcond`` × the largest are left out (:data:`RCOND`).
        edm_tolerance: τ of the EDM stop (:data:`EDM_TOLERANCE`).
    """

    rtol: float
    atol: float
    norm: Callable[[PyTree], Float[Array, ""]]
    descent: _TruncatedNewtonDescent
    search: optx.BacktrackingArmijo
    verbose: Callable[..., None]
    edm_tolerance: float

    def __init__(
        self,
        rtol: float,
        atol: float,
        norm: Callable[[PyTree], Float[Array, ""]] = optx.rms_norm,
        *,
        rcond: float = RCOND,
        edm_tolerance: float = EDM_TOLERANCE,
    ):
        self.rtol, self.atol, self.norm = rtol, atol, norm
        self.descent = _TruncatedNewtonDescent(rcond)
        self.search = optx.BacktrackingArmijo(decrease_factor=0.5, slope=1e-4)
        self.verbose = _quiet
        self.edm_tolerance = edm_tolerance

    def terminate(self, fn, y, args, options: dict[str, Any], state, tags) -> tuple[Bool[Array, ""], optx.RESULTS]:
        done, result = super().terminate(fn, y, args, options, state, tags)
        residual, _ = jfu.ravel_pytree(state.f_info.residual)
        rows = jnp.maximum(jnp.count_nonzero(residual), 1).astype(residual.dtype)
        settled = state.descent_state.edm <= self.edm_tolerance * jnp.sum(residual**2) / rows
        return done | (~state.first_step & settled), result


def _quiet(**kwargs) -> None:
    del kwargs
