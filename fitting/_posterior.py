"""The posterior every sampler of :func:`fitting.sample` draws from, and its sampling coordinates.

**Posterior.** In the model's unconstrained coordinates θ (:class:`fitting.Problem`),

    log p(θ | data) = −½ χ²(θ) + log π(θ) + const,   π uniform on the prior box lo ≤ θ ≤ hi

(:func:`log_posterior`; for the parametric model a log-uniform, scale-invariant prior on every
positive parameter over the ranges of docs/fitting.md; smoothness rows of the non-parametric
model are part of χ²) — the same for every sampler.

**Sampling coordinates.** The box is a hard wall, which gradient-based samplers handle
badly, so every sampler (emcee's ensembles as well as BlackJAX's NUTS and HMC) works in
unbounded coordinates z ∈ ℝᵈ, with per coordinate

    θ(z) = lo + w·[softplus((z − lo)/w) − softplus((z − hi)/w)],   w = (hi − lo)/50:

strictly increasing from lo (z → −∞) to hi (z → +∞), and the identity, to within w·e^{−δ/w},
at a distance δ from both walls — a posterior inside the box is sampled in its own
coordinates, unbent (a logistic map over the whole box would bend every ridge). The density
of z carries the map's Jacobian,

    log p(z | data) = log p(θ(z) | data) + Σ_i log dθ_i/dz_i,
    log dθ/dz = log σ((z − lo)/w) + log σ((hi − z)/w) + log(1 − e^{−50})
              = −softplus(−(z − lo)/w) − softplus((z − hi)/w) + log(1 − e^{−50})

(σ the logistic function), so the draws of z, mapped through θ(z), are draws of p(θ | data).

**Undetermined directions: the determined subspace is sampled.** The combinations the fit
marks *undetermined* (``FitResult.undetermined``: the k eigen-directions v_j of F = JᵀJ with
the smallest eigenvalues) are not sampled: the samplers move in the (d − k)-dimensional plane

    z = z₀ + B ζ,   ζ ∈ ℝ^{d−k},   z₀ = z(θ̂),   B ⊥ {D₀⁻¹ v_j}   (orthonormal columns),

D₀ = diag(dθ/dz) at z₀: the plane through the optimum along which, to first order, θ moves
in the determined directions only, the undetermined combinations held at the fit's values
(:class:`Target`; ``log_density(ζ) = log p(z₀ + Bζ | data)``, the conditional density of z on
the plane, its Jacobian included). The alternative — sampling them under the prior — walks a
ridge the data leave flat: on the width law with two scales (``mu_c``, ``exponent``
undetermined) NUTS and HMC then diverged in 600–950 of 4000 transitions and did not
converge on the determined ``amplitude`` and ``alpha_lobe``; in the plane they converge with
no divergence, and those two get the fit's Laplace standard deviations. The price, stated
with every result: the chain gives the undetermined combinations no spread (the report gives
them none either), and a determined quantity's spread is its conditional spread — without the
linearised contribution of the undetermined directions that the fit adds (at most a ninth of
its variance; :func:`brdfscale.laplace.laplace`). With no undetermined direction, B = I: the
full posterior.

**Preconditioning.** The Laplace approximation in ζ (:func:`laplace`) gives every sampler its
starts and NUTS/HMC their inverse mass matrix: the fit's Gaussian approximation of the
likelihood, ``−½ (θ − θ̂)ᵀ F (θ − θ̂)`` (:class:`fitting.FitResult`: ``eigenvalues``,
``eigenvectors``), times the Jacobian, is maximised over the plane by damped Gauss–Newton
steps (NumPy, no compilation); at the maximum ζ*, with D = diag(dθ/dz),

    P_ζ = Bᵀ [D F D + diag(−d² log(dθ/dz)/dz²)] B

is the Gauss–Newton precision and Σ_ζ = P_ζ⁻¹ the covariance (positive definite: only
determined directions remain). A θ̂ on the box's wall (``at_bounds``) gets a finite ζ* where
the likelihood's pull meets the Jacobian's.
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._batch import _pad_points, bucket_points
from ._problem import Rows


__all__ = [
    "COORDINATES",
    "PRIOR_TEXT",
    "Target",
    "initial_positions",
    "laplace",
    "log_jacobian",
    "log_posterior",
    "target",
    "theta_of_z",
    "z_of_theta",
]

BEND = 50.0
"""The map θ(z) bends over a width w = (hi − lo)/BEND next to each wall, and is the identity elsewhere."""
#: The sampling coordinates, as recorded in checkpoints (a change of the map changes this).
COORDINATES = "z: theta = lo + w (softplus((z - lo)/w) - softplus((z - hi)/w)), w = (hi - lo)/50"
#: What the prior is, in words (SampleResult and the report state it).
PRIOR_TEXT = (
    "uniform on the prior box lo ≤ θ ≤ hi of the model's coordinates θ (log-uniform on each positive "
    "parameter); sampled in z with θ = lo + w·[softplus((z − lo)/w) − softplus((z − hi)/w)], "
    "w = (hi − lo)/50, the Jacobian Σ log|dθ/dz| included; the combinations the fit does not determine are "
    "not sampled but held at the fit's values (the chain samples the determined subspace)"
)


def log_posterior(theta, problem):
    """``−½χ²(θ)`` inside the prior box, −∞ outside or where not finite: log p(θ | data) up to a
    constant, for the box-uniform prior (:class:`Target` adds the prior on undetermined combinations)."""
    lp = -0.5 * problem.chi2(theta)
    inside = jnp.all((theta >= problem.lower) & (theta <= problem.upper))
    return jnp.where(inside & jnp.isfinite(lp), lp, -jnp.inf)


def _map(xp, softplus, z, lo, hi):
    w = (hi - lo) / BEND
    return lo + w * (softplus((z - lo) / w) - softplus((z - hi) / w))


def _log_jacobian(xp, softplus, z, lo, hi):
    w = (hi - lo) / BEND
    return xp.sum(-softplus(-(z - lo) / w) - softplus((z - hi) / w) + xp.log(-xp.expm1(-BEND)), axis=-1)


def _softplus_np(x):
    return np.logaddexp(0.0, x)


def theta_of_z(z, problem):
    """θ(z) = lo + w·[softplus((z − lo)/w) − softplus((z − hi)/w)], w = (hi − lo)/50 (any leading
    batch axes): strictly increasing from lo (z → −∞) to hi (z → ∞), the identity to within
    ``w·e^{−d/w}`` at a distance d from both walls."""
    return _map(jnp, jax.nn.softplus, z, problem.lower, problem.upper)


def log_jacobian(z, problem):
    """``Σ_i log dθ_i/dz_i = Σ_i [−softplus(−(z_i − lo_i)/w_i) − softplus((z_i − hi_i)/w_i) + log(1 − e^{−50})]``."""
    return _log_jacobian(jnp, jax.nn.softplus, z, problem.lower, problem.upper)


def theta_of_z_np(z, lower, upper):
    """:func:`theta_of_z` in NumPy (emcee's host-side bookkeeping)."""
    return _map(np, _softplus_np, z, lower, upper)


def log_jacobian_np(z, lower, upper):
    """:func:`log_jacobian` in NumPy."""
    return _log_jacobian(np, _softplus_np, z, lower, upper)


def z_of_theta(theta, lower, upper):
    """The inverse map (NumPy): with x = (θ − lo)/w, R = 50, ``z = lo + w·[log(e^x − 1) − log(1 − e^{x − R})]``;
    θ on a wall (no finite z) is taken 1e-12 of the range inside it."""
    w = (upper - lower) / BEND
    x = np.clip((np.asarray(theta, float) - lower) / w, 1e-12 * BEND, BEND * (1 - 1e-12))
    return lower + w * (np.log(np.expm1(x)) - np.log(-np.expm1(x - BEND)))


def _sigmoid(x):
    return 0.5 * (1.0 + np.tanh(0.5 * x))


class Target(eqx.Module):
    """The sampled posterior (module docstring): ``problem`` — what :func:`log_posterior` needs
    (``chi2``, ``lower``, ``upper``): the residual rows of a :class:`fitting.Problem`, padded
    (:func:`padded_rows`) — and the determined subspace of z,
    ``z = origin + basis @ ζ`` (``basis`` (d, m) with orthonormal columns, m = d − k; with no
    undetermined direction the identity, and ζ = z − origin)."""

    problem: Rows
    origin: jax.Array
    basis: jax.Array

    def z(self, zeta):
        """z of the sampler's coordinates ζ (any leading batch axes)."""
        return self.origin + zeta @ self.basis.T

    def theta(self, zeta):
        """θ of the sampler's coordinates ζ."""
        return theta_of_z(self.z(zeta), self.problem)

    def log_density(self, zeta):
        """``log p(θ(z) | data) + Σ log dθ/dz`` at z = origin + basis·ζ: what every sampler draws ζ from."""
        z = self.z(zeta)
        return log_posterior(theta_of_z(z, self.problem), self.problem) + log_jacobian(z, self.problem)

    def log_prob_theta(self, zeta, log_density):
        """log p(θ | data) (up to a constant) from the sampler's log-density: the Jacobian taken off."""
        return log_density - log_jacobian(self.z(zeta), self.problem)

    def record(self) -> dict:
        """The subspace's arrays (NumPy), as the checkpoint stores them."""
        return {"origin": np.asarray(self.origin), "basis": np.asarray(self.basis)}

    @property
    def dimension(self) -> int:
        return self.basis.shape[1]


def undetermined_directions(fit) -> np.ndarray:
    """The fit's undetermined eigen-directions v_k as columns (d, k): the k = len(fit.undetermined)
    eigenvectors of F = JᵀJ with the smallest eigenvalues (the identifiability policy of
    :func:`brdfscale.laplace.laplace` marks exactly those)."""
    k = len(fit.undetermined)
    if getattr(fit, "eigenvectors", None) is not None:
        V = np.asarray(fit.eigenvectors)[:, np.argsort(np.asarray(fit.eigenvalues), kind="stable")]
    else:
        V = np.linalg.eigh(fisher(fit))[1]
    return V[:, :k]


def _dtheta_dz(z, lo, hi):
    bend = (hi - lo) / BEND
    return _sigmoid((z - lo) / bend) * _sigmoid(-(z - hi) / bend) * -np.expm1(-BEND)


def target(problem, fit, record: dict | None = None) -> Target:
    """The posterior of ``problem`` on the determined subspace of ``fit`` (module docstring) —
    or, given ``record`` (:meth:`Target.record` of a checkpoint), on that subspace exactly."""
    if record is None:
        lo, hi = np.asarray(problem.lower), np.asarray(problem.upper)
        z0 = z_of_theta(fit.theta, lo, hi)
        U = undetermined_directions(fit)
        d, k = U.shape
        if k == 0:
            basis = np.eye(d)
        else:
            # the z-directions that move θ along the undetermined v_k at z0 are D⁻¹ v_k; the
            # sampled plane is their orthogonal complement
            held = U / _dtheta_dz(z0, lo, hi)[:, None]
            q = np.linalg.qr(held, mode="complete")[0]
            basis = q[:, k:]
        record = {"origin": z0, "basis": basis}
    return Target(
        padded_rows(problem), jnp.asarray(record["origin"], jnp.float64), jnp.asarray(record["basis"], jnp.float64)
    )


def padded_rows(problem):
    """The residual rows of ``problem`` (:meth:`fitting.Problem.rows`) with the points of every
    scale padded, at zero weight, up to :func:`fitting._batch.bucket_points` — what
    :func:`fitting.fit_many` pads a material to. Padded rows add exactly 0 to χ², but XLA may
    sum a longer vector in another order: evaluated on the padded rows, the log-density of
    :func:`fitting.sample` is bit for bit the one :func:`fitting.sample_many` evaluates in its
    bucket where XLA compiles the stacked arithmetic alike (so their chains are equal, not just
    to rounding; :mod:`fitting._sample_many`, "What is equal"), and the compiled sampling
    programs depend on the rung of points, not on the dataset's layout (materials of one rung
    share them). The price: at most 1.5 × the rows (above 8 points per scale)."""
    rows = problem.rows()
    return dataclasses.replace(rows, points=_pad_points(rows.points, bucket_points(rows.points.mean.shape[1])))


def fisher(fit) -> np.ndarray:
    """F = JᵀJ at the optimum, from the fit's eigen-decomposition (else the pseudo-inverse of its covariance)."""
    if getattr(fit, "eigenvectors", None) is not None:
        V, lam = np.asarray(fit.eigenvectors), np.clip(np.asarray(fit.eigenvalues), 0, None)
        return (V * lam) @ V.T
    return np.linalg.pinv(np.asarray(fit.covariance), hermitian=True)


def laplace(target: Target, fit, iterations: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """``(ζ*, Σ_ζ)``: the maximum over the sampled subspace of the fit's Laplace likelihood times
    the Jacobian, and the Gauss–Newton covariance ``(Bᵀ P_z B)⁻¹`` there (module docstring)."""
    lo, hi = np.asarray(target.problem.lower), np.asarray(target.problem.upper)
    theta_hat, F = np.asarray(fit.theta, float), fisher(fit)
    rec = target.record()
    z0, B = rec["origin"], rec["basis"]
    bend = (hi - lo) / BEND

    def parts(zeta):
        z = z0 + B @ zeta
        a, b = (z - lo) / bend, (z - hi) / bend
        delta = theta_of_z_np(z, lo, hi) - theta_hat
        q = 0.5 * delta @ F @ delta - log_jacobian_np(z, lo, hi)  # −log, up to a constant
        D = _dtheta_dz(z, lo, hi)
        gradient = D * (F @ delta) + (_sigmoid(b) - _sigmoid(-a)) / bend
        curvature = (_sigmoid(a) * _sigmoid(-a) + _sigmoid(b) * _sigmoid(-b)) / bend**2
        P = D[:, None] * F * D[None, :] + np.diag(curvature)
        return q, B.T @ gradient, B.T @ P @ B

    zeta = np.zeros(B.shape[1])
    q, g, P = parts(zeta)
    for _ in range(iterations):
        lam, V = np.linalg.eigh(0.5 * (P + P.T))
        step = V @ ((V.T @ g) / np.clip(lam, 1e-300, None))
        t = 1.0
        while t > 1e-6:
            trial = parts(zeta - t * step)
            if trial[0] <= q:
                break
            t *= 0.5
        else:
            break
        zeta, (q, g, P) = zeta - t * step, trial
        if np.max(np.abs(t * step)) < 1e-10:
            break
    lam, V = np.linalg.eigh(0.5 * (P + P.T))
    return zeta, (V / np.clip(lam, 1e-300, None)) @ V.T


def covariance_root(cov) -> np.ndarray:
    """A square root L of a covariance, L Lᵀ = cov, from its eigendecomposition (negative rounding clipped to 0):
    the Laplace approximation's draws (:func:`initial_positions`) and :class:`fitting.IMH`'s proposal."""
    lam, V = np.linalg.eigh(cov)
    return V * np.sqrt(np.clip(lam, 0, None))


def initial_positions(centre, root, n: int, rng: np.random.Generator, scale: float = 1.0) -> np.ndarray:
    """``n`` draws of the Laplace approximation, ``centre + scale·L ξ`` (``root`` = L, L Lᵀ = the covariance:
    :func:`covariance_root`)."""
    return centre + scale * rng.standard_normal((n, centre.size)) @ root.T
