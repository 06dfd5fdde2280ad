"""Parametric slope densities: Delta, Gaussian (Beckmann), GGX, Disk."""

import math
from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._errors import InvalidInputError, SingularDensityError
from .._show import concrete, derived
from .._slopes import add_offset, centred, check_slopes, eig2, offset_norm, phase, safe_norm, shifted_cf
from .._special import jinc, xk1
from .._validation import as_float_array, is_concrete, positive, vector2
from ._base import AbstractSlopeDensity
from ._grid import axis_phase


def _per_axis(value, value_x, value_y, name: str):
    """Resolve ``alpha=`` versus ``alpha_x=, alpha_y=`` into a (..., 2) array.

    Returns the array and whether the density is structurally isotropic."""
    if value is not None:
        if value_x is not None or value_y is not None:
            raise InvalidInputError(f"give either {name}= or {name}_x= and {name}_y=, not both.")
        v = positive(value, name)
        return jnp.stack([v, v], axis=-1), True
    if value_x is None or value_y is None:
        raise InvalidInputError(f"give {name}= (isotropic) or both {name}_x= and {name}_y= (anisotropic).")
    vx = positive(value_x, f"{name}_x")
    vy = positive(value_y, f"{name}_y")
    vx, vy = jnp.broadcast_arrays(vx, vy)
    return jnp.stack([vx, vy], axis=-1), False


class Delta(AbstractSlopeDensity):
    """Point mass at ``mean`` (default: the origin): a perfectly flat surface, ``S(W) = e^{−iW·mean}``.

    It has no pointwise density; :meth:`density` raises :class:`SingularDensityError`.
    """

    mean: Float[Array, "*batch 2"] | None
    isotropic: bool = eqx.field(static=True)

    def __init__(self, mean: Float[ArrayLike, "*batch 2"] | Sequence[float] | None = None):
        self.mean = vector2(mean, "mean")
        self.isotropic = mean is None

    def _show_items(self) -> list[tuple[str, object]]:
        return [("mean", self.mean)] if self.mean is not None else [("", "point mass at the origin")]

    def density(self, m):
        raise SingularDensityError(
            "Delta (a point mass) has no pointwise density; use .cf(W), or convolve it with a "
            "smooth density (e.g. brdfscale.evolve) before evaluating."
        )

    def cf(self, W):
        return phase(check_slopes(W, "W"), self.mean)

    def cf_grid(self, grid):
        mx, my = (None, None) if self.mean is None else (self.mean[0], self.mean[1])
        return grid.separable(lambda w: axis_phase(w, mx), lambda w: axis_phase(w, my))

    def shifted(self, offset):
        return Delta(add_offset(self.mean, offset))

    def support_radius(self, tol):
        return jnp.asarray(offset_norm(self.mean))

    def bandwidth(self, tol):
        return jnp.asarray(jnp.inf)


def _same_axes(cov, isotropic: bool) -> bool:
    """Whether a diagonal covariance has equal variances: structurally (``isotropic``) or by its
    concrete values."""
    if isotropic:
        return True
    if not concrete(cov):
        return False
    c = np.asarray(cov)
    return bool(np.all(c[..., 0, 0] == c[..., 1, 1]))


def _same_axes_alpha(alpha, isotropic: bool) -> bool:
    """Whether per-axis widths (..., 2) are equal: structurally or by their concrete values."""
    if isotropic:
        return True
    if not concrete(alpha):
        return False
    a = np.asarray(alpha)
    return bool(np.all(a[..., 0] == a[..., 1]))


class Gaussian(AbstractSlopeDensity):
    """Gaussian slope density with covariance ``cov`` (2×2) and optional ``mean``.

    ``s(m) = exp(−½ dᵀ Σ⁻¹ d) / (2π √det Σ)`` with ``d = m − mean``;
    ``S(W) = exp(−i W·mean − ½ Wᵀ Σ W)``. Convolution adds covariances.

    Construct with ``cov=`` (full 2×2), or ``sigma=`` (a scalar: isotropic standard
    deviation per axis; a pair: per-axis standard deviations). See also :func:`Beckmann`.
    """

    cov: Float[Array, "*batch 2 2"]
    mean: Float[Array, "*batch 2"] | None
    isotropic: bool = eqx.field(static=True)
    diagonal: bool = eqx.field(static=True)
    """True when ``cov`` is diagonal by construction (``sigma=``), so ``S`` factorises."""

    def __init__(self, cov=None, *, sigma=None, mean=None):
        isotropic = False
        if (cov is None) == (sigma is None):
            raise InvalidInputError("Gaussian needs exactly one of cov= (2×2) or sigma= (scalar or pair).")
        if sigma is not None:
            s = positive(sigma, "sigma", "positive (a standard deviation)")
            if s.ndim >= 1 and s.shape[-1] == 2:
                var = s**2
            else:
                var = jnp.stack([s**2, s**2], axis=-1)
                isotropic = True
            zero = jnp.zeros_like(var[..., 0])
            cov = jnp.stack([jnp.stack([var[..., 0], zero], -1), jnp.stack([zero, var[..., 1]], -1)], axis=-2)
        else:
            cov = as_float_array(cov, "cov")
            if cov.ndim < 2 or cov.shape[-2:] != (2, 2):
                raise InvalidInputError(f"cov must have shape (..., 2, 2); got {cov.shape}.")
            if is_concrete(cov):
                c = np.asarray(cov)
                if not np.allclose(c, np.swapaxes(c, -1, -2), rtol=0, atol=1e-12 * np.max(np.abs(c))):
                    raise InvalidInputError(f"cov must be symmetric; got {c!r}.")
                lo, _ = eig2(c)
                if not np.all(lo > 0):
                    raise InvalidInputError(
                        f"cov must be positive definite (a Gaussian of zero or negative variance is "
                        f"not a density; use Delta for a flat surface); smallest eigenvalue {np.min(lo):.6g}."
                    )
        if is_concrete(cov):
            c = np.asarray(cov)
            det = c[..., 0, 0] * c[..., 1, 1] - c[..., 0, 1] ** 2
            if not (np.all(np.isfinite(c)) and np.all(np.isfinite(det)) and np.all(det >= np.finfo(c.dtype).tiny)):
                raise InvalidInputError(
                    f"the covariance's variances and determinant must be finite normal {c.dtype} numbers "
                    f"(standard deviations between about 1e-76 and 1e76 in float64); got variances "
                    f"{c[..., 0, 0]!r}, {c[..., 1, 1]!r} and determinant {det!r}."
                )
        self.cov = cov
        self.mean = vector2(mean, "mean")
        self.isotropic = isotropic and mean is None
        self.diagonal = sigma is not None

    def _show_items(self) -> list[tuple[str, object]]:
        # per-axis standard deviations (and the Beckmann width α = σ√2 of each axis), the
        # correlation where Σ has a cross term
        items: list[tuple[str, object]]
        if self.diagonal and _same_axes(self.cov, self.isotropic):
            sigma = derived(self.cov, lambda c: c[..., 0, 0] ** 0.5)
            items = [("sigma", sigma), ("alpha", derived(self.cov, lambda c: (2 * c[..., 0, 0]) ** 0.5))]
        else:
            items = [("sigma", derived(self.cov, lambda c: (c[..., (0, 1), (0, 1)]) ** 0.5))]
            if not self.diagonal:
                items.append(("rho", derived(self.cov, lambda c: c[..., 0, 1] / (c[..., 0, 0] * c[..., 1, 1]) ** 0.5)))
        return items + ([("mean", self.mean)] if self.mean is not None else [])

    def density(self, m):
        d = centred(m, self.mean)
        a, b, c = self.cov[..., 0, 0], self.cov[..., 0, 1], self.cov[..., 1, 1]
        det = a * c - b**2
        quad = (c * d[..., 0] ** 2 - 2 * b * d[..., 0] * d[..., 1] + a * d[..., 1] ** 2) / det
        return jnp.exp(-0.5 * quad) / (2 * jnp.pi * jnp.sqrt(det))

    def cf(self, W):
        W = check_slopes(W, "W")
        a, b, c = self.cov[..., 0, 0], self.cov[..., 0, 1], self.cov[..., 1, 1]
        quad = a * W[..., 0] ** 2 + 2 * b * W[..., 0] * W[..., 1] + c * W[..., 1] ** 2  # Wᵀ Σ W
        return shifted_cf(jnp.exp(-0.5 * quad), W, self.mean)

    def cf_grid(self, grid):
        # exp(−½WᵀΣW − iW·mean) = Π_axes exp(−½Σ_aa W_a² − iW_a mean_a) when Σ is diagonal by
        # construction: per-axis factors
        mx, my = (None, None) if self.mean is None else (self.mean[0], self.mean[1])
        a, b, c = self.cov[0, 0], self.cov[0, 1], self.cov[1, 1]
        if self.diagonal:
            return grid.separable(
                lambda w: jnp.exp(-0.5 * a * w**2) * axis_phase(w, mx),
                lambda w: jnp.exp(-0.5 * c * w**2) * axis_phase(w, my),
            )
        # with a cross term the per-axis factors can under- and overflow (0 · ∞); one exponential
        # of the whole (non-negative) quadratic form per node instead
        wx, wy = grid.wx[None, :], grid.wy[:, None]
        quad = a * wx**2 + 2 * b * wx * wy + c * wy**2
        return jnp.exp(-0.5 * quad) * grid.separable(lambda w: axis_phase(w, mx), lambda w: axis_phase(w, my))

    def shifted(self, offset):
        if self.diagonal:
            return Gaussian(
                sigma=jnp.sqrt(jnp.diagonal(self.cov, axis1=-2, axis2=-1)), mean=add_offset(self.mean, offset)
            )
        return Gaussian(cov=self.cov, mean=add_offset(self.mean, offset))

    def support_radius(self, tol):
        _, hi = eig2(self.cov)
        return jnp.max(jnp.sqrt(2 * hi * math.log(1 / tol)) + offset_norm(self.mean))

    def bandwidth(self, tol):
        lo, _ = eig2(self.cov)
        return jnp.max(jnp.sqrt(2 * math.log(1 / tol) / lo))


def Beckmann(alpha=None, *, alpha_x=None, alpha_y=None, mean=None) -> Gaussian:
    """Beckmann slope statistics: a Gaussian with per-axis variance ``α²/2`` (docs/conventions.md §1).

    ``S(W) = exp(−(α_x² W_x² + α_y² W_y²)/4)``; convolution adds ``α²``. The Beckmann normal
    distribution ``D(h) = exp(−tan²θ/α²)/(π α² cos⁴θ)`` is this density divided by cos⁴θ.
    """
    a, isotropic = _per_axis(alpha, alpha_x, alpha_y, "alpha")
    sigma = a / math.sqrt(2.0)
    return Gaussian(sigma=sigma[..., 0] if isotropic else sigma, mean=mean)


def _xk1_inverse(tol: float) -> float:
    """x with ``x K1(x) = tol`` (asymptotically ``√(πx/2) e^{−x} (1 + 3/(8x))``)."""
    x = math.log(1 / tol)
    for _ in range(8):
        x = math.log(1 / tol) + 0.5 * math.log(math.pi * x / 2) + math.log1p(3 / (8 * x))
    return x


class GGX(AbstractSlopeDensity):
    """GGX / Trowbridge–Reitz slope statistics (a bivariate Student-t with ν = 2).

    ``s(m) = 1 / (π α_x α_y (1 + x² )²)`` with ``x = ((m_x − mean_x)/α_x, (m_y − mean_y)/α_y)``;
    ``S(W) = |A W| K₁(|A W|) e^{−iW·mean}`` with ``A = diag(α_x, α_y)`` (docs/conventions.md §1). The
    tails fall off as ``|m|⁻⁴``: slopes have no finite variance.
    """

    alpha: Float[Array, "*batch 2"]
    mean: Float[Array, "*batch 2"] | None
    isotropic: bool = eqx.field(static=True)

    def __init__(self, alpha=None, *, alpha_x=None, alpha_y=None, mean=None):
        self.alpha, isotropic = _per_axis(alpha, alpha_x, alpha_y, "alpha")
        self.mean = vector2(mean, "mean")
        self.isotropic = isotropic and mean is None

    def _show_items(self) -> list[tuple[str, object]]:
        alpha = derived(self.alpha, lambda a: a[..., 0]) if _same_axes_alpha(self.alpha, self.isotropic) else self.alpha
        items: list[tuple[str, object]] = [("alpha", alpha)]
        return items + ([("mean", self.mean)] if self.mean is not None else [])

    def density(self, m):
        d = centred(m, self.mean)
        x2 = jnp.sum((d / self.alpha) ** 2, axis=-1)
        return 1.0 / (jnp.pi * self.alpha[..., 0] * self.alpha[..., 1] * (1 + x2) ** 2)

    def cf(self, W):
        W = check_slopes(W, "W")
        return shifted_cf(xk1(safe_norm(W * self.alpha)), W, self.mean)

    def cf_radial(self, k):
        return xk1(self.alpha[..., 0] * jnp.asarray(k))  # isotropic: α_x = α_y

    def shifted(self, offset):
        return GGX(alpha_x=self.alpha[..., 0], alpha_y=self.alpha[..., 1], mean=add_offset(self.mean, offset))

    def support_radius(self, tol):
        return jnp.max(jnp.max(self.alpha, axis=-1) * math.sqrt(tol**-0.5 - 1) + offset_norm(self.mean))

    def bandwidth(self, tol):
        return jnp.max(_xk1_inverse(tol) / jnp.min(self.alpha, axis=-1))


class Disk(AbstractSlopeDensity):
    """Uniform density on a disk of slope ``radius`` about ``mean``.

    ``s(m) = 1/(π r²)`` for ``|m − mean| < r``; ``S(W) = 2 J₁(r|W|)/(r|W|) e^{−iW·mean}``. The
    transform has zeros, so dividing by it (evolving *towards* a disk statistic) needs
    regularisation.
    """

    radius: Float[Array, "*batch"]
    mean: Float[Array, "*batch 2"] | None
    isotropic: bool = eqx.field(static=True)

    def __init__(self, radius, *, mean=None):
        self.radius = positive(radius, "radius")
        self.mean = vector2(mean, "mean")
        self.isotropic = mean is None

    def density(self, m):
        d = centred(m, self.mean)
        inside = jnp.sum(d**2, axis=-1) < self.radius**2
        return jnp.where(inside, 1.0 / (jnp.pi * self.radius**2), 0.0)

    def cf(self, W):
        W = check_slopes(W, "W")
        return shifted_cf(jinc(self.radius * safe_norm(W)), W, self.mean)

    def cf_radial(self, k):
        return jinc(self.radius * jnp.asarray(k))

    def shifted(self, offset):
        return Disk(self.radius, mean=add_offset(self.mean, offset))

    def support_radius(self, tol):
        return jnp.max(self.radius + offset_norm(self.mean))

    def bandwidth(self, tol):
        # |2 J1(x)/x| ≤ 2 √(2/(π x)) / x for large x.
        return jnp.max((2 * math.sqrt(2 / math.pi) / tol) ** (2 / 3) / self.radius)
