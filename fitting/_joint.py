"""A topography's facet statistics as a data term of a fit: :class:`TopographyData`.

A measured height field gives ``Σ(μ)``, the covariance of the facet slopes at each measured
scale, with standard errors (:func:`brdfscale.synth.facet_statistics`, ``covariance_error``).
The lobe images determine ``ΔΣ(μ0, μ_k) = Σ(μ0) − Σ(μ_k)`` (:func:`fitting._derived.covariance_differences`),
so the joint likelihood adds, for each entry ``c ∈ {xx, xy, yy}``, the whitened rows

    r_c = L_c⁻¹ (ΔΣ_model,c − ΔΣ_topo,c),   L_c L_cᵀ = V_c = e_{0,c}² 1 1ᵀ + diag(e_{k,c}²),

over the coarser scales k = 1 … K−1: the topography's ``ΔΣ_topo,k = Σ̂(μ0) − Σ̂(μ_k)`` all share
``Σ̂(μ0)``, whose variance ``e_0²`` is the common term of their covariance ``V_c``; the scales'
estimates are taken as independent of each other (they come from different windows; where they
are positively correlated the difference is known better than V says, so the term is
conservative), and so are the three entries xx, xy, yy (``covariance_error`` gives no
cross-entry covariance). With the images' whitened residuals these rows make one
``χ² = −2 log L + const`` (:class:`fitting.Problem` appends them: ``Dataset.with_topography``),
used by :func:`fitting.fit` and the samplers alike.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from brdfscale import InvalidInputError, synth
from brdfscale.show import Shown, Values


__all__ = ["TopographyData"]

_ENTRIES = ((0, 0), (0, 1), (1, 1))


class TopographyData(Shown, eqx.Module):
    """``Σ(μ)`` of a topography with standard errors at the scales of a dataset, whitened for the
    joint likelihood (module docstring).

    ``difference[k − 1, c]`` is ``ΔΣ_topo`` of entry ``c`` (xx, xy, yy) at the coarser scale k,
    ``whiten[c]`` the inverse Cholesky factor ``L_c⁻¹`` of its covariance.
    """

    scales: Float[Array, " k"]
    covariance: Float[Array, "k 2 2"]
    error: Float[Array, "k 2 2"]
    difference: Float[Array, "k1 3"]
    whiten: Float[Array, "3 k1 k1"]

    def __init__(self, scales, covariance, error):
        """``Σ(μ_k)`` (K, 2, 2) and its standard errors (K, 2, 2) at ascending ``scales`` (K ≥ 2).

        Raises:
            InvalidInputError: wrong shapes, scales not ascending and positive, a covariance not
                finite and symmetric, or an error not finite and > 0 (a scale with too few
                facets has an infinite error: leave it out).
        """
        scales = np.asarray(scales, dtype=float)
        covariance, error = np.asarray(covariance, dtype=float), np.asarray(error, dtype=float)
        if (
            scales.ndim != 1
            or len(scales) < 2
            or covariance.shape != (len(scales), 2, 2)
            or error.shape != covariance.shape
        ):
            raise InvalidInputError(
                f"TopographyData needs K ≥ 2 ascending scales, covariances (K, 2, 2) and errors (K, 2, 2); got "
                f"shapes {scales.shape}, {covariance.shape}, {error.shape}."
            )
        if not (np.all(np.isfinite(scales)) and np.all(scales > 0) and np.all(np.diff(scales) > 0)):
            raise InvalidInputError(f"the scales must be positive and ascending; got {scales.tolist()}.")
        if not (np.all(np.isfinite(covariance)) and np.allclose(covariance, np.swapaxes(covariance, 1, 2))):
            raise InvalidInputError("every covariance Σ(μ) must be finite and symmetric.")
        if not (np.all(np.isfinite(error)) and np.all(error > 0)):
            bad = [float(s) for s, e in zip(scales, error) if not (np.all(np.isfinite(e)) and np.all(e > 0))]
            raise InvalidInputError(
                f"the standard errors of Σ(μ) must be finite and > 0; not at μ = {bad} (too few facets there: "
                "leave that scale out of the measurements or the topography)."
            )
        diffs, whiten = [], []
        for a, b in _ENTRIES:
            diffs.append(covariance[0, a, b] - covariance[1:, a, b])
            e0, ek = error[0, a, b], error[1:, a, b]
            V = e0**2 + np.diag(ek**2)
            whiten.append(np.linalg.inv(np.linalg.cholesky(V)))
        self.scales = jnp.asarray(scales)
        self.covariance, self.error = jnp.asarray(covariance), jnp.asarray(error)
        self.difference = jnp.asarray(np.stack(diffs, axis=1))
        self.whiten = jnp.asarray(np.stack(whiten))

    @classmethod
    def from_field(cls, field: synth.HeightField, scales) -> "TopographyData":
        """Σ(μ) and its standard errors of ``field`` at ``scales`` (each a whole number of pixels;
        the dataset's scales, in the field's length unit) by :func:`brdfscale.synth.facet_statistics`.

        Raises:
            InvalidInputError: what facet_statistics refuses, or a scale with too few facets.
        """
        measured = synth.facet_statistics(field, [float(s) for s in np.asarray(scales)], bins=17)
        return cls(
            [m.mu for m in measured],
            np.stack([m.covariance for m in measured]),
            np.stack([m.covariance_error for m in measured]),
        )

    @property
    def n_rows(self) -> int:
        """The number of rows the term adds: 3 (K − 1)."""
        return int(np.prod(self.difference.shape))

    def _show_items(self):
        return [("scales", Values(self.scales)), ("rows", self.n_rows)]

    def check_scales(self, scales) -> None:
        """InvalidInputError unless ``scales`` are this topography's (relative tolerance 1e-9)."""
        mine, theirs = np.asarray(self.scales), np.asarray(scales, dtype=float)
        if mine.shape != theirs.shape or not np.allclose(mine, theirs, rtol=1e-9, atol=0):
            raise InvalidInputError(
                f"the topography's scales {mine.tolist()} are not the measurements' {theirs.tolist()}; build it "
                "with TopographyData.from_field(field, data.scales) (lengths in the same unit)."
            )

    def residuals(self, differences: Float[Array, "k 2 2"]) -> Float[Array, " m"]:
        """The whitened rows ``L_c⁻¹ (ΔΣ_model,c − ΔΣ_topo,c)`` of a model's ΔΣ (K, 2, 2), row 0 = 0."""
        model = jnp.stack([differences[1:, a, b] for a, b in _ENTRIES], axis=1)  # (K−1, 3)
        return jnp.einsum("cij,jc->ci", self.whiten, model - self.difference).ravel()
