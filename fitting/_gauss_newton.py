"""A Gauss–Newton solver that stops when the statistics are settled: line-searched Gauss–Newton
steps with the undetermined directions left out, stopped on the expected distance to the minimum
(the solver ``"gauss_newton_edm"`` of :data:`fitting.SOLVERS`; docs/fitting.md, "Estimation").

The solve minimises ``½‖r(θ)‖²`` (``r`` the whitened residual rows, normalised as
:mod:`fitting._solve` says; m the non-zero rows). At an accepted point with Jacobian ``J`` and
gradient ``g = Jᵀr``,

    δ = −(JᵀJ)⁺ g,   (JᵀJ)⁺ = Σ_{kept i} v_i v_iᵀ / λ_i,

the Gauss–Newton step on the eigen-decomposition ``JᵀJ = Σ λ_i v_i v_iᵀ`` with the directions left out that
the data neither determine nor ask to move along. In units of the inverse variance, inflated by the reduced χ²
(``s = m/‖r‖²``), a direction's curvature is ``c_i = λ_i s`` and the decrease of χ² the step along it alone
predicts is ``G_i = (v_iᵀg)²/λ_i · s``; it is kept where its eigenvalue is above the decomposition's rounding
level (:data:`RCOND` × the largest) and

* it is determined: ``c_i ≥`` :data:`DETERMINED` (a Laplace standard deviation of at most 1 in θ, inflated by
  the reduced χ²; the fit's report calls a direction determined, ``undetermined_std``, by its Fisher eigenvalue
  uninflated, ``λ_i ≥ 1`` in the rows' own units, so where ``‖r‖²/m ≤ 1`` — residuals no larger than the noise —
  no direction the report calls determined is one the solver did not fit; where the residuals exceed the noise,
  ``c_i = λ_i/(‖r‖²/m)`` is the stricter test, and a direction with ``1 ≤ λ_i < ‖r‖²/m`` is fitted only where it
  promises a significant gain); or
* the data ask for it: ``G_i ≥`` :data:`SIGNIFICANT_GAIN` (the step would lower χ² by 9 times the reduced χ²,
  a three-standard-deviation improvement) and ``c_i ≥`` :data:`FLAT` (a standard deviation of at most 10 in θ);
  or
* several ask for it together: of the directions left so far with ``c_i ≥ FLAT``, k in all, their gains
  summed reach ``q_k``, the upper ``p = P(χ²₁ > 9) = 0.0027`` quantile of χ² with k degrees of freedom
  (:func:`joint_thresholds`; ``q_1 = 9``, the single test). Why: where the current values of those k coordinates
  are the true ones, each ``v_iᵀg`` is the noise's projection, ``N(0, λ_i)`` in whitened units and independent
  across the orthogonal ``v_i``, so each ``G_i`` is χ²₁ (with ``s`` ≈ 1) and their sum χ²_k; the candidates are
  also those whose ``G_i`` fell below 9, so the test rejects that hypothesis at most at level ``p``. Then the
  largest-gain candidates are kept one by one until the gains of those still left out sum below ``q`` for their
  number — so "converged" (the EDM over the kept directions) also says that the directions left out with
  ``c_i ≥ FLAT``, together, have nothing significant to give (flatter ones and those at the rounding level are
  left out whatever they promise).

Left out, and so not moved from where they are: the rest — e.g. the anisotropic non-parametric model's
base-lobe nodes where the lobe is below the noise at every scale (``log g0`` there: its derivative is the lobe
itself, ≈ 0, and a Gauss–Newton step drives it towards −∞ by about 1 per step, the line search cutting every
other coordinate's step with it), where Levenberg–Marquardt keeps damping them (for such a log-amplitude
``G_i ≈ c_i < 1``: k of them sum below k, and ``q_k > k``); a node whose lobe the data show
brighter than the start (a heavy tail started from a Gaussian) has a large ``G_i`` and is fitted.
Every test is invariant under scaling σ (λ and ``‖r‖²`` scale alike, and so do ``(vᵀg)²/λ`` and ``‖r‖²``). An
earlier rule (to December 2026) kept a direction wherever its eigenvalue was above 1e-9 of the largest or
``c_i ≥ 1``: on README's chain at ``poisson:0.05:1``
(mi-1, the μ0 lobe's flux 37 times its noise) that kept dozens of such nodes, which walked one after another to
the prior's floor, and the solve ran out of steps (docs/fitting.md, "The anisotropic non-parametric model";
tests/test_gauss_newton_edm.py checks each case on linear problems). Until the joint test (December 2026) the
directions were tested one at a time only.

The step is scaled by a backtracking line search (Armijo: halved until ``½‖r‖²`` falls by at least 1e-4 of the
decrease the linearisation predicts).

**Stop.** The expected distance to the minimum of ``½χ²`` (MINUIT's EDM; −log-likelihood units),

    EDM = −½ gᵀδ = ½ gᵀ(JᵀJ)⁺g,

the decrease the full step predicts, is compared with the reduced χ²: the solve stops when

    EDM ≤ τ · ‖r‖²/m   (τ = :data:`EDM_TOLERANCE`),

and on nothing else (optimistix's ``rtol``/``atol`` test is not used: a step cut short by the line
search can change θ and r by little while far from the minimum). For an adequate model (‖r‖²/m ≈ 1)
that is EDM ≤ 1e-3: θ̂ lies within about √(2 EDM) ≈ 0.045 standard errors of the optimum along every
direction kept — what the uncertainties need, where optimistix's test asks for the rounding level and the
470-parameter fit of experiments/nonparametric_solvers.py takes 256 Levenberg–Marquardt steps without
reaching it. For an inadequate model the test loosens with ‖r‖²/m, as standard errors scaled by
√(χ²/dof) do. Like the cut, it is the same in normalised and in raw units, so the solve keeps
:mod:`fitting._solve`'s scale invariance (tests/test_gauss_newton_edm.py). A start that already meets
it is stationary by this solver's own test: :func:`fitting._solve.solve_rows` reports it converged, not
``stopped_at_start`` (:meth:`GaussNewtonEDM.settled`).

Each iteration materialises ``J`` once (forward mode, one pass per parameter) and decomposes the n × n
matrix ``JᵀJ`` (n the parameters): meant for problems with many more rows than parameters.
"""

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.flatten_util as jfu
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
import scipy.stats
from jaxtyping import Array, Bool, Float, PyTree


__all__ = [
    "DETERMINED",
    "EDM_TOLERANCE",
    "FLAT",
    "GaussNewtonEDM",
    "JOINT_LEVEL",
    "RCOND",
    "SIGNIFICANT_GAIN",
    "joint_thresholds",
]

EDM_TOLERANCE = 1e-3
"""τ: the solve stops when the expected distance to the minimum is at most τ times the reduced χ²
(module docstring)."""

RCOND = 1e-13
"""Eigenvalues of ``JᵀJ`` below this times the largest are at the rounding level of its decomposition (a few
hundred times double precision's 2.2e-16): their directions are left out (module docstring)."""

DETERMINED = 1.0
"""A direction whose curvature ``λ · m/‖r‖²`` is at least this is determined, and kept (module docstring)."""

SIGNIFICANT_GAIN = 9.0
"""A direction less curved than :data:`DETERMINED` is kept where the step along it predicts a decrease of χ² of at
least this many times the reduced χ² (module docstring)."""

FLAT = 0.01
"""…and where its curvature is at least this (module docstring)."""

JOINT_LEVEL = float(scipy.stats.chi2.sf(SIGNIFICANT_GAIN, 1))
"""The level of the joint test of the directions left out, that of the single test: ``P(χ²₁ > 9) ≈ 0.0027``
(module docstring)."""


def _rows(residual) -> jax.Array:
    """m: the non-zero rows (padding rows of :func:`fitting.fit_many` are zero), at least 1."""
    return jnp.maximum(jnp.count_nonzero(residual), 1).astype(residual.dtype)


def truncated_step(jac: Float[Array, "m n"], residual: Float[Array, " m"], *, rcond: float = RCOND):
    """``(δ⁺, EDM)``: the Gauss–Newton step ``(JᵀJ)⁺Jᵀr`` (to be subtracted) with the undetermined directions
    left out, and ``EDM = ½ gᵀ(JᵀJ)⁺g`` (module docstring; traced)."""
    gradient = jac.T @ residual
    values, vectors = jnp.linalg.eigh(jac.T @ jac)
    per_variance = _rows(residual) / jnp.maximum(residual @ residual, jnp.finfo(residual.dtype).tiny)
    along = vectors.T @ gradient  # vᵢᵀg
    resolved = values > rcond * values[-1]
    curvature = values * per_variance
    gain = along**2 / jnp.where(resolved, values, 1.0) * per_variance  # the χ² decrease the step along vᵢ predicts
    keep = resolved & ((curvature >= DETERMINED) | ((gain >= SIGNIFICANT_GAIN) & (curvature >= FLAT)))
    keep = keep | _jointly_significant(resolved & ~keep & (curvature >= FLAT), gain)
    newton = vectors @ jnp.where(keep, along / jnp.where(keep, values, 1.0), 0.0)
    return newton, 0.5 * gradient @ newton


def joint_thresholds(n: int) -> np.ndarray:
    """``q_k`` for k = 0 … n: the upper :data:`JOINT_LEVEL` quantile of χ² with k degrees of freedom (``q_0 = ∞``;
    ``q_1`` = :data:`SIGNIFICANT_GAIN`), the threshold of the joint test (module docstring). SciPy's ``chi2.isf``,
    at trace time (n is the parameter count, static)."""
    return np.concatenate([[np.inf], scipy.stats.chi2.isf(JOINT_LEVEL, np.arange(1, n + 1))])


def _jointly_significant(candidate: Bool[Array, " n"], gain: Float[Array, " n"]) -> Bool[Array, " n"]:
    """The candidates to keep by the joint test (module docstring): the j largest gains among the k candidates, j
    the least for which the other k − j gains sum below ``q_{k−j}`` (traced)."""
    n = gain.shape[0]
    order = jnp.argsort(jnp.where(candidate, -gain, jnp.inf))  # the candidates first, largest gain first
    ranked = jnp.where(candidate[order], gain[order], 0.0)
    left = jnp.cumsum(ranked[::-1])[::-1]  # left[j]: the gains summed over the candidates ranked j and after
    remaining = jnp.sum(candidate) - jnp.arange(n)  # how many candidates those are
    significant = (remaining > 0) & (left >= jnp.asarray(joint_thresholds(n), gain.dtype)[jnp.maximum(remaining, 0)])
    kept = jnp.argmin(jnp.append(significant, False).astype(jnp.int32))  # the first j whose rest is not significant
    return jnp.zeros(n, bool).at[order].set(jnp.arange(n) < kept)


def settled(edm, residual, tolerance: float = EDM_TOLERANCE) -> jax.Array:
    """Whether ``EDM ≤ τ · ‖r‖²/m`` (module docstring; traced)."""
    return edm <= tolerance * (residual @ residual) / _rows(residual)


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
        newton, edm = truncated_step(jac, residual, rcond=self.rcond)
        finite = jnp.all(jnp.isfinite(newton)) & jnp.isfinite(edm)
        result = optx.RESULTS.where(finite, optx.RESULTS.successful, optx.RESULTS.nonlinear_divergence)
        return _DescentState(unravel(newton.astype(flat.dtype)), jnp.where(finite, edm, jnp.inf), result)

    def step(self, step_size, state: _DescentState):
        flat, unravel = jfu.ravel_pytree(state.step)
        return unravel(-step_size * flat), state.result


class GaussNewtonEDM(optx.AbstractGaussNewton):
    """Line-searched, truncated Gauss–Newton stopped on the expected distance to the minimum
    (module docstring; ``fitting.fit(..., solver="gauss_newton_edm")``).

    Args:
        rtol, atol, norm: kept for optimistix's interface (the named solvers are made with them); not
            used: the EDM is the only stop (module docstring).
        rcond: the rounding level of ``JᵀJ``'s eigenvalues relative to the largest (:data:`RCOND`): directions below
            it are left out whatever the noise says (module docstring).
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
        # the EDM of the last accepted point (infinite before the first step); optimistix's own test
        # (state.terminate) is not used: module docstring
        return self.settled(state), state.result

    def settled(self, state) -> jax.Array:
        """Whether the last accepted point of a solve that ended in ``state`` (``Solution.state``) meets this
        solver's stop (traced; the EDM its final descent computed there, not decomposed again):
        :func:`fitting._solve.solve_rows` asks it of a start the solve returned unmoved."""
        residual, _ = jfu.ravel_pytree(state.f_info.residual)
        return settled(state.descent_state.edm, residual, self.edm_tolerance)


def _quiet(**kwargs) -> None:
    del kwargs
