"""Scale laws: how the facet-slope statistics s(·, μ) change with the facet size μ.

A *facet* at scale μ is a window of size μ (length units of the height field). Its slope,
relative to the global orientation, is the window-averaged surface gradient. For a
Gaussian random height field with power spectrum ``P(k)`` (normalised so that
``∫ P(k) d²k / (2π)² = ⟨h²⟩``) that slope is Gaussian with covariance (docs/conventions.md §2)

    Σ(μ) = ∫ k kᵀ P(k) |ŵ_μ(k)|² d²k / (2π)²,

where ``ŵ_μ`` is the transform of the unit-integral facet window. As μ → ∞, ``ŵ_μ → δ``-like
cut-off and Σ → 0: s(·, μ→∞) → δ, the consistency boundary condition (seed §3).
"""

import abc
import inspect
import math
from typing import Callable, Literal

import equinox as eqx
import jax.numpy as jnp
from jax.scipy.special import erf
from jaxtyping import Array, ArrayLike, Float

from .._errors import InvalidInputError
from .._quadrature import gauss_legendre
from .._show import Shown
from .._validation import facet_size, is_concrete, positive
from ._base import AbstractSlopeDensity
from ._families import Gaussian


class AbstractPowerSpectrum(Shown, eqx.Module):
    """Height power spectral density ``P(k)`` of a stationary random surface.

    ``P`` takes wave vectors of shape (..., 2) (radians per length unit) and is normalised
    so that ``∫ P d²k/(2π)² = ⟨h²⟩`` (height variance, length²). All spectra here are even,
    ``P(k) = P(−k)``, as for any real height field.
    """

    isotropic: eqx.AbstractVar[bool]
    """True when ``P`` depends on ``|k|`` only (known structurally, not from values)."""

    @abc.abstractmethod
    def __call__(self, k: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch"]: ...

    @abc.abstractmethod
    def wavenumber_range(self) -> tuple[Float[Array, ""], Float[Array, ""]]:
        """Wavenumbers (k_lo, k_hi) between which the slope spectrum ``k² P`` lives."""

    def windowed_slope_variances(self, mu, window: "FacetWindow") -> Float[Array, "2"] | None:
        """``(Σ_xx(μ), Σ_yy(μ))`` in closed form where spectrum and window factorise over the
        axes (then ``Σ_xy = 0``); ``None`` where there is none, and :class:`GaussianSurface`
        integrates numerically."""
        return None


class GaussianCorrelation(AbstractPowerSpectrum):
    """Gaussian-correlated heights: ``C(r) = σ_h² exp(−x²/ℓ_x² − y²/ℓ_y²)``.

    ``P(k) = π ℓ_x ℓ_y σ_h² exp(−(k_x² ℓ_x² + k_y² ℓ_y²)/4)``; unwindowed slope variances
    ``⟨(∂_x h)²⟩ = 2 σ_h²/ℓ_x²``. ``correlation_length`` may be a scalar or a pair (ℓ_x, ℓ_y).
    """

    rms_height: Float[Array, ""]
    correlation_length: Float[Array, "2"]
    isotropic: bool = eqx.field(static=True)
    """True when built with one correlation length (known structurally, not from values)."""

    def __init__(self, rms_height, correlation_length):
        self.rms_height = positive(rms_height, "rms_height")
        ell = positive(correlation_length, "correlation_length")
        self.isotropic = ell.ndim == 0
        self.correlation_length = jnp.broadcast_to(ell, (2,)) if ell.ndim == 0 else ell

    def __call__(self, k):
        k = jnp.asarray(k)
        lx, ly = self.correlation_length[0], self.correlation_length[1]
        return jnp.pi * lx * ly * self.rms_height**2 * jnp.exp(-((k[..., 0] * lx) ** 2 + (k[..., 1] * ly) ** 2) / 4)

    def wavenumber_range(self):
        return 1e-4 / jnp.max(self.correlation_length), 14.0 / jnp.min(self.correlation_length)

    def windowed_slope_variances(self, mu, window):
        """Spectrum and both windows factorise, so ``Σ_xx`` is a product of 1D Gaussian integrals.

        With ``x_a = μ/ℓ_a`` and the unwindowed variance ``σ_x² = 2σ_h²/ℓ_x²``:

        * Gaussian window: ``Σ_xx = σ_x² (1 + x_x²/3)^{−3/2} (1 + x_y²/3)^{−1/2}``;
        * box window: ``Σ_xx = σ_x² b(x_x) p(x_y)`` with ``b(x) = (1 − e^{−x²})/x²`` (from
          ``∫ k² e^{−ℓ²k²/4} sinc²(kμ/2) dk``) and ``p(x) = √π erf(x)/x − b(x)`` (from
          ``∫ e^{−ℓ²k²/4} sinc²(kμ/2) dk``); both → 1 as μ → 0 and → 0 as μ → ∞.

        ``Σ_yy`` swaps the axes.
        """
        x2 = (jnp.asarray(mu) / self.correlation_length) ** 2  # (x_x², x_y²)
        unwindowed = 2 * self.rms_height**2 / self.correlation_length**2
        if window == "gaussian":
            along, across = (1 + x2 / 3) ** -1.5, (1 + x2 / 3) ** -0.5
        else:
            x2 = jnp.maximum(x2, 1e-200)  # μ > 0; the floor only keeps x = 0 out of 0/0
            x = jnp.sqrt(x2)
            along = -jnp.expm1(-x2) / x2
            across = math.sqrt(math.pi) * erf(x) / x - along  # cancels at most a factor 2
        return unwindowed * along * across[::-1]


class KCorrelation(AbstractPowerSpectrum):
    """K-correlation ("ABC") model of optical-scatter metrology: ``P(k) = A / (1 + (B k)²)^{C/2}``.

    ``A`` (length⁴), ``B`` (length, the correlation length) and ``C`` (dimensionless, > 2) are
    the usual parameters; the spectrum is fractal (∝ k^{−C}) for ``k ≫ 1/B``. The unwindowed
    slope variance is finite only for ``C > 4``; a facet window of size μ > 0 makes it finite
    for ``C > 2``. ``k_max`` (default ``1e4/B``) is the band limit of the metrology.
    """

    A: Float[Array, ""]
    B: Float[Array, ""]
    C: Float[Array, ""]
    k_max: Float[Array, ""]
    isotropic: bool = eqx.field(default=True, static=True)

    def __init__(self, A, B, C, k_max=None):
        self.A = positive(A, "A")
        self.B = positive(B, "B")
        self.C = positive(C, "C")
        if is_concrete(self.C) and float(self.C) <= 2:
            raise InvalidInputError(f"C must exceed 2 for finite facet slopes; got {float(self.C)}.")
        self.k_max = positive(1e4 / self.B if k_max is None else k_max, "k_max")

    def __call__(self, k):
        k2 = jnp.sum(jnp.asarray(k) ** 2, axis=-1)
        return jnp.where(k2 <= self.k_max**2, self.A / (1 + self.B**2 * k2) ** (self.C / 2), 0.0)

    def wavenumber_range(self):
        return 1e-3 / self.B, self.k_max


FacetWindow = Literal["box", "gaussian"]


def window_power(k, mu, window: FacetWindow):
    """``|ŵ_μ(k)|²`` of a unit-integral facet window of size μ.

    ``"box"``: a μ×μ square, ``sinc²(k_x μ/2) sinc²(k_y μ/2)``. ``"gaussian"``: a Gaussian of
    standard deviation ``μ/√12`` per axis (the box's second moment), ``exp(−|k|² μ²/12)``.
    """
    k = jnp.asarray(k)
    if window == "box":
        x = k * mu / 2
        safe = jnp.where(jnp.abs(x) < 1e-4, 1.0, x)
        s = jnp.where(jnp.abs(x) < 1e-4, 1 - x**2 / 6, jnp.sin(safe) / safe)
        return jnp.prod(s**2, axis=-1)
    if window == "gaussian":
        return jnp.exp(-jnp.sum(k**2, axis=-1) * mu**2 / 12)
    raise InvalidInputError(f"window must be 'box' or 'gaussian'; got {window!r}.")


class AbstractScaleLaw(Shown, eqx.Module):
    """Maps a facet size μ to the facet-slope statistics ``s(·, μ)``."""

    @abc.abstractmethod
    def at(self, mu: Float[ArrayLike, ""]) -> AbstractSlopeDensity:
        """The facet-slope density at scale μ (differentiable in μ and the parameters)."""

    def plot(self, mu, **options):
        """A figure of ``s(·, μ)`` and ``S(W, μ)`` at the facet sizes ``mu`` (a sequence):
        :func:`brdfscale.plot.statistics` (options as there); returns a ``matplotlib.figure.Figure``."""
        from .._figures import draw

        return draw("statistics", self, mu=mu, **options)


class GaussianSurface(AbstractScaleLaw):
    """Facet slopes of a Gaussian random surface: ``s(·, μ) = Gaussian(cov=Σ(μ))``.

    ``Σ(μ)`` is the window-averaged gradient covariance of the module docstring: in closed
    form where the spectrum has one (:class:`GaussianCorrelation`, both windows), otherwise
    by quadrature in polar wave-vector coordinates: ``n_phi`` trapezoidal nodes in the angle
    (spectrally accurate for the periodic integrand) and ``n_k`` Gauss–Legendre nodes in
    ``log k`` over the spectrum's range. Both are tested against adaptive SciPy quadrature
    and against each other.
    """

    spectrum: AbstractPowerSpectrum
    window: FacetWindow = eqx.field(static=True)
    n_k: int = eqx.field(static=True)
    n_phi: int = eqx.field(static=True)

    def __init__(self, spectrum: AbstractPowerSpectrum, window: FacetWindow = "box", n_k: int = 256, n_phi: int = 32):
        if not isinstance(spectrum, AbstractPowerSpectrum):
            raise InvalidInputError(
                "spectrum must be a brdfscale.stats power spectrum (GaussianCorrelation, KCorrelation)."
            )
        window_power(jnp.zeros(2), 1.0, window)  # validates the name
        self.spectrum, self.window, self.n_k, self.n_phi = spectrum, window, n_k, n_phi

    def slope_covariance(self, mu: Float[ArrayLike, ""]) -> Float[Array, "2 2"]:
        """``Σ(μ)`` (dimensionless slope²)."""
        variances, cov = self._covariance(facet_size(mu))
        return jnp.diag(variances) if cov is None else cov

    def _covariance(self, mu):
        """``(diagonal of Σ(μ), Σ(μ))``; ``Σ`` is None where the spectrum gives the (diagonal)
        variances in closed form, else the jitted quadrature's."""
        variances = self.spectrum.windowed_slope_variances(mu, self.window)
        if variances is not None:
            return variances, None
        cov = _quadrature_covariance_jit(self, mu)
        return jnp.diagonal(cov), cov

    def _quadrature_covariance(self, mu):
        k_lo, k_hi = self.spectrum.wavenumber_range()
        k_lo = jnp.minimum(k_lo, 1e-3 / mu)  # the window passes k ≲ 1/μ: start well below
        x, w = gauss_legendre(self.n_k)
        t_lo, t_hi = jnp.log(k_lo), jnp.log(k_hi)
        t = 0.5 * (t_hi - t_lo) * x + 0.5 * (t_hi + t_lo)
        wt = 0.5 * (t_hi - t_lo) * w
        phi = jnp.arange(self.n_phi) * (jnp.pi / self.n_phi)  # P(k) = P(−k): half circle, ×2
        k = jnp.exp(t)[:, None]
        kv = k[..., None] * jnp.stack([jnp.cos(phi), jnp.sin(phi)], axis=-1)  # (n_k, n_phi, 2)
        # d²k = k dk dφ = k² dt dφ
        f = self.spectrum(kv) * window_power(kv, mu, self.window) * (k**2)
        weights = wt[:, None] * (2 * jnp.pi / self.n_phi) / (2 * jnp.pi) ** 2
        cov = jnp.einsum("ab,ab,abi,abj->ij", weights * jnp.ones_like(f), f, kv, kv)
        return 0.5 * (cov + cov.T)

    def at(self, mu):
        """``Gaussian(cov=Σ(μ))``; isotropic where the spectrum is (Σ = σ² I, σ² its mean
        diagonal), built from per-axis standard deviations where Σ is diagonal by
        construction (closed form), so that :func:`brdfscale.evolve` (radial path) and the
        grid path (separable factors) can exploit the structure."""
        variances, cov = self._covariance(facet_size(mu))
        if cov is not None and not self.spectrum.isotropic:
            return Gaussian(cov=cov)
        if self.spectrum.isotropic:  # Σ = σ² I
            return Gaussian(sigma=jnp.sqrt(0.5 * (variances[..., 0] + variances[..., 1])))
        return Gaussian(sigma=jnp.sqrt(variances))


_quadrature_covariance_jit = eqx.filter_jit(lambda law, mu: law._quadrature_covariance(mu))


class WidthLaw(Shown, eqx.Module):
    """A parametric width law ``α(μ) = α_max (1 + (μ/μ_c)²)^{−H/2}``.

    Saturates at ``α_max`` for facets much smaller than the corner scale ``μ_c`` (finite
    slopes of the finest structure) and decays as the power law ``(μ/μ_c)^{−H}`` for
    ``μ ≫ μ_c``, so ``α → 0`` and the statistics tend to δ as μ → ∞. ``H`` (> 0) plays the
    role of a roughness (Hurst-like) exponent of the slope field.
    """

    alpha_max: Float[Array, ""]
    mu_c: Float[Array, ""]
    exponent: Float[Array, ""]

    def __init__(self, alpha_max, mu_c, exponent):
        self.alpha_max = positive(alpha_max, "alpha_max")
        self.mu_c = positive(mu_c, "mu_c")
        self.exponent = positive(exponent, "exponent")

    def __call__(self, mu):
        return self.alpha_max * (1 + (jnp.asarray(mu) / self.mu_c) ** 2) ** (-self.exponent / 2)


class ScaledFamily(AbstractScaleLaw):
    """Any one-width family paired with a width law: ``s(·, μ) = family(alpha=law(μ))``.

    ``family`` is a constructor taking ``alpha=`` — e.g. ``stats.Beckmann`` or ``stats.GGX`` —
    and ``law`` maps μ to α (e.g. :class:`WidthLaw`).
    """

    family: Callable[..., AbstractSlopeDensity] = eqx.field(static=True)
    law: WidthLaw

    def __init__(self, family: Callable[..., AbstractSlopeDensity], law: WidthLaw):
        if not callable(law):
            raise InvalidInputError(f"law must map a facet size μ to a width α (e.g. stats.WidthLaw); got {law!r}.")
        try:
            inspect.signature(family).bind(alpha=None)
        except TypeError as err:
            raise InvalidInputError(
                f"family must be a constructor taking alpha= (e.g. stats.Beckmann, stats.GGX); {family!r} does "
                f"not: {err}"
            ) from None
        except ValueError:  # no signature to read (a builtin): left to the first call
            pass
        self.family, self.law = family, law

    def at(self, mu):
        density = self.family(alpha=self.law(facet_size(mu)))
        if not isinstance(density, AbstractSlopeDensity):
            raise InvalidInputError(
                f"family(alpha=...) must build a brdfscale.stats density; got {type(density).__name__}."
            )
        return density
