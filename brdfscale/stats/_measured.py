"""A measured topography as a scale law: Σ(μ) tabulated at many scales, interpolated in ln μ.

The facet statistics of a height field at scales ``μ_1 < … < μ_n`` (``synth.facet_statistics``:
the covariance ``Σ_i`` of the facet slopes and the standard error of each entry) define the law

    Σ(μ) = (1 − t) Σ_i + t Σ_{i+1},    t = (ln μ − ln μ_i) / (ln μ_{i+1} − ln μ_i),

for ``μ_i ≤ μ ≤ μ_{i+1}`` — linear in ln μ, entry by entry — and ``s(·, μ) = Gaussian(cov=Σ(μ))``:
the shape is Gaussian, the second moments are the measured ones (the seed's Eq. 4.4 for Gaussian
lobes needs no more: covariances add, docs/conventions.md §2). A convex combination of positive
definite matrices is positive definite, and of Loewner-ordered ones lies between them, so the law
is positive definite everywhere and monotone in μ wherever the measurements are.

Its uncertainty (:meth:`MeasuredScaleLaw.slope_covariance_error`) is the standard error of each
entry, interpolated the same way, and — between the measured scales — the interpolation error:
twice its leading term, the difference between the linear interpolant and the quadratic through
three neighbouring scales, on whichever side of the interval is larger (for a smooth Σ(ln μ) that
difference is ``Σ''·(x − x_i)(x − x_{i+1})/2``, the linear interpolant's error to leading order),
added in quadrature. At the measured scales it
is the measured standard error itself. Verified in ``tests/test_scale_laws_real.py`` against an
analytic :class:`GaussianSurface` and against the facet statistics of a real field.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._errors import InvalidInputError
from .._validation import as_float_array, facet_size, is_concrete
from ._families import Gaussian
from ._scale_laws import AbstractScaleLaw


class MeasuredScaleLaw(AbstractScaleLaw):
    """Facet-slope statistics measured at scales ``mu`` (module docstring).

    Args:
        mu: the measured facet sizes, increasing (length units of the field), at least 2.
        covariance: ``Σ(μ_i)``, shape ``(n, 2, 2)``, symmetric positive definite (slope²).
        covariance_error: the standard error of each entry of ``Σ(μ_i)``, shape ``(n, 2, 2)``
            (0: exact); default 0.

    The data a fit uses, as measured: :attr:`mu`, :attr:`covariance` (``Σ(μ_i)``) and
    :attr:`covariance_error` (their standard errors; the entries are treated as independent).
    Between and at the scales: :meth:`slope_covariance` and :meth:`slope_covariance_error`.
    ``at(μ)`` outside ``[μ_1, μ_n]`` is refused (InvalidInputError; under ``jax.jit`` an
    ``equinox`` run-time error with the same message).
    """

    mu: Float[Array, " n"]
    covariance: Float[Array, "n 2 2"]
    covariance_error: Float[Array, "n 2 2"]

    def __init__(self, mu, covariance, covariance_error=None):
        mu = as_float_array(mu, "mu")
        cov = as_float_array(covariance, "covariance")
        if mu.ndim != 1 or mu.shape[0] < 2:
            raise InvalidInputError(f"mu must be a 1-D array of at least 2 facet sizes; got shape {mu.shape}.")
        if cov.shape != (mu.shape[0], 2, 2):
            raise InvalidInputError(
                f"covariance must have shape (n, 2, 2) with n = len(mu) = {mu.shape[0]}; got {cov.shape}."
            )
        err = jnp.zeros_like(cov) if covariance_error is None else as_float_array(covariance_error, "covariance_error")
        if err.shape != cov.shape:
            raise InvalidInputError(f"covariance_error must have the shape of covariance {cov.shape}; got {err.shape}.")
        if is_concrete((mu, cov, err)):
            m, c, e = np.asarray(mu), np.asarray(cov), np.asarray(err)
            if not (np.all(np.isfinite(m)) and np.all(m > 0) and np.all(np.diff(m) > 0)):
                raise InvalidInputError(f"mu must be finite, positive and increasing; got {m!r}.")
            if not np.all(np.isfinite(c)) or not np.allclose(c, np.swapaxes(c, -1, -2), rtol=1e-12, atol=0):
                raise InvalidInputError("covariance must be finite and symmetric at every scale.")
            if not np.all(np.linalg.eigvalsh(c) > 0):
                bad = np.nonzero(np.linalg.eigvalsh(c)[:, 0] <= 0)[0]
                raise InvalidInputError(
                    f"covariance must be positive definite at every scale; it is not at mu = {m[bad]!r}."
                )
            if not (np.all(np.isfinite(e)) and np.all(e >= 0)):
                raise InvalidInputError("covariance_error must be finite standard errors ≥ 0.")
        self.mu, self.covariance, self.covariance_error = mu, cov, err

    @classmethod
    def from_facets(cls, facets) -> "MeasuredScaleLaw":
        """From a sequence of facet statistics (:func:`brdfscale.synth.facet_statistics`'s items:
        anything with ``.mu``, ``.covariance`` and ``.covariance_error``), sorted by μ."""
        items = sorted(facets, key=lambda s: float(s.mu))
        if len(items) < 2:
            raise InvalidInputError(
                f"a measured scale law needs facet statistics at 2 scales or more; got {len(items)}."
            )
        try:
            mu = np.array([float(s.mu) for s in items])
            cov = np.stack([np.asarray(s.covariance, dtype=float) for s in items])
            err = np.stack([np.asarray(s.covariance_error, dtype=float) for s in items])
        except AttributeError as exc:
            raise InvalidInputError(
                "facets must be facet statistics with .mu, .covariance and .covariance_error "
                f"(brdfscale.synth.facet_statistics); {exc}."
            ) from None
        return cls(mu, cov, err)

    # -- interpolation (module docstring) ----------------------------------------------------------
    def _where(self, mu):
        """``(i, t)``: the interval ``[μ_i, μ_{i+1}]`` holding μ and the weight of its right end."""
        mu = facet_size(mu)
        lo, hi = self.mu[0], self.mu[-1]
        message = "μ outside the measured scales of this MeasuredScaleLaw"
        if is_concrete((mu, self.mu)):
            if not (float(lo) * (1 - 1e-12) <= float(mu) <= float(hi) * (1 + 1e-12)):
                raise InvalidInputError(
                    f"{message}: μ = {float(mu):.6g} is not in [{float(lo):.6g}, {float(hi):.6g}] "
                    "(it interpolates, it does not extrapolate; fit a parametric law to go beyond)."
                )
        else:
            mu = eqx.error_if(mu, (mu < lo * (1 - 1e-12)) | (mu > hi * (1 + 1e-12)), message)
        x = jnp.log(self.mu)
        xm = jnp.log(jnp.clip(mu, lo, hi))
        i = jnp.clip(jnp.searchsorted(x, xm, side="right") - 1, 0, x.shape[0] - 2)
        t = (xm - x[i]) / (x[i + 1] - x[i])
        return i, t, xm

    def slope_covariance(self, mu: Float[ArrayLike, ""]) -> Float[Array, "2 2"]:
        """``Σ(μ)``: linear in ln μ between the measured scales (slope²)."""
        i, t, _ = self._where(mu)
        return (1 - t) * self.covariance[i] + t * self.covariance[i + 1]

    def slope_covariance_error(self, mu: Float[ArrayLike, ""]) -> Float[Array, "2 2"]:
        """The standard error of each entry of ``Σ(μ)``: the measured errors interpolated like
        ``Σ``, and between the scales twice the interpolation's leading error term, in quadrature
        (module docstring). At a measured scale, that scale's standard error."""
        i, t, xm = self._where(mu)
        measured = (1 - t) * self.covariance_error[i] + t * self.covariance_error[i + 1]
        x = jnp.log(self.mu)
        n = x.shape[0]
        if n < 3:
            return measured
        # second divided differences of Σ with the neighbour on each side of the interval (one
        # side only at the ends); the larger one bounds the curvature of Σ(ln μ) on the interval
        c_i, c_k = self.covariance[i], self.covariance[i + 1]
        d1 = (c_k - c_i) / (x[i + 1] - x[i])

        def second(j):
            j = jnp.clip(j, 0, n - 1)
            slope = (self.covariance[j] - jnp.where(j < i, c_i, c_k)) / (x[j] - jnp.where(j < i, x[i], x[i + 1]))
            return (slope - d1) / (x[j] - jnp.where(j < i, x[i + 1], x[i]))

        left = jnp.where(i > 0, jnp.abs(second(i - 1)), 0.0)
        right = jnp.where(i + 2 < n, jnp.abs(second(i + 2)), 0.0)
        interpolation = 2 * jnp.maximum(left, right) * jnp.abs((xm - x[i]) * (xm - x[i + 1]))
        return jnp.sqrt(measured**2 + interpolation**2)

    def at(self, mu):
        """``Gaussian(cov=Σ(μ))`` (module docstring)."""
        return Gaussian(cov=self.slope_covariance(mu))
