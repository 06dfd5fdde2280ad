"""Nearly-specular statistics ``a δ + Σ c_n h_n + w s_smooth`` and what an instrument sees of them."""

import math

import equinox as eqx
import jax.numpy as jnp
import jax.scipy.special as jss
import numpy as np
from jaxtyping import Array, ArrayLike, Complex, Float

from .._errors import InvalidInputError, NoBRDFAtScaleError, SingularDensityError
from .._evolve import evolve
from .._slopes import add_offset, check_slopes, offset_norm, phase
from .._validation import as_float_array, is_concrete, positive, vector2
from ..lobes import Lobe
from ..stats import AbstractSlopeDensity, Delta, Gaussian, require_density
from ._action import radial_action
from ._transform import MAX_ORDER, transforms_radial, transforms_scaled


class NearlySpecular(AbstractSlopeDensity):
    """Nearly-specular facet-slope statistics (seed §6, docs/conventions.md §4):

        s = a δ_c + Σ_{n=0}^{N−1} c_n h_n + w s_smooth,
        S(W) = (a + Σ_n c_n H_n(|W| x0)) e^{−iW·c} + w S_smooth(W),

    with the plus-distributions ``h_n`` of :class:`PlusDistribution` (all with the same cut-off
    ``x0`` and centre ``c = mean``), a non-negative specular weight ``a``, strengths ``c_n`` of
    either sign, and an optional smooth statistic ``s_smooth`` with weight ``w ≥ 0``.

    **Normalisation.** The ``h_n`` integrate to zero against constants, so the mass of ``s`` is
    ``a + w``; like :class:`brdfscale.stats.Mixture`, the constructor divides ``a``, ``w`` *and*
    the ``c_n`` by ``a + w``, so that ``S(0) = 1`` and ``s`` can serve as the statistic of
    :func:`brdfscale.evolve`. The stored attributes are the normalised values. Signs of ``c_n``
    are not restricted here; whether ``s`` is physical (non-negative as seen by a given
    instrument) is checked by :func:`observe`.

    Args:
        specular: ``a ≥ 0``.
        strengths: ``(c_0, …, c_{N−1})``, ``1 ≤ N ≤ 7``.
        x0: the cut-off slope (> 0).
        smooth: an optional smooth :mod:`brdfscale.stats` density (e.g. ``Beckmann(0.1)``).
        smooth_weight: ``w ≥ 0`` (must be 0 without ``smooth``).
        mean: the centre ``c`` of the δ and plus parts (default: the origin).
    """

    specular: Float[Array, ""]
    strengths: Float[Array, " N"]
    x0: Float[Array, ""]
    smooth: AbstractSlopeDensity | None
    smooth_weight: Float[Array, ""]
    mean: Float[Array, "2"] | None
    isotropic: bool = eqx.field(static=True)

    def __init__(self, specular, strengths, x0, *, smooth=None, smooth_weight: ArrayLike = 0.0, mean=None):
        a = as_float_array(specular, "specular")
        c = as_float_array(strengths, "strengths")
        w = as_float_array(smooth_weight, "smooth_weight")
        if a.ndim != 0 or w.ndim != 0:
            raise InvalidInputError("specular and smooth_weight must be scalars.")
        if c.ndim != 1 or not 1 <= c.shape[0] <= MAX_ORDER + 1:
            raise InvalidInputError(
                f"strengths must be a 1D array (c_0, …, c_{{N−1}}) with 1 ≤ N ≤ {MAX_ORDER + 1}; got shape {c.shape}."
            )
        if smooth is not None:
            require_density(
                smooth,
                "smooth",
                other=" or None",
                use="Plus-distributions enter through the strengths c_n; give a density such as stats.Beckmann(0.1).",
            )
        if is_concrete((a, w)):
            if float(a) < 0 or float(w) < 0 or float(a + w) <= 0:
                raise InvalidInputError(
                    f"specular and smooth_weight must be ≥ 0 with a positive sum (the statistic's mass); "
                    f"got {float(a)} and {float(w)}."
                )
            if smooth is None and float(w) != 0:
                raise InvalidInputError("smooth_weight must be 0 when no smooth density is given.")
        mass = a + w
        self.specular, self.strengths, self.smooth_weight = a / mass, c / mass, w / mass
        self.x0 = positive(x0, "x0", "a positive cut-off slope")
        if self.x0.ndim != 0:
            raise InvalidInputError(f"x0 must be a scalar; got shape {self.x0.shape}.")
        self.smooth = smooth
        self.mean = vector2(mean, "mean")
        self.isotropic = mean is None and (smooth is None or smooth.isotropic)

    @property
    def max_order(self) -> int:
        return self.strengths.shape[0] - 1

    def _singular_cf(self, H):
        """``a + Σ c_n H_n(k x0)`` from ``H_0 … H_N``: the δ and plus parts' transform about
        their centre."""
        return self.specular + H @ self.strengths

    def density(self, m):
        raise SingularDensityError(
            "a nearly-specular statistic (δ plus plus-distributions) has no pointwise density; "
            "use .cf(W), or brdfscale.plus.observe(statistic, kernel) for what an instrument of "
            "finite resolution sees."
        )

    def cf(self, W: Float[ArrayLike, "*batch 2"]) -> Complex[Array, "*batch"]:
        W = check_slopes(W, "W")
        value = self._singular_cf(transforms_scaled(W, self.x0, self.max_order)) * phase(W, self.mean)
        if self.smooth is not None:
            value = value + self.smooth_weight * self.smooth.cf(W)
        return value

    def cf_radial(self, k: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch"]:
        if not self.isotropic:
            return super().cf_radial(k)
        k = jnp.asarray(k)
        value = self._singular_cf(transforms_radial(k, self.x0, self.max_order))
        if self.smooth is not None:
            value = value + self.smooth_weight * self.smooth.cf_radial(k)
        return value

    def shifted(self, offset):
        return NearlySpecular(
            self.specular,
            self.strengths,
            self.x0,
            smooth=None if self.smooth is None else self.smooth.shifted(offset),
            smooth_weight=self.smooth_weight,
            mean=add_offset(self.mean, offset),
        )

    def support_radius(self, tol):
        radius = self.x0 + offset_norm(self.mean)
        if self.smooth is not None:
            radius = jnp.maximum(radius, self.smooth.support_radius(tol))
        return jnp.asarray(radius)

    def bandwidth(self, tol):
        return jnp.asarray(jnp.inf)


def _norm(d):
    """|d| with a finite gradient at d = 0."""
    r2 = jnp.sum(d * d, axis=-1)
    positive_r2 = r2 > 0
    return jnp.where(positive_r2, jnp.sqrt(jnp.where(positive_r2, r2, 1.0)), 0.0)


_BREAKS = np.array([-6.0, -3.0, -1.5, 0.0, 1.5, 3.0, 6.0])


class ObservedDensity(AbstractSlopeDensity):
    """What an instrument of Gaussian angular resolution sees: ``g = K ∗ s`` (docs/conventions.md §4).

    ``s`` is a :class:`NearlySpecular` statistic, ``K`` an isotropic centred Gaussian kernel in
    slope space with per-axis standard deviation ``σ`` (e.g. ``stats.Gaussian(sigma=σ)`` or
    ``stats.Beckmann(α)``, ``σ = α/√2``). In slope space, with ``d = u − c`` and the kernel's
    circular mean ``K̄(x; |d|) = exp(−(|d| − x)²/2σ²) I₀e(|d| x/σ²)/(2πσ²)``,

        g(u) = a K(d) + Σ_n c_n ∫_0^{x0} (logⁿ(x/x0)/x)(K̄(x; |d|) − K(d)) dx + w (K ∗ s_smooth)(u),

    the middle term being the action ``⟨h_n, K(u − ·)⟩`` evaluated by the radial quadrature of
    ``brdfscale.plus._action`` and the last one by :func:`brdfscale.evolve` (closed form for a
    Gaussian smooth part, the radial Hankel path otherwise). ``G(W) = K(W) S(W)``.

    ``σ²`` must be a positive normal floating-point number (σ from about 1.5e-154 to 1.3e154 in
    float64), so that the kernel's peak ``1/(2πσ²)`` is finite; checked when concrete.

    ``g`` may be negative where the ``c_n`` are not physical at this resolution;
    :meth:`minimum` finds its most negative value and :func:`observe` refuses such statistics.
    """

    statistic: NearlySpecular
    kernel: Gaussian
    isotropic: bool = eqx.field(static=True)

    def __init__(self, statistic: NearlySpecular, kernel: Gaussian):
        if not isinstance(statistic, NearlySpecular):
            raise InvalidInputError(
                f"statistic must be a brdfscale.plus.NearlySpecular; got {type(statistic).__name__}."
            )
        if not (isinstance(kernel, Gaussian) and kernel.isotropic):
            raise InvalidInputError(
                "kernel must be an isotropic, centred brdfscale.stats.Gaussian (Gaussian(sigma=σ) or "
                f"Beckmann(α)); got {type(kernel).__name__}. For other instrument kernels use "
                "brdfscale.evolve(lobes.Lobe(kernel), statistic, stats.Delta()) (spectral path)."
            )
        if is_concrete(kernel.cov):
            var = np.asarray(kernel.cov[..., 0, 0])
            tiny = np.finfo(var.dtype).tiny
            if not (np.all(np.isfinite(var)) and np.all(var >= tiny) and np.all(np.isfinite(1 / (2 * np.pi * var)))):
                raise InvalidInputError(
                    f"the kernel's variance σ² = {var!r} must be a positive, normal {var.dtype} number "
                    f"(σ² in [{tiny:.3g}, {np.finfo(var.dtype).max:.3g}]: σ between about {np.sqrt(tiny):.2g} and "
                    f"{np.sqrt(np.finfo(var.dtype).max):.2g}) so that the kernel's peak 1/(2πσ²) is finite."
                )
        self.statistic, self.kernel = statistic, kernel
        self.isotropic = statistic.isotropic

    @property
    def sigma(self) -> Float[Array, ""]:
        """The kernel's per-axis standard deviation σ."""
        return jnp.sqrt(self.kernel.cov[..., 0, 0])

    def singular_part(self, u: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch"]:
        """``a K(d) + Σ c_n ⟨h_n, K(u − ·)⟩``: the δ and plus parts seen by the instrument."""
        return _singular_part(self, check_slopes(u, "u"))

    def density(self, m: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch"]:
        u = check_slopes(m, "m")
        value = self.singular_part(u)
        s = self.statistic
        if s.smooth is not None:
            value = value + s.smooth_weight * evolve(Lobe(self.kernel), s.smooth, Delta()).density(u)
        return value

    def cf(self, W):
        W = check_slopes(W, "W")
        return self.kernel.cf(W) * self.statistic.cf(W)

    def cf_radial(self, k):
        return self.kernel.cf_radial(k) * self.statistic.cf_radial(k)

    def shifted(self, offset):
        return ObservedDensity(self.statistic.shifted(offset), self.kernel)

    def support_radius(self, tol):
        return self.statistic.support_radius(tol) + self.kernel.support_radius(tol)

    def bandwidth(self, tol):
        # |G| ≤ B exp(−σ²W²/2) with B = 1 + Σ|c_n|(1 + |ln(W x0)|)^{n+1} bounding |S|; B grows only
        # logarithmically, so bound it at twice the kernel's own bandwidth.
        s = self.statistic
        ell = 1 + jnp.abs(jnp.log(2 * self.kernel.bandwidth(tol) * s.x0))
        bound = 1 + jnp.sum(jnp.abs(s.strengths) * ell ** (jnp.arange(s.max_order + 1) + 1))
        return jnp.sqrt(2 * jnp.log(bound / tol)) / self.sigma

    def minimum(self, points: int = 1024) -> tuple[Float[Array, ""], Float[Array, ""], Float[Array, "2"]]:
        """``(g_min, g_max, u_min)``: the smallest and largest value of ``g`` and where the smallest is.

        Sampled on ``points`` radii from the centre to the support radius (1e-12) along one ray
        (isotropic) or 8 rays; the spacing must resolve σ, so ``points`` should exceed about
        ``4 R/σ`` (the default suits ``x0/σ`` up to about 200). ``points``: an integer in
        [16, :data:`MAX_POINTS`]; the samples are evaluated in batches of at most
        ``_BATCH`` = 4096, so memory stays bounded.
        """
        if isinstance(points, bool) or not isinstance(points, (int, np.integer)) or not 16 <= points <= MAX_POINTS:
            raise InvalidInputError(
                f"points must be an integer in [16, {MAX_POINTS}] (radii sampled per ray); got {points!r}."
            )
        R = self.support_radius(1e-12)
        rays = 1 if self.isotropic else 8
        phi = jnp.arange(rays) * (math.pi * 2 / rays)
        radii = jnp.linspace(0.0, 1.0, points) * R
        centre = 0.0 if self.statistic.mean is None else self.statistic.mean
        u = centre + radii[:, None, None] * jnp.stack([jnp.cos(phi), jnp.sin(phi)], axis=-1)[None]
        u = u.reshape(-1, 2)
        n = u.shape[0]
        if n <= _BATCH:
            values = self.density(u)
        else:  # equal batches (one compilation), the last one padded with the first sample
            pad = -n % _BATCH
            padded = jnp.concatenate([u, jnp.broadcast_to(u[:1], (pad, 2))]) if pad else u
            values = jnp.concatenate([self.density(batch) for batch in padded.reshape(-1, _BATCH, 2)])[:n]
        i = jnp.argmin(values)
        return values[i], jnp.max(values), u[i]


MAX_POINTS = 65536
"""Largest ``points`` accepted by :meth:`ObservedDensity.minimum` and :func:`observe` (radii per ray;
8 rays for an anisotropic statistic)."""
_BATCH = 4096


@eqx.filter_jit
def _singular_part(observed: "ObservedDensity", u):
    s = observed.statistic
    d = u if s.mean is None else u - s.mean
    r = _norm(d)
    var = observed.kernel.cov[..., 0, 0]
    norm = 1.0 / (2 * math.pi * var)
    at_r = norm * jnp.exp(-r * r / (2 * var))

    def excess(x):
        rr = r[..., None]
        return norm * jnp.exp(-((rr - x) ** 2) / (2 * var)) * jss.i0e(rr * x / var) - at_r[..., None]

    sigma = jnp.sqrt(var)
    breaks = jnp.maximum(r[..., None] + sigma * jnp.asarray(_BREAKS, r.dtype), 0.0)
    actions = radial_action(excess, s.x0, s.max_order, jnp.broadcast_to(sigma, r.shape), breaks)
    return s.specular * at_r + actions @ s.strengths


def observe(statistic: NearlySpecular, kernel: Gaussian, *, rtol: float = 1e-9, points: int = 1024) -> ObservedDensity:
    """The nearly-specular ``statistic`` as an instrument with resolution ``kernel`` sees it.

    Returns an :class:`ObservedDensity` (use ``brdfscale.lobes.Lobe(observe(s, K), A)`` for a
    lobe of amplitude ``A``). When the parameters are concrete it checks that what the
    instrument sees is non-negative: a facet-slope statistic is a probability density, so
    ``K ∗ s`` must be ≥ 0 at every resolution.

    Args:
        statistic: a :class:`NearlySpecular` statistic.
        kernel: the instrument's isotropic, centred Gaussian kernel.
        rtol: a finite number ≥ 0: negative values down to ``−rtol · max g`` are accepted as
            rounding (0: none at all).
        points: radii sampled per ray by :meth:`ObservedDensity.minimum`, an integer in
            [16, :data:`MAX_POINTS`].

    Raises:
        NoBRDFAtScaleError: ``min g < −rtol · max g`` (the ``c_n`` are not physical at this
            resolution); the message gives the value and where it occurs. Under ``jax.jit``
            the check is skipped — call :meth:`ObservedDensity.minimum` for the diagnostic.
        InvalidInputError: a wrong statistic or kernel, ``rtol`` negative or not finite,
            ``points`` outside [16, MAX_POINTS].
    """
    if (
        isinstance(rtol, bool)
        or not isinstance(rtol, (int, float, np.floating, np.integer))
        or not math.isfinite(rtol)
        or rtol < 0
    ):
        raise InvalidInputError(
            f"rtol must be a finite number ≥ 0 (the negative fraction of the peak tolerated as rounding); got {rtol!r}."
        )
    observed = ObservedDensity(statistic, kernel)
    if is_concrete(observed):
        low, high, where = (np.asarray(v) for v in observed.minimum(points))
        if low < -rtol * high:
            raise NoBRDFAtScaleError(
                f"what an instrument of resolution σ = {float(observed.sigma):.4g} sees of this "
                f"nearly-specular statistic is negative: g = {float(low):.6g} at u = {where.tolist()} "
                f"({float(low / high):.3g} of the peak {float(high):.6g}). With specular weight "
                f"a = {float(statistic.specular):.6g}, strengths c_n = {np.asarray(statistic.strengths).tolist()} "
                f"and x0 = {float(statistic.x0):.6g} the statistic is not a non-negative density at "
                "this resolution; reduce |c_n|, raise a, or compare with a coarser instrument."
            )
    return observed
