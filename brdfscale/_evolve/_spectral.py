"""The evolved lobe as a spectral quotient, and the two paths that invert its transform.

Seed Eq. 4.4 in terms of the facet-slope densities (DESIGN §2): the lobe at the target
scale has the transform

    G_to(W) = G_from(W) · S_from(W) / S_to(W).

:class:`EvolvedDensity` holds the three factors and evaluates ``G_to`` exactly; the density
``g_to(u) = (2π)⁻² ∫ G_to(W) e^{+iW·u} d²W`` is then obtained by

* the radial (Hankel) path, when all three factors are radially symmetric:
  ``g(r) = (2π)⁻¹ ∫_0^K G(k) J₀(k r) k dk``, Gauss–Legendre in k on [0, K]; or
* the grid path: ``G`` sampled on a regular frequency grid and inverted by a real 2D FFT
  (``irfft2``) onto the slope grid, or summed directly at query offsets (a non-uniform
  inverse DFT on the same frequency grid, so queries need no interpolation).

Division uses Tikhonov regularisation, ``1/S → S*/(|S|² + λ²)``: ``λ = 0`` (the default) is
the exact Eq. 4.4; a positive λ suppresses the frequencies where ``|S_to| ≲ λ``. For
tabulated or noisy input choose λ ≈ the relative noise level of ``G_from`` in frequency
space (Wiener's rule: λ² = noise power / signal power); see :func:`brdfscale.evolve`.
"""

import math
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._errors import InvalidInputError, NoBRDFAtScaleError
from .._quadrature import gauss_legendre
from .._special import j0
from ..stats import AbstractSlopeDensity, Delta, FrequencyGrid
from .._validation import is_concrete
from ..stats._base import check_slopes

_PROBE_DIRECTIONS = 8
_PROBE_POINTS = 206  # 9 decades, ~23 per decade
_PROBE_POINTS_BEYOND = 24  # 8 per decade: beyond the grid, |G| is only watched for growth
_CF_EXCESS = 1e-6
CORE_TOL = 1e-3  # the probe's frequency window is scaled to the lobe's extent at this level
_NO_BRDF = "no BRDF exists at the requested scale"
_NO_BRDF_MESSAGE = (
    _NO_BRDF + ": the evolved lobe's transform exceeds 1 in modulus, which no non-negative "
    "lobe has (evolving towards a finer scale than the data support). Choose a coarser target "
    "scale or set regularisation > 0."
)


class EvolvedDensity(AbstractSlopeDensity):
    """``g_to`` of seed Eq. 4.4: transform ``G_from S_from / S_to`` (regularised by λ).

    ``method`` is ``"radial"`` or ``"grid"``; ``size`` is the number of Gauss–Legendre nodes
    (radial) or the grid's side (grid); ``tol`` is the error target relative to the peak
    that sets the frequency cut-off and, unless ``extent`` is given, the grid's half-width.
    """

    base: AbstractSlopeDensity
    s_from: AbstractSlopeDensity
    s_to: AbstractSlopeDensity
    regularisation: Float[Array, ""]
    extent: Float[Array, ""] | None
    method: str = eqx.field(static=True)
    size: int = eqx.field(static=True)
    tol: float = eqx.field(static=True)
    isotropic: bool = eqx.field(static=True)
    check: bool = eqx.field(static=True)
    """Whether evaluations attach the existence check (|G| ≤ 1) at run time."""

    def __init__(self, base, s_from, s_to, regularisation, method, size, tol, extent=None, check=True):
        self.base, self.s_from, self.s_to = base, s_from, s_to
        self.regularisation = jnp.asarray(regularisation)
        self.extent = None if extent is None else jnp.asarray(extent)
        self.method, self.size, self.tol = method, size, tol
        self.isotropic = base.isotropic and s_from.isotropic and s_to.isotropic
        self.check = bool(check)

    # -- the exact transform -------------------------------------------------------------
    def _divide(self, numerator, denominator):
        """``N S*/(|S|² + λ²)`` written as ``N / (S + λ²/S*)`` so that a denormal S still
        divides exactly when λ = 0. Where S = 0: 0 if N = 0 or λ > 0, else ∞ (which the
        existence check then reports) — never 0/0."""
        lam2 = self.regularisation**2
        zero = denominator == 0
        safe = jnp.where(zero, 1.0, denominator)
        ratio = numerator / (safe + lam2 / jnp.conj(safe))
        at_zero = jnp.where((numerator == 0) | (lam2 > 0), 0.0, jnp.inf)
        return jnp.where(zero, at_zero, ratio)

    def _quotient(self, transform):
        """``G_from S_from / S_to`` from ``transform(density)`` of each factor."""
        numerator = transform(self.base) * transform(self.s_from)
        if isinstance(self.s_to, Delta) and self.s_to.mean is None:  # μ = ∞: nothing to divide
            return numerator
        return self._divide(numerator, transform(self.s_to))

    def cf(self, W):
        W = check_slopes(W, "W")
        return self._quotient(lambda density: density.cf(W))

    def cf_grid(self, grid):
        return self._quotient(lambda density: density.cf_grid(grid))

    def cf_radial(self, k):
        return jnp.real(self._divide(self.base.cf_radial(k) * self.s_from.cf_radial(k), self.s_to.cf_radial(k)))

    def shifted(self, offset):
        return EvolvedDensity(self.base.shifted(offset), self.s_from, self.s_to, self.regularisation,
                              self.method, self.size, self.tol, self.extent, self.check)

    def support_radius(self, tol):
        return self.base.support_radius(tol) + self.s_from.support_radius(tol)

    def _probe(self, k_lo=None):
        """|G| on rays at log-spaced frequencies: over nine decades scaled to the lobe's
        spatial extent (its support radius at 10⁻³ of the peak, or at ``tol`` when looser:
        the core, not a heavy tail's reach, which at a tight ``tol`` would pull the window
        below the frequencies the lobe has), or (``k_lo`` given) over the three decades above
        ``k_lo``.

        Only used for discretisation choices and the existence check, so no gradient flows
        through it (|G| is not differentiable where G = 0)."""
        return _probe(jax.lax.stop_gradient(self), k_lo)

    def _probe_values(self, k_lo):
        dtype = jnp.result_type(*jax.tree_util.tree_leaves(self))
        if k_lo is None:
            R = jnp.maximum(self.support_radius(max(self.tol, CORE_TOL)), 1e-12)
            k = jnp.asarray(np.logspace(-2, 7, _PROBE_POINTS), dtype=dtype) / R
        else:
            k = k_lo * jnp.asarray(np.logspace(0, 3, _PROBE_POINTS_BEYOND), dtype=dtype)
        directions = 1 if self.isotropic else _PROBE_DIRECTIONS  # one ray says all for radial G
        phi = jnp.asarray(np.arange(directions) * np.pi / directions, dtype=dtype)
        W = k[:, None, None] * jnp.stack([jnp.cos(phi), jnp.sin(phi)], -1)[None]
        return k, jnp.abs(self.cf(W))

    def bandwidth(self, tol):
        """The frequency beyond which |G| stays below ``tol`` (the largest probe frequency
        when it does not fall that low in the probed window: :func:`choose_size` reports
        that for concrete inputs)."""
        return _cutoff(*self._probe(), tol)

    # -- inversion ------------------------------------------------------------------------
    def density(self, m):
        m = check_slopes(m, "m")
        shape = self
        if self.method == "radial" and is_concrete((self, m)):
            # evaluate only what is asked: nodes enough for the largest queried radius
            r_max = float(jnp.max(jnp.linalg.norm(m, axis=-1))) if m.size else 0.0
            # J₀(k r) oscillates over r_max, and G itself over the lobe's extent
            reach = r_max + float(self.support_radius(self.tol))
            n = radial_nodes(float(self.bandwidth(self.tol)), reach, self.tol)
            if n > self.size:
                warnings.warn(
                    f"queries at offsets up to {r_max:.3g} need {n} Gauss–Legendre nodes for tol={self.tol:g}; "
                    f"this lobe has {self.size} (evolve(..., size=...) raises it): errors there may exceed tol.",
                    stacklevel=2)
            elif n < self.size:
                shape = EvolvedDensity(self.base, self.s_from, self.s_to, self.regularisation,
                                       self.method, n, self.tol, self.extent, self.check)
        return _translate_errors(_density, shape, m)

    def _density(self, m):
        if self.method == "radial":
            k, mag = self._probe()
            peak = jnp.max(mag) if self.check else None
            return _checked(self._radial(jnp.linalg.norm(m, axis=-1), _cutoff(k, mag, self.tol)), peak)
        return self._grid_at(m)

    def _radial(self, r, K):
        x, w = gauss_legendre(self.size)
        k = (0.5 * (jnp.asarray(x, r.dtype) + 1)) * K
        wk = 0.5 * K * jnp.asarray(w, r.dtype)
        G = self.cf_radial(k)
        return jnp.sum(wk * G * k * j0(r[..., None] * k), axis=-1) / (2 * jnp.pi)

    def grid_spacing(self):
        """Slope-grid spacing h and half-width a = N h / 2 of the grid path."""
        a = self.support_radius(self.tol) if self.extent is None else self.extent
        a = jax.lax.stop_gradient(a)  # a discretisation choice
        return 2 * a / self.size, a

    def frequency_grid(self, h) -> FrequencyGrid:
        """The real-FFT frequencies of the ``size × size`` slope grid of spacing ``h``."""
        return FrequencyGrid(self.size, 2 * jnp.pi / (self.size * h))

    def on_grid(self):
        """``(u, values)``: nodes ``u`` (N,) from −a to a − h and ``g_to`` on the N×N grid
        (rows u_y, columns u_x), by one real inverse FFT."""
        return _translate_errors(_on_grid, self)

    def _grid_transform(self, grid: FrequencyGrid):
        """``G`` on ``grid`` and the largest ``|G|`` for the
        existence check: on the grid itself, and on rays beyond its Nyquist frequency π/h
        (where the grid cannot see), 24 frequencies per ray over three decades. ``None``
        when nothing is divided (``s_to`` a point mass, |S_to| = 1): then G is a product of
        transforms of densities, |G| ≤ 1 holds by construction and there is nothing to check;
        and when the check is switched off (``check=False``)."""
        G = self.cf_grid(grid)
        if isinstance(self.s_to, Delta) or not self.check:
            return G, None
        G_fixed = jax.lax.stop_gradient(G)
        on_grid = jnp.sqrt(jnp.max(G_fixed.real**2 + G_fixed.imag**2))  # no per-node hypot
        beyond = jnp.max(self._probe(grid.step * (grid.size / 2))[1])  # from π/h
        return G, jnp.maximum(on_grid, beyond)

    def _on_grid(self):
        h, a = self.grid_spacing()
        n = self.size
        G, peak = self._grid_transform(self.frequency_grid(h))
        # nodes start at −a: multiply by e^{+iW·a} = (−1)^{kx+ky} for a = N h / 2 (a constant
        # pattern; cheaper than rolling the output by half a period); the 1/h² of the inverse
        # DFT is applied on the half-size frequency side, in the same pass
        sign = 1.0 - 2.0 * ((np.arange(n)[:, None] + np.arange(n // 2 + 1)[None, :]) % 2)
        values = jnp.fft.irfft2(G * (sign / h**2), s=(n, n))
        u = -a + h * jnp.arange(n, dtype=h.dtype)
        return u, _checked(values, peak)

    def _grid_at(self, m):
        """Inverse DFT of the grid path summed directly at query offsets (no interpolation)."""
        h, _ = self.grid_spacing()
        grid = self.frequency_grid(h)
        G, peak = self._grid_transform(grid)  # (n, n//2+1): half plane, the other half is the conjugate
        fx, fy = grid.wx, grid.wy
        weight = jnp.where((jnp.arange(fx.shape[0]) == 0) | (2 * jnp.arange(fx.shape[0]) == self.size), 1.0, 2.0)
        flat = m.reshape(-1, 2)
        ex = jnp.exp(1j * flat[:, 0, None] * fx[None, :])  # (q, nx)
        ey = jnp.exp(1j * flat[:, 1, None] * fy[None, :])  # (q, ny)
        total = jnp.einsum("qy,yx,qx->q", ey, G * weight, ex)
        dW2 = (2 * jnp.pi / (self.size * h)) ** 2
        return _checked((jnp.real(total) * dW2 / (2 * jnp.pi) ** 2).reshape(m.shape[:-1]), peak)


def _cutoff(k, mag, tol):
    """The cut-off frequency K for an error ``tol`` relative to the lobe's peak: the larger of
    the first probe frequency past the last one where ``|G| > tol``, and the first beyond which
    the k-weighted tail is below ``tol`` of the whole,

        Σ_{k_i ≥ K} |G(k_i)| k_i² ≤ tol · Σ_i |G(k_i)| k_i²   (log-spaced k: k² d ln k = k dk),

    since truncating the inverse transform at K changes the density by at most
    ``(2π)⁻¹ ∫_K^∞ |G| k dk`` (radially; the largest |G| over the probe's rays otherwise),
    and ``(2π)⁻¹ ∫ |G| k dk`` is the peak of a lobe whose transform does not change sign — a
    slowly decaying transform (GGX's e^{−αk}) needs the tail criterion, a fast one the pointwise."""
    n = k.shape[0]
    above = jnp.any(mag > tol, axis=1)
    pointwise = jnp.minimum(jnp.max(jnp.where(above, jnp.arange(n), 0)) + 1, n - 1)
    weight = jnp.max(mag, axis=1) * k**2
    tail = jnp.cumsum(weight[::-1])[::-1]  # tail[i] = Σ_{j ≥ i} weight_j
    inside = tail <= tol * tail[0]
    by_tail = jnp.where(jnp.any(inside), jnp.argmax(inside), n - 1)
    return k[jnp.maximum(pointwise, by_tail)]


def _checked(value, peak):
    """Attach the existence check: a non-negative density has |G(W)| ≤ G(0) = 1 (``peak``:
    the largest |G| found; None: nothing to check)."""
    if peak is None:
        return value
    excess = peak - 1
    return eqx.error_if(value, (excess > _CF_EXCESS) | jnp.isnan(excess), _NO_BRDF_MESSAGE)


_density = eqx.filter_jit(lambda shape, m: shape._density(m))
_probe = eqx.filter_jit(lambda shape, k_lo: shape._probe_values(k_lo))
_on_grid = eqx.filter_jit(lambda shape: shape._on_grid())


def _translate_errors(fn, *args):
    """Call a jitted evaluation; outside any trace, turn its run-time existence check into
    :class:`NoBRDFAtScaleError` (inside a user's ``jax.jit`` it surfaces as equinox's
    ``EquinoxRuntimeError`` with the same message)."""
    try:
        return fn(*args)
    except eqx.EquinoxRuntimeError as err:
        if _NO_BRDF in str(err):
            raise NoBRDFAtScaleError(_NO_BRDF_MESSAGE) from None
        raise


def radial_nodes(K: float, r_max: float, tol: float) -> int:
    """Gauss–Legendre nodes on [0, K] that integrate ``G(k) J0(k r) k`` to ``tol`` when the
    integrand's oscillation spans ``r_max`` in slope (the query radius plus the lobe's own
    extent, over which G oscillates): about ``K r_max/2`` oscillations' worth plus a margin,
    in multiples of 64. The
    margin grows as ``tol^{−1/5}`` below 1e-8: the rule converges algebraically on the
    ``k² ln k`` behaviour of K₀/K₁-type transforms (GGX, Student-t) at the origin (64 nodes
    leave ~5e-10 of the peak there; measured in tests/test_evolve.py)."""
    margin = 64 * math.ceil(max(1e-8 / tol, 1.0) ** 0.2)
    return int(64 * math.ceil(max(64.0, 0.6 * K * r_max + margin) / 64))


def choose_size(density: EvolvedDensity, method: str, max_size: int) -> tuple[int, float]:
    """Nodes (radial) or grid side (grid) that resolve ``density`` to its ``tol``.

    Returns ``(size, tol)``: a power of two (grid) or a multiple of 64 (radial), capped at
    ``max_size``. When the cap cannot meet the target (heavy tails, e.g. GGX's |m|⁻⁴, need
    grids of extent ∝ tol^{−1/4}), the grid path relaxes the target by decades until the
    grid fits and returns the tolerance it can honour; InvalidInputError when not even 1e-2
    fits (a lobe far narrower along one axis than its extent along another).
    NoBRDFAtScaleError when the transform exceeds 1 in modulus (no tol can help). Needs
    concrete parameter values.
    """
    k, mag = density._probe()  # one probe serves every check and cut-off below
    if density.check and not isinstance(density.s_to, Delta):  # a transform above 1 is no lobe, whatever tol
        if not float(jnp.max(mag)) <= 1 + _CF_EXCESS:
            raise NoBRDFAtScaleError(_NO_BRDF_MESSAGE)
    # every ray must decay within the window: a lobe narrow along one axis decays late along it
    if not bool(jnp.all(mag[-1] <= density.tol)):
        raise InvalidInputError(
            f"tol={density.tol:g}: the evolved lobe's transform does not fall below tol within nine decades "
            "of frequency above the lobe's width (a transform that decays this slowly, or a tol below the "
            "rounding of its evaluation); choose a larger tol.")
    if method == "radial":
        K = float(_cutoff(k, mag, density.tol))
        R = float(density.support_radius(density.tol))
        # queries out to the support R; G itself oscillates over the lobe's extent R as well
        return min(max_size, radial_nodes(K, 2 * R, density.tol)), density.tol
    tol = density.tol
    while True:
        K = float(_cutoff(k, mag, tol))
        R = float(density.support_radius(tol) if density.extent is None else density.extent)
        # spacing h = 2R/N must resolve K: π/h ≥ K  ⇒  N ≥ 2 R K / π
        need = max(64.0, 2 * R * K / math.pi)
        if need <= max_size:
            return int(2 ** math.ceil(math.log2(need))), tol
        if tol >= 1e-2:
            raise InvalidInputError(
                f"the grid path cannot resolve this lobe even to 1e-2: it needs {need:.3g} nodes per side (extent "
                f"{R:.3g}, bandwidth {K:.3g}), more than {max_size}. Pass a larger size= (memory ∝ size²), use "
                "method='radial' for radially symmetric inputs, or evolve the narrow and wide parts separately.")
        tol *= 10
