"""Forward maps from unconstrained parameter vectors θ to predicted lobe images.

Every model predicts, for each measured scale μ_k, the lobe ``A·g_{μ_k}(u)`` at the pixel
offsets of the dataset through the core evolution operator (seed Eq. 4.4, docs/conventions.md §2)

    G(W, μ_k) = G(W, μ0) · S(W, μ0) / S(W, μ_k),

with μ0 the finest measured scale. θ lives in ℝⁿ; each model maps it onto the valid
domain of its physical quantities (logarithms for positive quantities, softplus for
non-negative increments), so optimisers and samplers need no bounds.

* :class:`ParametricModel` — base lobe family (Beckmann or GGX: width ``alpha_lobe`` and
  amplitude ``A`` at μ0) and statistics family (Beckmann or GGX) whose width follows
  :class:`brdfscale.stats.WidthLaw` ``α(μ) = alpha_max (1 + (μ/mu_c)²)^{−exponent/2}``.
  The law tends to δ as μ → ∞, which supplies the boundary condition ``S(W, ∞) = 1`` that
  multi-scale data alone cannot (docs/conventions.md §2).
* :class:`NonParametricModel` — a tabulated base lobe at μ0 and, for each coarser scale, the
  *relative statistics* ``r_k`` defined by ``s(μ0) = r_k ∗ s(μ_k)``, i.e.
  ``R_k(W) = S(W, μ0)/S(W, μ_k) = exp(−D_k(|W|))`` on a radial W grid: exactly the
  combinations the data determine. Positivity (``R_k > 0``), monotone decay in |W|,
  monotone ordering in μ (``D_{k+1} ≥ D_k``) are built into the parameterisation,
  smoothness is a Gaussian prior on second differences (extra residual rows).
"""

import abc
import math
from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from brdfscale import InvalidInputError, MeasurementSet, MethodNotApplicableError, evolve, lobes, stats
from brdfscale.special import j0

from brdfscale.checks import integer, real
from brdfscale.show import Shown
from ._data import Dataset

__all__ = ["AbstractModel", "ParametricModel", "NonParametricModel", "RelativeStatistics"]

_LOBES = {"beckmann": lobes.Beckmann, "ggx": lobes.GGX}
_STATISTICS = {"beckmann": stats.Beckmann, "ggx": stats.GGX}


def _moments(data: Dataset) -> tuple[float, np.ndarray]:
    """Robust amplitude and width² of the measured lobe at each scale (for starting points).

    For a Gaussian lobe ``A exp(−|u|²/α²)/(π α²)`` the area where the lobe exceeds half its
    peak is ``π α² ln 2``; that gives α², and the amplitude is ``peak · π α²``. Pixels below
    half the peak (where the noise lives) do not enter.

    Raises:
        InvalidInputError: an image has no positive valid pixel (no lobe to measure).
    """
    n_scales = data.scales.shape[0]
    amp, width2, count = np.zeros(n_scales), np.zeros(n_scales), np.zeros(n_scales)
    for i, k in enumerate(data.scale_of_image):
        n, a = data.image_sizes[i], data.extents[i]
        valid = np.asarray(data.weight[i, : n * n]) > 0
        v = np.where(valid, np.asarray(data.values[i, : n * n]), -np.inf)
        peak = v.max()
        if not peak > 0:
            raise InvalidInputError(
                f"image {i} (μ = {float(data.scales[k]):g}) has no positive valid pixel (largest value {peak:g}); "
                "a lobe image must be positive where the lobe is, or no amplitude and width can be estimated."
            )
        area = np.count_nonzero(v > peak / 2) * (2 * a / (n - 1)) ** 2
        w2 = max(area, (2 * a / (n - 1)) ** 2) / (math.pi * math.log(2))
        width2[k] += w2
        amp[k] += peak * math.pi * w2
        count[k] += 1
    return float(np.mean(amp / count)), width2 / count


class AbstractModel(Shown, eqx.Module):
    """A forward map θ ↦ predicted images, with names, a prior box and starting points."""

    _show_hidden = ("smoothness_choice", "knots")

    @property
    @abc.abstractmethod
    def names(self) -> tuple[str, ...]:
        """Names of the unconstrained coordinates θ_i (e.g. ``"log alpha_lobe"``)."""

    @property
    @abc.abstractmethod
    def radial(self) -> bool:
        """Whether every predicted lobe is radially symmetric (then it depends on |u| only)."""

    @abc.abstractmethod
    def predict_points(
        self, theta: Float[Array, " n"], scales: Float[Array, " n_scales"], points: Float[Array, "n_scales n_points 2"]
    ) -> Float[Array, "n_scales n_points"]:
        """The lobe at ``scales[k]`` evaluated at the offsets ``points[k]`` (``scales[0]`` = μ0).

        ``scales`` ascend (``scales[0]`` the finest, as :class:`~fitting.Dataset` orders them):
        models evolve from μ0 towards coarser scales and may rely on it (ParametricModel
        leaves out the run-time existence check, which holds only in that direction)."""

    def predict(self, theta: Float[Array, " n"], data: Dataset) -> Float[Array, "n_img n_pix"]:
        """The predicted lobe at every pixel of every image (padding pixels: anything)."""
        n_scales, n_pix = data.scales.shape[0], data.values.shape[1]
        groups = [data.images_of_scale(k) for k in range(n_scales)]
        n = max(len(g) for g in groups) * n_pix
        points = jnp.stack([jnp.pad(data.offsets[jnp.asarray(g)].reshape(-1, 2), ((0, n - len(g) * n_pix), (0, 0)))
                            for g in groups])
        if self.radial:
            points = jnp.stack([jnp.linalg.norm(points, axis=-1), jnp.zeros(points.shape[:-1])], axis=-1)
        values = self.predict_points(theta, data.scales, points)
        rows = {i: values[k, j * n_pix:(j + 1) * n_pix] for k, g in enumerate(groups) for j, i in enumerate(g)}
        return jnp.stack([rows[i] for i in range(len(data.scale_of_image))])

    @abc.abstractmethod
    def quantities(self, theta: Float[Array, " n"]) -> dict[str, Float[Array, ""]]:
        """The physical quantities of θ by name (what a report prints)."""

    @abc.abstractmethod
    def initial(self, data: Dataset) -> np.ndarray:
        """A data-driven starting point θ0."""

    @abc.abstractmethod
    def bounds(self, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
        """The prior support ``lo ≤ θ ≤ hi`` (a uniform prior in θ; see docs/fitting.md)."""

    @abc.abstractmethod
    def relative_statistics(self, theta: Float[Array, " n"], W: Float[Array, " w"], data: Dataset) -> Float[Array, "k w"]:
        """``S(W, μ0)/S(W, μ_k)`` for every measured scale (row 0 is 1): the data-determined part."""

    @property
    @abc.abstractmethod
    def identifiability_notes(self) -> tuple[str, ...]:
        """What the model assumes to make absolute quantities determinable (docs/conventions.md §2)."""

    def penalty(self, theta: Float[Array, " n"]) -> Float[Array, " m"]:
        """Whitened prior residuals appended to the data residuals (none by default)."""
        return jnp.zeros((0,), dtype=theta.dtype)

    def check_data(self, data: Dataset) -> None:
        """Raise :class:`~brdfscale.InvalidInputError` unless ``data`` is a :class:`~fitting.Dataset`
        this model can be fitted to (a model built from one dataset fixes its layout)."""
        require_dataset(data, f"{type(self).__name__}.check_data(data)")


def require_dataset(data, where: str) -> None:
    """InvalidInputError naming ``where`` unless ``data`` is a :class:`~fitting.Dataset`."""
    if not isinstance(data, Dataset):
        hint = (" (build one with fitting.Dataset.from_measurements(measurement_set))"
                if isinstance(data, MeasurementSet) else "")
        raise InvalidInputError(f"{where}: data must be a fitting.Dataset{hint}; got {type(data).__name__}.")


@eqx.filter_jit
def predict_images(model: AbstractModel, theta: Float[Array, " n"], data: Dataset) -> Float[Array, "n_img n_pix"]:
    """``model.predict(theta, data)``, compiled once per model and data layout."""
    return model.predict(theta, data)


class ParametricModel(AbstractModel):
    """Parametric lobe + statistics family with a scale law (see the module docstring).

    Args:
        lobe: ``"beckmann"`` or ``"ggx"``: the family of the base lobe at μ0.
        statistics: ``"beckmann"`` or ``"ggx"``: the family of the facet-slope density s(·, μ).
        law: ``"width"`` — :class:`brdfscale.stats.WidthLaw` for the family's width α(μ);
            ``"gaussian_surface"`` — Beckmann statistics of a Gaussian-correlated random
            surface with a ``window`` facet window (:class:`brdfscale.stats.GaussianSurface`
            of a :class:`~brdfscale.stats.GaussianCorrelation` spectrum: Σ(μ) of docs/conventions.md §2
            in closed form).
        fixed: physical parameters held at given values (e.g. ``{"mu_c": 1.0}``) — the way
            to supply prior knowledge that the data lack.
        radial_nodes: Gauss–Legendre nodes of the radial evolution path (used whenever GGX is
            involved; Beckmann with Beckmann has a closed form); an integer ≥ 8.

    Parameters (all positive, θ = their logarithms): ``amplitude`` A (the lobe's integral
    over u), ``alpha_lobe`` (base-lobe width at μ0), and for ``law="width"``: ``alpha_max``,
    ``mu_c`` (length units of μ), ``exponent``; for ``law="gaussian_surface"``:
    ``rms_height`` and ``correlation_length`` (length units of μ).
    """

    lobe: str = eqx.field(static=True)
    statistics: str = eqx.field(static=True)
    law_kind: str = eqx.field(static=True)
    window: str = eqx.field(static=True)
    fixed: tuple[tuple[str, float], ...] = eqx.field(static=True)
    radial_nodes: int = eqx.field(static=True)

    _LAWS = {
        "width": ("amplitude", "alpha_lobe", "alpha_max", "mu_c", "exponent"),
        "gaussian_surface": ("amplitude", "alpha_lobe", "rms_height", "correlation_length"),
    }

    def __init__(self, lobe: str = "beckmann", statistics: str = "beckmann", *, law: str = "width",
                 fixed: dict | None = None, window: str = "box", radial_nodes: int = 96):
        if lobe not in _LOBES:
            raise InvalidInputError(f"lobe must be one of {sorted(_LOBES)}; got {lobe!r}.")
        if statistics not in _STATISTICS:
            raise InvalidInputError(f"statistics must be one of {sorted(_STATISTICS)}; got {statistics!r}.")
        if law not in self._LAWS:
            raise InvalidInputError(f"law must be one of {sorted(self._LAWS)}; got {law!r}.")
        if law == "gaussian_surface" and (lobe, statistics) != ("beckmann", "beckmann"):
            raise InvalidInputError("law='gaussian_surface' gives Gaussian (Beckmann) statistics; use lobe='beckmann'.")
        if window not in ("box", "gaussian"):
            raise InvalidInputError(f"window must be 'box' or 'gaussian'; got {window!r}.")
        parameters = self._LAWS[law]
        fixed = dict(fixed or {})
        for name, value in fixed.items():
            if name not in parameters:
                raise InvalidInputError(f"cannot fix unknown parameter {name!r}; the parameters are {parameters}.")
            real(value, f"fixed value of {name}", minimum=0.0, strict=True)
        if len(fixed) == len(parameters):
            raise InvalidInputError("every parameter is fixed; leave at least one free.")
        self.lobe, self.statistics, self.law_kind, self.window = lobe, statistics, law, window
        self.fixed = tuple(sorted((k, float(v)) for k, v in fixed.items()))
        self.radial_nodes = integer(radial_nodes, "radial_nodes", 8)

    @property
    def parameters(self) -> tuple[str, ...]:
        return self._LAWS[self.law_kind]

    @property
    def free(self) -> tuple[str, ...]:
        fixed = dict(self.fixed)
        return tuple(p for p in self.parameters if p not in fixed)

    @property
    def names(self):
        return tuple(f"log {p}" for p in self.free)

    @property
    def identifiability_notes(self):
        limit = "width law's limit α(μ → ∞) = 0" if self.law_kind == "width" else "surface law's limit Σ(μ → ∞) = 0"
        return (
            "Multi-scale data determine the base lobe at μ0 and the ratios S(W, μ0)/S(W, μ_k) only. The "
            f"absolute S(W, μ) reported here rests on the {limit}, i.e. on the boundary condition "
            "S(W, ∞) = 1 being built into the model, not on a measurement.",
        )

    def quantities(self, theta):
        values = dict(zip(self.free, jnp.exp(theta)))
        values.update({k: jnp.asarray(v, dtype=theta.dtype) for k, v in self.fixed})
        return {p: values[p] for p in self.parameters}

    def theta_from(self, params: dict) -> np.ndarray:
        """θ of the physical parameters ``params`` (a dict with every free parameter; other
        keys are ignored).

        Raises:
            InvalidInputError: a free parameter is missing, or its value is not a positive,
                finite number (θ holds its logarithm).
        """
        if not isinstance(params, Mapping):
            raise InvalidInputError(f"params must be a dict of parameter values; got {type(params).__name__}.")
        missing = [p for p in self.free if p not in params]
        if missing:
            raise InvalidInputError(f"parameters {missing} are missing; need {self.free}.")
        values = []
        for p in self.free:
            try:
                value = float(params[p])
            except (TypeError, ValueError):
                raise InvalidInputError(f"parameter {p} must be a positive, finite number; got {params[p]!r}.") from None
            if not (math.isfinite(value) and value > 0):
                raise InvalidInputError(f"parameter {p} must be a positive, finite number (θ holds its "
                                        f"logarithm); got {params[p]!r}.")
            values.append(value)
        return np.log(values)

    def law(self, theta) -> stats.AbstractScaleLaw:
        """The scale law μ ↦ s(·, μ) at θ."""
        q = self.quantities(theta)
        if self.law_kind == "gaussian_surface":
            spectrum = stats.GaussianCorrelation(q["rms_height"], q["correlation_length"])
            return stats.GaussianSurface(spectrum, window=self.window)
        return stats.ScaledFamily(_STATISTICS[self.statistics], stats.WidthLaw(q["alpha_max"], q["mu_c"], q["exponent"]))

    def statistics_at(self, theta, mu) -> stats.AbstractSlopeDensity:
        """The facet-slope density ``s(·, μ)``."""
        return self.law(theta).at(mu)

    def base_lobe(self, theta) -> lobes.AbstractLobe:
        """The lobe at μ0."""
        q = self.quantities(theta)
        return _LOBES[self.lobe](q["alpha_lobe"], amplitude=q["amplitude"])

    def evolved(self, theta, mu0, mu) -> lobes.AbstractLobe:
        """The lobe at scale μ > μ0 evolved from the base lobe at μ0 (seed Eq. 4.4)."""
        return self._evolve(self.base_lobe(theta), self.statistics_at(theta, mu0), self.statistics_at(theta, mu))

    def _evolve(self, base, s0, s, check=True):
        if self.lobe == "beckmann" and self.statistics == "beckmann":
            return evolve(base, s0, s, method="closed_form", check=check)
        return evolve(base, s0, s, method="radial", size=self.radial_nodes, check=check)

    @property
    def radial(self):
        return True

    def predict_points(self, theta, scales, points):
        # the statistics of every scale in one batch (one evaluation of the scale law); k = 0
        # is the identity (the radial path would form 0/0 where S(W, μ0) underflows); the
        # coarser scales share one vectorised evolution. Both laws' slope widths decrease
        # with μ (tests/test_fit.py checks it over the prior box), so a lobe exists at every
        # coarser scale and the evolution's run-time existence check is left out (check=False).
        base = self.base_lobe(theta)
        statistics = jax.vmap(lambda mu: self.statistics_at(theta, mu))(scales)
        s0 = jax.tree.map(lambda leaf: leaf[0], statistics)
        coarser_statistics = jax.tree.map(lambda leaf: leaf[1:], statistics)
        coarser = jax.vmap(lambda s, u: self._evolve(base, s0, s, check=False).density(u))(coarser_statistics, points[1:])
        return jnp.concatenate([base.density(points[0])[None], coarser])

    def relative_statistics(self, theta, W, data):
        s0 = self.statistics_at(theta, data.scales[0]).cf_radial(W)
        return jnp.stack([s0 / self.statistics_at(theta, mu).cf_radial(W) for mu in data.scales])

    def initial(self, data):
        amp, width2 = _moments(data)
        # the half-maximum width of a GGX lobe is that of a Beckmann lobe with 0.77 α
        factor = 1.0 if self.lobe == "beckmann" else 1.3
        alpha_lobe = factor * math.sqrt(width2[0])
        spread = max(float(width2[-1] - width2[0]), 1e-6 * width2[0])
        alpha_s = 1.5 * math.sqrt(spread)
        mid = math.sqrt(float(data.scales[0]) * float(data.scales[-1]))
        # Gaussian correlation: α_s² = 2·(2σ_h²/ℓ²) unwindowed, so σ_h = ℓ α_s / 2
        start = {"amplitude": amp, "alpha_lobe": alpha_lobe, "alpha_max": alpha_s, "mu_c": mid, "exponent": 1.0,
                 "correlation_length": mid, "rms_height": mid * alpha_s / 2}
        return self.theta_from(start)

    def box(self, data) -> dict[str, tuple[float, float]]:
        """The prior box of every parameter (fixed ones included), in physical units: a
        uniform prior in log θ between the two values (docs/fitting.md)."""
        mu0, mu1 = float(data.scales[0]), float(data.scales[-1])
        return {
            "amplitude": (1e-8, 1e8),
            "alpha_lobe": (1e-4, 10.0),
            "alpha_max": (1e-4, 10.0),
            "mu_c": (mu0 * 1e-3, mu1 * 1e3),
            "exponent": (0.05, 10.0),
            "rms_height": (mu0 * 1e-8, mu1 * 1e2),
            "correlation_length": (mu0 * 1e-2, mu1 * 1e2),
        }

    def check_data(self, data: Dataset) -> None:
        """Also: every fixed value lies inside its prior box (:meth:`box`), where the model is
        defined and tested; InvalidInputError naming the parameter and its box otherwise."""
        super().check_data(data)
        box = self.box(data)
        for name, value in self.fixed:
            lo, hi = box[name]
            if not lo <= value <= hi:
                raise InvalidInputError(f"fixed {name} = {value:g} lies outside its prior box [{lo:g}, {hi:g}] for "
                                        f"these data (scales μ = {np.asarray(data.scales).tolist()}); fix it inside.")

    def bounds(self, data):
        box = self.box(data)
        lo = np.log([box[p][0] for p in self.free])
        hi = np.log([box[p][1] for p in self.free])
        return lo, hi


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
        t = jnp.where(self.decay[-1] >= level, jnp.interp(level, self.decay, tk), tk[-1] + (level - self.decay[-1]) / slope)
        return jnp.sqrt(t)


SMOOTHNESS_RULES = ("auto", "gcv")
DEFAULT_SMOOTHNESS = 3.0
SMOOTHNESS_CANDIDATES = tuple(np.logspace(-2.0, 3.0, 31).tolist())
"""The smoothness weights :func:`choose_smoothness` compares (6 per decade)."""


def choose_smoothness(model: "NonParametricModel", data: Dataset, *, candidates=SMOOTHNESS_CANDIDATES,
                      max_steps: int = 300) -> tuple[float, tuple]:
    """The smoothness weight s of ``model`` chosen by generalised cross-validation.

    The fit minimises ``‖r(θ)‖² + s² ‖Δ²D(θ)‖²`` (whitened data residuals r, second
    differences of the decay D across knots). A pilot fit at the model's weight ``s0`` gives
    θ̂; about it the problem is linear: with the Jacobians ``J`` (data rows) and ``L`` (the
    second differences per unit weight) and the residuals ``r0``, ``p0`` there, one
    Gauss–Newton step for weight s,

        δ(s) = −(JᵀJ + s² LᵀL)⁺ (Jᵀr0 + s² Lᵀp0),

    predicts the data residual ``r0 + J δ`` and has the influence matrix
    ``A(s) = J (JᵀJ + s² LᵀL)⁺ Jᵀ``. The choice minimises

        GCV(s) = n χ²(s) / (n − tr A(s))²,   χ²(s) = ‖r0 + J δ(s)‖² + (within-pixel scatter),

    over ``candidates`` (n: the valid pixels). The linearisation is exact for a linear model
    and good near s0; one pilot fit suffices when the curvature of the model is mild
    (re-construct with ``regularisation=<the choice>`` and compare if in doubt).

    Returns ``(s, record)``: the choice and ``(candidates, GCV values, s0)`` as tuples.
    """
    from ._estimate import Problem, fit

    problem = Problem(model, data)
    pilot = fit(model, data, starts=1, max_steps=max_steps)
    theta = jnp.asarray(pilot.theta)
    jac = np.asarray(jax.jacfwd(problem.residuals)(theta))
    res = np.asarray(problem.residuals(theta))
    n_pen = len(np.asarray(model.penalty(theta)))
    s0 = model.smoothness
    J, r0 = jac[: len(res) - n_pen], res[: len(res) - n_pen]
    if n_pen == 0 or s0 == 0:
        return s0, (tuple(candidates), tuple(float("nan") for _ in candidates), s0)
    L, p0 = jac[len(res) - n_pen:] / s0, res[len(res) - n_pen:] / s0
    n = data.n_data
    offset = float(problem.points.chi2_offset)
    JtJ, LtL, Jtr, Ltp = J.T @ J, L.T @ L, J.T @ r0, L.T @ p0
    values = []
    for s in candidates:
        H = JtJ + s * s * LtL
        Hinv = np.linalg.pinv(H, rcond=1e-12, hermitian=True)
        delta = -Hinv @ (Jtr + s * s * Ltp)
        r = r0 + J @ delta
        trace = float(np.sum(Hinv * JtJ))  # tr(J H⁺ Jᵀ) = tr(H⁺ JᵀJ)
        values.append(n * (float(r @ r) + offset) / max(n - trace, 1e-12) ** 2)
    best = int(np.argmin(values))
    return float(candidates[best]), (tuple(float(c) for c in candidates), tuple(float(v) for v in values), float(s0))


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

    def __init__(self, data: Dataset, *, base_nodes: int = 13, base_extent: float | None = None,
                 n_knots: int = 8, w_max: float | None = None, smoothness: float | None = None,
                 regularisation: float | str | None = None, grid_size: int = 48):
        require_dataset(data, "NonParametricModel(data)")
        base_nodes = integer(base_nodes, "base_nodes", 3)
        n_knots = integer(n_knots, "n_knots", 2)
        grid_size = integer(grid_size, "grid_size", 8)
        if smoothness is not None and regularisation is not None:
            raise InvalidInputError("give the smoothness prior's weight once: regularisation= (a number or 'auto') or "
                                    "smoothness= (its earlier name), not both.")
        weight = regularisation if regularisation is not None else (3.0 if smoothness is None else smoothness)
        auto = isinstance(weight, str)
        if auto and weight not in SMOOTHNESS_RULES:
            raise InvalidInputError(f"regularisation must be a number ≥ 0 or one of {SMOOTHNESS_RULES} (generalised "
                                    f"cross-validation); got {weight!r}.")
        smoothness = DEFAULT_SMOOTHNESS if auto else real(weight, "regularisation" if regularisation is not None
                                                          else "smoothness", minimum=0.0)
        if base_extent is not None:
            base_extent = real(base_extent, "base_extent", minimum=0.0, strict=True)
        if w_max is not None:
            w_max = real(w_max, "w_max", minimum=0.0, strict=True)
        _, width2 = _moments(data)
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
            pilot = NonParametricModel(data, base_nodes=base_nodes, base_extent=self.base_extent, n_knots=n_knots,
                                       w_max=w_max, regularisation=DEFAULT_SMOOTHNESS, grid_size=grid_size)
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

    def decay(self, theta) -> Float[Array, "k J+1"]:
        """``D_k(W_j)`` for k = 0..K−1 (row 0 is zero), j = 0..J."""
        J = len(self.knots) - 1
        inc = jax.nn.softplus(theta[self._n_base:].reshape(self.n_scales - 1, J))
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

    def relative_statistics(self, theta, W, data):
        return jnp.stack([self.relative(theta, k).cf_radial(W) for k in range(self.n_scales)])

    def penalty(self, theta):
        d = self.decay(theta)[1:]
        return self.smoothness * (d[:, 2:] - 2 * d[:, 1:-1] + d[:, :-2]).ravel()

    def initial(self, data):
        amp, width2 = _moments(data)
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
        amp, width2 = _moments(data)
        peak = amp / (math.pi * max(width2[0], 1e-12))
        n_z = len(self.names) - self._n_base
        lo = np.concatenate([np.full(self._n_base, math.log(peak) - 40), np.full(n_z, -30.0)])
        hi = np.concatenate([np.full(self._n_base, math.log(peak) + 10), np.full(n_z, 10.0)])
        return lo, hi
