"""The non-parametric model: a tabulated base lobe and the relative statistics
``R_k(W) = S(W, μ0)/S(W, μ_k) = exp(−D_k(|W|))`` (docs/fitting.md)."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from brdfscale import evolve, InvalidInputError, lobes, MethodNotApplicableError, stats
from brdfscale.checks import integer, real
from brdfscale.choices import MODEL
from brdfscale.special import j0

from ._data import Dataset
from ._model import AbstractModel, moments, require_dataset
from ._smoothness import choose_smoothness, DEFAULT_SMOOTHNESS, smoothness_rows, SMOOTHNESS_RULES


__all__ = ["NonParametricModel", "RelativeStatistics"]


class RelativeStatistics(stats.AbstractSlopeDensity):
    """The isotropic density ``r`` with ``R(W) = exp(−D(|W|))``, ``D`` piecewise linear in W².

    ``D`` is given at knots ``W_0 = 0 < W_1 < … < W_J`` (``D(0) = 0``, so r integrates to 1)
    and continued linearly in W² beyond ``W_J``. Linear in W² makes ``r`` Gaussian-like near
    the origin (finite variance ``2·D'(0)`` per axis in W² units). Used as ``s_from`` of
    :func:`brdfscale.evolve` with ``s_to = Delta()``, it evolves a lobe by the ratio
    ``S(μ0)/S(μ_k)`` directly.
    """

    knots: Float[Array, " J"]
    decay: Float[Array, " J"]
    isotropic: bool = eqx.field(static=True)

    def __init__(self, knots, decay):
        self.knots, self.decay = jnp.asarray(knots), jnp.asarray(decay)
        self.isotropic = True

    def _slopes(self):
        t = self.knots**2
        return (self.decay[1:] - self.decay[:-1]) / (t[1:] - t[:-1])

    def log_cf_radial(self, k):
        """``−D(k)``."""
        t, tk = jnp.asarray(k) ** 2, self.knots**2
        beyond = self.decay[-1] + self._slopes()[-1] * (t - tk[-1])
        return -jnp.where(t <= tk[-1], jnp.interp(t, tk, self.decay), beyond)

    def cf(self, W):
        return jnp.exp(self.log_cf_radial(jnp.linalg.norm(jnp.asarray(W), axis=-1))).astype(jnp.result_type(W, 1j))

    def cf_radial(self, k):
        return jnp.exp(self.log_cf_radial(k))

    def density(self, m):
        """``r(m) = (2π)⁻¹ ∫_0^K R(k) J₀(k|m|) k dk`` (Gauss–Legendre, K where R = 1e-14)."""
        r = jnp.linalg.norm(jnp.asarray(m), axis=-1)
        x, w = np.polynomial.legendre.leggauss(256)
        K = self.bandwidth(1e-14)
        k = 0.5 * (jnp.asarray(x) + 1) * K
        return jnp.sum(0.5 * K * jnp.asarray(w) * self.cf_radial(k) * k * j0(r[..., None] * k), axis=-1) / (2 * jnp.pi)

    def shifted(self, offset):
        raise MethodNotApplicableError("RelativeStatistics is centred by construction and cannot be shifted.")

    def support_radius(self, tol):
        # A Gaussian with R = exp(−c W²) has support radius √(4 c ln(1/tol)); c = the steepest segment.
        c = jnp.maximum(jnp.max(self._slopes()), 1e-30)
        return jnp.sqrt(4 * c * math.log(1 / tol))

    def bandwidth(self, tol):
        level, tk = math.log(1 / tol), self.knots**2
        slope = jnp.maximum(self._slopes()[-1], 1e-30)
        t = jnp.where(
            self.decay[-1] >= level, jnp.interp(level, self.decay, tk), tk[-1] + (level - self.decay[-1]) / slope
        )
        return jnp.sqrt(t)


def _softplus_inverse(x):
    return np.log(np.expm1(np.maximum(x, 1e-12)))


class NonParametricModel(AbstractModel):
    """Tabulated base lobe + relative statistics on a radial W grid (module docstring).

    Args:
        data: the dataset (fixes the number of scales, the base-lobe grid and the W knots).
        base_nodes: the base lobe is tabulated on ``base_nodes × base_nodes`` nodes over
            ``[−base_extent, base_extent]²`` (default: where the finest-scale lobe lives,
            3.5 × its half-maximum width α (α² = area above half peak / π ln 2), capped at the image extent).
        n_knots: number of W knots after ``W_0 = 0``, evenly spaced up to ``W_max`` (default
            ``6/α``, where a Gaussian lobe's transform has fallen to e⁻⁹).
        regularisation: the Tikhonov weight of the smoothness prior — a number (the inverse
            prior standard deviation of the second differences of ``D_k`` across knots; larger:
            smoother), or ``"auto"`` (``"gcv"``): chosen from the data by generalised
            cross-validation, linearised about a pilot fit (:func:`choose_smoothness`; this runs
            one fit at construction, about as long as the fit itself). Default 3.0.
        smoothness: the same number under its earlier name (give one of the two).
        grid_size: side of the FFT grid of the evolution's grid path (≥ 8).

    θ = (log base-lobe values row-major, then z[k, j] for k = 1..K−1, j = 1..J) with
    ``D_k(W_j) = Σ_{k'≤k} Σ_{j'≤j} softplus(z[k', j'])``.

    Raises:
        InvalidInputError: ``data`` is not a :class:`~fitting.Dataset`, an image has no
            positive valid pixel, or an option is out of range (``base_nodes`` ≥ 3,
            ``n_knots`` ≥ 2, ``grid_size`` ≥ 8 integers; ``base_extent``, ``w_max`` > 0,
            ``smoothness`` ≥ 0, finite; ``regularisation`` such a number or ``"auto"``/``"gcv"``;
            not both ``smoothness`` and ``regularisation``).

    ``smoothness_choice`` records an automatic choice (None for a given number): the
    candidates, their GCV values and the pilot fit's smoothness.
    """

    n_scales: int = eqx.field(static=True)
    base_nodes: int = eqx.field(static=True)
    base_extent: float = eqx.field(static=True)
    knots: tuple[float, ...] = eqx.field(static=True)
    smoothness: float = eqx.field(static=True)
    grid_size: int = eqx.field(static=True)
    smoothness_choice: tuple | None = eqx.field(static=True)

    def __init__(
        self,
        data: Dataset,
        *,
        base_nodes: int = MODEL.base_nodes,
        base_extent: float | None = None,
        n_knots: int = MODEL.knots,
        w_max: float | None = None,
        smoothness: float | None = None,
        regularisation: float | str | None = MODEL.regularisation,
        grid_size: int = 48,
    ):
        require_dataset(data, "NonParametricModel(data)")
        base_nodes = integer(base_nodes, "base_nodes", 3)
        n_knots = integer(n_knots, "n_knots", 2)
        grid_size = integer(grid_size, "grid_size", 8)
        if smoothness is not None and regularisation is not None:
            raise InvalidInputError(
                "give the smoothness prior's weight once: regularisation= (a number or 'auto') or "
                "smoothness= (its earlier name), not both."
            )
        weight = (
            regularisation if regularisation is not None else (DEFAULT_SMOOTHNESS if smoothness is None else smoothness)
        )
        auto = isinstance(weight, str)
        if auto and weight not in SMOOTHNESS_RULES:
            raise InvalidInputError(
                f"regularisation must be a number ≥ 0 or one of {SMOOTHNESS_RULES} (generalised "
                f"cross-validation); got {weight!r}."
            )
        smoothness = (
            DEFAULT_SMOOTHNESS
            if auto
            else real(weight, "regularisation" if regularisation is not None else "smoothness", minimum=0.0)
        )
        if base_extent is not None:
            base_extent = real(base_extent, "base_extent", minimum=0.0, strict=True)
        if w_max is not None:
            w_max = real(w_max, "w_max", minimum=0.0, strict=True)
        _, width2 = moments(data)
        rms = math.sqrt(width2[0])
        extent = min(data.extents)
        self.n_scales = int(data.scales.shape[0])
        self.base_nodes = base_nodes
        self.base_extent = base_extent if base_extent is not None else min(3.5 * rms, extent)
        w_max = w_max if w_max is not None else 6.0 / rms
        self.knots = tuple(np.linspace(0.0, w_max, n_knots + 1).tolist())
        self.smoothness = smoothness
        self.grid_size = grid_size
        self.smoothness_choice = None
        if auto:  # a pilot model, complete, at the default weight (this one is still being built)
            pilot = NonParametricModel(
                data,
                base_nodes=base_nodes,
                base_extent=self.base_extent,
                n_knots=n_knots,
                w_max=w_max,
                regularisation=DEFAULT_SMOOTHNESS,
                grid_size=grid_size,
            )
            self.smoothness, self.smoothness_choice = choose_smoothness(pilot, data)

    def check_data(self, data: Dataset) -> None:
        """The model's θ layout is fixed by the dataset it was built from: ``data`` must have
        as many scales (:class:`~brdfscale.InvalidInputError` otherwise)."""
        super().check_data(data)
        n = int(data.scales.shape[0])
        if n != self.n_scales:
            raise InvalidInputError(
                f"this NonParametricModel was built for a dataset with {self.n_scales} scales, but the data have "
                f"{n} (μ = {np.asarray(data.scales).tolist()}); build the model from the dataset it is fitted to: "
                "NonParametricModel(data)."
            )

    @property
    def identifiability_notes(self):
        return (
            "Reported: D_k(W) = −ln[S(W, μ0)/S(W, μ_k)], the combinations the data determine. The absolute "
            "S(W, μ_k) is NOT determined by these data: it needs the boundary condition S(W, ∞) = 1 through a "
            "measurement at a scale coarse enough for δ statistics, or a parametric scale law "
            "(ParametricModel).",
        )

    @property
    def _n_base(self):
        return self.base_nodes**2

    @property
    def names(self):
        nb, J = self.base_nodes, len(self.knots) - 1
        base = tuple(f"log base[{r},{c}]" for r in range(nb) for c in range(nb))
        return base + tuple(f"z[{k},{j}]" for k in range(1, self.n_scales) for j in range(1, J + 1))

    def base_lobe(self, theta) -> lobes.Tabulated:
        nb = self.base_nodes
        return lobes.Tabulated(jnp.exp(theta[: self._n_base]).reshape(nb, nb), extent=self.base_extent)

    def decay(self, theta) -> Float[Array, "n_scales n_knots"]:
        """``D_k(W_j)`` for k = 0..K−1 (row 0 is zero), j = 0..J (J + 1 = the number of knots)."""
        J = len(self.knots) - 1
        inc = jax.nn.softplus(theta[self._n_base :].reshape(self.n_scales - 1, J))
        d = jnp.cumsum(jnp.cumsum(inc, axis=0), axis=1)
        d = jnp.concatenate([jnp.zeros((self.n_scales - 1, 1), d.dtype), d], axis=1)
        return jnp.concatenate([jnp.zeros((1, J + 1), d.dtype), d], axis=0)

    def relative(self, theta, k: int) -> RelativeStatistics:
        return RelativeStatistics(jnp.asarray(self.knots, dtype=theta.dtype), self.decay(theta)[k])

    def quantities(self, theta):
        out = {"amplitude": self.base_lobe(theta).amplitude}
        d = self.decay(theta)
        for k in range(1, self.n_scales):
            for j in range(1, len(self.knots)):
                out[f"D[{k}](W={self.knots[j]:.4g})"] = d[k, j]
        return out

    @property
    def radial(self):
        return False

    def predict_points(self, theta, scales, points):
        base = self.base_lobe(theta)
        knots = jnp.asarray(self.knots, dtype=theta.dtype)

        def at_scale(decay, u):
            relative = RelativeStatistics(knots, decay)
            return evolve(base, relative, stats.Delta(), method="grid", size=self.grid_size).density(u)

        coarser = jax.vmap(at_scale)(self.decay(theta)[1:], points[1:])
        return jnp.concatenate([base.density(points[0])[None], coarser])

    def relative_statistics(self, theta, W, scales):
        return jnp.stack([self.relative(theta, k).cf_radial(W) for k in range(self.n_scales)])

    def penalty(self, theta):
        return smoothness_rows(self.decay(theta)[1:], self.smoothness)

    def initial(self, data):
        amp, width2 = moments(data)
        nb = self.base_nodes
        # a Gaussian base lobe of the finest image's half-maximum width (α² = 2σ²)
        x = np.linspace(-self.base_extent, self.base_extent, nb)
        var = max(width2[0], 1e-12) / 2
        g = amp * np.exp(-(x[None, :] ** 2 + x[:, None] ** 2) / (2 * var)) / (2 * np.pi * var)
        base = np.log(np.maximum(g, g.max() * 1e-6)).ravel()
        W = np.asarray(self.knots)
        d = np.maximum(width2 - width2[0], 1e-6 * max(width2[0], 1e-12))[:, None] * W[None, :] ** 2 / 4
        inc = np.diff(np.diff(d, axis=0), axis=1)
        return np.concatenate([base, _softplus_inverse(np.maximum(inc, 1e-3)).ravel()])

    def bounds(self, data):
        amp, width2 = moments(data)
        peak = amp / (math.pi * max(width2[0], 1e-12))
        n_z = len(self.names) - self._n_base
        lo = np.concatenate([np.full(self._n_base, math.log(peak) - 40), np.full(n_z, -30.0)])
        hi = np.concatenate([np.full(self._n_base, math.log(peak) + 10), np.full(n_z, 10.0)])
        return lo, hi
