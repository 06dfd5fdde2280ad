"""In-memory measurement sets: lobe images at several scales and incident directions.

A :class:`MeasurementSet` is what a (real or synthetic) gonioreflectometer delivers and
what the fitting code consumes; :mod:`brdfscale.exr` stores it as multi-part OpenEXR
(docs/conventions.md §6). Each :class:`LobeImage` is one (scale μ, incident direction i) pair: the lobe
sampled on a regular ``n × n`` grid of half-vector slope offsets ``u = m_s − m∞`` whose
nodes span ``[−extent, extent]`` on both axes (rows u_y, columns u_x, as
:class:`brdfscale.stats.Tabulated`), with optional per-pixel standard deviations and a mask.
"""

import dataclasses
import types
from collections.abc import Iterable, Mapping, Sequence

import numpy as np
from jaxtyping import Real

from ._errors import InvalidInputError
from ._show import Shown, Table, Values
from ._validation import real, real_array, RealNumber


__all__ = ["LobeImage", "MeasurementSet"]


def boolean_mask(x, name: str) -> np.ndarray:
    """``x`` as a bool array; only True/False or the numbers 0 and 1 are accepted."""
    try:
        m = np.asarray(x)
    except (TypeError, ValueError) as err:
        raise InvalidInputError(
            f"{name} must be a boolean array (True/False or 0/1); got {type(x).__name__} ({err})."
        ) from None
    if m.dtype.kind == "b":
        return m
    if m.dtype.kind in "iuf" and np.all((m == 0) | (m == 1)):
        return m.astype(bool)
    bad = (
        "" if m.dtype.kind not in "iuf" else f" with {np.count_nonzero((m != 0) & (m != 1))} entries other than 0 and 1"
    )
    raise InvalidInputError(
        f"{name} must be boolean-valued, True (or 1) where the pixel is valid and False (or 0) where not; got dtype "
        f"{m.dtype}{bad}. Threshold it yourself (e.g. mask=weights > 0) if another rule is meant."
    )


@dataclasses.dataclass(frozen=True, repr=False, init=False)
class LobeImage(Shown):
    """One lobe image.

    Attributes:
        mu: the observation scale (facet size, length units of the surface; > 0).
        incident: unit direction towards the light, shape (3,), z > 0.
        extent: half-width ``a`` of the offset grid (slope units; > 0).
        values: the lobe ``A·g(u)`` (per unit slope area), shape (n, n), or
            (n, n, 3) for R, G, B.
        sigma: per-pixel standard deviation of ``values`` (same shape), or None.
        mask: boolean (n, n), True where the pixel is valid, or None (all valid); the
            numbers 0 and 1 are accepted for False and True.

    Raises InvalidInputError for a value of the wrong type or range: ``mu``/``extent`` not a
    positive real number (a string, None, bool, complex or array is refused, not converted),
    arrays that are not finite real numbers (complex, bool, text or ragged input is refused,
    not cast), wrong shapes, a σ ≤ 0, or a mask with entries other than True/False/0/1.
    """

    # the fields hold the validated values; the constructor takes what it converts (a Python or NumPy
    # number for mu/extent, any real 3-sequence for incident) and refuses the rest with InvalidInputError
    mu: float
    incident: np.ndarray
    extent: float
    values: np.ndarray
    sigma: np.ndarray | None
    mask: np.ndarray | None

    def __init__(
        self,
        mu: RealNumber,
        incident: Real[np.ndarray, "3"] | Sequence[float],
        extent: RealNumber,
        values: np.ndarray,
        sigma: np.ndarray | None = None,
        mask: np.ndarray | None = None,
    ):
        scale = real(mu, "mu", minimum=0, strict=True)
        inc = real_array(incident, "incident", 1)
        if inc.shape != (3,) or abs(np.linalg.norm(inc) - 1) > 1e-6 or inc[2] <= 0:
            raise InvalidInputError(f"incident must be a unit 3-vector with z > 0; got {inc!r}.")
        half_width = real(extent, "extent", minimum=0, strict=True)
        image = real_array(values, "values")
        if (
            image.ndim not in (2, 3)
            or image.shape[0] != image.shape[1]
            or image.shape[0] < 2
            or (image.ndim == 3 and image.shape[2] != 3)
        ):
            raise InvalidInputError(f"values must have shape (n, n) or (n, n, 3) with n ≥ 2; got {image.shape}.")
        if sigma is not None:
            sigma = real_array(sigma, "sigma")
            if sigma.shape != image.shape:
                raise InvalidInputError(f"sigma must have the shape of values {image.shape}; got {sigma.shape}.")
            if np.any(sigma <= 0):
                bad = np.argwhere(sigma <= 0)
                first = tuple(int(i) for i in bad[np.argmin(sigma[tuple(bad.T)])])
                raise InvalidInputError(
                    f"sigma of the image at μ = {scale:g}: {len(bad)} of {sigma.size} values ≤ 0 (smallest "
                    f"{float(sigma[first]):g} at index {first}); σ is each pixel's noise standard deviation, a "
                    "positive finite number — where it is unknown, mask the pixel (mask=False) instead."
                )
        if mask is not None:
            mask = boolean_mask(mask, "mask")
            if mask.shape != image.shape[:2]:
                raise InvalidInputError(f"mask must have shape {image.shape[:2]}; got {mask.shape}.")
        object.__setattr__(self, "mu", scale)
        object.__setattr__(self, "incident", inc)
        object.__setattr__(self, "extent", half_width)
        object.__setattr__(self, "values", image)
        object.__setattr__(self, "sigma", sigma)
        object.__setattr__(self, "mask", mask)

    @property
    def size(self) -> int:
        return self.values.shape[0]

    @property
    def incident_angles(self) -> tuple[float, float]:
        """``(θ_i, φ_i)`` of the incident direction in degrees (polar angle from the normal, azimuth)."""
        x, y, z = (float(c) for c in self.incident)
        return float(np.degrees(np.arccos(np.clip(z, -1, 1)))), float(np.degrees(np.arctan2(y, x)))

    def _show_items(self):
        theta, phi = self.incident_angles
        items = [
            ("mu", self.mu),
            ("incident", f"(θ {theta:.4g}°, φ {phi:.4g}°)"),
            ("extent", self.extent),
            ("values", self.values),
            ("sigma", self.sigma),
        ]
        if self.mask is not None:
            items.append(("mask", f"{int(np.count_nonzero(~self.mask))} of {self.mask.size} px masked"))
        return items

    def plot(self, **options):
        """A figure of the image and its σ: :func:`brdfscale.plot.measurements` of this image
        alone (options as there); returns a ``matplotlib.figure.Figure``."""
        return MeasurementSet((self,)).plot(**options)

    def offsets(self) -> np.ndarray:
        """Offsets ``u`` of the pixels, shape (n, n, 2): ``u[j, k] = (x_k, y_j)``."""
        x = np.linspace(-self.extent, self.extent, self.size)
        return np.stack(np.meshgrid(x, x, indexing="xy"), axis=-1)


_NO_METADATA = types.MappingProxyType({})


@dataclasses.dataclass(frozen=True, repr=False, init=False)
class MeasurementSet(Shown):
    """Lobe images of one material at several scales and incident directions.

    ``metadata`` is a dict of extras (e.g. the ground truth of a synthetic set) with str keys
    and JSON-serialisable values: its type is checked here (another mapping is copied into a
    dict), its JSON when :func:`brdfscale.exr.write_measurements` stores it.
    """

    # the fields hold the validated values; the constructor takes any sequence of images and any mapping
    images: tuple[LobeImage, ...]
    metadata: dict

    def __init__(self, images: Iterable[LobeImage], metadata: Mapping = _NO_METADATA):
        try:
            kept = tuple(images)
        except TypeError:
            raise InvalidInputError(
                f"images must be a non-empty sequence of LobeImage; got {type(images).__name__}."
            ) from None
        if not kept or not all(isinstance(p, LobeImage) for p in kept):
            raise InvalidInputError("images must be a non-empty sequence of LobeImage.")
        object.__setattr__(self, "images", kept)
        if not isinstance(metadata, Mapping):
            raise InvalidInputError(
                f"metadata must be a dict (str keys, JSON-serialisable values); got {type(metadata).__name__}."
            )
        object.__setattr__(self, "metadata", metadata if isinstance(metadata, dict) else dict(metadata))

    @property
    def scales(self) -> np.ndarray:
        """The distinct scales μ, ascending."""
        return np.unique([p.mu for p in self.images])

    def _show_items(self):
        images = self.images
        sizes = sorted({p.values.shape for p in images})
        angles = sorted({round(p.incident_angles[0], 2) for p in images})
        with_sigma = sum(p.sigma is not None for p in images)
        items = [
            ("images", len(images)),
            ("scales", Values(self.scales)),
            (
                "sizes",
                ", ".join("×".join(str(n) for n in shape) for shape in sizes[:3]) + (" …" if len(sizes) > 3 else ""),
            ),
            ("theta_i", "(" + ", ".join(f"{a:.4g}°" for a in angles[:6]) + (", …)" if len(angles) > 6 else ")")),
            (
                "sigma",
                "all"
                if with_sigma == len(images)
                else "none"
                if not with_sigma
                else f"{with_sigma} of {len(images)} images",
            ),
        ]
        masked = sum(p.mask is not None for p in images)
        if masked:
            items.append(("masks", f"{masked} of {len(images)} images"))
        if self.metadata:
            keys = list(self.metadata)
            items.append(("metadata", ", ".join(str(k) for k in keys[:5]) + (", …" if len(keys) > 5 else "")))
        return items

    def _show_tables(self):
        rows = []
        for i, p in enumerate(self.images):
            theta, phi = p.incident_angles
            rows.append(
                (
                    i,
                    p.mu,
                    f"{theta:.4g}°",
                    f"{phi:.4g}°",
                    p.extent,
                    "×".join(str(n) for n in p.values.shape),
                    "yes" if p.sigma is not None else "no",
                    "—" if p.mask is None else int(np.count_nonzero(~p.mask)),
                )
            )
        return [Table("images", ("image", "μ", "θ_i", "φ_i", "extent", "values", "σ", "masked px"), rows)]

    def plot(self, **options):
        """A figure of every image (values and σ): :func:`brdfscale.plot.measurements`
        (options as there); returns a ``matplotlib.figure.Figure``."""
        from ._figures import draw

        return draw("measurements", self, **options)
