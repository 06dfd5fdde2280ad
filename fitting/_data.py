"""The multi-scale dataset a fit consumes: lobe images flattened, whitened and masked.

A :class:`brdfscale.MeasurementSet` holds lobe images ``A·g_μ(u)`` on grids of half-vector
slope offsets ``u = m_s − m∞`` (docs/conventions.md §6). In the nearly-flat approximation the lobe in
those offsets does not depend on the incident direction (seed §2), so every image at scale
μ is a measurement of the same function ``A·g_μ``; several incident directions at one scale
are replicates. :class:`Dataset` stacks the images into padded arrays:

* ``offsets[i, p]`` — the offset ``u`` of pixel ``p`` of image ``i`` (slope units);
* ``values[i, p]`` — the measured lobe (per unit slope area);
* ``weight[i, p]`` — ``1/σ`` for valid pixels, 0 for masked or padding pixels, so the
  whitened residual of a model prediction ``f`` is ``(f − values)·weight``;

A model predicts the same value at every pixel of one scale with the same offset (replicate
images), and a radially symmetric model at every pixel of one scale with the same radius
``|u|``. Least squares therefore needs only the sufficient statistics of each such group
``u`` of pixels ``p`` (:meth:`Dataset.points`): with ``c_u = Σ_p w_p²`` and the weighted
mean ``v̄_u = Σ_p w_p² v_p / c_u``,

    χ² = Σ_p w_p² (f_u − v_p)² = Σ_u c_u (f_u − v̄_u)² + Σ_u Σ_p w_p² (v_p − v̄_u)²,

exactly, so the residuals ``√c_u (f_u − v̄_u)`` have the same optimum, the same Jacobian
product ``JᵀJ`` (hence the same Laplace covariance) and, with the constant second sum
added, the same χ² as the per-pixel residuals — at a fraction of the rows (a square grid
has about 8× fewer radii than pixels).

RGB images are reduced to luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` (Rec. 709) with
``σ_Y² = Σ_c w_c² σ_c²`` (independent channel noise).

σ of a valid pixel must lie in :data:`SIGMA_RANGE` ``= [1e-100, 1e100]`` (lobe units): outside
it ``1/σ²`` leaves float64's normal numbers (a denormal σ makes the weight infinite, a σ of
1e300 makes ``1/σ² = 0``, which would drop the pixel as if masked) or χ² overflows. Inside it
the fit does not depend on σ's overall scale (fitting._solve: σ × c for c in [1e-30, 1e30]
gives the same optimum, tests/test_scale_invariance.py).
"""

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from brdfscale import InvalidInputError, lobes, MeasurementSet
from brdfscale.checks import real, require_float64
from brdfscale.choices import MIN_FIT_SCALES
from brdfscale.show import concrete, Shown, Values

from ._joint import TopographyData
from ._masking import masking_factors


__all__ = ["Dataset", "PointData", "SIGMA_RANGE"]

_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])

SIGMA_RANGE = (1e-100, 1e100)
"""The σ (lobe units) a valid pixel may have: ``1/σ²`` and χ² stay float64 numbers (module docstring)."""

_SIGMA_ACCEPTED = (
    f"σ is the noise standard deviation in lobe units: a number in [{SIGMA_RANGE[0]:g}, {SIGMA_RANGE[1]:g}] "
    "(1/σ² and χ² must be float64 numbers; the fit does not depend on σ's overall scale)"
)


def _check_sigma(sigma: np.ndarray, valid: np.ndarray, where: str) -> None:
    """InvalidInputError naming ``where``, how many valid pixels have σ outside
    :data:`SIGMA_RANGE`, the worst value and its pixel, and what is accepted."""
    lo, hi = SIGMA_RANGE
    if sigma.ndim == 3:
        valid = np.broadcast_to(valid[..., None], sigma.shape)
    bad = valid & ~((sigma >= lo) & (sigma <= hi))  # NaN fails both
    if not bad.any():
        return
    index = np.argwhere(bad)
    values = sigma[tuple(index.T)]
    distance = np.where(np.isnan(values), np.inf, np.abs(np.log10(np.maximum(values, 1e-320) / np.sqrt(lo * hi))))
    worst = tuple(int(i) for i in index[np.argmax(distance)])
    raise InvalidInputError(
        f"{where}: {len(index)} of the {int(np.count_nonzero(valid))} σ values of its valid pixels lie outside "
        f"[{lo:g}, {hi:g}] (e.g. {float(sigma[worst]):g} at index {worst}); {_SIGMA_ACCEPTED} — mask the pixels "
        "whose σ is unknown instead."
    )


def _luminance(values, sigma):
    if values.ndim == 2:
        return values, sigma
    y = values @ _LUMINANCE
    s = None if sigma is None else np.sqrt((sigma**2) @ (_LUMINANCE**2))
    return y, s


class Dataset(Shown, eqx.Module):
    """Lobe images at the scales ``scales`` (ascending), flattened and padded.

    ``scale_of_image[i]`` is the index into ``scales`` of image ``i``; the finest scale
    ``scales[0]`` is the reference scale μ0 at which the base lobe is described. Only the
    layout (image count and sizes, which image has which scale index) is static, so
    datasets of one layout share compiled fits whatever their values and scales.
    """

    offsets: Float[Array, "n_img n_pix 2"]
    values: Float[Array, "n_img n_pix"]
    weight: Float[Array, "n_img n_pix"]
    scales: Float[Array, " n_scales"]
    scale_of_image: tuple[int, ...] = eqx.field(static=True)
    image_sizes: tuple[int, ...] = eqx.field(static=True)
    extents: tuple[float, ...] = eqx.field(static=True)
    topography: TopographyData | None = None
    """A joint fit's topography term (:meth:`with_topography`; fitting._joint), else None."""
    masking: str = eqx.field(static=True, default="none")
    """The masking removed from the images (:meth:`from_measurements`; ``brdfscale.choices.MASKING``)."""

    @classmethod
    def from_measurements(cls, mset: MeasurementSet, *, default_sigma: float | None = None, masking=None) -> "Dataset":
        """Build a dataset from a measurement set.

        Args:
            mset: the measurements (at least two distinct scales: a single scale carries no
                information about the evolution).
            default_sigma: standard deviation (lobe units) used for images that carry no
                ``sigma``; without it such images are refused.
            masking: the masking and shadowing in the forward model — None (the library default,
                ``brdfscale.choices.MASKING``), a name of it (``"none"``, ``"smith"``) or a
                :class:`brdfscale.lobes.AbstractMasking`. Other than none, each valid pixel's value
                and σ are divided by the fixed factor ``G₂(i, o(u))`` of fitting._masking (the image's
                own lobe as the slope density), so the models' unmasked lobe times that factor is
                the forward model; pixels with no light towards their detector are masked out
                (docs/masking.md).

        Raises:
            InvalidInputError: fewer than two scales, an image without σ and no
                ``default_sigma``, a valid pixel's σ (or ``default_sigma``) outside
                :data:`SIGMA_RANGE`, or an image with no valid pixel.
        """
        require_float64("fitting.Dataset.from_measurements")
        if not isinstance(mset, MeasurementSet):
            raise InvalidInputError(f"expected a brdfscale.MeasurementSet; got {type(mset).__name__}.")
        scales = tuple(float(s) for s in mset.scales)
        if len(scales) < MIN_FIT_SCALES:
            raise InvalidInputError(
                f"a fit needs images at {MIN_FIT_SCALES} or more distinct scales μ; got only μ = {scales}. The "
                "evolution between scales is what carries the information about the slope statistics."
            )
        if default_sigma is not None:
            default_sigma = real(default_sigma, "default_sigma", minimum=0.0, strict=True)
            if not SIGMA_RANGE[0] <= default_sigma <= SIGMA_RANGE[1]:
                raise InvalidInputError(
                    f"default_sigma= ({default_sigma:g}) lies outside [{SIGMA_RANGE[0]:g}, {SIGMA_RANGE[1]:g}]; "
                    f"{_SIGMA_ACCEPTED}."
                )
        masking = lobes.as_masking(masking)
        factors = None
        if not isinstance(masking, lobes.NoMasking):  # G₂ per pixel from each scale's lobe (fitting._masking)
            lum = [_luminance(img.values, None)[0] for img in mset.images]
            valid = [np.ones(v.shape, bool) if img.mask is None else img.mask for v, img in zip(lum, mset.images)]
            factors = masking_factors(masking, mset.images, lum, valid)
        n_pix = max(img.size**2 for img in mset.images)
        offsets, values, weight, which = [], [], [], []
        for i, img in enumerate(mset.images):
            m = np.ones(img.values.shape[:2], bool) if img.mask is None else img.mask
            if img.sigma is not None:  # as given (R, G, B each), before the luminance
                _check_sigma(img.sigma, m, f"image {i} (μ = {img.mu:g})")
            v, s = _luminance(img.values, img.sigma)
            if s is None:
                if default_sigma is None:
                    raise InvalidInputError(
                        f"image {i} (μ = {img.mu}) has no per-pixel sigma; pass default_sigma= (the noise "
                        "standard deviation in lobe units) or store a 'sigma' channel."
                    )
                s = np.full_like(v, float(default_sigma))
            if not m.any():
                raise InvalidInputError(f"image {i} (μ = {img.mu}) has no valid pixel (its mask is all False).")
            if factors is not None:  # the fixed masking factor out of value and σ
                g = factors[i]
                m = m & (g > 0)
                v, s = np.divide(v, g, out=np.zeros_like(v), where=m), np.divide(s, g, out=np.ones_like(s), where=m)
            pad = n_pix - v.size
            offsets.append(np.pad(img.offsets().reshape(-1, 2), ((0, pad), (0, 0))))
            values.append(np.pad(v.ravel(), (0, pad)))
            weight.append(np.pad(np.divide(1.0, s, out=np.zeros_like(s), where=m).ravel(), (0, pad)))
            which.append(scales.index(img.mu))
        return cls(
            offsets=jnp.asarray(np.stack(offsets), dtype=jnp.float64),
            values=jnp.asarray(np.stack(values), dtype=jnp.float64),
            weight=jnp.asarray(np.stack(weight), dtype=jnp.float64),
            scales=jnp.asarray(scales, dtype=jnp.float64),
            scale_of_image=tuple(which),
            image_sizes=tuple(img.size for img in mset.images),
            extents=tuple(img.extent for img in mset.images),
            masking=masking.name,
        )

    @property
    def n_data(self) -> int:
        """Number of valid (unmasked) pixels, plus the topography's rows in a joint fit."""
        extra = 0 if self.topography is None else self.topography.n_rows
        return int(np.count_nonzero(np.asarray(self.weight))) + extra

    def with_topography(self, topography: TopographyData) -> "Dataset":
        """This dataset with a topography's ``Σ(μ)`` as a joint data term (:class:`fitting.TopographyData`
        at these scales); InvalidInputError otherwise."""
        if not isinstance(topography, TopographyData):
            raise InvalidInputError(f"topography must be a fitting.TopographyData; got {type(topography).__name__}.")
        topography.check_scales(self.scales)
        return dataclasses.replace(self, topography=topography)

    def _show_items(self):
        sizes = sorted(set(self.image_sizes))
        items = [
            ("images", len(self.scale_of_image)),
            ("scales", Values(self.scales)),
            ("sizes", ", ".join(f"{n}×{n}" for n in sizes[:3]) + (" …" if len(sizes) > 3 else "")),
        ]
        if concrete(self.weight):  # not under jax.jit
            items.append(("valid_pixels", self.n_data))
        extents = sorted(set(self.extents))
        shown = (
            extents[0]
            if len(extents) == 1
            else Values(np.asarray(extents), 3)
            if len(extents) <= 3
            else f"{len(extents)} values from {extents[0]:.4g} to {extents[-1]:.4g}"
        )
        return items + [("extents" if len(extents) > 1 else "extent", shown)]

    def images_of_scale(self, k: int) -> list[int]:
        """Indices of the images measured at ``scales[k]``."""
        return [i for i, j in enumerate(self.scale_of_image) if j == k]

    def points(self, radial: bool) -> "PointData":
        """The sufficient statistics of the pixels that share a prediction (module docstring).

        Args:
            radial: group by radius ``|u|`` (radially symmetric models) instead of by offset.
                Coordinates are rounded to 1e-12 of the largest extent before grouping, so
                mirror-symmetric pixels share a group.
        """
        offsets, values = np.asarray(self.offsets), np.asarray(self.values)
        w2 = np.asarray(self.weight) ** 2
        scale = max(self.extents)
        groups, n_scales = [], len(np.asarray(self.scales))
        for k in range(n_scales):
            images = self.images_of_scale(k)
            u = offsets[images].reshape(-1, 2)
            key = np.linalg.norm(u, axis=-1, keepdims=True) if radial else u
            key, index = np.unique(np.round(key / scale, 12), axis=0, return_inverse=True)
            index = index.ravel()
            c = np.bincount(index, w2[images].ravel(), len(key))
            sums = np.bincount(index, (w2[images] * values[images]).ravel(), len(key))
            mean = np.divide(sums, c, out=np.zeros_like(sums), where=c > 0)
            spread = float(np.sum(w2[images].ravel() * (values[images].ravel() - mean[index]) ** 2))
            point = np.concatenate([key * scale, np.zeros_like(key)], axis=1) if radial else key * scale
            groups.append((point, mean, np.sqrt(c), spread))
        n = max(len(g[1]) for g in groups)

        def padded(i):  # zero rows up to n points (zero weight: no contribution)
            return jnp.asarray(
                np.stack([np.pad(g[i], [(0, n - len(g[i]))] + [(0, 0)] * (g[i].ndim - 1)) for g in groups])
            )

        return PointData(
            points=padded(0),
            mean=padded(1),
            weight=padded(2),
            chi2_offset=jnp.asarray(sum(g[3] for g in groups)),
        )

    def whitened(self, prediction: Float[Array, "n_img n_pix"]) -> Float[Array, " n_img*n_pix"]:
        """``(prediction − values)/σ`` over all pixels (0 where masked), flattened."""
        return ((prediction - self.values) * self.weight).ravel()

    def image(self, i: int, flat: Float[Array | np.ndarray, " n_pix"]) -> np.ndarray:
        """Pixel row ``flat`` of image ``i`` reshaped to its (n, n) grid."""
        n = self.image_sizes[i]
        return np.asarray(flat[: n * n]).reshape(n, n)


class PointData(eqx.Module):
    """The dataset reduced to the distinct points of each scale (:meth:`Dataset.points`).

    ``points[k, j]`` is a measured offset (for radial grouping ``(|u|, 0)``) at ``scales[k]``,
    ``mean[k, j]`` the σ-weighted mean of its pixels and ``weight[k, j] = √c`` (0 for padding
    and fully masked points); ``chi2_offset`` is the within-group scatter, the constant that
    turns the reduced χ² into the per-pixel χ². The arrays are JAX arrays, or NumPy arrays where
    :func:`fitting.fit_many` pads them on the host.
    """

    points: Float[Array | np.ndarray, "n_scales n_points 2"]
    mean: Float[Array | np.ndarray, "n_scales n_points"]
    weight: Float[Array | np.ndarray, "n_scales n_points"]
    chi2_offset: Float[Array, ""]
