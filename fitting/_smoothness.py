"""The smoothness prior of the non-parametric models: its residual rows (:func:`smoothness_rows`,
shared by :class:`fitting.NonParametricModel` and :class:`fitting.AnisotropicNonParametricModel`)
and its weight from the data by generalised cross-validation (:func:`choose_smoothness`;
docs/fitting.md)."""

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np

from brdfscale.choices import MODEL

from ._data import Dataset


if TYPE_CHECKING:
    from ._nonparametric import NonParametricModel

__all__ = ["choose_smoothness", "smoothness_rows", "SMOOTHNESS_RULES", "DEFAULT_SMOOTHNESS", "SMOOTHNESS_CANDIDATES"]

SMOOTHNESS_RULES = ("auto", "gcv")
DEFAULT_SMOOTHNESS = MODEL.smoothness  # brdfscale.choices: the one source of defaults
SMOOTHNESS_CANDIDATES = tuple(np.logspace(-2.0, 3.0, 31).tolist())
"""The smoothness weights :func:`choose_smoothness` compares (6 per decade)."""


def smoothness_rows(profiles: jax.Array, weight: float) -> jax.Array:
    """The whitened rows of the smoothness prior: ``weight`` times the second differences of
    ``profiles`` along their last axis (the knots), ``s (P_{j+1} − 2 P_j + P_{j−1})``, flattened —
    a Gaussian prior of standard deviation 1/s on every second difference."""
    return weight * (profiles[..., 2:] - 2 * profiles[..., 1:-1] + profiles[..., :-2]).ravel()


def choose_smoothness(
    model: "NonParametricModel", data: Dataset, *, candidates=SMOOTHNESS_CANDIDATES, max_steps: int = 300
) -> tuple[float, tuple]:
    """The smoothness weight s of ``model`` chosen by generalised cross-validation.

    The fit minimises ``‖r(θ)‖² + s² ‖Δ²D(θ)‖²`` (whitened data residuals r, second
    differences of the decay D across knots). A pilot fit at the model's weight ``s0`` gives
    θ̂; about it the problem is linear: with the Jacobians ``J`` (data rows) and ``L`` (the
    second differences per unit weight) and the residuals ``r0``, ``p0`` there, one
    Gauss–Newton step for weight s,

        δ(s) = −(JᵀJ + s² LᵀL)⁺ (Jᵀr0 + s² Lᵀp0),

    predicts the data residual ``r0 + J δ`` and has the influence matrix
    ``A(s) = J (JᵀJ + s² LᵀL)⁺ Jᵀ``. The choice minimises

        GCV(s) = n χ²(s) / (n − tr A(s))²,   χ²(s) = ‖r0 + J δ(s)‖² + (within-pixel scatter),

    over ``candidates`` (n: the valid pixels). The linearisation is exact for a linear model
    and good near s0; one pilot fit suffices when the curvature of the model is mild
    (re-construct with ``regularisation=<the choice>`` and compare if in doubt).

    Returns ``(s, record)``: the choice and ``(candidates, GCV values, s0)`` as tuples.
    """
    from ._fit import fit
    from ._problem import Problem

    problem = Problem(model, data)
    pilot = fit(model, data, starts=1, max_steps=max_steps)
    theta = jnp.asarray(pilot.theta)
    jac = np.asarray(jax.jacfwd(problem.residuals)(theta))
    res = np.asarray(problem.residuals(theta))
    n_pen = len(np.asarray(model.penalty(theta)))
    s0 = model.smoothness
    J, r0 = jac[: len(res) - n_pen], res[: len(res) - n_pen]
    if n_pen == 0 or s0 == 0:
        return s0, (tuple(candidates), tuple(float("nan") for _ in candidates), s0)
    L, p0 = jac[len(res) - n_pen :] / s0, res[len(res) - n_pen :] / s0
    n = data.n_data
    offset = float(problem.points.chi2_offset)
    JtJ, LtL, Jtr, Ltp = J.T @ J, L.T @ L, J.T @ r0, L.T @ p0
    values = []
    for s in candidates:
        H = JtJ + s * s * LtL
        Hinv = np.linalg.pinv(H, rcond=1e-12, hermitian=True)
        delta = -Hinv @ (Jtr + s * s * Ltp)
        r = r0 + J @ delta
        trace = float(np.sum(Hinv * JtJ))  # tr(J H⁺ Jᵀ) = tr(H⁺ JᵀJ)
        values.append(n * (float(r @ r) + offset) / max(n - trace, 1e-12) ** 2)
    best = int(np.argmin(values))
    return float(candidates[best]), (tuple(float(c) for c in candidates), tuple(float(v) for v in values), float(s0))
