"""The multi-scale dataset a fit consumes: lobe images flattened, whitened and masked.

A :class:`brdfscale.MeasurementSet` holds lobe images ``A·g_μ(u)`` on grids of half-vector
slope offsets ``u = m_s − m∞`` (DESIGN §6). In the nearly-flat approximation the lobe in
those offsets does not depend on the incident direction (seed §2), so every image at scale
μ is a measurement of the same function ``A·g_μ``; several incident directions at one scale
are replicates. :class:`Dataset` stacks the images into padded arrays:

* ``offsets[i, p]`` — the offset ``u`` of pixel ``p`` of image ``i`` (slope units);
* ``values[i, p]`` — the measured lobe (per unit slope area);
* ``weight[i, p]`` — ``1/σ`` for valid pixels, 0 for masked or padding pixels, so the
  whitened residual of a model prediction ``f`` is ``(f − values)·weight``;
* ``radii`` and ``radius_index`` — the distinct offset radii ``|u|`` of all pixels and, per
  pixel, the index of its radius: a radially symmetric lobe is evaluated once per distinct
  radius (a square grid has about 8× fewer radii than pixels).

RGB images are reduced to luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` (Rec. 709) with
``σ_Y² = Σ_c w_c² σ_c²`` (independent channel noise).
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from brdfscale import InvalidInputError, MeasurementSet

__all__ = ["Dataset"]

_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def _luminance(values, sigma):
    if values.ndim == 2:
        return values, sigma
    y = values @ _LUMINANCE
    s = None if sigma is None else np.sqrt((sigma**2) @ (_LUMINANCE**2))
    return y, s


class Dataset(eqx.Module):
    """Lobe images at the scales ``scales`` (ascending), flattened and padded.

    ``scale_of_image[i]`` is the index into ``scales`` of image ``i``; the finest scale
    ``scales[0]`` is the reference scale μ0 at which the base lobe is described. Only the
    layout (image count and sizes, which image has which scale index) is static, so
    datasets of one layout share compiled fits whatever their values and scales.
    """

    offsets: Float[Array, "n_img n_pix 2"]
    values: Float[Array, "n_img n_pix"]
    weight: Float[Array, "n_img n_pix"]
    radii: Float[Array, " n_radii"]
    radius_index: Int[Array, "n_img n_pix"]
    scales: Float[Array, " n_scales"]
    scale_of_image: tuple[int, ...] = eqx.field(static=True)
    image_sizes: tuple[int, ...] = eqx.field(static=True)
    extents: tuple[float, ...] = eqx.field(static=True)

    @classmethod
    def from_measurements(cls, mset: MeasurementSet, *, default_sigma: float | None = None) -> "Dataset":
        """Build a dataset from a measurement set.

        Args:
            mset: the measurements (at least two distinct scales: a single scale carries no
                information about the evolution).
            default_sigma: standard deviation (lobe units) used for images that carry no
                ``sigma``; without it such images are refused.

        Raises:
            InvalidInputError: fewer than two scales, an image without σ and no
                ``default_sigma``, or an image with no valid pixel.
        """
        if not isinstance(mset, MeasurementSet):
            raise InvalidInputError(f"expected a brdfscale.MeasurementSet; got {type(mset).__name__}.")
        scales = tuple(float(s) for s in mset.scales)
        if len(scales) < 2:
            raise InvalidInputError(
                f"a fit needs images at two or more distinct scales μ; got only μ = {scales}. The evolution "
                "between scales is what carries the information about the slope statistics."
            )
        if default_sigma is not None and not (np.isfinite(default_sigma) and default_sigma > 0):
            raise InvalidInputError(f"default_sigma must be a positive number; got {default_sigma!r}.")
        n_pix = max(img.size**2 for img in mset.images)
        offsets, values, weight, which = [], [], [], []
        for i, img in enumerate(mset.images):
            v, s = _luminance(img.values, img.sigma)
            if s is None:
                if default_sigma is None:
                    raise InvalidInputError(
                        f"image {i} (μ = {img.mu}) has no per-pixel sigma; pass default_sigma= (the noise "
                        "standard deviation in lobe units) or store a 'sigma' channel."
                    )
                s = np.full_like(v, float(default_sigma))
            m = np.ones(v.shape, bool) if img.mask is None else img.mask
            if not m.any():
                raise InvalidInputError(f"image {i} (μ = {img.mu}) has no valid pixel (its mask is all False).")
            pad = n_pix - v.size
            offsets.append(np.pad(img.offsets().reshape(-1, 2), ((0, pad), (0, 0))))
            values.append(np.pad(v.ravel(), (0, pad)))
            weight.append(np.pad(np.where(m, 1.0 / s, 0.0).ravel(), (0, pad)))
            which.append(scales.index(img.mu))
        offsets = np.stack(offsets)
        # radii rounded to 1e-12 (relative to the extent) so mirror-symmetric pixels share one
        scale = max(img.extent for img in mset.images)
        radius = np.round(np.linalg.norm(offsets, axis=-1) / scale, 12)
        radii, radius_index = np.unique(radius, return_inverse=True)
        return cls(
            offsets=jnp.asarray(offsets, dtype=jnp.float64),
            values=jnp.asarray(np.stack(values), dtype=jnp.float64),
            weight=jnp.asarray(np.stack(weight), dtype=jnp.float64),
            radii=jnp.asarray(radii * scale, dtype=jnp.float64),
            radius_index=jnp.asarray(radius_index.reshape(radius.shape), dtype=jnp.int32),
            scales=jnp.asarray(scales, dtype=jnp.float64),
            scale_of_image=tuple(which),
            image_sizes=tuple(img.size for img in mset.images),
            extents=tuple(img.extent for img in mset.images),
        )

    @property
    def n_data(self) -> int:
        """Number of valid (unmasked) pixels."""
        return int(np.count_nonzero(np.asarray(self.weight)))

    def whitened(self, prediction: Float[Array, "n_img n_pix"]) -> Float[Array, " n_img*n_pix"]:
        """``(prediction − values)/σ`` over all pixels (0 where masked), flattened."""
        return ((prediction - self.values) * self.weight).ravel()

    def image(self, i: int, flat: Float[Array, " n_pix"]) -> np.ndarray:
        """Pixel row ``flat`` of image ``i`` reshaped to its (n, n) grid."""
        n = self.image_sizes[i]
        return np.asarray(flat[: n * n]).reshape(n, n)
