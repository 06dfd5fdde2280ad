"""The anisotropic parametric model (the default of ``brdfscale fit``): a base lobe at μ0 of full
scale matrix, any orientation and free centre — Gaussian (Beckmann), GGX or Student-t with a free
tail index ν — and per coarser scale the covariance difference ΔΣ_k = Σ(μ0) − Σ(μ_k) of the slope
statistics, a full 2 × 2 matrix of its own orientation (docs/fitting.md, "The default model").

The evolution of seed Eq. 4.4, ``G(W, μ_k) = G(W, μ0) S(W, μ0)/S(W, μ_k)``, needs of the
statistics only the relative statistics ``R_k = S(μ0)/S(μ_k)``. For Gaussian statistics
``R_k(W) = exp(−½ Wᵀ ΔΣ_k W)`` whatever Σ(μ0) and Σ(μ_k) are, and a Gaussian lobe of
covariance ``C0`` and mean ``m0`` at μ0 evolves to the Gaussian of covariance ``C0 + ΔΣ_k`` and
the same mean (covariances add, ``brdfscale.evolve``'s closed form, ``brdfscale._evolve._algebra``).
ΔΣ_k is the model-independent second-moment description: what a topography measures too
(``Σ(μ)`` of :func:`brdfscale.synth.facet_statistics`), and no absolute Σ(μ) is claimed.

Heavy-tailed lobes (``shape="student_t"``, ``"ggx"``). The bivariate Student-t lobe of scale
matrix ``C0`` and tail index ν (:class:`brdfscale.stats.StudentT`; GGX is ν = 2 with
``C0 = α²/2 I`` when isotropic) is a Gaussian scale mixture, ``t_ν(m0, C0) = E_τ N(m0, C0/τ)``
with ``τ ~ Gamma(ν/2, rate ν/2)``. Convolved with the statistics' Gaussian increment — the
evolution by ``R_k`` — each component's covariance grows by ΔΣ_k:

    g_k(u) = A · E_τ N(u; m0, C0/τ + ΔΣ_k),

evaluated by the trapezoidal rule in ln τ on :data:`MIXTURE_NODES` nodes
(:meth:`brdfscale.stats.StudentT.gaussian_mixture`, cut where the mixing density falls below
``e^{−MIXTURE_CUTOFF}`` of its peak); at μ0 the closed-form density is used. Against SciPy
quadrature of the same integral the error is ≤ 5e-7 of the peak for every ν of the prior, 1 … 200
(measured ≤ 1.1e-7; tests/test_anisotropic.py), far below the noise of any measured lobe.

θ (every value valid, no bounds needed by the parameterisation itself):

* ``log amplitude`` — A, the lobe's integral over slope offsets;
* the base covariance ``C0 = L Lᵀ`` by its Cholesky factor ``L = [[e^a, 0], [b, e^c]]``
  (``log L0_xx``, ``L0_yx``, ``log L0_yy``): every θ gives a positive-definite C0 of any
  orientation;
* ``mean_x``, ``mean_y`` — the lobe's centre (slope units; left out with ``centred=True``);
* per coarser scale k = 1 … K−1 the lobe's covariance at μ_k, ``C_k = C0 + ΔΣ_k``, by its Cholesky factor
  (``log L{k}_xx``, ``L{k}_yx``, ``log L{k}_yy``, as C0's), so ``ΔΣ_k = C_k − C0``: a full symmetric matrix of
  either sign, every θ giving a positive-definite lobe covariance at every scale;
* ``logit w``, ``log f-1`` (``increments="mixture"`` only; below) — the increments' tail weight and width ratio;
* ``log nu`` (last; ``shape="student_t"`` only) — the tail index, 1 ≤ ν ≤ 200 in the prior.

Heavy-tailed increments (``increments="mixture"``). On a real surface the change of the lobe between two scales
is often not Gaussian: a few steep facets carry most of the slope variance (on frt-1 of tests/data 0.9 % of the
pixel slopes carry 98 % of Σ, :func:`brdfscale.topography.slope_outliers`), so the lobe at μ_k has a core of the
μ0 lobe's width and tails far wider. The change is then a two-Gaussian scale mixture of covariance ΔΣ_k,

    K_k = (1 − w) N(0, s_c ΔΣ_k) + w N(0, s_t ΔΣ_k),   s_c = 1/(1 − w + w f),  s_t = f s_c,

whose covariance is ΔΣ_k exactly (``(1 − w) s_c + w s_t = 1``), so ΔΣ_k keeps its meaning — the second-moment
difference a topography measures — while the tail weight ``w`` and the ratio ``f > 1`` of the two components'
variances (shared by every scale: two coordinates, not two per scale) give the change its kurtosis, ``3[(1 − w +
w f²)/(1 − w + w f)² − 1]`` in excess. Its relative statistics are ``R_k(W) = (1 − w) exp(−½ s_c Wᵀ ΔΣ_k W) + w
exp(−½ s_t Wᵀ ΔΣ_k W)`` (seed Eq. 4.4 with the kernel's characteristic function), and the lobe at μ_k is
``A Σ_j Σ_i c_j v_i N(u; m0, C_j + s_i ΔΣ_k)`` over the base lobe's components C_j (one for a Gaussian lobe,
the scale mixture above for a heavy-tailed one) and the kernel's two. ``f → 1`` is the Gaussian increment.
(:meth:`AbstractCovarianceModel.increment_mixture`; tests/test_increments.py checks the density against SciPy's
quadrature of the convolution and R_k against the kernel's characteristic function by quadrature.)

``isotropic=True`` is the special case ``C_k = v_k I``, centred (θ: ``log amplitude``, ``log v0``, ``log v_k``,
``ΔΣ_k = (v_k − v0) I``): it is :class:`fitting.ParametricModel`'s Beckmann lobe with Beckmann statistics and any
scale law, with ``v0 = alpha_lobe²/2`` and ``ΔΣ_k = (α(μ0)² − α(μ_k)²)/2 · I`` (tests/test_anisotropic.py checks the
predictions equal).

**Why the lobe's covariance per scale, not the increments.** Physically ΔΣ_k is positive semi-definite and grows
with k (a coarser facet averages finer slopes), and an earlier θ built that in: the Cholesky factors of the
increments ``ΔΣ_k − ΔΣ_{k−1}``, logarithms on their diagonals. Where the data leave an increment near zero — below
the noise, as between neighbouring scales of a measured surface — its logarithm has no curvature down to the
prior's floor: the fit called it undetermined and left out the increment's uncertainty, so ΔΣ's standard errors
were too small, the optimiser ended short of the optimum from most starts (on tests/test_anisotropic.py's set with
a zero change between two scales it did not converge), and the samplers met a plateau ending in a cliff (NUTS
diverged or ran out of time on the real files of tests/data at ``poisson:0.05:1``). The lobe's covariance at a
scale is never near zero — the images resolve it — so its log-Cholesky coordinates are curved everywhere, the
posterior is close to Gaussian, and a ΔΣ_k the data cannot tell from zero gets a standard error that says so
(estimates may then fall slightly below zero or out of order, within their errors; a scale law fitted to them,
:func:`fitting.law_from_differences`, is monotone). Where the base lobe or the change is a scale mixture (``shape``
``"student_t"``, ``"ggx"``; ``increments="mixture"``) a component's covariance ``c_j C0 + s_i ΔΣ_k`` must be
positive definite as well: a component that is not (a ΔΣ_k far below zero: Eq. 4.4's deconvolution of a heavy tail
does not exist) contributes nothing, so the residuals rise there like a wall (:func:`_mixture_density`).
"""

import abc
import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from brdfscale import evolve, InvalidInputError, lobes, stats
from brdfscale.checks import integer
from brdfscale.choices import INCREMENTS, MODEL, SHAPES

from ._data import Dataset
from ._model import AbstractModel, moments


__all__ = ["AnisotropicModel", "image_moments", "MIXTURE_CUTOFF", "MIXTURE_NODES", "NU_RANGE", "TAIL_START"]

MIXTURE_NODES = 64
"""Trapezoidal nodes in ln τ of a heavy-tailed lobe's Gaussian scale mixture (module docstring)."""

MIXTURE_CUTOFF = 15.0
"""The mixture is cut where the mixing density falls below ``e^{−15}`` of its largest value (the
truncation, ~3e-7, then dominates the trapezoidal rule's error on 64 nodes down to ν = 1)."""

NU_RANGE = (1.0, 200.0)
"""The prior range of the Student-t tail index ν (ν = 1: Cauchy-like tails; 200: Gaussian to
within the noise of any lobe measured here)."""

TAIL_START = (0.1, 5.0)
"""The start of a mixture increment's tail weight w and variance ratio f (``increments="mixture"``): on the real files
of tests/data the fits end at w from 0.001 to 0.33 and f from 2 to the prior's 1e4 (experiments/bench_increments.py's
table in docs/benchmarks.md)."""

_TAIL_BOUNDS = ((-12.0, 4.0), (math.log(0.05), math.log(1e4)))
"""The prior box of ``logit w`` (w from 6e-6 to 0.98) and ``log f-1`` (f from 1.05 to 1e4)."""

_HALF_MAX_FACTOR = 2 / math.log(2)
"""A Gaussian of covariance C exceeds half its peak on the ellipse ``dᵀC⁻¹d ≤ 2 ln 2``; the uniform
distribution on an ellipse ``dᵀC⁻¹d ≤ r²`` has covariance ``C r²/4``, so ``C = (2/ln 2) ·
(covariance of the pixel offsets above half the peak)``."""


def image_moments(data: Dataset) -> tuple[np.ndarray, np.ndarray]:
    """Centre (K, 2) and covariance (K, 2, 2) of the measured lobe at each scale, from the pixels
    above half the peak (:data:`_HALF_MAX_FACTOR`), averaged over a scale's images: the
    anisotropic starting point. A covariance smaller than one pixel² is floored at it."""
    n_scales = data.scales.shape[0]
    centre, cov, count = np.zeros((n_scales, 2)), np.zeros((n_scales, 2, 2)), np.zeros(n_scales)
    weights, values, offsets = (np.asarray(x) for x in (data.weight, data.values, data.offsets))
    moments(data)  # the same refusal of an image without a positive valid pixel
    for i, k in enumerate(data.scale_of_image):
        n, a = data.image_sizes[i], data.extents[i]
        v = np.where(weights[i, : n * n] > 0, values[i, : n * n], -np.inf)
        above = v > v.max() / 2
        u = offsets[i, : n * n][above]
        pixel2 = (2 * a / (n - 1)) ** 2
        c = np.atleast_2d(np.cov(u.T, bias=True)) if len(u) > 1 else np.zeros((2, 2))
        centre[k] += u.mean(axis=0)
        cov[k] += _HALF_MAX_FACTOR * c + pixel2 / 12 * np.eye(2)
        count[k] += 1
    return centre / count[:, None], cov / count[:, None, None]


def _spd(matrix: np.ndarray, floor: float) -> np.ndarray:
    """A symmetric matrix with its eigenvalues floored at ``floor``."""
    w, v = np.linalg.eigh(0.5 * (matrix + matrix.T))
    return (v * np.maximum(w, floor)) @ v.T


def _cholesky_coordinates(matrix: np.ndarray, floor: float) -> tuple[float, float, float]:
    """``(log L_xx, L_yx, log L_yy)`` of a symmetric matrix with its eigenvalues floored at ``floor``."""
    L = np.linalg.cholesky(_spd(matrix, floor))
    return math.log(L[0, 0]), float(L[1, 0]), math.log(L[1, 1])


_NU_START = 4.0
"""The starting tail index of a Student-t base lobe (between GGX's 2 and the Gaussian)."""


def _mixture_density(
    d: Float[Array, "n 2"],
    factor: Float[Array, " j"],
    scale: Float[Array, " j"],
    weight: Float[Array, " j"],
    c0: Float[Array, "2 2"],
    delta: Float[Array, "2 2"],
) -> Float[Array, " n"]:
    """``Σ_j w_j N(d; 0, c_j C0 + s_j ΔΣ)`` (the Gaussian written out: one 2 × 2 determinant and
    inverse per component); a component whose covariance is not positive definite counts 0."""
    cov = factor[:, None, None] * c0 + scale[:, None, None] * delta
    # a component whose covariance is not positive definite (ΔΣ far below zero) contributes nothing: computed with a
    # valid stand-in (c_j C0) so that neither its value nor its gradient is NaN, then weighted 0 (module docstring)
    valid = (cov[:, 0, 0] > 0) & (cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] ** 2 > 0)
    cov = jnp.where(valid[:, None, None], cov, factor[:, None, None] * c0)
    a, b, c = cov[:, 0, 0, None], cov[:, 0, 1, None], cov[:, 1, 1, None]
    det = a * c - b * b
    x, y = d[None, :, 0], d[None, :, 1]
    q = (c * x * x - 2 * b * x * y + a * y * y) / det
    weight = jnp.where(valid, weight, 0.0)
    return jnp.sum(weight[:, None] * jnp.exp(-0.5 * q) / (2 * jnp.pi * jnp.sqrt(det)), axis=0)


def _from_cholesky(log_xx, yx, log_yy) -> Float[Array, "2 2"]:
    """``L Lᵀ`` with ``L = [[e^{log_xx}, 0], [yx, e^{log_yy}]]``."""
    a, c = jnp.exp(log_xx), jnp.exp(log_yy)
    return jnp.stack([jnp.stack([a * a, a * yx]), jnp.stack([a * yx, yx * yx + c * c])])


class AbstractCovarianceModel(AbstractModel):
    """A model whose scales differ by covariance differences ``ΔΣ_k = Σ(μ0) − Σ(μ_k)`` of the slope statistics
    (:meth:`covariance_differences`), so its relative statistics are ``R_k(W) = S(W, μ0)/S(W, μ_k) =
    exp(−½ Wᵀ ΔΣ_k W)`` (seed Eq. 4.4: Gaussian statistics' covariances add): :class:`AnisotropicModel` and
    :class:`fitting.AnisotropicLawModel`, which share these two methods here."""

    @abc.abstractmethod
    def covariance_differences(self, theta: Float[Array, " n"], scales: Float[Array, " k"]) -> Float[Array, "k 2 2"]:
        """``ΔΣ(μ0, μ_k)`` at each scale."""

    def increment_mixture(self, theta: Float[Array, " n"]) -> tuple[Float[Array, " i"], Float[Array, " i"]]:
        """``(v_i, s_i)``: the change between μ0 and μ_k is ``Σ_i v_i N(0, s_i ΔΣ_k)`` with ``Σ v_i s_i = 1``
        (its covariance is ΔΣ_k). Here one Gaussian, ``(1,), (1,)``; :class:`AnisotropicModel` with
        ``increments="mixture"`` two (module docstring)."""
        one = jnp.ones(1, jnp.asarray(theta).dtype)
        return one, one

    def relative_statistics(self, theta, W, scales):
        """``R_k`` at radii ``|W|`` (W of shape (w,)): for an anisotropic ΔΣ_k the geometric mean of
        ``R_k`` over the directions of the circle |W|, ``exp(−¼ |W|² tr ΔΣ_k)`` (the mean of
        ``Wᵀ ΔΣ W`` over directions is ``½ |W|² tr ΔΣ``), taken per component of a mixture increment
        (:meth:`increment_mixture`) and mixed; for an isotropic ΔΣ it is ``R_k`` itself.
        :meth:`relative_statistics_plane` gives ``R_k`` over the W plane."""
        differences = self.covariance_differences(theta, scales)
        trace = differences[:, 0, 0] + differences[:, 1, 1]
        weight, scale = self.increment_mixture(theta)
        exponent = -0.25 * scale[:, None, None] * trace[None, :, None] * jnp.asarray(W)[None, None, :] ** 2
        return jnp.sum(weight[:, None, None] * jnp.exp(exponent), axis=0)

    def relative_statistics_plane(
        self, theta: Float[Array, " n"], W: Float[Array, "w 2"], scales: Float[Array, " k"]
    ) -> Float[Array, "k w"]:
        """``R_k(W) = S(W, μ0)/S(W, μ_k) = Σ_i v_i exp(−½ s_i Wᵀ ΔΣ_k W)`` at points ``W`` of the plane (one term,
        ``exp(−½ Wᵀ ΔΣ_k W)``, for Gaussian increments: :meth:`increment_mixture`)."""
        W = jnp.asarray(W)
        quadratic = jnp.einsum("wi,kij,wj->kw", W, self.covariance_differences(theta, scales), W)
        weight, scale = self.increment_mixture(theta)
        return jnp.sum(weight[:, None, None] * jnp.exp(-0.5 * scale[:, None, None] * quadratic[None]), axis=0)


class AnisotropicModel(AbstractCovarianceModel):
    """Base lobe of full scale matrix and free mean at μ0 — Gaussian, GGX or Student-t — with a
    covariance difference ΔΣ_k per coarser scale (module docstring).

    Args:
        n_scales: the number of measured scales K (≥ 2; the model has a covariance per scale).
        isotropic: the isotropic, centred special case (module docstring).
        centred: hold the lobe's centre at the origin (no ``mean_x``, ``mean_y`` in θ).
        shape: the base lobe's shape, a name of :data:`brdfscale.choices.SHAPES`: ``"gaussian"``
            (default), ``"ggx"`` (Student-t, ν = 2) or ``"student_t"`` (free ν, θ's last coordinate).
        increments: the change between scales, a name of :data:`brdfscale.choices.INCREMENTS`: ``"gaussian"``
            (default) or ``"mixture"`` (heavy-tailed: ``logit w``, ``log f-1`` before ν; module docstring).

    Raises:
        InvalidInputError: ``n_scales`` not an integer ≥ 2; an unknown ``shape`` or ``increments``.
    """

    n_scales: int = eqx.field(static=True)
    isotropic: bool = eqx.field(static=True)
    centred: bool = eqx.field(static=True)
    shape: str = eqx.field(static=True)
    increments: str = eqx.field(static=True)
    preferred_solver: ClassVar[str] = "lm_normal"

    def __init__(
        self,
        n_scales: int,
        *,
        isotropic: bool = False,
        centred: bool = False,
        shape: str = MODEL.shape,
        increments: str = MODEL.increments,
    ):
        self.n_scales = integer(n_scales, "n_scales", 2)
        if not isinstance(isotropic, bool) or not isinstance(centred, bool):
            raise InvalidInputError(f"isotropic and centred must be True or False; got {isotropic!r} and {centred!r}.")
        self.isotropic, self.centred = isotropic, centred or isotropic
        self.shape = SHAPES.check(shape)
        self.increments = INCREMENTS.check(increments)

    @property
    def tail_names(self) -> tuple[str, ...]:
        """The coordinates at θ's end, after the base lobe and the increments: the mixture increment's (``logit w``,
        ``log f-1``) and the tail index's (``log nu``, last), each where the model has it."""
        mixture = ("logit w", "log f-1") if self.increments == "mixture" else ()
        return mixture + (("log nu",) if self.shape == "student_t" else ())

    @property
    def names(self) -> tuple[str, ...]:
        tail = self.tail_names
        if self.isotropic:
            return ("log amplitude", "log v0", *(f"log v{k}" for k in range(1, self.n_scales)), *tail)
        base = ("log amplitude", "log L0_xx", "L0_yx", "log L0_yy")
        mean = () if self.centred else ("mean_x", "mean_y")
        steps = tuple(n for k in range(1, self.n_scales) for n in (f"log L{k}_xx", f"L{k}_yx", f"log L{k}_yy"))
        return base + mean + steps + tail

    def tail_index(self, theta: Float[Array, " n"]) -> Float[Array, ""] | None:
        """ν of a Student-t or GGX lobe (None: Gaussian)."""
        if self.shape == "gaussian":
            return None
        return jnp.exp(jnp.asarray(theta)[-1]) if self.shape == "student_t" else jnp.asarray(2.0)

    @property
    def radial(self) -> bool:
        return self.isotropic

    @property
    def identifiability_notes(self) -> tuple[str, ...]:
        return (
            "The data determine the base lobe at μ0 (amplitude, covariance, centre) and the covariance "
            "differences ΔΣ(μ0, μk) = Σ(μ0) − Σ(μk) only; no absolute Σ(μ) is claimed (it would need the "
            "boundary condition S(W, ∞) = 1 of a scale law).",
        )

    def parts(self, theta: Float[Array, " n"]) -> tuple:
        """``(A, C0 (2, 2), m0 (2,), ΔΣ (K, 2, 2))`` of θ: ``ΔΣ_k = C_k − C0``, ``ΔΣ[0] = 0`` exactly."""
        theta = jnp.asarray(theta)
        theta = theta[: theta.shape[0] - len(self.tail_names)]  # w, f: increment_mixture; ν: tail_index
        amplitude = jnp.exp(theta[0])
        eye = jnp.eye(2, dtype=theta.dtype)
        if self.isotropic:
            variances = jnp.exp(theta[1:])  # v0, v_1 … v_{K−1}
            c0 = variances[0] * eye
            differences = (variances - variances[0])[:, None, None] * eye
            mean = jnp.zeros(2, theta.dtype)
        else:
            start = 4 if self.centred else 6
            mean = jnp.zeros(2, theta.dtype) if self.centred else theta[4:6]
            factors = jnp.concatenate([theta[1:4], theta[start:]]).reshape(self.n_scales, 3)
            covariances = jax.vmap(_from_cholesky)(factors[:, 0], factors[:, 1], factors[:, 2])  # C_k
            c0 = covariances[0]
            differences = covariances - c0
        return amplitude, c0, mean, differences

    def increment_mixture(self, theta: Float[Array, " n"]) -> tuple[Float[Array, " i"], Float[Array, " i"]]:
        """``(v_i, s_i)`` of the change between scales (:meth:`AbstractCovarianceModel.increment_mixture`):
        ``((1 − w, w), (s_c, s_t))`` for ``increments="mixture"`` (module docstring), one Gaussian otherwise."""
        if self.increments == "gaussian":
            return super().increment_mixture(theta)
        theta = jnp.asarray(theta)
        i = theta.shape[0] - len(self.tail_names)
        w, f = jax.nn.sigmoid(theta[i]), 1 + jnp.exp(theta[i + 1])
        core = 1 / (1 - w + w * f)
        return jnp.stack([1 - w, w]), jnp.stack([core, f * core])

    @property
    def start_widening(self) -> float:
        """ΔΣ over the widening the half-maximum moments of the images show, at the start (:meth:`initial`, and
        :meth:`fitting.AnisotropicLawModel.initial`): those moments see the core of a mixture increment, ``s_c ΔΣ``,
        so ΔΣ starts at ``1/s_c = 1 − w + w f`` of them (:data:`TAIL_START`); 1 for Gaussian increments."""
        if self.increments == "gaussian":
            return 1.0
        w, f = TAIL_START
        return 1 - w + w * f

    def covariance_differences(self, theta: Float[Array, " n"], scales: Float[Array, " k"]) -> Float[Array, "k 2 2"]:
        """ΔΣ(μ0, μ_k) for every measured scale (row 0 is 0): exact, from θ."""
        del scales  # one increment per measured scale: the layout fixes them
        return self.parts(theta)[3]

    def base_lobe(self, theta) -> lobes.AbstractLobe:
        """The lobe at μ0: ``A · N(m0, C0)``, or ``A · t_ν(m0, C0)`` (Student-t, GGX)."""
        amplitude, c0, mean, _ = self.parts(theta)
        mean = None if self.centred else mean
        nu = self.tail_index(theta)
        shape = stats.Gaussian(cov=c0, mean=mean) if nu is None else stats.StudentT(cov=c0, nu=nu, mean=mean)
        return lobes.Lobe(shape, amplitude)

    def quantities(self, theta):
        """Amplitude, the base lobe's covariance (Gaussian) or scale matrix (Student-t, GGX)
        ``C0_*``, its centre, (mixture increments) the tail weight ``w_tail`` and variance ratio ``f_tail`` and
        (Student-t) ν."""
        amplitude, c0, mean, _ = self.parts(theta)
        values = {"amplitude": amplitude, "C0_xx": c0[0, 0], "C0_xy": c0[0, 1], "C0_yy": c0[1, 1]}
        if not self.centred:
            values.update(mean_x=mean[0], mean_y=mean[1])
        if self.increments == "mixture":
            weight, scale = self.increment_mixture(theta)
            values.update(w_tail=weight[1], f_tail=scale[1] / scale[0])
        if self.shape == "student_t":
            values["nu"] = self.tail_index(theta)
        return values

    def predict_points(self, theta, scales, points):
        return self.predict_with(theta, self.parts(theta)[3], points)

    def predict_with(
        self, theta: Float[Array, " n"], differences: Float[Array, "k 2 2"], points: Float[Array, "k p 2"]
    ) -> Float[Array, "k p"]:
        """θ's base lobe at ``points[0]`` and, for k ≥ 1, evolved by the covariance differences
        ``differences[k]`` (C0 + ΔΣ_k positive definite; a scale mixture's components: :func:`_mixture_density`) at
        ``points[k]``; θ's own increments are not used (shared with
        :class:`fitting.AnisotropicLawModel`, whose ΔΣ follow a scale law)."""
        # the base lobe at μ0; at μ_k the evolution by the relative statistics R_k = exp(−½ Wᵀ ΔΣ_k W)
        base = self.base_lobe(theta)
        amplitude, c0, mean, _ = self.parts(theta)
        if self.shape == "gaussian" and self.increments == "gaussian":
            # brdfscale.evolve(lobe, N(0, ΔΣ_k), δ)'s closed form: covariance C0 + ΔΣ_k
            coarser = jax.vmap(
                lambda d, u: evolve(
                    base, stats.Gaussian(cov=d), stats.Delta(), method="closed_form", check=False
                ).density(u)
            )(differences[1:], points[1:])
        else:  # the scale mixtures of the module docstring: every pair of a lobe's and an increment's components
            nu = self.tail_index(theta)
            if nu is None:
                factor = weight = jnp.ones(1, c0.dtype)
            else:
                factor, weight = stats.StudentT(cov=c0, nu=nu).gaussian_mixture(MIXTURE_NODES, MIXTURE_CUTOFF)
            v, s = self.increment_mixture(theta)
            factor, scale = jnp.repeat(factor, s.shape[0]), jnp.tile(s, factor.shape[0])
            weight = (weight[:, None] * v[None, :]).reshape(-1)
            coarser = jax.vmap(lambda d, u: amplitude * _mixture_density(u - mean, factor, scale, weight, c0, d))(
                differences[1:], points[1:]
            )
        return jnp.concatenate([base.density(points[0])[None], coarser])

    def initial(self, data):
        """From the pixels above half the peak (:func:`image_moments`); a heavy-tailed base lobe
        starts at ν = :data:`_NU_START` with the scale matrix whose half-maximum ellipse is the
        measured one (``(1 + q/ν)^{−(ν+2)/2} = ½`` at ``q = ν(2^{2/(ν+2)} − 1)`` against the
        Gaussian's ``q = 2 ln 2``)."""
        centre, measured = image_moments(data)
        nu = {"gaussian": None, "ggx": 2.0, "student_t": _NU_START}[self.shape]
        c0 = measured[0].copy()
        if nu is not None:
            c0 *= 2 * math.log(2) / (nu * (2 ** (2 / (nu + 2)) - 1))
        tail = [math.log(_NU_START)] if self.shape == "student_t" else []
        if self.increments == "mixture":
            w, f = TAIL_START
            tail = [math.log(w / (1 - w)), math.log(f - 1), *tail]
        pixel2 = min((2 * a / (n - 1)) ** 2 for a, n in zip(data.extents, data.image_sizes))
        floor = max(pixel2 / 12, 1e-30)
        amp, _ = moments(data)
        # ΔΣ_k starts at the positive part of the widening the half-maximum moments show (a mixture increment's ΔΣ
        # exceeds its core's: × start_widening), so that C_k = C0 + ΔΣ_k is positive definite
        change = measured - measured[0]
        w, v = np.linalg.eigh(0.5 * (change + np.swapaxes(change, 1, 2)))
        widening = np.einsum("kij,kj,klj->kil", v, np.maximum(w, 0), v) * self.start_widening
        if self.isotropic:
            var = np.trace(c0) / 2 + np.trace(widening, axis1=1, axis2=2) / 2
            return np.concatenate([[math.log(amp)], np.log(np.maximum(var[: self.n_scales], floor)), tail])
        c0 = _spd(c0, floor)
        theta = [math.log(amp), *_cholesky_coordinates(c0, floor)]
        if not self.centred:
            theta += list(centre[0])
        for k in range(1, self.n_scales):
            theta += _cholesky_coordinates(c0 + widening[k], floor)
        return np.asarray(theta + tail)

    def start_scales(self, theta0):
        """The jitter of the starts (:meth:`fitting.AbstractModel.start_scales`) in the lobe's own
        units: 1 for the logarithms (a relative change of every width, of A and ν); the centre
        by the base lobe's standard deviation along each axis, ``√C0_xx``, ``√C0_yy``; each
        Cholesky off-diagonal ``L_yx`` by its factor's ``L_yy`` (a shear of the ellipse
        relative to its width). Unscaled, a spread of 0.5 moved the centre by half the slope
        range — off a lobe 0.05 wide, where no solver finds its way back (7 of 8 starts of
        experiments/bench_anisotropic.py's set ran to ``max_steps`` at χ² 130 × the optimum's)."""
        theta0 = np.asarray(theta0, dtype=float)
        scales = np.ones_like(theta0)
        if self.isotropic:
            return scales
        c0 = np.asarray(_from_cholesky(*theta0[1:4]))
        scales[2] = math.exp(theta0[3])
        start = 4
        if not self.centred:
            scales[4:6] = np.sqrt(np.diag(c0))
            start = 6
        for k in range(self.n_scales - 1):  # each scale's Cholesky factor as C0's
            i = start + 3 * k
            scales[i + 1] = math.exp(theta0[i + 2])
        return scales

    def bounds(self, data):
        """A uniform prior in θ: amplitude 1e-8 … 1e8; the Cholesky diagonals of C0 and of every C_k (standard
        deviations along an axis) 1e-6 … 10 in slope units, their off-diagonals ±10; the centre inside the
        largest image; (isotropic) variances 1e-12 … 100; (mixture increments) w from 6e-6 to 0.98, f from 1.05
        to 1e4; (Student-t) ν in :data:`NU_RANGE`."""
        extent = max(data.extents)
        amp, sd = (math.log(1e-8), math.log(1e8)), (math.log(1e-6), math.log(10.0))
        tail_lo, tail_hi = ([math.log(NU_RANGE[0])], [math.log(NU_RANGE[1])]) if self.shape == "student_t" else ([], [])
        if self.increments == "mixture":
            tail_lo, tail_hi = [b[0] for b in _TAIL_BOUNDS] + tail_lo, [b[1] for b in _TAIL_BOUNDS] + tail_hi
        if self.isotropic:
            var = (2 * sd[0], 2 * sd[1])
            lo = [amp[0]] + [var[0]] * self.n_scales
            hi = [amp[1]] + [var[1]] * self.n_scales
            return np.asarray(lo + tail_lo), np.asarray(hi + tail_hi)
        chol_lo, chol_hi = [sd[0], -10.0, sd[0]], [sd[1], 10.0, sd[1]]
        lo, hi = [amp[0], *chol_lo], [amp[1], *chol_hi]
        if not self.centred:
            lo += [-extent, -extent]
            hi += [extent, extent]
        lo += chol_lo * (self.n_scales - 1)
        hi += chol_hi * (self.n_scales - 1)
        return np.asarray(lo + tail_lo), np.asarray(hi + tail_hi)

    def check_data(self, data: Dataset) -> None:
        """Also: the dataset has this model's number of scales."""
        super().check_data(data)
        if data.scales.shape[0] != self.n_scales:
            raise InvalidInputError(
                f"the model was built for {self.n_scales} scales but the data have {data.scales.shape[0]} "
                f"(μ = {np.asarray(data.scales).tolist()}); build it with AnisotropicModel(len(data.scales))."
            )
