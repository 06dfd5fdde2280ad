"""Physical models on SO(3): facet-orientation statistics and an anisotropic microfacet lobe.

A facet's orientation relative to the global one is a rotation Δ = Γ∞⁻¹Γ whose columns are
the facet's tangent, bitangent and normal; ``s(Δ)`` is its density with respect to the Haar
measure ``dΓ = sin β dα dβ dγ`` (total 8π²), what a histogram of facet frames shows. Every
density exposes ``operator(B)``: ``S̃^J = (8π²/(2J+1)) s^J`` for J < B, padded to (2B−1)² with
the identity (so block solves stay well posed), and ``coefficients(B)``: ``s^J`` itself.
The seed's q is the reflection: ``Q̃^J = (S̃^J)†`` (:mod:`._convolution`).
"""

import abc
import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Complex, Float

from .. import stats
from .._errors import InvalidInputError
from .._special import xk1
from .._validation import as_float_array, is_concrete, positive
from ..geometry import microfacet_factor, validate_directions
from ._convolution import to_operator
from ._generators import check_diffusion, diffusion_operator, DiffusionCoefficients
from ._grid import check_band_limit, grid, MAX_BAND_LIMIT
from ._rotations import check_rotation, euler_to_matrix, matrix_to_euler
from ._transform import analyse_points, forward


__all__ = [
    "AbstractOrientationDensity",
    "Identity",
    "RotationalDiffusion",
    "TiltTwist",
    "EmpiricalOrientations",
    "AnisotropicMicrofacetLobe",
    "operator_padding",
]


def operator_padding(B: int) -> np.ndarray:
    """The identity on the padding of (B, 2B−1, 2B−1) blocks (entries with |M| or |M'| > J)."""
    M = np.arange(-(B - 1), B)
    outside = np.abs(M)[None, :] > np.arange(B)[:, None]
    return outside[:, :, None] * np.eye(2 * B - 1)[None]


class AbstractOrientationDensity(eqx.Module):
    """A density ``s(Δ)`` of facet orientations relative to the global one (module docstring)."""

    @abc.abstractmethod
    def operator(self, B: int) -> Complex[Array, "B 2*B-1 2*B-1"]:
        """``S̃^J = (8π²/(2J+1)) s^J`` for J < B, identity on the padding."""

    def coefficients(self, B: int) -> Complex[Array, "B 2*B-1 2*B-1"]:
        """``s^J = (2J+1)/(8π²) ∫ s D^{J*} dΓ`` for J < B (zeros on the padding)."""
        B = check_band_limit(B)
        op = self.operator(B) - operator_padding(B)
        return op * jnp.asarray((2 * np.arange(B) + 1) / (8 * np.pi**2))[:, None, None]


def _with_padding(coefficients, B):
    return to_operator(coefficients) + operator_padding(B)


class Identity(AbstractOrientationDensity):
    """δ at the identity: every facet aligned with the global frame (μ → ∞). ``S̃^J = I``."""

    def operator(self, B):
        B = check_band_limit(B)
        return jnp.broadcast_to(jnp.eye(2 * B - 1, dtype=complex), (B, 2 * B - 1, 2 * B - 1))


class RotationalDiffusion(AbstractOrientationDensity):
    """Rotational diffusion from the identity for time τ: ``S̃^J = exp(−τ G^J)``.

    ``G = D_x J_x² + D_y J_y² + D_z J_z²`` (:mod:`._generators`); for small τ the facet tilt
    about x (y) has angular variance ``2 D_x τ`` (``2 D_y τ``) and the twist ``2 D_z τ``.
    Isotropic D is the heat kernel of SO(3); D_x ≠ D_y gives anisotropic tilt (grooves).
    """

    tau: Float[Array, ""]
    D: Float[Array, "3"]

    def __init__(self, tau: Float[ArrayLike, ""], D: DiffusionCoefficients = 1.0):
        self.tau = as_float_array(tau, "tau")
        if is_concrete(self.tau) and float(self.tau) < 0:
            raise InvalidInputError(f"tau must be ≥ 0; got {float(self.tau)}.")
        self.D = check_diffusion(D)

    def operator(self, B):
        return diffusion_operator(check_band_limit(B), self.D, self.tau).astype(jnp.result_type(self.tau, 1j))


_MAX_TWIST_TERMS = 4096
_FOURIER_TWIST_TERMS = 9  # σ ≥ 1: e^{−σ²k²/2} < e^{−40} beyond 9 terms; narrower twists use wrapped Gaussians


def _twist_terms(std) -> int:
    """Fourier terms of a wrapped normal of standard deviation ``std`` (concrete): e^{−σ²k²/2} < e^{−40}."""
    return int(min(_MAX_TWIST_TERMS, math.ceil(9.0 / max(float(std), 1e-6))))


def _wrapped_normal(psi, mean, std, terms: int):
    """Wrapped normal density on the circle, by its Fourier series (1/2π) Σ_{k≤terms} e^{−σ²k²/2} cos k(ψ − ψ0)."""
    k = jnp.arange(1, terms + 1)
    series = jnp.exp(-0.5 * (std * k) ** 2) * jnp.cos(k * (psi[..., None] - mean))
    return (1 + 2 * jnp.sum(series, axis=-1)) / (2 * jnp.pi)


def _wrapped_gaussian(psi, mean, std):
    """The same density as a sum of Gaussians over the wraps n = −1, 0, 1 of ``ψ − ψ0`` reduced to
    [−π, π): for σ < 1 the omitted wraps lie ≥ 3π away (below e^{−44} of the peak)."""
    d = jnp.mod(psi - mean + jnp.pi, 2 * jnp.pi) - jnp.pi
    shifts = jnp.asarray([-2 * math.pi, 0.0, 2 * math.pi], dtype=d.dtype)
    z = (d[..., None] + shifts) / std
    return jnp.sum(jnp.exp(-0.5 * z * z), axis=-1) / (std * math.sqrt(2 * math.pi))


MAX_AUTO_RESOLUTION = 256
"""Largest sampling band limit :class:`TiltTwist` chooses by itself (the grid has (2N)³ points:
1 GiB of float64 samples at N = 256; the operator then peaks near 6 GiB).
Tilt densities that need more raise :class:`InvalidInputError`; an explicit ``resolution=`` (up
to :data:`MAX_BAND_LIMIT`) overrides the cap."""


class TiltTwist(AbstractOrientationDensity):
    """Tilt × twist: the facet normal tilts with a slope density, the frame twists independently.

    A facet with normal of slope ``m`` (``n = (m, 1)/√(1+|m|²)``: polar angle β = atan|m|,
    azimuth α) and twist ψ about its normal has Euler angles ``(α, β, ψ − α)`` (the minimal
    tilt ``U(α)A(β)U(−α)`` followed by the twist ``U(ψ)``). Its density on SO(3) is

        s(α, β, γ) = s_m(tan β (cos α, sin α)) / cos³β · p(α + γ),     β < π/2,

    with ``s_m`` any :mod:`brdfscale.stats` slope density (``d²m = dω/cos³β``) and ``p`` a
    wrapped normal twist density of ``twist_mean`` and ``twist_std`` (radians; None: uniform,
    an isotropic twist). Coefficients J < B come from :func:`forward` on a grid fine enough
    to integrate s (:meth:`quadrature_band_limit`), so narrow densities are not aliased.

    The twist enters the coefficients exactly, whatever ``twist_std``: on the grid only its
    Fourier terms |k| ≤ 2N − B are kept (N the grid's band limit), which the γ sum integrates
    without aliasing, and only |k| ≤ B − 1 reach the coefficients. The grid's band limit N
    (``resolution``) is therefore set by the tilt alone: by default enough to integrate it to
    1e-10 (:meth:`quadrature_band_limit`), at most :data:`MAX_AUTO_RESOLUTION`; a tilt that
    needs more (very narrow or discontinuous, e.g. a coarse ``stats.Tabulated``) or that has no
    pointwise density (``stats.Delta``, plus-distributions) raises :class:`InvalidInputError`
    unless an explicit ``resolution`` (≤ :data:`MAX_BAND_LIMIT`) is given.

    The grid's band limit and the number of twist Fourier terms are fixed when the density is
    built (from its concrete parameters; ``resolution`` overrides the former): ``operator`` and
    ``coefficients`` are then jit-compatible with the parameters traced, e.g. a
    ``jax.jit(lambda s: s.operator(B))`` or a gradient with respect to the roughness. Building
    the density inside a traced function needs an explicit ``resolution`` (and ``twist_std``
    None or concrete).
    """

    tilt: stats.AbstractSlopeDensity
    twist_mean: Float[Array, ""]
    twist_std: Float[Array, ""] | None
    resolution: int = eqx.field(static=True)
    twist_terms: int = eqx.field(static=True)

    def __init__(
        self,
        tilt: stats.AbstractSlopeDensity,
        twist_mean: Float[ArrayLike, ""] = 0.0,
        twist_std: Float[ArrayLike, ""] | None = None,
        *,
        resolution: int | None = None,
    ):
        self.tilt = stats.require_density(
            tilt,
            "tilt",
            use="It has no finite slope bandwidth either; use a brdfscale.stats density such as stats.Beckmann(α).",
        )
        self.twist_mean = as_float_array(twist_mean, "twist_mean")
        if twist_std is not None and not is_concrete(twist_std):
            raise InvalidInputError(
                "twist_std must be concrete (not traced) when a TiltTwist is built: it sets the "
                "number of twist Fourier terms. Build the density outside jit and pass it in."
            )
        self.twist_std = None if twist_std is None else positive(twist_std, "twist_std")
        self.twist_terms = 0 if twist_std is None else _twist_terms(np.asarray(twist_std))
        if resolution is None:
            if not is_concrete(tilt.bandwidth(1e-10)):
                raise InvalidInputError(
                    "TiltTwist built from traced parameters needs an explicit resolution= "
                    "(the sampling grid's band limit); or build it outside jit."
                )
            need = self._tilt_band_limit(1e-10)
            if need > MAX_AUTO_RESOLUTION:
                raise InvalidInputError(
                    f"the tilt density {type(tilt).__name__} needs a sampling grid of band limit about "
                    f"N = {math.ceil(need)} to be integrated to 1e-10 (from its slope bandwidth; the grid has (2N)³ "
                    f"points, {_grid_gib(need):.3g} GiB of float64 samples), more than TiltTwist chooses by itself "
                    f"(MAX_AUTO_RESOLUTION = {MAX_AUTO_RESOLUTION}, {_grid_gib(MAX_AUTO_RESOLUTION):.2g} GiB). "
                    f"Use a wider tilt density, or pass resolution= explicitly (an integer ≤ {MAX_BAND_LIMIT}; "
                    "a grid coarser than needed integrates the tilt less accurately)."
                )
            resolution = self.quadrature_band_limit(1)
        self.resolution = check_band_limit(resolution, "resolution")

    def density(self, alpha, beta, gamma) -> Float[Array, "..."]:
        """``s(α, β, γ)`` per unit Haar measure."""
        alpha, beta, gamma = jnp.broadcast_arrays(
            *(as_float_array(x, n) for x, n in ((alpha, "alpha"), (beta, "beta"), (gamma, "gamma")))
        )
        return self._tilt(alpha, beta) * self._twist(alpha + gamma)

    def _tilt(self, alpha, beta):
        """``s_m(tan β (cos α, sin α)) / cos³β`` for β < π/2, else 0."""
        upper = beta < jnp.pi / 2
        b = jnp.where(upper, beta, 0.0)
        t = jnp.tan(b)
        m = jnp.stack([t * jnp.cos(alpha), t * jnp.sin(alpha)], axis=-1)
        return jnp.where(upper, self.tilt.density(m) / jnp.cos(b) ** 3, 0.0)

    def _twist(self, psi, terms: int | None = None):
        """The twist density ``p(ψ)``; ``terms``: keep exactly the Fourier terms |k| ≤ terms."""
        if self.twist_std is None:
            return jnp.full_like(psi, 1 / (2 * jnp.pi))
        if terms is not None:
            return _wrapped_normal(psi, self.twist_mean, self.twist_std, min(terms, self.twist_terms))
        if self.twist_terms <= _FOURIER_TWIST_TERMS:
            return _wrapped_normal(psi, self.twist_mean, self.twist_std, self.twist_terms)
        return _wrapped_gaussian(psi, self.twist_mean, self.twist_std)

    def _tilt_band_limit(self, tol: float) -> float:
        """The grid band limit that integrates the tilt to ``tol`` (J ≈ |W| for small tilts), as
        a float, uncapped; :class:`InvalidInputError` for a tilt without finite bandwidth."""
        bandwidth = float(self.tilt.bandwidth(tol))
        if not math.isfinite(bandwidth):
            raise InvalidInputError(
                f"the tilt density {type(self.tilt).__name__} has no finite slope bandwidth (e.g. stats.Delta, a "
                "plus-distribution or a nearly-specular statistic: no pointwise density to sample on the SO(3) "
                "grid); TiltTwist needs a tilt with a pointwise density (e.g. stats.Beckmann, stats.GGX). For "
                "facets with no tilt use a narrow tilt or RotationalDiffusion(tau, D=(0, 0, D_z))."
            )
        return bandwidth + 4

    def quadrature_band_limit(self, B: int, tol: float = 1e-10) -> int:
        """Band limit of the sampling grid: at least B, and enough to integrate the tilt density
        to ``tol`` (from the tilt's slope bandwidth, J ≈ |W| for small tilts), at most
        :data:`MAX_BAND_LIMIT`. The twist needs no resolution of its own (class docstring)."""
        return min(MAX_BAND_LIMIT, int(math.ceil(max(B, self._tilt_band_limit(tol)))))

    def operator(self, B):
        B = check_band_limit(B)
        Bq = max(B, self.resolution)  # quadrature_band_limit(B), fixed at construction
        a, b, _ = grid(Bq)
        tilt = self._tilt(jnp.asarray(a)[:, None], jnp.asarray(b)[None, :])  # (α, β)
        # on the grid α_j + γ_l = π (j + l)/Bq: the twist takes 2Bq values, gathered onto (α, γ);
        # Fourier terms |k| ≤ 2Bq − B are integrated by the γ sum without aliasing into |M'| < B
        twist = self._twist(jnp.asarray(a), terms=2 * Bq - B)
        index = np.add.outer(np.arange(2 * Bq), np.arange(2 * Bq)) % (2 * Bq)
        samples = tilt[:, :, None] * twist[index][:, None, :]
        return _with_padding(forward(samples, m_max=B - 1, n_max=B - 1)[:B], B)


def _grid_gib(B) -> float:
    """GiB of float64 samples on the grid of band limit B."""
    return (2 * B) ** 3 * 8 / 2**30


class EmpiricalOrientations(AbstractOrientationDensity):
    """The distribution of n measured facet frames, optionally smoothed (a kernel density).

    ``frames`` (n, 3, 3): rotation matrices (columns: tangent, bitangent, normal in the
    global frame). The coefficients are the exact transform of the empirical measure,
    ``(2J+1)/(8π²) (1/n) Σ_k D^J(Δ_k)*`` (no binning), multiplied by the heat kernel
    ``exp(−τ_s J(J+1))`` when ``smoothing = τ_s > 0`` (Gaussian kernel of angular variance
    2τ_s per axis), which makes it a smooth, band-limited density estimate.
    """

    frames: Float[Array, "n 3 3"]
    smoothing: Float[Array, ""]

    def __init__(self, frames: Float[ArrayLike, "n 3 3"], smoothing: Float[ArrayLike, ""] = 0.0):
        f = as_float_array(frames, "frames")
        if f.ndim != 3 or f.shape[1:] != (3, 3) or f.shape[0] == 0:
            raise InvalidInputError(f"frames must have shape (n, 3, 3) with n ≥ 1; got {f.shape}.")
        matrix_to_euler(f)  # validates: proper rotations
        self.frames = f
        self.smoothing = as_float_array(smoothing, "smoothing")
        if is_concrete(self.smoothing) and float(self.smoothing) < 0:
            raise InvalidInputError(f"smoothing must be ≥ 0; got {float(self.smoothing)}.")

    def operator(self, B):
        B = check_band_limit(B)
        a, b, g = matrix_to_euler(self.frames)
        J = jnp.arange(B, dtype=self.smoothing.dtype)
        kernel = jnp.exp(-self.smoothing * J * (J + 1))
        return _with_padding(analyse_points(a, b, g, B) * kernel[:, None, None], B)


class AnisotropicMicrofacetLobe(eqx.Module):
    """An anisotropic microfacet BRDF of a facet with orientation Γ: ``ρ(i, o, Γ)`` (seed §2, §5).

    In the facet's frame (``i' = Γᵀ i``, ``o' = Γᵀ o``, ``h' = Γᵀ h``) the facet is a rough
    surface with slope statistics ``g`` — Beckmann or GGX with roughness α_x along the facet's
    tangent and α_y along its bitangent — and (no masking, Fresnel 1, docs/conventions.md §1)

        ρ(i, o, Γ) = A · g(m(h')) / (4 o'_z cos⁴θ_h')   (:func:`brdfscale.geometry.microfacet_factor`),

    zero where the light or the detector is below the facet's horizon (i'_z ≤ 0 or o'_z ≤ 0).
    Units 1/sr. For fixed (i, o) this is a function on SO(3) whose coefficients evolve
    with the statistics (:func:`evolve`). ``amplitude`` A ≥ 0 (checked when concrete).
    """

    shape: stats.Gaussian | stats.GGX  # Beckmann (a Gaussian) or GGX, as ``family`` says
    amplitude: Float[Array, ""]
    family: str = eqx.field(static=True)

    def __init__(self, alpha_x, alpha_y, family: str = "beckmann", amplitude=1.0):
        if family == "beckmann":
            self.shape = stats.Beckmann(alpha_x=alpha_x, alpha_y=alpha_y)
        elif family == "ggx":
            self.shape = stats.GGX(alpha_x=alpha_x, alpha_y=alpha_y)
        else:
            raise InvalidInputError(f"family must be 'beckmann' or 'ggx'; got {family!r}.")
        self.family = family
        self.amplitude = as_float_array(amplitude, "amplitude")
        if is_concrete(self.amplitude) and np.any(np.asarray(self.amplitude) < 0):
            raise InvalidInputError(
                f"amplitude must be ≥ 0 (a BRDF is non-negative); got {np.asarray(self.amplitude)!r}."
            )

    def _alpha_min(self):
        if isinstance(self.shape, stats.GGX):  # family "ggx"
            return jnp.min(self.shape.alpha)
        return jnp.sqrt(2 * jnp.min(jnp.diagonal(self.shape.cov)))

    def evaluate(
        self,
        i: Float[ArrayLike, "*#batch 3"],
        o: Float[ArrayLike, "*#batch 3"],
        rotation: Float[ArrayLike, "*#batch 3 3"],
    ) -> Float[Array, "*batch"]:
        """``ρ(i, o, Γ)`` for global directions i, o (z > 0) and facet orientations Γ (3×3), their
        batch shapes broadcast together.

        Concrete ``rotation`` must be proper rotation matrices (finite, ``max |ΓᵀΓ − I| ≤ 1e-6``,
        det +1; :func:`brdfscale.so3._rotations.check_rotation`), else :class:`InvalidInputError`.
        """
        return self._evaluate(
            validate_directions(i, "i"), validate_directions(o, "o"), check_rotation(rotation, "rotation")
        )

    @eqx.filter_jit
    def _evaluate(self, i, o, rot):
        ip = jnp.einsum("...ji,...j->...i", rot, i)
        op = jnp.einsum("...ji,...j->...i", rot, o)
        visible = (ip[..., 2] > 0) & (op[..., 2] > 0)
        up = jnp.array([0.0, 0.0, 1.0], dtype=ip.dtype)
        ip = jnp.where(visible[..., None], ip, up)
        op = jnp.where(visible[..., None], op, up)
        h = ip + op
        m = h[..., :2] / h[..., 2:3]
        value = self.amplitude * self.shape.density(m) * microfacet_factor(ip, op)
        return jnp.where(visible, value, 0.0)

    def samples(self, i: Float[ArrayLike, "3"], o: Float[ArrayLike, "3"], B: int) -> Float[Array, "n n n"]:
        """``ρ(i, o, Γ)`` on the Kostelec–Rockmore grid of band limit B (axes α, β, γ, n = 2B each)."""
        B = check_band_limit(B)
        a, b, g = (jnp.asarray(x) for x in grid(B))
        return self._on_grid(validate_directions(i, "i"), validate_directions(o, "o"), a, b, g)

    @eqx.filter_jit
    def _on_grid(self, i, o, a, b, g):
        return self._evaluate(i, o, euler_to_matrix(a[:, None, None], b[None, :, None], g[None, None, :]))

    def coefficients(self, i, o, B: int) -> Complex[Array, "B 2*B-1 2*B-1"]:
        """SO(3) coefficients of ``Γ ↦ ρ(i, o, Γ)`` at band limit B (:func:`forward` of :meth:`samples`)."""
        return forward(self.samples(i, o, B))

    def spectrum(self, J: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch"]:
        """Decay of the lobe's degree-J content along its narrowest axis, ``|G(W)|`` at |W|² = J(J+1):
        ``exp(−α_min² J(J+1)/4)`` (Beckmann) or ``x K₁(x)``, ``x = α_min √(J(J+1))`` (GGX)."""
        J = jnp.asarray(J, dtype=float)
        w = jnp.sqrt(J * (J + 1))
        a = self._alpha_min()
        if self.family == "ggx":
            return xk1(a * w)
        return jnp.exp(-((a * w) ** 2) / 4)
