"""The anisotropic scale-law model: :class:`fitting.AnisotropicModel`'s base lobe (full scale matrix C0,
free centre; Gaussian, GGX or Student-t) with slope statistics that follow a *continuous* law in μ, so
that it predicts the lobe at any scale, measured or not (docs/fitting.md, "The anisotropic scale law").

The statistics are Gaussian with the covariance

    Σ(μ) = R(φ) diag(σ_1²(μ), σ_2²(μ)) R(φ)ᵀ,        R(φ) = [[cos φ, −sin φ], [sin φ, cos φ]],

principal axes at a free angle φ shared by every scale, and each principal variance following a law
in μ (:class:`Width` or :class:`Spline`). The evolution of seed Eq. 4.4 needs of them only the
covariance difference

    ΔΣ(μ0, μ) = Σ(μ0) − Σ(μ) = R(φ) diag(σ_1²(μ0) − σ_1²(μ), σ_2²(μ0) − σ_2²(μ)) R(φ)ᵀ,

which is positive semidefinite for every μ ≥ μ0 because both laws' σ_a(μ) are non-increasing (a
coarser facet averages more of the surface): the lobe at every coarser scale exists, and is
:class:`fitting.AnisotropicModel`'s evolution of the same base lobe by this ΔΣ
(:meth:`fitting.AnisotropicModel.predict_with`: covariances add for a Gaussian lobe, every
component of a Student-t lobe's Gaussian scale mixture widens by ΔΣ). Towards a finer scale μ < μ0,
ΔΣ is negative semidefinite and the evolution a deconvolution: a Gaussian lobe exists there while
``C0 + ΔΣ`` stays positive definite, a heavy-tailed one never (its mixture has components of
arbitrarily small covariance), and :meth:`AnisotropicLawModel.predict_at` refuses what does not exist.

Laws of the principal variances (a :class:`Law` object carries its parameters, start and prior):

* :class:`Width` (``law="width"``, default) — per axis a the Beckmann width law of
  :class:`brdfscale.stats.WidthLaw`, ``σ_a²(μ) = α_a(μ)²/2`` with
  ``α_a(μ) = alpha_max_a (1 + (μ/mu_c_a)²)^(−exponent_a/2)``: a floor (saturation at alpha_max_a) for
  facets far below mu_c_a and a power law ``μ^(−exponent_a)`` above it, each axis with its own three
  parameters, so the anisotropy ratio σ_2²/σ_1² may change with scale. With both axes' parameters
  equal it is :class:`fitting.ParametricModel`'s Beckmann statistics with the width law (tested:
  the predictions equal). Extrapolation to coarser scales follows the power law (the boundary
  condition Σ(∞) = 0 built in), to finer ones the floor.
* :class:`Spline` (``law="spline"``) — :class:`brdfscale.stats.MonotoneSplineLaw`: ``ln σ_a`` C¹,
  piecewise quadratic in ln μ on ``knots`` knots spread over the fitted scales, non-increasing with
  rates ``r_{a,k} > 0``. Not a power law inside the fitted range; **beyond its end knots it is the
  power law of the end rate** (``σ_a ∝ μ^(−r_{a,K−1})`` above the coarsest fitted scale): a
  prediction there is an extrapolation of the slope at the last fitted scale, nothing more.

θ: AnisotropicModel's base coordinates (``log amplitude``, ``log L0_xx``, ``L0_yx``, ``log L0_yy``,
``mean_x``, ``mean_y`` unless centred), then ``phi`` (radians, prior −π … π: two periods, so that the
optimiser reaches any orientation from its start), then the law's coordinates, then (mixture increments,
``increments="mixture"``: :class:`AnisotropicModel`'s) ``logit w``, ``log f-1``, then (Student-t) ``log nu``.
The data determine ΔΣ only: absolute Σ(μ) rests on the law's boundary condition.

Verified in tests/test_anisotropic_law.py: predictions against a hand-written Gaussian of covariance
``C0 + ΔΣ`` over hypothesis-drawn orientations and anisotropy ratios, ΔΣ positive semidefinite and
monotone, the isotropic case against :class:`fitting.ParametricModel`, jit/grad/vmap equal to eager,
and a synthetic anisotropic field's law recovered within 3 standard errors at held-out scales.
"""

import abc
import math
from collections.abc import Sequence
from typing import ClassVar

import equinox as eqx
import jax
import jax.core
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from brdfscale import InvalidInputError, lobes, stats
from brdfscale.checks import flag, integer
from brdfscale.choices import INCREMENTS, MODEL, SHAPES

from ._anisotropic import AbstractCovarianceModel, AnisotropicModel, image_moments
from ._data import Dataset
from ._parametric import ParametricModel


__all__ = ["AnisotropicLawModel", "Law", "Spline", "Width", "ANISOTROPIC_LAWS"]


class Law(eqx.Module):
    """A law of the two principal slope variances ``(σ_1²(μ), σ_2²(μ))``, each non-increasing in μ."""

    @property
    @abc.abstractmethod
    def names(self) -> tuple[str, ...]:
        """The law's coordinates in θ."""

    @abc.abstractmethod
    def variances(self, p: Float[Array, " m"], mu: Float[ArrayLike, ""]) -> Float[Array, "2"]:
        """``(σ_1²(μ), σ_2²(μ))`` of the law's coordinates ``p``."""

    @abc.abstractmethod
    def quantities(self, p: Float[Array, " m"]) -> dict[str, Float[Array, ""]]:
        """The law's physical parameters by name."""

    @abc.abstractmethod
    def initial(self, scales: np.ndarray, differences: np.ndarray) -> list[float]:
        """A start whose ΔΣ along each axis, ``differences`` (K, 2) at ``scales``, is roughly the measured one."""

    @abc.abstractmethod
    def bounds(self, data: Dataset) -> tuple[list[float], list[float]]:
        """The prior box of the coordinates."""


class Width(Law):
    """Per axis ``σ_a²(μ) = α_a(μ)²/2``, α_a a :class:`brdfscale.stats.WidthLaw` (module docstring);
    coordinates the logarithms of ``alpha_max_a``, ``mu_c_a``, ``exponent_a`` for a = 1, 2."""

    @property
    def names(self):
        return tuple(f"log {p}_{a}" for a in (1, 2) for p in ("alpha_max", "mu_c", "exponent"))

    def variances(self, p, mu):
        q = jnp.exp(jnp.asarray(p)).reshape(2, 3)
        return stats.WidthLaw(q[:, 0], q[:, 1], q[:, 2])(mu) ** 2 / 2

    def quantities(self, p):
        return {n.removeprefix("log "): v for n, v in zip(self.names, jnp.exp(jnp.asarray(p)))}

    def initial(self, scales, differences):
        # as ParametricModel.initial per axis: alpha_max 1.5 × the measured spread of α², mu_c mid-range, exponent 1
        mid = math.sqrt(float(scales[0]) * float(scales[-1]))
        out = []
        for a in (0, 1):
            out += [math.log(1.5 * math.sqrt(2 * float(differences[-1, a]))), math.log(mid), 0.0]
        return out

    def bounds(self, data):
        box = ParametricModel().box(data)  # alpha_max, mu_c, exponent: the parametric model's prior box
        lo = [math.log(box[p][0]) for p in ("alpha_max", "mu_c", "exponent")] * 2
        hi = [math.log(box[p][1]) for p in ("alpha_max", "mu_c", "exponent")] * 2
        return lo, hi


class Spline(Law):
    """:class:`brdfscale.stats.MonotoneSplineLaw` with ``knots`` knots from ``mu_min`` to ``mu_max``
    (module docstring); coordinates ``log sigma_1``, ``log sigma_2`` (at ``mu_min``) and the logarithms
    of the rates ``r_{a,k}``."""

    mu_min: float = eqx.field(static=True)
    mu_max: float = eqx.field(static=True)
    knots: int = eqx.field(static=True)

    def __init__(self, mu_min: float, mu_max: float, knots: int = 3):
        self.knots = integer(knots, "knots", 2)
        lo, hi = float(mu_min), float(mu_max)
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
            raise InvalidInputError(f"the spline law needs 0 < mu_min < mu_max; got {mu_min!r}, {mu_max!r}.")
        self.mu_min, self.mu_max = lo, hi

    @property
    def names(self) -> tuple[str, ...]:
        return ("log sigma_1", "log sigma_2") + tuple(f"log rate_{a}_{k}" for a in (1, 2) for k in range(self.knots))

    def _law(self, p) -> stats.MonotoneSplineLaw:
        q = jnp.exp(jnp.asarray(p))
        return stats.MonotoneSplineLaw(self.mu_min, self.mu_max, q[:2], q[2:].reshape(2, self.knots))

    def variances(self, p, mu):
        return self._law(p).principal_sigmas(mu) ** 2

    def quantities(self, p):
        return {n.removeprefix("log "): v for n, v in zip(self.names, jnp.exp(jnp.asarray(p)))}

    def initial(self, scales, differences):
        # a constant rate r and σ0² = 2 ΔΣ_last per axis: ΔΣ(μ) = σ0² (1 − (μ/μ0)^(−2r)), half of σ0² at the last scale
        x = max(math.log(float(scales[-1]) / self.mu_min), 1e-3)
        rate = math.log(2) / (2 * x)
        out = []
        for a in (0, 1):
            out.append(0.5 * math.log(max(2 * float(differences[-1, a]), 1e-12)))
        return out + [math.log(rate)] * (2 * self.knots)

    def bounds(self, data):
        sd, rate = (math.log(1e-6), math.log(10.0)), (math.log(1e-4), math.log(10.0))
        n = 2 * self.knots
        return [sd[0]] * 2 + [rate[0]] * n, [sd[1]] * 2 + [rate[1]] * n


ANISOTROPIC_LAWS = ("width", "spline")
"""The laws of :class:`AnisotropicLawModel` (``law=``)."""


def _rotated(phi, variances):
    """``R(φ) diag(v) R(φ)ᵀ`` written out: ``[[c²v1 + s²v2, cs(v1 − v2)], [cs(v1 − v2), s²v1 + c²v2]]``."""
    c, s = jnp.cos(phi), jnp.sin(phi)
    v1, v2 = variances[..., 0], variances[..., 1]
    xy = c * s * (v1 - v2)
    return jnp.stack([jnp.stack([c * c * v1 + s * s * v2, xy], -1), jnp.stack([xy, s * s * v1 + c * c * v2], -1)], -2)


class AnisotropicLawModel(AbstractCovarianceModel):
    """:class:`AnisotropicModel`'s base lobe with ΔΣ(μ0, μ) from a continuous anisotropic scale law
    (module docstring): it predicts any scale.

    Args:
        law: ``"width"`` (per-axis width laws, default) or ``"spline"`` (monotone splines in ln μ;
            needs ``scales``), or a :class:`Law` object.
        scales: the fitted scales (the spline's knots span them; ignored by the width law).
        knots: the spline's knots per axis (≥ 2; default 3).
        centred: hold the lobe's centre at the origin.
        shape: the base lobe's shape, a name of :data:`brdfscale.choices.SHAPES`.
        increments: the change between scales, a name of :data:`brdfscale.choices.INCREMENTS`
            (:class:`AnisotropicModel`'s: ``"mixture"`` a two-Gaussian scale mixture of covariance ΔΣ).

    Raises:
        InvalidInputError: an unknown law, shape or increments; ``law="spline"`` without at least two scales.
    """

    law: Law
    lobe: AnisotropicModel
    preferred_solver: ClassVar[str] = "lm_normal"

    def __init__(
        self,
        law: "str | Law" = "width",
        *,
        scales=None,
        knots: int = 3,
        centred: bool = False,
        shape: str = MODEL.shape,
        increments: str = MODEL.increments,
    ):
        if isinstance(law, Law):
            self.law = law
        elif law == "width":
            self.law = Width()
        elif law == "spline":
            mus = np.unique(np.asarray([] if scales is None else scales, float))
            if mus.size < 2:
                raise InvalidInputError(
                    f"law='spline' needs the fitted scales (at least two, to place its knots); got scales={scales!r}."
                )
            self.law = Spline(float(mus[0]), float(mus[-1]), knots)
        else:
            raise InvalidInputError(f"law must be one of {list(ANISOTROPIC_LAWS)} or a fitting Law; got {law!r}.")
        self.lobe = AnisotropicModel(
            2, centred=flag(centred, "centred"), shape=SHAPES.check(shape), increments=INCREMENTS.check(increments)
        )

    @property
    def shape(self) -> str:
        return self.lobe.shape

    @property
    def increments(self) -> str:
        return self.lobe.increments

    @property
    def centred(self) -> bool:
        return self.lobe.centred

    @property
    def _n_base(self) -> int:
        return 4 if self.centred else 6

    @property
    def names(self) -> tuple[str, ...]:
        return (*self.lobe.names[: self._n_base], "phi", *self.law.names, *self.lobe.tail_names)

    @property
    def radial(self) -> bool:
        return False

    @property
    def identifiability_notes(self) -> tuple[str, ...]:
        return (
            "The data determine the base lobe at μ0 and the covariance differences ΔΣ(μ0, μk) = Σ(μ0) − Σ(μk) at "
            "the measured scales; the scale law carries them to other scales. Absolute Σ(μ) rests on the law's "
            "boundary condition Σ(μ → ∞) = 0, not on a measurement.",
        )

    def _split(self, theta):
        """``(θ of self.lobe, φ, the law's coordinates)``; the lobe's one increment is unused (zeros)."""
        theta = jnp.asarray(theta)
        nb, nl = self._n_base, len(self.law.names)
        tail = theta[theta.shape[0] - len(self.lobe.tail_names) :]
        lobe = jnp.concatenate([theta[:nb], jnp.zeros(3, theta.dtype), tail])
        return lobe, theta[nb], theta[nb + 1 : nb + 1 + nl]

    def slope_covariance(self, theta: Float[Array, " n"], mu: Float[ArrayLike, "*m"]) -> Float[Array, "*m 2 2"]:
        """``Σ(μ) = R(φ) diag(σ_1²(μ), σ_2²(μ)) R(φ)ᵀ`` (absolute: rests on the law's Σ(∞) = 0)."""
        _, phi, p = self._split(theta)
        mu = jnp.asarray(mu, dtype=jnp.asarray(theta).dtype)
        variances = jax.vmap(lambda m: self.law.variances(p, m))(mu.reshape(-1)).reshape(*mu.shape, 2)
        return _rotated(phi, variances)

    def covariance_differences(self, theta: Float[Array, " n"], scales: Float[Array, " k"]) -> Float[Array, "k 2 2"]:
        """``ΔΣ(μ0, μ_k) = Σ(scales[0]) − Σ(scales[k])`` (row 0 is 0), any scales: the law's."""
        _, phi, p = self._split(theta)
        scales = jnp.asarray(scales, dtype=jnp.asarray(theta).dtype)
        variances = jax.vmap(lambda m: self.law.variances(p, m))(scales)
        return _rotated(phi, variances[0] - variances)

    def base_lobe(self, theta) -> lobes.AbstractLobe:
        """The lobe at μ0 (:meth:`AnisotropicModel.base_lobe`)."""
        return self.lobe.base_lobe(self._split(theta)[0])

    def tail_index(self, theta) -> Float[Array, ""] | None:
        return self.lobe.tail_index(self._split(theta)[0])

    def increment_mixture(self, theta):
        """The base lobe's model's (:meth:`AnisotropicModel.increment_mixture`)."""
        return self.lobe.increment_mixture(self._split(theta)[0])

    def quantities(self, theta):
        """The base lobe's (:meth:`AnisotropicModel.quantities`), ``phi`` and the law's parameters."""
        lobe, phi, p = self._split(theta)
        return {**self.lobe.quantities(lobe), "phi": phi, **self.law.quantities(p)}

    def predict_points(self, theta, scales, points):
        return self.lobe.predict_with(self._split(theta)[0], self.covariance_differences(theta, scales), points)

    def predict_at(
        self,
        theta: Float[Array, " n"],
        mu0: float,
        mu: Float[ArrayLike, "*scales"] | Sequence[float],
        u: Float[ArrayLike, "m p 2"],
    ) -> Float[Array, "m p"]:
        """The lobe at scales ``mu`` (any, coarser or finer than μ0 = ``mu0``, the finest fitted scale)
        evaluated at offsets ``u[j]``: the base lobe evolved by ``ΔΣ(μ0, μ_j)``.

        Raises:
            InvalidInputError: (concrete inputs) a scale where the lobe does not exist: finer than μ0
                with ``C0 + ΔΣ`` not positive definite (Gaussian), or finer than μ0 at all (a heavy-tailed
                lobe: module docstring).
        """
        mu = jnp.atleast_1d(jnp.asarray(mu, dtype=jnp.asarray(theta).dtype))
        u = jnp.asarray(u, dtype=mu.dtype)
        if u.ndim != 3 or u.shape[0] != mu.shape[0] or u.shape[-1] != 2:
            raise InvalidInputError(f"u must have shape (len(mu), points, 2) = ({mu.shape[0]}, p, 2); got {u.shape}.")
        concrete = not isinstance(mu, jax.core.Tracer) and not isinstance(theta, jax.core.Tracer)
        finer = np.asarray(mu) < float(mu0) if concrete else np.zeros(0, bool)
        if finer.any() and (self.shape != "gaussian" or self.increments != "gaussian"):
            what = f"a {self.shape} lobe" if self.shape != "gaussian" else "a lobe with mixture increments"
            raise InvalidInputError(
                f"{what} has no lobe at scales finer than μ0 = {float(mu0):g} (μ = "
                f"{np.asarray(mu)[finer].tolist()}): the deconvolution of a heavy-tailed lobe, or by heavy-tailed "
                "increments, does not exist; predict at μ ≥ μ0."
            )
        scales = jnp.concatenate([jnp.asarray([mu0], mu.dtype), mu])
        differences = self.covariance_differences(theta, scales)
        if finer.any():
            c0 = np.asarray(self.lobe.parts(self._split(theta)[0])[1])
            smallest = np.linalg.eigvalsh(c0 + np.asarray(differences[1:])).min(axis=-1)
            if np.any(smallest <= 0):
                raise InvalidInputError(
                    f"no lobe exists at μ = {np.asarray(mu)[smallest <= 0].tolist()}: C0 + ΔΣ(μ0, μ) is not positive "
                    "definite (the finer-scale statistics are wider than the base lobe can be deconvolved by)."
                )
        points = jnp.concatenate([jnp.zeros((1, u.shape[1], 2), u.dtype), u])
        return self.lobe.predict_with(self._split(theta)[0], differences, points)[1:]

    def initial(self, data):
        """The base lobe's start (:meth:`AnisotropicModel.initial`); φ the principal axis of the measured
        ``ΔΣ`` at the coarsest scale (second moments of the pixels above half the peak); the law's start
        from the measured ΔΣ along the two axes."""
        start = self.lobe.initial(data)
        _, cov = image_moments(data)
        # a change the half-maximum moments do not resolve starts at 5 % of the base lobe's variance: inside every law's
        # prior box (a width law's logarithms need a positive start)
        delta = (cov - cov[0]) * self.lobe.start_widening  # a mixture increment's ΔΣ exceeds its core's widening
        phi, law = self.law_start(np.asarray(data.scales), delta, 0.05 * float(np.trace(cov[0])) / 2)
        tail = list(start[len(start) - len(self.lobe.tail_names) :])
        return np.asarray([*start[: self._n_base], phi, *law, *tail])

    def law_start(
        self, scales: np.ndarray, delta: np.ndarray, floor: float, phi: float | None = None
    ) -> tuple[float, list[float]]:
        """``(φ, the law's start)`` for estimates ``delta`` (K, 2, 2) of ΔΣ(μ0, μ_k) at ``scales``: φ the principal
        axis of the coarsest (the larger eigenvalue's as axis 1; or the ``phi`` given), the law's own start
        (:meth:`Law.initial`) from ΔΣ along the two axes, each floored at ``floor``."""
        if phi is None:
            w, v = np.linalg.eigh(delta[-1])
            phi = math.atan2(v[1, 1], v[0, 1])
            phi = (phi + math.pi / 2) % math.pi - math.pi / 2
        rot = np.array([[math.cos(phi), -math.sin(phi)], [math.sin(phi), math.cos(phi)]])
        along = np.einsum("ia,kij,ja->ka", rot, delta, rot)  # (K, 2): ΔΣ along axes 1, 2
        return phi, list(self.law.initial(np.asarray(scales), np.maximum(along, floor)))

    @property
    def n_base(self) -> int:
        """The base lobe's coordinates at the head of θ (those of :class:`AnisotropicModel`, same names, same
        order)."""
        return self._n_base

    def start_scales(self, theta0):
        """The jitter of the starts: the base lobe's coordinates as :meth:`AnisotropicModel.start_scales`
        scales them (the centre by the lobe's width), 1 for φ (radians) and the law's logarithms."""
        theta0 = np.asarray(theta0, dtype=float)
        lobe = self.lobe.start_scales(np.asarray(self._split(jnp.asarray(theta0))[0]))
        scales = np.ones_like(theta0)
        scales[: self._n_base] = lobe[: self._n_base]
        return scales

    def bounds(self, data):
        """The base lobe's prior (:meth:`AnisotropicModel.bounds`), φ in [−π, π], the law's box."""
        lo, hi = self.lobe.bounds(data)
        law_lo, law_hi = self.law.bounds(data)
        tail = slice(len(lo) - len(self.lobe.tail_names), None)
        n = self._n_base
        return (
            np.asarray([*lo[:n], -math.pi, *law_lo, *lo[tail]]),
            np.asarray([*hi[:n], math.pi, *law_hi, *hi[tail]]),
        )
