"""Least-squares fit of nearly-specular strengths ``c_n`` and cut-off ``x0`` (seed §6).

Model of a measured lobe (values ``y_i ± σ_i`` at half-vector slope offsets ``u_i``), seen by an
instrument with a known Gaussian kernel ``K``:

    y(u) = A · (K ∗ s)(u),   s = f δ + Σ_n c_n h_n + (1 − f) s_smooth    (NearlySpecular)

with amplitude ``A``, cut-off ``x0``, strengths ``c_n`` and — only when a smooth shape is
given — the specular fraction ``f``. The model is linear in ``(A f, A c_n, A (1 − f))`` at
fixed ``x0``: those are solved by linear least squares at the initial ``x0`` to start
Levenberg–Marquardt (optimistix) on ``θ = (ln A, ln x0, c_0…c_{N−1}[, logit f])`` —
the logarithms and the logit keep ``A, x0 > 0`` and ``0 < f < 1`` without bounds.

Uncertainties: the Laplace (Gauss–Newton) approximation of the whitened residuals' Jacobian at
the optimum by :func:`brdfscale.laplace.laplace` — the identifiability policy of every fit in the
project: an eigen-decomposition of ``JᵀJ``, its pseudo-inverse over the determined directions,
the numerically null directions named as undetermined combinations — mapped to the natural
parameters by the delta method. A parameter the undetermined directions move gets σ = NaN and
the combination is listed in :attr:`StrengthFit.undetermined`, instead of arbitrary numbers.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Float

from .._errors import BrdfscaleError, InvalidInputError
from .._validation import as_float_array, positive, require_float64
from ..laplace import laplace
from ..stats import AbstractSlopeDensity, Gaussian
from ._nearly_specular import NearlySpecular, ObservedDensity
from ._transform import MAX_ORDER


_SOLVER = optx.LevenbergMarquardt(rtol=1e-10, atol=1e-12)


class StrengthFit(eqx.Module):
    """The result of :func:`fit_strengths`: estimates, 1σ (Laplace) uncertainties and diagnostics.

    ``covariance`` is over the natural parameters in the order ``names`` (the pseudo-inverse
    over the determined directions, :mod:`brdfscale.laplace`). ``undetermined`` names the
    combinations of ``(ln A, ln x0, c_n[, logit f])`` the data do not determine; a parameter
    they move has σ = None — no interval that would look like a measurement (the project's one
    representation of "undetermined", :mod:`brdfscale.laplace`); the σ fields are Python floats.
    Without a smooth shape the specular fraction is 1 by construction (``specular_fraction_sigma`` = 0).
    ``chi2`` is the minimum of Σ((model − y)/σ)², ``dof`` the samples minus the parameters.
    """

    strengths: Float[Array, " N"]
    strengths_sigma: tuple[float | None, ...] = eqx.field(static=True)
    x0: Float[Array, ""]
    x0_sigma: float | None = eqx.field(static=True)
    amplitude: Float[Array, ""]
    amplitude_sigma: float | None = eqx.field(static=True)
    specular_fraction: Float[Array, ""]
    specular_fraction_sigma: float | None = eqx.field(static=True)
    covariance: Float[Array, "p p"]
    names: tuple[str, ...] = eqx.field(static=True)
    chi2: float = eqx.field(static=True)
    dof: int = eqx.field(static=True)
    steps: int = eqx.field(static=True)
    statistic: NearlySpecular
    kernel: Gaussian
    undetermined: tuple[str, ...] = eqx.field(static=True, default=())

    @property
    def determined(self) -> bool:
        """True when the data determine every parameter (no undetermined combination)."""
        return not self.undetermined

    def model(self) -> ObservedDensity:
        """The fitted lobe shape as the instrument sees it (multiply by ``amplitude``)."""
        return ObservedDensity(self.statistic, self.kernel)


def _statistic(theta, smooth, orders):
    x0 = jnp.exp(theta[1])
    c = theta[2 : 2 + orders]
    if smooth is None:
        return NearlySpecular(jnp.asarray(1.0, theta.dtype), c, x0)
    f = jax.nn.sigmoid(theta[2 + orders])
    return NearlySpecular(f, c, x0, smooth=smooth, smooth_weight=1 - f)


def _residuals(theta, args):
    u, y, sigma, kernel, smooth = args
    orders = theta.shape[0] - 2 - (smooth is not None)
    model = jnp.exp(theta[0]) * ObservedDensity(_statistic(theta, smooth, orders), kernel).density(u)
    return (model - y) / sigma


def _linear_start(u, y, sigma, kernel, smooth, orders, x0):
    """θ from the linear least-squares solution for (A f, A c_n, A(1 − f)) at fixed x0."""
    basis = []
    for n in range(orders):
        c = jnp.zeros(orders, y.dtype).at[n].set(1.0)
        basis.append(
            ObservedDensity(NearlySpecular(1.0, c, x0), kernel).singular_part(u)
            - ObservedDensity(NearlySpecular(1.0, jnp.zeros(orders, y.dtype), x0), kernel).singular_part(u)
        )
    specular = ObservedDensity(NearlySpecular(1.0, jnp.zeros(orders, y.dtype), x0), kernel).singular_part(u)
    columns = [specular] + basis
    if smooth is not None:
        zero = jnp.zeros(orders, y.dtype)
        columns.append(
            ObservedDensity(NearlySpecular(0.0, zero, x0, smooth=smooth, smooth_weight=1.0), kernel).density(u)
        )
    design = np.stack([np.asarray(col).reshape(-1) for col in columns], axis=-1) / np.asarray(sigma).reshape(-1, 1)
    names = ["A·a"] + [f"A·c_{n}" for n in range(orders)] + (["A·w"] if smooth is not None else [])
    start = laplace(design, names, undetermined_std=np.inf)  # the linear model's Jacobian is its design matrix
    if start.undetermined:
        combinations = "; ".join(u["combination"] for u in start.undetermined)
        raise BrdfscaleError(
            "the data do not determine the strength fit: at the starting x0 the linear parameters have "
            f"an undetermined combination: {combinations}. Measure more distinct offsets or fit fewer orders."
        )
    beta, *_ = np.linalg.lstsq(design, np.asarray(y).reshape(-1) / np.asarray(sigma).reshape(-1), rcond=None)
    mass = beta[0] + (beta[-1] if smooth is not None else 0.0)
    if not mass > 0:
        raise BrdfscaleError(
            "the linear start of the strength fit found a non-positive total lobe mass; the data "
            "do not look like a nearly-specular lobe seen through this instrument kernel."
        )
    theta = [np.log(mass), np.log(float(x0))] + list(beta[1 : 1 + orders] / mass)
    if smooth is not None:
        f = np.clip(beta[0] / mass, 1e-6, 1 - 1e-6)
        theta.append(np.log(f / (1 - f)))
    return jnp.asarray(theta, dtype=jnp.float64)


def fit_strengths(
    u: Float[ArrayLike, "*batch 2"],
    values: Float[ArrayLike, "*batch"],
    sigma: Float[ArrayLike, "*batch"],
    *,
    kernel: Gaussian,
    orders: int,
    x0: Float[ArrayLike, ""],
    smooth: AbstractSlopeDensity | None = None,
    max_steps: int = 200,
) -> StrengthFit:
    """Fit ``A``, ``x0``, ``c_0 … c_{orders−1}`` (and ``f`` with ``smooth``) to a measured lobe.

    Args:
        u: half-vector slope offsets of the samples, (..., 2).
        values: the measured lobe ``A (K ∗ s)(u)`` (per unit slope area), same leading shape.
        sigma: per-sample standard deviations (> 0).
        kernel: the instrument's resolution, an isotropic centred :class:`brdfscale.stats.Gaussian`.
        orders: how many strengths ``c_0 … c_{orders−1}`` to fit (1 … 7).
        x0: the starting cut-off slope (> 0).
        smooth: a fixed smooth statistic shape, if the lobe has one; its weight is fitted.
        max_steps: Levenberg–Marquardt step limit.

    Returns:
        A :class:`StrengthFit`. Everything runs in float64 (optimistix requires one dtype).

    Raises:
        BrdfscaleError: the solver did not converge, there are fewer samples than
            parameters, or the linear start is singular (the message names the combination).
        InvalidInputError: bad shapes or values.
    """
    require_float64("fit_strengths")
    if isinstance(orders, bool) or not isinstance(orders, (int, np.integer)) or not 1 <= orders <= MAX_ORDER + 1:
        raise InvalidInputError(f"orders must be an integer in 1…{MAX_ORDER + 1}; got {orders!r}.")
    if not (isinstance(kernel, Gaussian) and kernel.isotropic):
        raise InvalidInputError("kernel must be an isotropic, centred brdfscale.stats.Gaussian.")
    u = as_float_array(u, "u").astype(jnp.float64)
    y = as_float_array(values, "values").astype(jnp.float64)
    s = positive(sigma, "sigma", "positive (standard deviations)").astype(jnp.float64)
    if u.shape[-1:] != (2,) or u.shape[:-1] != y.shape:
        raise InvalidInputError(f"u must have shape values.shape + (2,); got {u.shape} and {y.shape}.")
    s = jnp.broadcast_to(s, y.shape)
    x0 = positive(x0, "x0").astype(jnp.float64)
    kernel = jax.tree_util.tree_map(lambda a: jnp.asarray(a, jnp.float64), kernel)
    if smooth is not None:
        smooth = jax.tree_util.tree_map(lambda a: jnp.asarray(a, jnp.float64) if eqx.is_inexact_array(a) else a, smooth)

    n_params = 2 + orders + (smooth is not None)
    if y.size <= n_params:
        raise BrdfscaleError(
            f"the data do not determine the strength fit: {y.size} samples for {n_params} parameters "
            "(amplitude, x0, the strengths and any specular fraction); measure more offsets or fit fewer orders."
        )
    theta0 = _linear_start(u, y, s, kernel, smooth, orders, x0)
    args = (u, y, s, kernel, smooth)
    solution = optx.least_squares(_residuals, _SOLVER, theta0, args=args, max_steps=max_steps, throw=False)
    if solution.result != optx.RESULTS.successful:
        raise BrdfscaleError(
            f"the strength fit did not converge in {max_steps} Levenberg–Marquardt steps "
            f"({optx.RESULTS[solution.result]}); try another starting x0 or more max_steps."
        )
    theta = solution.value
    J = np.asarray(jax.jacfwd(_residuals)(theta, args))
    names = (
        ("amplitude", "x0")
        + tuple(f"c_{n}" for n in range(orders))
        + (("specular_fraction",) if smooth is not None else ())
    )
    internal = ("ln A", "ln x0") + names[2 : 2 + orders] + (("logit f",) if smooth is not None else ())
    # brdfscale.laplace, the one policy of every fit: only numerically null directions are
    # undetermined here (θ mixes logarithms, strengths and a logit: no common unit for a threshold)
    analysis = laplace(J, internal, undetermined_std=np.inf)
    theta_np = np.asarray(theta)
    scale = np.ones_like(theta_np)  # dθ_natural/dθ: the delta method
    scale[0], scale[1] = np.exp(theta_np[0]), np.exp(theta_np[1])
    if smooth is not None:
        f = 1 / (1 + np.exp(-theta_np[-1]))
        scale[-1] = f * (1 - f)
    covariance = scale[:, None] * analysis.covariance * scale[None, :]
    sd = analysis.std(np.diag(scale))  # None for a parameter the undetermined directions move (never a fake precision)
    statistic = _statistic(theta, smooth, orders)
    residual = np.asarray(_residuals(theta, args))
    return StrengthFit(
        strengths=theta[2 : 2 + orders],
        strengths_sigma=tuple(sd[2 : 2 + orders]),
        x0=jnp.exp(theta[1]),
        x0_sigma=sd[1],
        amplitude=jnp.exp(theta[0]),
        amplitude_sigma=sd[0],
        specular_fraction=statistic.specular,
        specular_fraction_sigma=sd[-1] if smooth is not None else 0.0,
        covariance=jnp.asarray(covariance),
        names=names,
        chi2=float(residual @ residual),
        dof=int(residual.size - theta_np.size),
        steps=int(solution.stats["num_steps"]),
        statistic=statistic,
        kernel=kernel,
        undetermined=tuple(u["combination"] for u in analysis.undetermined),
    )
