"""The bivariate Student-t slope density: heavy tails with a free tail index ν.

With scale matrix ``Σ`` (2 × 2, positive definite) and ``ν > 0`` degrees of freedom,

    s(m) = Γ(ν/2 + 1) / (Γ(ν/2) π ν √det Σ) · (1 + dᵀΣ⁻¹d/ν)^{−(ν+2)/2},   d = m − mean,

whose tails fall off as ``|m|^{−(ν+2)}`` (ν = 2 is GGX, ν → ∞ the Gaussian of covariance Σ; the
covariance is ``Σ ν/(ν − 2)`` for ν > 2, infinite otherwise). It is a scale mixture of Gaussians,
``m | τ ~ N(mean, Σ/τ)`` with ``τ ~ Gamma(ν/2, rate ν/2)``, so its transform is

    S(W) = E_τ[exp(−q/(2τ))] = φ_{ν/2}(√(ν q)) e^{−iW·mean},   q = WᵀΣW,
    φ_a(x) = x^a K_a(x) / (Γ(a) 2^{a−1})

(a Matérn function; ``K_a`` the modified Bessel function of real order a, which JAX does not
provide). It is evaluated from the mixture itself: the expectation as an integral over
``u = ln τ`` by the trapezoidal rule on :data:`NODES` nodes over the range where the Gamma
density (times τ) exceeds e^{−45} of its largest value; the integrand is analytic in the strip
``|Im u| < π/2`` and decays doubly exponentially at the upper end, so the rule converges
geometrically (error ~ e^{−2π(π/2)/h}, h the step). The weights are normalised so that S(0) = 1
exactly. Verified against SciPy's ``kv`` and against quadrature of the density in
``tests/test_scale_laws_real.py``; differentiable in Σ and ν.
"""

import equinox as eqx
import jax.numpy as jnp
from jax.scipy.special import gammaln
from jaxtyping import Array, Float

from .._errors import InvalidInputError
from .._slopes import add_offset, centred, check_slopes, eig2, offset_norm, shifted_cf
from .._validation import as_float_array, is_concrete, positive, vector2
from ._base import AbstractSlopeDensity


NODES = 512
"""Trapezoidal nodes in ln τ of the transform's mixture integral (module docstring)."""


def _mixture_nodes(nu, nodes: int = NODES, cutoff: float = 45.0):
    """``(ln τ_j, w_j)``: trapezoidal nodes and normalised weights of the Gamma(ν/2, rate ν/2)
    mixing density in u = ln τ (the density of u is ``b^a/Γ(a) e^{a u − b e^u}``), over the
    range where it exceeds ``e^{−cutoff}`` of its largest value."""
    a = nu / 2
    # ln of the u-density relative to its maximum at e^u = a/b = 1: a u − a e^u + a ≥ −cutoff
    lo = -cutoff / a - 1.0
    hi = jnp.log1p(cutoff / a + jnp.log1p(cutoff / a)) + 1.0
    u = jnp.linspace(0.0, 1.0, nodes) * (hi - lo) + lo
    log_w = a * u - a * jnp.exp(u)
    w = jnp.exp(log_w - jnp.max(log_w))
    return u, w / jnp.sum(w)


def matern(x, a):
    """``φ_a(x) = x^a K_a(x)/(Γ(a) 2^{a−1})`` at ``x ≥ 0`` (φ_a(0) = 1), via the Gamma mixture:
    ``φ_a(x) = E[exp(−x²/(4a τ))]`` with τ ~ Gamma(a, rate a) (module docstring)."""
    u, w = _mixture_nodes(2 * a)
    q = jnp.asarray(x)[..., None] ** 2 / (2 * a)  # q = x²/ν with ν = 2a
    return jnp.sum(w * jnp.exp(-0.5 * q * jnp.exp(-u)), axis=-1)


class StudentT(AbstractSlopeDensity):
    """Bivariate Student-t slope statistics with scale matrix ``cov`` (or ``sigma=``, a scalar
    or per-axis scale) and tail index ``nu`` (module docstring). ``nu`` may be traced and
    differentiated; ν → ∞ tends to ``Gaussian(cov)``, ν = 2 is GGX with ``α = √2 σ``."""

    cov: Float[Array, "2 2"]
    nu: Float[Array, ""]
    mean: Float[Array, "2"] | None
    isotropic: bool = eqx.field(static=True)

    def __init__(self, cov=None, *, nu, sigma=None, mean=None):
        if (cov is None) == (sigma is None):
            raise InvalidInputError("StudentT needs exactly one of cov= (2×2 scale matrix) or sigma= (scalar or pair).")
        isotropic = False
        if sigma is not None:
            s = positive(sigma, "sigma", "positive (a scale)")
            if s.ndim == 0:
                s, isotropic = jnp.stack([s, s]), True
            elif s.shape != (2,):
                raise InvalidInputError(f"sigma must be a scalar or a pair; got shape {s.shape}.")
            cov = jnp.diag(s**2)
        else:
            cov = as_float_array(cov, "cov")
            if cov.shape != (2, 2):
                raise InvalidInputError(f"cov must have shape (2, 2); got {cov.shape}.")
            if is_concrete(cov):
                lo, _ = eig2(cov)
                if not float(lo) > 0 or abs(float(cov[0, 1] - cov[1, 0])) > 1e-12 * float(jnp.max(jnp.abs(cov))):
                    raise InvalidInputError(f"cov must be symmetric positive definite; got {cov!r}.")
        self.cov = cov
        self.nu = positive(nu, "nu", "positive (the tail index: tails fall off as |m|^−(ν+2))")
        if self.nu.ndim != 0:
            raise InvalidInputError(f"nu must be one number; got shape {self.nu.shape}.")
        self.mean = vector2(mean, "mean")
        self.isotropic = isotropic and mean is None

    def density(self, m):
        d = centred(m, self.mean)
        inv = jnp.linalg.inv(self.cov)
        x2 = jnp.einsum("...i,ij,...j->...", d, inv, d)
        nu = self.nu
        log_norm = (
            gammaln(nu / 2 + 1) - gammaln(nu / 2) - jnp.log(jnp.pi * nu) - 0.5 * jnp.log(jnp.linalg.det(self.cov))
        )
        return jnp.exp(log_norm - (nu + 2) / 2 * jnp.log1p(x2 / nu))

    def _phi(self, q):
        u, w = _mixture_nodes(self.nu)
        return jnp.sum(w * jnp.exp(-0.5 * jnp.asarray(q)[..., None] * jnp.exp(-u)), axis=-1)

    def cf(self, W):
        W = check_slopes(W, "W")
        q = jnp.einsum("...i,ij,...j->...", W, self.cov, W)
        return shifted_cf(self._phi(q), W, self.mean)

    def cf_radial(self, k):
        return self._phi(self.cov[0, 0] * jnp.asarray(k) ** 2)  # isotropic: Σ = σ² I

    def gaussian_mixture(
        self, nodes: int = NODES, cutoff: float = 45.0
    ) -> tuple[Float[Array, " nodes"], Float[Array, " nodes"]]:
        """``(c_j, w_j)`` with ``s ≈ Σ_j w_j N(mean, c_j Σ)``, ``Σ_j w_j = 1``: the scale mixture of
        the module docstring (``c_j = 1/τ_j``) on ``nodes`` trapezoidal nodes in ln τ over the range
        where the mixing density exceeds ``e^{−cutoff}`` of its largest value. A Gaussian convolved
        with it is the same mixture with every covariance increased (fitting.AnisotropicModel's
        Student-t lobes; accuracy against SciPy quadrature in tests/test_anisotropic.py)."""
        u, w = _mixture_nodes(self.nu, nodes, cutoff)
        return jnp.exp(-u), w

    def shifted(self, offset):
        return StudentT(self.cov, nu=self.nu, mean=add_offset(self.mean, offset))

    def support_radius(self, tol):
        _, hi = eig2(self.cov)
        # (1 + r²/(ν σ²))^{−(ν+2)/2} = tol along the widest axis
        return jnp.sqrt(hi * self.nu * (tol ** (-2.0 / (self.nu + 2)) - 1)) + offset_norm(self.mean)

    def bandwidth(self, tol):
        """``|W|`` beyond which ``|S| < tol``: ``φ_a(x) ≤ √(π/2) x^{a−½} e^{−x}/(Γ(a) 2^{a−1})·(1 + …)``
        solved for x by fixed-point iteration (as GGX's), ``|W| = x/√(ν λ_min(Σ))``."""
        a = self.nu / 2
        log_c = 0.5 * jnp.log(jnp.pi / 2) - gammaln(a) - (a - 1) * jnp.log(2.0)
        x = jnp.maximum(jnp.log(1 / tol) + log_c, 1.0)
        for _ in range(12):
            x = jnp.maximum(jnp.log(1 / tol) + log_c + (a - 0.5) * jnp.log(x) + jnp.log(2.0), 1.0)
        lo, _ = eig2(self.cov)
        return x / jnp.sqrt(self.nu * lo)
