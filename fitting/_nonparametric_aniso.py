"""The anisotropic non-parametric model: a tabulated base lobe at μ0 of any shape and centre, and
per coarser scale the relative statistics ``R_k(W) = S(W, μ0)/S(W, μ_k)`` over the W plane
(docs/fitting.md, "The anisotropic non-parametric model").

Seed Eq. 4.4, ``G(W, μ_k) = G(W, μ0) R_k(W)``, needs of the statistics only ``R_k``. This model
writes its logarithm in polar W = ρ(cos φ, sin φ) as an even and an odd part,

    log R_k(W) = −D_k(W) + i Ψ_k(W),
    D_k(W) = ρ² Σ_f P_{k,f}(ρ) A_f(φ),   A_f ∈ {1, cos 2φ, sin 2φ, …, cos 2Nφ, sin 2Nφ}   (N = ``harmonics``),
    Ψ_k(W) = ρ³ Σ_g Q_{k,g}(ρ) B_g(φ),   B_g ∈ {cos φ, sin φ, cos 3φ, sin 3φ, …, sin (2M−1)φ}   (M = ``odd_harmonics``),

each radial profile ``P_{k,f}``, ``Q_{k,g}`` piecewise linear in ρ on the knots ``ρ_j = j W_max/J``
(j = 0 … J) and constant beyond ``W_max``; the profiles of the even harmonics n ≥ 2 vanish at ρ = 0,
so that ``D_k`` is twice differentiable at W = 0 (their terms are O(ρ³)), and so do those of the odd harmonics
5φ and above, so that Ψ_k is three times differentiable there (their terms are O(ρ⁴)).

What is imposed, and why:

* ``R_k(0) = 1`` (``D_k(0) = 0``: the ρ² factor) — the relative density ``r_k`` integrates to 1;
* ``R_k(−W) = conj R_k(W)`` (D even, Ψ odd) — the relative density is real;
* no linear term in Ψ (the ρ³ factor) — the statistics change scale without moving their mean (the mean facet
  slope of a stationary surface is the mean of its gradient at every scale); the base lobe carries any centre;
* a smoothness prior: second differences of every profile across the knots, times
  ``regularisation`` (in units of the reference variance v = the finest lobe's half-maximum
  variance, and v^{3/2} for the odd profiles, so the weight is dimensionless), appended as residual rows.

Not imposed: ``|R_k| ≤ 1``, a positive density ``r_k``, ordering in μ (``D_{k+1} ≥ D_k``). They
hold when coarse-graining is a convolution by a density, as for Gaussian statistics, but not for
every measured pair of slope densities, and the data judge them.

Why an odd part, and why it is not the default: the within-facet lobes of a measured surface change their
skewness with the facet size, which a real ``R_k`` cannot follow. experiments/real_nonparametric.py (JSON
experiments/results/real_nonparametric.json; docs/fitting.md, "The anisotropic non-parametric model") fits the
lobes ``brdfscale synth --topography`` makes of tests/data's plu-1 with and without it. Its 252 more coordinates
(8 scales, 8 knots) make each iteration dearer and the fit slower to settle: on experiments/bench_anisotropic.py's
synthetic set, whose lobes have no skew, the model with ``odd_harmonics=2`` used all 256 solver steps (396 s, a
run of b113c53, not committed) where the default converges in about a minute. Pass it where the residuals show
odd structure.

The covariance difference is exact from θ: near 0, ``D_k ≈ ρ²(a + b cos 2φ + c sin 2φ) =
a(W_x² + W_y²) + b(W_x² − W_y²) + 2c W_x W_y = ½ Wᵀ ΔΣ_k W`` with a, b, c the profiles at ρ = 0, so

    ΔΣ_k = −∇² log R_k(0) = 2 [[a + b, c], [c, a − b]]

(:meth:`covariance_differences`; Gaussian statistics are the special case of constant profiles,
no higher harmonics and no odd part, ``R_k = exp(−½ Wᵀ ΔΣ_k W)``; ``harmonics=0, odd_harmonics=0`` is the
isotropic case ``R_k = exp(−ρ² P_{k,0}(ρ))``), and so is the third cumulant the evolution adds, from the odd
profiles at ρ = 0 (:meth:`third_cumulant_differences`).

**Base lobe.** ``log g0`` is tabulated on ``base_nodes × base_nodes`` nodes, per axis dense near the
μ0 lobe's centre and stretched (sinh) out to the edge of the largest image, and interpolated to
the model grid by a not-a-knot cubic spline in each axis (one matrix product each way; a Gaussian's
log is a quadratic, which that spline reproduces exactly). ``g0 = exp(·) > 0``.

**Discretisation.** The model grid is the pixel grid of the finest-pitched image (pitch h,
aligned with its pixels) extended over the largest image; the evolved lobe at scale k is

    g_k = IDFT[ DFT[g0] · R_k(W_q) ],   W_q = 2π q/(N h)   (q the DFT indices, |q| ≤ N/2),

on an N × N periodic grid, N ≥ (1 + ``padding``) × the model grid's side g (zero padding, default
½): the samples of the continuous convolution ``g0 ∗ r_k`` up to the band limit π/h of the
samples and the periodisation (what the evolved lobe puts more than ``padding`` · g pixels beyond
the grid's edge re-enters at the opposite edge); the base lobe is zero beyond the largest image (its
mass there is not modelled). tests/test_nonparametric_aniso.py checks it against the closed-form
Gaussian evolution, covariances adding, to 1e-6 of the peak (the FFT alone) and 1e-7 (the whole
forward map at the pixels). ``R_k(−W) = conj R_k(W)`` makes ``g_k`` real, so a real FFT (half the plane)
suffices (on an even N's Nyquist column and row, ±π/h, the sin 2nφ and odd terms' values at ±W are not each
other's conjugates, and the inverse real FFT keeps their Hermitian part: an error only where the μ0 lobe's
transform, resolved by the pixels, is negligible). The images are then read at their pixels by
bilinear interpolation: exact where the pixels are the model grid's nodes (images of one pitch and
centring, as ``brdfscale synth`` writes them).
"""

import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.interpolate
from jaxtyping import Array, Float

from brdfscale import InvalidInputError, lobes
from brdfscale.checks import integer, real
from brdfscale.choices import MODEL

from ._anisotropic import image_moments
from ._data import Dataset
from ._model import AbstractModel, moments, require_dataset
from ._smoothness import smoothness_rows


__all__ = ["AnisotropicNonParametricModel", "evolve_on_grid"]

_CENTRE_SPACING = 0.5
"""The base-lobe nodes' spacing at the lobe's centre, in units of the μ0 lobe's standard deviation
along that axis (where the stretched node placement allows it)."""


def _stretched_nodes(centre: float, sd: float, lo: float, hi: float, n: int) -> np.ndarray:
    """``n`` (odd) nodes from ``lo`` to ``hi`` with ``centre`` the middle one, spaced about
    ``_CENTRE_SPACING · sd`` near it and growing like sinh towards the ends (uniform where that
    spacing is already coarser than uniform)."""
    half = (n - 1) // 2
    u = np.arange(1, half + 1) / half
    target = _CENTRE_SPACING * sd

    def side(length):
        if length <= 0:
            return np.zeros(half)
        ratio = target * half / length  # s/sinh(s) = ratio at the wanted first spacing
        if ratio >= 1:
            return length * u
        a, b = 1e-9, 50.0
        for _ in range(200):
            s = 0.5 * (a + b)
            a, b = (s, b) if s / math.sinh(s) > ratio else (a, s)
        s = 0.5 * (a + b)
        return length * np.sinh(s * u) / math.sinh(s)

    centre = min(max(centre, lo + 1e-9 * (hi - lo)), hi - 1e-9 * (hi - lo))
    return np.concatenate([centre - side(centre - lo)[::-1], [centre], centre + side(hi - centre)])


_SIGNAL_FLOOR = 2.0
"""The least ``ln(F/N)`` :func:`_noise_frequency` uses (a lobe whose flux is hardly above its noise still gets
knots out to ``2/σ_min``)."""


def _noise_frequency(data: Dataset, sd_min: float) -> float:
    """The frequency where the μ0 lobe's transform falls to the noise of the images' transform, along the lobe's
    narrow axis: a Gaussian lobe of flux F (the sum of an image's valid pixels) has ``|DFT| = F e^{−σ²W²/2}``, the
    noise of one DFT coefficient of the image is ``N = (Σ σ_i²)^{1/2}`` over those pixels, so
    ``W_noise = √(2 ln(F/N))/σ_min``; replicate μ0 images are independent measurements of that coefficient, so
    their ratios add in quadrature, ``F/N = (Σ_images (F/N)²)^{1/2}`` (whatever each image's pixel pitch);
    ``ln(F/N)`` is at least :data:`_SIGNAL_FLOOR` (also where F ≤ 0). Beyond it R_k multiplies noise: knots there
    are held by the smoothness prior alone, and on README's chain at ``poisson:0.05:1`` (F/N ≈ 37 on mi-1) the
    solve spent its steps on them (docs/fitting.md, "The anisotropic non-parametric model";
    tests/test_nonparametric_aniso.py checks the closed form, masked pixels, replicates and the floor)."""
    squares = 0.0
    for i in data.images_of_scale(0):
        weight = np.asarray(data.weight[i])  # 0 at masked and padding pixels
        valid = weight > 0
        flux = float(np.sum(np.where(valid, np.asarray(data.values[i]), 0.0)))
        noise2 = float(np.sum(1.0 / weight[valid] ** 2))
        if flux > 0 and noise2 > 0:
            squares += flux**2 / noise2
    ratio = math.sqrt(squares)
    return math.sqrt(2.0 * max(math.log(ratio) if ratio > 0 else 0.0, _SIGNAL_FLOOR)) / sd_min


def _fast_length(n: int) -> int:
    """The smallest 2^a 3^b 5^c ≥ n (an FFT length without large prime factors)."""
    best = 2 ** math.ceil(math.log2(max(n, 1)))
    for p3 in range(0, 1 + math.ceil(math.log(n, 3))):
        for p5 in range(0, 1 + math.ceil(math.log(n, 5))):
            m = 3**p3 * 5**p5
            if m <= 2 * n:
                best = min(best, m * 2 ** max(0, math.ceil(math.log2(n / m))))
    return best


def _spline_matrix(nodes: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(len(x), len(nodes)): the not-a-knot cubic spline through values at ``nodes`` evaluated at ``x``
    (clipped into the nodes' range), as a linear map of the values."""
    spline = scipy.interpolate.CubicSpline(nodes, np.eye(len(nodes)), bc_type="not-a-knot", axis=0)
    return spline(np.clip(x, nodes[0], nodes[-1]))


def evolve_on_grid(base: Float[Array, "g g"], log_ratio, pitch: float, size: int) -> Float[Array, "k g g"]:
    """``IDFT[DFT[g0] · R(W_q)]`` on a ``size × size`` periodic grid holding ``base`` (rows: y) in its
    first rows and columns, zeros elsewhere (module docstring): ``log_ratio`` maps W (…, 2) to
    ``log R_k(W)`` (k, …); the result is cut back to the base's grid."""
    g = base.shape[0]
    padded = jnp.zeros((size, size), base.dtype).at[:g, :g].set(base)
    qx = 2 * jnp.pi * jnp.fft.rfftfreq(size, d=pitch)  # real input: the half plane q_x ≥ 0 suffices
    qy = 2 * jnp.pi * jnp.fft.fftfreq(size, d=pitch)
    W = jnp.stack(jnp.meshgrid(qx, qy, indexing="xy"), axis=-1)  # W[iy, ix] = (q_x, q_y)
    ratio = jnp.exp(log_ratio(W))
    return jnp.fft.irfft2(jnp.fft.rfft2(padded)[None] * ratio, s=(size, size))[:, :g, :g]


class AnisotropicNonParametricModel(AbstractModel):
    """Tabulated base lobe + anisotropic relative statistics ``R_k(W)`` in polar W with radial
    knots × angular harmonics, even (the modulus) and odd (the phase) (module docstring).

    Args:
        data: the dataset (fixes the number of scales, the model grid and the nodes).
        base_nodes: the base lobe's ``log g0`` on ``base_nodes × base_nodes`` nodes (odd, ≥ 5).
        n_knots: J, the radial knots after ρ = 0 (≥ 1).
        harmonics: N, the highest angular harmonic ``cos 2Nφ``/``sin 2Nφ`` (0: isotropic ``R_k``).
        odd_harmonics: M, the odd part's highest harmonic ``cos (2M−1)φ``/``sin (2M−1)φ`` (0, the default:
            no odd part, ``R_k`` real and the relative density centro-symmetric; 2: ``cos φ, sin φ, cos 3φ,
            sin 3φ``, the whole third cumulant — module docstring, "Why an odd part", for what it does on a real
            file and why it is not the default).
        w_max: the last knot (default: ``6/σ_min``, σ_min the μ0 lobe's smallest standard
            deviation, where a Gaussian lobe's transform has fallen to e⁻¹⁸, capped at the model
            grid's Nyquist frequency π/h and at the frequency where the μ0 lobe's transform falls to the
            images' noise, ``√(2 ln(F/N))/σ_min`` (:func:`_noise_frequency`)).
        regularisation: the smoothness prior's weight (≥ 0; module docstring).
        padding: the zero padding of the FFT grid, a fraction (> 0) of the model grid's side:
            ``N = next_fast_len((1 + padding) · g)``.

    θ = (``log base[r,c]`` row-major (row: y), then per coarser scale k and function f the
    profile values ``P_{k,f}(ρ_j)/v`` (j from 0, from 1 for the harmonics n ≥ 2), then its odd profiles
    ``Q_{k,g}(ρ_j)/v^{3/2}`` (j from 0)), named ``"P{k}[{f}](W={ρ_j}) [v]"`` and ``"Q{k}[{g}](W={ρ_j}) [v^1.5]"``
    — in units of v; no "/" in a name, which NetCDF (posterior.nc) refuses).

    Raises:
        InvalidInputError: ``data`` not a :class:`~fitting.Dataset`, an image without a positive
            valid pixel, or an option out of range.
    """

    n_scales: int = eqx.field(static=True)
    base_nodes: int = eqx.field(static=True)
    knots: tuple[float, ...] = eqx.field(static=True)
    harmonics: int = eqx.field(static=True)
    odd_harmonics: int = eqx.field(static=True)
    smoothness: float = eqx.field(static=True)
    reference_variance: float = eqx.field(static=True)
    # hundreds of coordinates, some undetermined where the μ0 lobe is below the noise: the truncated,
    # EDM-stopped Gauss–Newton from the one data-driven start (docs/fitting.md; experiments/nonparametric_solvers.py)
    preferred_solver: ClassVar[str] = "gauss_newton_edm"
    preferred_starts: ClassVar[int] = 1
    # a chain over those coordinates is far slower than the fit: Laplace unless steps are asked for
    sampled_by_default: ClassVar[bool] = False
    pitch: float = eqx.field(static=True)
    origin: float = eqx.field(static=True)
    grid_points: int = eqx.field(static=True)
    fft_size: int = eqx.field(static=True)
    interpolation: Float[Array, "2 g b"]
    node_x: tuple[float, ...] = eqx.field(static=True)
    node_y: tuple[float, ...] = eqx.field(static=True)

    def __init__(
        self,
        data: Dataset,
        *,
        base_nodes: int = 17,
        n_knots: int = 6,
        harmonics: int = 2,
        odd_harmonics: int = 0,
        w_max: float | None = None,
        regularisation: float = MODEL.smoothness,
        padding: float = 0.5,
    ):
        require_dataset(data, "AnisotropicNonParametricModel(data)")
        base_nodes = integer(base_nodes, "base_nodes", 5)
        if base_nodes % 2 == 0:
            raise InvalidInputError(f"base_nodes must be an odd integer ≥ 5 (a node at the centre); got {base_nodes}.")
        self.n_scales = int(data.scales.shape[0])
        self.base_nodes = base_nodes
        self.harmonics = integer(harmonics, "harmonics", 0)
        self.odd_harmonics = integer(odd_harmonics, "odd_harmonics", 0)
        n_knots = integer(n_knots, "n_knots", 1)
        padding = real(padding, "padding", minimum=0.0, strict=True)
        self.smoothness = real(regularisation, "regularisation", minimum=0.0)
        pitches = [2 * a / (n - 1) for a, n in zip(data.extents, data.image_sizes)]
        finest = int(np.argmin(pitches))
        h, half = pitches[finest], max(data.extents)
        x0 = -data.extents[finest]
        m_lo, m_hi = math.floor((-half - x0) / h + 1e-9), math.ceil((half - x0) / h - 1e-9)
        self.pitch, self.origin, self.grid_points = h, x0 + m_lo * h, m_hi - m_lo + 1
        self.fft_size = _fast_length(self.grid_points + max(math.ceil(padding * self.grid_points), 1))
        centre, cov = image_moments(data)
        sd = np.sqrt(np.maximum(np.diag(cov[0]), h * h / 12))
        self.reference_variance = float(np.trace(cov[0]) / 2)
        if w_max is None:
            sd_min = math.sqrt(max(float(np.linalg.eigvalsh(cov[0])[0]), h * h / 12))
            w_max = min(6.0 / sd_min, math.pi / h, _noise_frequency(data, sd_min))
        w_max = real(w_max, "w_max", minimum=0.0, strict=True)
        self.knots = tuple(np.linspace(0.0, w_max, n_knots + 1).tolist())
        ends = (self.origin, self.origin + (self.grid_points - 1) * h)
        nx = _stretched_nodes(float(centre[0, 0]), float(sd[0]), *ends, base_nodes)
        ny = _stretched_nodes(float(centre[0, 1]), float(sd[1]), *ends, base_nodes)
        self.node_x, self.node_y = tuple(nx.tolist()), tuple(ny.tolist())
        grid = self.origin + h * np.arange(self.grid_points)
        self.interpolation = jnp.asarray(np.stack([_spline_matrix(nx, grid), _spline_matrix(ny, grid)]))

    # --- layout -------------------------------------------------------------------------------

    @property
    def _n_base(self) -> int:
        return self.base_nodes**2

    @property
    def _functions(self) -> tuple[str, ...]:
        """The angular functions' names: ``1``, ``cos2φ``, ``sin2φ``, ``cos4φ``, …"""
        return ("1", *(f"{t}{2 * n}φ" for n in range(1, self.harmonics + 1) for t in ("cos", "sin")))

    @property
    def _odd_functions(self) -> tuple[str, ...]:
        """The odd part's angular functions: ``cosφ``, ``sinφ``, ``cos3φ``, ``sin3φ``, …"""
        return tuple(
            f"{t}{'' if m == 1 else 2 * m - 1}φ" for m in range(1, self.odd_harmonics + 1) for t in ("cos", "sin")
        )

    def _layout(self, odd: bool) -> tuple[tuple[str, ...], int, int]:
        """The even (``odd=False``: P, A_f) or odd part (Q, B_g) of θ's profiles: its angular functions' names, how
        many of them (the first) have a coordinate at ρ = 0, and its profile values per coarser scale. The others'
        profiles vanish at ρ = 0 and start at ρ_1: the even harmonics n ≥ 2 (``D_k`` twice differentiable at 0)
        and the odd ones 5φ and above (ρ³ cos 5φ is not a cubic polynomial: ``Ψ_k`` three times differentiable),
        so the free ones there are ``1, cos 2φ, sin 2φ`` and ``cos φ, sin φ, cos 3φ, sin 3φ`` (the third cumulant)."""
        functions = self._odd_functions if odd else self._functions
        at_zero, J1 = min(len(functions), 4 if odd else 3), len(self.knots)
        return functions, at_zero, at_zero * J1 + (len(functions) - at_zero) * (J1 - 1)

    def _first_knot(self, f: int, odd: bool) -> int:
        """The first free knot of the part's function f: 0, or 1 where its profile is 0 at ρ = 0 (:meth:`_layout`)."""
        return 0 if f < self._layout(odd)[1] else 1

    @property
    def names(self) -> tuple[str, ...]:
        nb = self.base_nodes
        base = tuple(f"log base[{r},{c}]" for r in range(nb) for c in range(nb))
        profiles = tuple(
            f"{letter}{k}[{name}](W={self.knots[j]:.4g}) [{unit}]"
            for odd, letter, unit in ((False, "P", "v"), (True, "Q", "v^1.5"))
            for k in range(1, self.n_scales)
            for f, name in enumerate(self._layout(odd)[0])
            for j in range(self._first_knot(f, odd), len(self.knots))
        )
        return base + profiles

    @property
    def radial(self) -> bool:
        return False

    @property
    def identifiability_notes(self) -> tuple[str, ...]:
        return (
            "Reported: the base lobe at μ0, R_k(W) = S(W, μ0)/S(W, μ_k) over the W plane and ΔΣ(μ0, μk) = "
            "−∇² log R_k(0), the combinations the data determine; the absolute S(W, μ_k) is not (it needs the "
            "boundary condition S(W, ∞) = 1 of a scale law).",
        )

    def check_data(self, data: Dataset) -> None:
        """Also: the dataset has this model's number of scales (its θ layout and grid come from it)."""
        super().check_data(data)
        if data.scales.shape[0] != self.n_scales:
            raise InvalidInputError(
                f"this AnisotropicNonParametricModel was built for {self.n_scales} scales but the data have "
                f"{data.scales.shape[0]} (μ = {np.asarray(data.scales).tolist()}); build the model from the dataset "
                "it is fitted to: AnisotropicNonParametricModel(data)."
            )

    # --- the parts of θ -------------------------------------------------------------------------

    def _unpack(self, theta: Float[Array, " n"], odd: bool) -> Float[Array, "k f j"]:
        """The even (``odd=False``) or odd part's profiles from θ (:meth:`_layout`), in slope units² (³): θ's
        values times v (v^{3/2}), 0 at ρ = 0 for the functions without a coordinate there, row 0 zero."""
        functions, at_zero, per_scale = self._layout(odd)
        F, J1, K1 = len(functions), len(self.knots), self.n_scales - 1
        start = self._n_base + (K1 * self._layout(False)[2] if odd else 0)
        rows = jnp.asarray(theta)[start : start + K1 * per_scale].reshape(K1, per_scale)
        rows = rows * (self.reference_variance**1.5 if odd else self.reference_variance)
        low = rows[:, : at_zero * J1].reshape(K1, at_zero, J1)
        if F > at_zero:
            high = rows[:, at_zero * J1 :].reshape(K1, F - at_zero, J1 - 1)
            low = jnp.concatenate([low, jnp.concatenate([jnp.zeros_like(high[..., :1]), high], axis=-1)], axis=1)
        return jnp.concatenate([jnp.zeros((1, F, J1), low.dtype), low])

    def profiles(self, theta: Float[Array, " n"]) -> Float[Array, "k f j"]:
        """``P_{k,f}(ρ_j)`` (slope units²) for k = 0 … K−1 (row 0 zero), every function f, j = 0 … J."""
        return self._unpack(theta, odd=False)

    def odd_profiles(self, theta: Float[Array, " n"]) -> Float[Array, "k g j"]:
        """``Q_{k,g}(ρ_j)`` (slope units³) for k = 0 … K−1 (row 0 zero), every odd function g, j = 0 … J."""
        return self._unpack(theta, odd=True)

    def _polar(self, W):
        rho2 = jnp.sum(W * W, axis=-1)
        rho = jnp.sqrt(jnp.where(rho2 > 0, rho2, 1.0)) * (rho2 > 0)
        return rho2, rho, jnp.arctan2(W[..., 1], W[..., 0])

    def _radial(self, profiles, rho):
        """The profiles (k, f, j) read at radii ``rho`` (…): (k, f, …), constant beyond the last knot."""
        knots = jnp.asarray(self.knots, dtype=profiles.dtype)
        t = jnp.clip(rho, knots[0], knots[-1])
        return jax.vmap(jax.vmap(lambda p: jnp.interp(t, knots, p)))(profiles)

    def _log_ratio_parts(
        self, theta: Float[Array, " n"], W: Float[Array, "... 2"], parts: tuple[bool, ...]
    ) -> list[Float[Array, "k ..."]]:
        """For each part asked (False: even, True: odd), ``−D_k(W)`` or ``Ψ_k(W)`` for every measured scale, from
        one polar transform of ``W`` (:meth:`evolved_grids` asks for both)."""
        rho2, rho, phi = self._polar(jnp.asarray(W))
        out = []
        for odd in parts:
            if odd and not self.odd_harmonics:  # Ψ_k = 0 (an empty sum would not have its shape)
                out.append(jnp.zeros((self.n_scales, *phi.shape), phi.dtype))
                continue
            if odd:
                orders = [2 * m - 1 for m in range(1, self.odd_harmonics + 1)]  # B_g: cos φ, sin φ, cos 3φ, …
                angular = [t(n * phi) for n in orders for t in (jnp.cos, jnp.sin)]
            else:
                angular = [jnp.ones_like(phi)]  # A_f: 1, cos 2φ, sin 2φ, …
                angular += [t(2 * n * phi) for n in range(1, self.harmonics + 1) for t in (jnp.cos, jnp.sin)]
            radial = self._radial(self._unpack(theta, odd), rho)  # (k, f, *w)
            total = sum(radial[:, f] * a[None] for f, a in enumerate(angular))
            out.append((rho2 * rho)[None] * total if odd else -rho2[None] * total)
        return out

    def log_relative(self, theta: Float[Array, " n"], W: Float[Array, "... 2"]) -> Float[Array, "k ..."]:
        """``log |R_k(W)| = −D_k(W)`` (the even part) for every measured scale at points ``W`` of the plane."""
        (even,) = self._log_ratio_parts(theta, W, (False,))
        return even

    def phase(self, theta: Float[Array, " n"], W: Float[Array, "... 2"]) -> Float[Array, "k ..."]:
        """``Ψ_k(W) = arg R_k(W) = ρ³ Σ_g Q_{k,g}(ρ) B_g(φ)`` (the odd part; module docstring)."""
        (odd,) = self._log_ratio_parts(theta, W, (True,))
        return odd

    def covariance_differences(self, theta: Float[Array, " n"], scales: Float[Array, " k"]) -> Float[Array, "k 2 2"]:
        """ΔΣ(μ0, μ_k) = 2 [[a + b, c], [c, a − b]] (module docstring), exact from θ; row 0 is 0."""
        del scales  # one set of profiles per measured scale: the layout fixes them
        P = self.profiles(theta)[:, :, 0]
        a = P[:, 0]
        b, c = (P[:, 1], P[:, 2]) if self.harmonics else (jnp.zeros_like(a), jnp.zeros_like(a))
        return 2 * jnp.stack([jnp.stack([a + b, c], -1), jnp.stack([c, a - b], -1)], -2)

    def third_cumulant_differences(self, theta: Float[Array, " n"]) -> Float[Array, "k 4"]:
        """κ3(g_k) − κ3(g_0) = κ3(r_k), the third cumulants the evolution adds, ``[xxx, xxy, xyy, yyy]`` (slope³),
        exact from θ; row 0 is 0. With the odd profiles at ρ = 0 ``Q_{cos φ}, Q_{sin φ}, Q_{cos 3φ}, Q_{sin 3φ}``
        (``c1, s1, c3, s3``), ``Ψ_k ≈ κ3(W, W, W)/6`` near 0 (``R_k = ∫ r_k(v) e^{−iW·v} dv``) gives
        ``κ_xxx = 6(c1 + c3)``, ``κ_xxy = 2(s1 + 3 s3)``, ``κ_xyy = 2(c1 − 3 c3)``, ``κ_yyy = 6(s1 − s3)``;
        the harmonics above 3φ vanish at 0 like ρ⁴ (their profiles are 0 at ρ = 0).
        tests/test_nonparametric_aniso.py checks it against
        the third central moments of the evolved lobes on the model grid."""
        Q = self.odd_profiles(theta)[:, :, 0]
        zero = jnp.zeros(Q.shape[0], Q.dtype)
        c1, s1 = (Q[:, 0], Q[:, 1]) if Q.shape[1] >= 2 else (zero, zero)
        c3, s3 = (Q[:, 2], Q[:, 3]) if Q.shape[1] >= 4 else (zero, zero)
        return jnp.stack([6 * (c1 + c3), 2 * (s1 + 3 * s3), 2 * (c1 - 3 * c3), 6 * (s1 - s3)], axis=-1)

    def base_grid(self, theta: Float[Array, " n"]) -> Float[Array, "g g"]:
        """``g0`` on the model grid (rows: y), positive."""
        nb = self.base_nodes
        log_nodes = jnp.asarray(theta)[: self._n_base].reshape(nb, nb)
        sx, sy = (jnp.asarray(m) for m in self.interpolation)
        return jnp.exp(sy @ log_nodes @ sx.T)

    def base_lobe(self, theta) -> lobes.Tabulated:
        """The lobe at μ0 on the model grid (for plots): :class:`brdfscale.lobes.Tabulated`, cut to the
        square the grid spans symmetrically about 0."""
        g = self.base_grid(theta)
        lo, hi = self.origin, self.origin + (self.grid_points - 1) * self.pitch
        i0 = int(round((max(lo, -hi) - lo) / self.pitch))
        m = int(round(2 * min(-lo, hi) / self.pitch)) + 1
        return lobes.Tabulated(g[i0 : i0 + m, i0 : i0 + m], extent=min(-lo, hi))

    def evolved_grids(self, theta: Float[Array, " n"]) -> Float[Array, "k g g"]:
        """``g_k`` on the model grid for every measured scale (module docstring: zero-padded FFT)."""

        def log_ratio(W):  # real, and a real product in the hot path, where there is no odd part
            if not self.odd_harmonics:
                return self.log_relative(theta, W)
            even, odd = self._log_ratio_parts(theta, W, (False, True))  # one polar transform for both
            return even + 1j * odd

        return evolve_on_grid(self.base_grid(theta), log_ratio, self.pitch, self.fft_size)

    def predict_points(self, theta, scales, points):
        grids = self.evolved_grids(theta)
        g = self.grid_points

        def read(grid, u):
            fx, fy = (u[:, 0] - self.origin) / self.pitch, (u[:, 1] - self.origin) / self.pitch
            ix = jnp.clip(jnp.floor(fx), 0, g - 2).astype(int)
            iy = jnp.clip(jnp.floor(fy), 0, g - 2).astype(int)
            tx, ty = jnp.clip(fx - ix, 0.0, 1.0), jnp.clip(fy - iy, 0.0, 1.0)
            return (1 - ty) * ((1 - tx) * grid[iy, ix] + tx * grid[iy, ix + 1]) + ty * (
                (1 - tx) * grid[iy + 1, ix] + tx * grid[iy + 1, ix + 1]
            )

        return jax.vmap(read)(grids, points)

    def quantities(self, theta):
        """The base lobe's integral, centre and covariance on the model grid (``amplitude``,
        ``mean_x/y``, ``C0_xx/xy/yy``: the μ0 lobe's moments) and ΔΣ_k's entries."""
        g = self.base_grid(theta)
        x = self.origin + self.pitch * jnp.arange(self.grid_points, dtype=g.dtype)
        mass = jnp.sum(g)
        mx, my = jnp.sum(g * x[None, :]) / mass, jnp.sum(g * x[:, None]) / mass
        dx, dy = x[None, :] - mx, x[:, None] - my
        out = {
            "amplitude": mass * self.pitch**2,
            "mean_x": mx,
            "mean_y": my,
            "C0_xx": jnp.sum(g * dx * dx) / mass,
            "C0_xy": jnp.sum(g * dx * dy) / mass,
            "C0_yy": jnp.sum(g * dy * dy) / mass,
        }
        d = self.covariance_differences(theta, jnp.zeros(self.n_scales))
        for k in range(1, self.n_scales):
            out.update({f"ΔΣ{k}_xx": d[k, 0, 0], f"ΔΣ{k}_xy": d[k, 0, 1], f"ΔΣ{k}_yy": d[k, 1, 1]})
        return out

    def relative_statistics(self, theta, W, scales):
        """``R_k`` at radii ``|W|``: the geometric mean over the directions of the circle,
        ``exp(−ρ² P_{k,0}(ρ))`` (the harmonics average to 0); :meth:`relative_statistics_plane`
        gives ``R_k`` over the plane."""
        del scales
        W = jnp.asarray(W)
        return jnp.exp(-(W**2)[None] * self._radial(self.profiles(theta)[:, :1], jnp.abs(W))[:, 0])

    def relative_statistics_plane(
        self, theta: Float[Array, " n"], W: Float[Array, "w 2"], scales: Float[Array, " k"]
    ) -> Float[Array, "k w"]:
        """``|R_k(W)| = |S(W, μ0)/S(W, μ_k)|`` at points ``W`` of the plane (the odd part is R_k's phase,
        :meth:`phase`)."""
        del scales
        return jnp.exp(self.log_relative(theta, W))

    def penalty(self, theta):
        v = self.reference_variance
        even = smoothness_rows(self.profiles(theta)[1:] / v, self.smoothness)
        if not self.odd_harmonics:
            return even
        return jnp.concatenate([even, smoothness_rows(self.odd_profiles(theta)[1:] / v**1.5, self.smoothness)])

    # --- starting point and prior box -----------------------------------------------------------

    def initial(self, data):
        """The μ0 images (averaged) read at the base nodes where they stand above their noise (3 times
        the image's median σ), elsewhere the Gaussian of the μ0 lobe's half-maximum moments
        (:func:`image_moments`, amplitude :func:`moments`'s), floored at e⁻³⁸ of the peak (inside the
        prior box); the profiles of the measured lobes' half-maximum covariance differences (constant
        in ρ, no higher harmonics: Gaussian statistics). Reading the noise itself at the outer nodes
        (the logarithm of noise, or of a floor where it is negative) made the spline of ``log g0``
        ring between neighbouring nodes up to e⁴⁴ (experiments/bench_anisotropic.py's set: χ²/dof
        5e33 at the start, still 5e27 after 12 steps)."""
        amp, _ = moments(data)
        centre, cov = image_moments(data)
        nx, ny = np.asarray(self.node_x), np.asarray(self.node_y)
        yy, xx = np.meshgrid(ny, nx, indexing="ij")
        nodes = np.stack([xx, yy], -1)
        d = nodes - centre[0]
        q = np.einsum("...i,ij,...j->...", d, np.linalg.inv(cov[0]), d)
        gaussian = amp * np.exp(-0.5 * q) / (2 * math.pi * math.sqrt(np.linalg.det(cov[0])))
        stacked, significant = [], []
        for i in data.images_of_scale(0):
            n, a = data.image_sizes[i], data.extents[i]
            weight = data.image(i, np.asarray(data.weight[i]))
            valid = weight > 0
            img = np.where(valid, data.image(i, np.asarray(data.values[i])), 0.0)
            noise = 3.0 / np.median(weight[valid])  # 3 × the median σ (weight = 1/σ)
            ux = data.image(i, np.asarray(data.offsets[i, :, 0]))
            if ux[0, 0] == ux[0, 1]:  # u_x constant along a row: rows are x; make them y
                img = img.T
            x = np.linspace(-a, a, n)
            read = scipy.interpolate.RegularGridInterpolator((x, x), img, bounds_error=False, fill_value=0.0)
            values = read(np.stack([yy, xx], -1))
            stacked.append(values)
            significant.append(values > noise)
        base = np.where(np.all(significant, axis=0), np.mean(stacked, axis=0), gaussian)
        base = np.log(np.maximum(base, max(base.max(), 1e-300) * math.exp(-38.0))).ravel()
        v = self.reference_variance
        J1 = len(self.knots)
        rows = []
        for k in range(1, self.n_scales):
            d = (cov[k] - cov[0]) / v
            a, b, c = (d[0, 0] + d[1, 1]) / 4, (d[0, 0] - d[1, 1]) / 4, d[0, 1] / 2
            row = [np.full(J1, a)]
            if self.harmonics:
                row += [np.full(J1, b), np.full(J1, c)]
                row += [np.zeros(J1 - 1)] * (2 * (self.harmonics - 1))
            rows.append(np.concatenate(row))
        del amp
        odd = np.zeros((self.n_scales - 1) * self._layout(True)[2])  # no skewness change to start
        return np.concatenate([base, *rows, odd])

    def bounds(self, data):
        """log base values within log(peak) − 40 … log(peak) + 10 (peak: the μ0 lobe's estimated
        peak); the profiles within ±1e4 reference variances."""
        amp, width2 = moments(data)
        peak = amp / (math.pi * max(width2[0], 1e-300))
        n_p = len(self.names) - self._n_base
        lo = np.concatenate([np.full(self._n_base, math.log(peak) - 40), np.full(n_p, -1e4)])
        hi = np.concatenate([np.full(self._n_base, math.log(peak) + 10), np.full(n_p, 1e4)])
        return lo, hi
