"""The parametric model: base lobe family and statistics family with a width law or a Gaussian
surface (docs/fitting.md)."""

import math
from collections.abc import Mapping
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from brdfscale import evolve, InvalidInputError, lobes, stats
from brdfscale.checks import integer, real
from brdfscale.choices import MODEL

from ._data import Dataset
from ._model import AbstractModel, moments


__all__ = ["ParametricModel"]

_LOBES = {"beckmann": lobes.Beckmann, "ggx": lobes.GGX}
_STATISTICS = {"beckmann": stats.Beckmann, "ggx": stats.GGX}


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
    window: Literal["box", "gaussian"] = eqx.field(static=True)
    fixed: tuple[tuple[str, float], ...] = eqx.field(static=True)
    radial_nodes: int = eqx.field(static=True)

    _LAWS = {
        "width": ("amplitude", "alpha_lobe", "alpha_max", "mu_c", "exponent"),
        "gaussian_surface": ("amplitude", "alpha_lobe", "rms_height", "correlation_length"),
    }

    def __init__(
        self,
        lobe: str = MODEL.family,
        statistics: str = MODEL.family,
        *,
        law: str = MODEL.law,
        fixed: dict | None = None,
        window: str = "box",
        radial_nodes: int = 96,
    ):
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
                raise InvalidInputError(
                    f"parameter {p} must be a positive, finite number; got {params[p]!r}."
                ) from None
            if not (math.isfinite(value) and value > 0):
                raise InvalidInputError(
                    f"parameter {p} must be a positive, finite number (θ holds its logarithm); got {params[p]!r}."
                )
            values.append(value)
        return np.log(values)

    def law(self, theta) -> stats.AbstractScaleLaw:
        """The scale law μ ↦ s(·, μ) at θ."""
        q = self.quantities(theta)
        if self.law_kind == "gaussian_surface":
            spectrum = stats.GaussianCorrelation(q["rms_height"], q["correlation_length"])
            return stats.GaussianSurface(spectrum, window=self.window)
        return stats.ScaledFamily(
            _STATISTICS[self.statistics], stats.WidthLaw(q["alpha_max"], q["mu_c"], q["exponent"])
        )

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
        coarser = jax.vmap(lambda s, u: self._evolve(base, s0, s, check=False).density(u))(
            coarser_statistics, points[1:]
        )
        return jnp.concatenate([base.density(points[0])[None], coarser])

    def relative_statistics(self, theta, W, scales):
        """``R_k(|W|) = S(W, μ0)/S(W, μ_k)`` (seed Eq. 4.4) as ``exp(log R_k)``: far out in |W| both
        transforms underflow to 0 and a direct division would give 0/0 (:func:`_log_ratio`;
        tests/test_adequacy.py checks it against mpmath at large |W|)."""
        W = jnp.asarray(W)
        statistics = jax.vmap(lambda mu: self.statistics_at(theta, mu))(jnp.asarray(scales))  # one evaluation:
        s0 = jax.tree.map(lambda leaf: leaf[0], statistics)  # R_0 = 1 exactly, eager and jitted
        return jax.vmap(lambda s: jnp.exp(_log_ratio(s0, s, W)))(statistics)

    def initial(self, data):
        amp, width2 = moments(data)
        # the half-maximum width of a GGX lobe is that of a Beckmann lobe with 0.77 α
        factor = 1.0 if self.lobe == "beckmann" else 1.3
        alpha_lobe = factor * math.sqrt(width2[0])
        spread = max(float(width2[-1] - width2[0]), 1e-6 * width2[0])
        alpha_s = 1.5 * math.sqrt(spread)
        mid = math.sqrt(float(data.scales[0]) * float(data.scales[-1]))
        # Gaussian correlation: α_s² = 2·(2σ_h²/ℓ²) unwindowed, so σ_h = ℓ α_s / 2
        start = {
            "amplitude": amp,
            "alpha_lobe": alpha_lobe,
            "alpha_max": alpha_s,
            "mu_c": mid,
            "exponent": 1.0,
            "correlation_length": mid,
            "rms_height": mid * alpha_s / 2,
        }
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
                raise InvalidInputError(
                    f"fixed {name} = {value:g} lies outside its prior box [{lo:g}, {hi:g}] for "
                    f"these data (scales μ = {np.asarray(data.scales).tolist()}); fix it inside."
                )

    def bounds(self, data):
        box = self.box(data)
        lo = np.log([box[p][0] for p in self.free])
        hi = np.log([box[p][1] for p in self.free])
        return lo, hi


_XK1_FAR = 600.0  # beyond: x K1(x) by its asymptotic series (relative error of the dropped term < 1e-12)


def _log_ratio(s0, s, k):
    """``log(S(k; s0)/S(k; s))`` of two isotropic, centred slope densities of one family, without
    underflow (Gaussian: without the cancellation of two large logarithms either).

    Gaussian (Beckmann, Gaussian surface): ``−½ (Σ0_xx − Σ_xx) k²``. GGX: ``S = x K1(x)``, ``x = α k``;
    ``log S(x0) − log S(x)`` by :func:`_log_xk1`. Otherwise the logarithm of the direct ratio."""
    if isinstance(s0, stats.Gaussian) and isinstance(s, stats.Gaussian):
        return -0.5 * (s0.cov[..., 0, 0] - s.cov[..., 0, 0]) * k**2
    if isinstance(s0, stats.GGX) and isinstance(s, stats.GGX):
        return _log_xk1(s0.alpha[..., 0] * jnp.abs(k)) - _log_xk1(s.alpha[..., 0] * jnp.abs(k))
    return jnp.log(s0.cf_radial(k) / s.cf_radial(k))


def _log_xk1(x):
    """``log(x K1(x))``, x ≥ 0: for ``x > 600`` (where ``x K1(x)`` underflows near ``e^−745``) by the
    asymptotic series ``K1(x) ≈ √(π/2x) e^−x (1 + 3/(8x) − 15/(128x²) + 105/(1024x³))`` (DLMF 10.40.2;
    the first dropped term is below 1e-12 there), else of GGX's own ``cf_radial``."""
    far = x > _XK1_FAR
    near, xf = jnp.where(far, 0.0, x), jnp.where(far, x, _XK1_FAR)
    series = 0.5 * jnp.log(0.5 * jnp.pi * xf) - xf + jnp.log1p(3 / (8 * xf) - 15 / (128 * xf**2) + 105 / (1024 * xf**3))
    return jnp.where(far, series, jnp.log(stats.GGX(alpha_x=1.0, alpha_y=1.0).cf_radial(near)))
