"""Scale laws for real surfaces: a monotone spline in ln μ learned from data, and Student-t
statistics whose width and tail index follow laws in μ.

:class:`MonotoneSplineLaw` — the facet-slope covariance

    Σ(μ) = R(θ) diag(σ_1(μ)², σ_2(μ)²) R(θ)ᵀ,
    ln σ_a(x) = ln σ_a(x_0) − Σ_k r_{a,k} ∫_{x_0}^{x} h_k(t) dt,   x = ln μ,

with ``K`` knots ``x_0 < … < x_{K−1}`` equally spaced in ln μ, ``h_k`` the piecewise-linear hat
functions on them (the first and last extended as constants beyond the ends) and rates
``r_{a,k} ≥ 0``. ``d ln σ_a/d ln μ = −Σ_k r_{a,k} h_k`` is continuous and ≤ 0, so ln σ_a is C¹,
piecewise quadratic in ln μ and non-increasing; beyond the end knots it is a power law with the
end rate. Positive definite for every μ (σ_a > 0), and monotone in the Loewner order (fixed
axes, non-increasing variances): Σ(μ) − Σ(μ') ⪰ 0 for μ < μ'. Not a power law: the local
exponent ``Σ r h`` varies with μ. The shape is Gaussian, or Student-t with ``nu``
(:class:`~brdfscale.stats.StudentT` with scale matrix Σ(μ)).

:class:`StudentTLaw` — ``s(·, μ) = StudentT(sigma=α(μ)/√2, ν(μ))`` with a :class:`WidthLaw` α(μ)
(the Beckmann convention: per-axis variance α²/2 for ν → ∞) and ``ν(μ) = ν_0 (μ/μ_ν)^p``: the tail
index free (``p = 0``) or following a power law (``p > 0``: coarser facets average more pixel
slopes, so their tails thin, the central limit theorem's direction).

Verified in ``tests/test_scale_laws_real.py`` (densities of mass 1 by SciPy quadrature, positive
definite and monotone over hypothesis-drawn parameters, jit/grad/vmap equal to eager).
"""

import math

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._errors import InvalidInputError
from .._validation import as_float_array, facet_size, is_concrete, positive
from ._families import Gaussian
from ._scale_laws import AbstractScaleLaw, WidthLaw
from ._student import StudentT


def _ramp(z):
    """``∫_{−∞}^{z} hat(t) dt`` of the unit hat on [−1, 1]."""
    return jnp.where(z < -1, 0.0, jnp.where(z < 0, 0.5 * (z + 1) ** 2, jnp.where(z < 1, 1 - 0.5 * (1 - z) ** 2, 1.0)))


def _first(z):
    """The first knot's hat, constant 1 below the knot: its integral from the knot."""
    return jnp.where(z < 0, z, jnp.where(z < 1, z - 0.5 * z**2, 0.5))


def _last(z):
    """The last knot's hat, constant 1 above the knot: its integral from −∞ (0 below −1)."""
    return jnp.where(z < 0, _ramp(z), 0.5 + z)


def hat_integrals(x, knots):
    """``∫_{x_0}^{x} h_k(t) dt`` for every knot k (last axis), knots equally spaced."""
    step = knots[1] - knots[0]
    z = (jnp.asarray(x)[..., None] - knots) / step
    z0 = (knots[0] - knots) / step
    count = knots.shape[0]
    index = jnp.arange(count)
    inner = _ramp(z) - _ramp(z0)
    last = _last(z) - _last(z0)
    values = jnp.where(index == 0, _first(z), jnp.where(index == count - 1, last, inner))
    return step * values


class MonotoneSplineLaw(AbstractScaleLaw):
    """Σ(μ) monotone in μ, smooth in ln μ, with free principal axes (module docstring).

    Args:
        mu_min, mu_max: the first and last knot (facet sizes, length units).
        sigma: ``(σ_1, σ_2)`` at ``mu_min`` (slope standard deviations along the principal axes;
            one number: both).
        rates: ``(2, K)`` rates ``r_{a,k} ≥ 0`` (``d ln σ_a / d ln μ`` at the knots, negated),
            ``K ≥ 2``; a ``(K,)`` array: both axes.
        angle: θ, the first principal axis' angle from x (radians); default 0.
        nu: None (Gaussian shape) or the Student-t tail index (> 0).
    """

    knots: Float[Array, " K"]
    sigma: Float[Array, "2"]
    rates: Float[Array, "2 K"]
    angle: Float[Array, ""]
    nu: Float[Array, ""] | None

    def __init__(self, mu_min, mu_max, sigma, rates, angle=0.0, nu=None):
        lo = positive(mu_min, "mu_min")
        hi = positive(mu_max, "mu_max")
        if is_concrete((lo, hi)) and not float(hi) > float(lo):
            raise InvalidInputError(f"mu_max must exceed mu_min; got {float(lo)!r}, {float(hi)!r}.")
        s = positive(sigma, "sigma", "positive (slope standard deviations)")
        self.sigma = jnp.broadcast_to(s, (2,)) if s.ndim == 0 else s
        if self.sigma.shape != (2,):
            raise InvalidInputError(f"sigma must be one number or a pair; got shape {s.shape}.")
        r = as_float_array(rates, "rates")
        if r.ndim == 1:
            r = jnp.stack([r, r])
        if r.ndim != 2 or r.shape[0] != 2 or r.shape[1] < 2:
            raise InvalidInputError(f"rates must have shape (K,) or (2, K) with K ≥ 2 knots; got {r.shape}.")
        if is_concrete(r) and not bool(jnp.all(r >= 0)):
            raise InvalidInputError("rates must be ≥ 0 (a non-increasing width: Σ shrinks as facets grow).")
        self.rates = r
        self.knots = jnp.linspace(jnp.log(lo), jnp.log(hi), r.shape[1])
        self.angle = as_float_array(angle, "angle")
        if self.angle.ndim != 0:
            raise InvalidInputError(f"angle must be one number; got shape {self.angle.shape}.")
        self.nu = None if nu is None else positive(nu, "nu", "positive (the Student-t tail index)")

    def principal_sigmas(self, mu: Float[ArrayLike, ""]) -> Float[Array, "2"]:
        """``(σ_1(μ), σ_2(μ))``."""
        x = jnp.log(facet_size(mu))
        return self.sigma * jnp.exp(-jnp.sum(self.rates * hat_integrals(x, self.knots), axis=-1))

    def slope_covariance(self, mu: Float[ArrayLike, ""]) -> Float[Array, "2 2"]:
        """``Σ(μ)`` (the scale matrix for a Student-t shape; slope²)."""
        s = self.principal_sigmas(mu)
        c, n = jnp.cos(self.angle), jnp.sin(self.angle)
        rot = jnp.array([[c, -n], [n, c]])
        return rot @ jnp.diag(s**2) @ rot.T

    def at(self, mu):
        cov = self.slope_covariance(mu)
        return Gaussian(cov=cov) if self.nu is None else StudentT(cov, nu=self.nu)


class StudentTLaw(AbstractScaleLaw):
    """``s(·, μ) = StudentT(sigma=α(μ)/√2, ν(μ))``, ``ν(μ) = ν_0 (μ/μ_ν)^p`` (module docstring).

    Args:
        width: the :class:`WidthLaw` α(μ).
        nu: ν_0 (> 0), the tail index at ``mu_nu``.
        nu_exponent: p ≥ 0; 0 (default): a free, scale-independent tail index.
        mu_nu: the reference scale of ν (default 1).
    """

    width: WidthLaw
    nu: Float[Array, ""]
    nu_exponent: Float[Array, ""]
    mu_nu: Float[Array, ""]

    def __init__(self, width: WidthLaw, nu, nu_exponent=0.0, mu_nu=1.0):
        if not isinstance(width, WidthLaw):
            raise InvalidInputError(f"width must be a brdfscale.stats.WidthLaw; got {type(width).__name__}.")
        self.width = width
        self.nu = positive(nu, "nu", "positive (the Student-t tail index)")
        p = as_float_array(nu_exponent, "nu_exponent")
        if is_concrete(p) and not float(p) >= 0:
            raise InvalidInputError(f"nu_exponent must be ≥ 0; got {float(p)!r}.")
        self.nu_exponent = p
        self.mu_nu = positive(mu_nu, "mu_nu")

    def tail_index(self, mu: Float[ArrayLike, ""]) -> Float[Array, ""]:
        """``ν(μ)``."""
        return self.nu * (facet_size(mu) / self.mu_nu) ** self.nu_exponent

    def at(self, mu):
        mu = facet_size(mu)
        return StudentT(sigma=self.width(mu) / math.sqrt(2.0), nu=self.tail_index(mu))
