"""Facet-slope statistics of a Gaussian-correlated random surface in closed form.

For heights with the Gaussian correlation ``C(r) = σ_h² exp(−|r|²/ℓ²)`` the power spectrum
``P(k) = π ℓ² σ_h² exp(−ℓ²|k|²/4)`` and both facet windows of
:func:`brdfscale.stats.window_power` (box: ``sinc²(k_x μ/2) sinc²(k_y μ/2)``; Gaussian:
``exp(−|k|² μ²/12)``) factorise over the axes, so the window-averaged gradient covariance
(DESIGN §2)

    Σ(μ) = ∫ k kᵀ P(k) |ŵ_μ(k)|² d²k/(2π)²

is diagonal, isotropic, and a product of one-dimensional Gaussian integrals. With
``x = μ/ℓ`` and the unwindowed slope variance ``σ∞² = 2σ_h²/ℓ²``:

* Gaussian window: ``Σ_xx = σ∞² / (1 + x²/3)²``;
* box window: ``Σ_xx = σ∞² · [(1 − e^{−x²})/x²] · [h(x)/x²]`` with
  ``h(x) = √π x erf(x) − (1 − e^{−x²}) = x² − x⁴/6 + x⁶/30 − …``.

(Box: ``∫ k² e^{−ak²} sinc²(kb) dk = √(π/a)(1 − e^{−b²/a})/(2b²)`` and
``∫ e^{−ak²} sinc²(kb) dk = F(2b)/(2b²)`` with ``F'' (c) = √(π/a) e^{−c²/4a}``,
``F(0) = F'(0) = 0``; here ``a = ℓ²/4``, ``b = μ/2``.) Both tend to ``σ∞²`` as μ → 0 and to 0
as μ → ∞ (s → δ, the boundary condition S(W, ∞) = 1).

This is the law :class:`brdfscale.stats.GaussianSurface` evaluates by 2D quadrature for any
spectrum; tests/test_fit.py checks the two against each other and against mpmath.
"""

import math

import equinox as eqx
import jax.numpy as jnp
from jax.scipy.special import erf
from jaxtyping import Array, ArrayLike, Float

from brdfscale import stats
from brdfscale._validation import positive

__all__ = ["GaussianCorrelatedSurface"]

class GaussianCorrelatedSurface(stats.AbstractScaleLaw):
    """``s(·, μ) = Gaussian(σ(μ))`` of an isotropic Gaussian-correlated surface (module docstring).

    Args:
        rms_height: σ_h (length units of μ).
        correlation_length: ℓ (length units of μ).
        window: ``"box"`` (a μ×μ square facet) or ``"gaussian"`` (standard deviation μ/√12).
    """

    rms_height: Float[Array, ""]
    correlation_length: Float[Array, ""]
    window: str = eqx.field(static=True)

    def __init__(self, rms_height, correlation_length, window: str = "box"):
        self.rms_height = positive(rms_height, "rms_height")
        self.correlation_length = positive(correlation_length, "correlation_length")
        stats.window_power(jnp.zeros(2), 1.0, window)  # validates the name
        self.window = window

    def slope_variance(self, mu: Float[ArrayLike, ""]) -> Float[Array, ""]:
        """``Σ_xx(μ) = Σ_yy(μ)`` (dimensionless slope²)."""
        x2 = (jnp.asarray(mu) / self.correlation_length) ** 2
        unwindowed = 2 * self.rms_height**2 / self.correlation_length**2
        if self.window == "gaussian":
            return unwindowed / (1 + x2 / 3) ** 2
        x2 = jnp.maximum(x2, 1e-200)  # μ > 0; the floor only keeps x = 0 out of 0/0
        x = jnp.sqrt(x2)
        blur = -jnp.expm1(-x2) / x2
        spread = math.sqrt(math.pi) * erf(x) / x - blur  # h(x)/x²: at most a factor 2 cancels
        return unwindowed * blur * spread

    def at(self, mu):
        return stats.Gaussian(sigma=jnp.sqrt(self.slope_variance(mu)))
