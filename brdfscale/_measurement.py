"""In-memory measurement sets: lobe images at several scales and incident directions.

A :class:`MeasurementSet` is what a (real or synthetic) gonioreflectometer delivers and
what the fitting code consumes; :mod:`brdfscale.exr` stores it as multi-part OpenEXR
(DESIGN §6). Each :class:`LobeImage` is one (scale μ, incident direction i) pair: the lobe
sampled on a regular ``n × n`` grid of half-vector slope offsets ``u = m_s − m∞`` whose
nodes span ``[−extent, extent]`` on both axes (rows u_y, columns u_x, as
:class:`brdfscale.stats.Tabulated`), with optional per-pixel standard deviations and a mask.
"""

import dataclasses
import math
from collections.abc import Mapping

import numpy as np

from ._errors import InvalidInputError

__all__ = ["LobeImage", "MeasurementSet"]


def _finite_array(x, name: str, ndim: int) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim != ndim:
        raise InvalidInputError(f"{name} must have {ndim} dimensions; got shape {a.shape}.")
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"{name} contains non-finite values.")
    return a


@dataclasses.dataclass(frozen=True)
class LobeImage:
    """One lobe image.

    Attributes:
        mu: the observation scale (facet size, length units of the surface; > 0).
        incident: unit direction towards the light, shape (3,), z > 0.
        extent: half-width ``a`` of the offset grid (slope units; > 0).
        values: the lobe ``A·g(u)`` (per unit slope area), shape (n, n), or
            (n, n, 3) for R, G, B.
        sigma: per-pixel standard deviation of ``values`` (same shape), or None.
        mask: boolean (n, n), True where the pixel is valid, or None (all valid).
    """

    mu: float
    incident: np.ndarray
    extent: float
    values: np.ndarray
    sigma: np.ndarray | None = None
    mask: np.ndarray | None = None

    def __post_init__(self):
        mu = float(self.mu)
        if not (math.isfinite(mu) and mu > 0):
            raise InvalidInputError(f"mu must be a positive finite scale; got {self.mu!r}.")
        inc = _finite_array(self.incident, "incident", 1)
        if inc.shape != (3,) or abs(np.linalg.norm(inc) - 1) > 1e-6 or inc[2] <= 0:
            raise InvalidInputError(f"incident must be a unit 3-vector with z > 0; got {inc!r}.")
        extent = float(self.extent)
        if not (math.isfinite(extent) and extent > 0):
            raise InvalidInputError(f"extent must be positive; got {self.extent!r}.")
        values = np.asarray(self.values, dtype=float)
        if values.ndim not in (2, 3) or values.shape[0] != values.shape[1] or values.shape[0] < 2 or (
            values.ndim == 3 and values.shape[2] != 3
        ):
            raise InvalidInputError(f"values must have shape (n, n) or (n, n, 3) with n ≥ 2; got {values.shape}.")
        if not np.all(np.isfinite(values)):
            raise InvalidInputError("values contains non-finite entries.")
        sigma = None
        if self.sigma is not None:
            sigma = np.asarray(self.sigma, dtype=float)
            if sigma.shape != values.shape or not np.all(np.isfinite(sigma)) or np.any(sigma <= 0):
                raise InvalidInputError(
                    f"sigma must be positive and finite with the shape of values {values.shape}; got {sigma.shape}."
                )
        mask = None
        if self.mask is not None:
            mask = np.asarray(self.mask).astype(bool)
            if mask.shape != values.shape[:2]:
                raise InvalidInputError(f"mask must have shape {values.shape[:2]}; got {mask.shape}.")
        object.__setattr__(self, "mu", mu)
        object.__setattr__(self, "incident", inc)
        object.__setattr__(self, "extent", extent)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "sigma", sigma)
        object.__setattr__(self, "mask", mask)

    @property
    def size(self) -> int:
        return self.values.shape[0]

    def offsets(self) -> np.ndarray:
        """Offsets ``u`` of the pixels, shape (n, n, 2): ``u[j, k] = (x_k, y_j)``."""
        x = np.linspace(-self.extent, self.extent, self.size)
        return np.stack(np.meshgrid(x, x, indexing="xy"), axis=-1)


@dataclasses.dataclass(frozen=True)
class MeasurementSet:
    """Lobe images of one material at several scales and incident directions.

    ``metadata`` is a dict of extras (e.g. the ground truth of a synthetic set) with str keys
    and JSON-serialisable values: its type is checked here (another mapping is copied into a
    dict), its JSON when :func:`brdfscale.exr.write_measurements` stores it.
    """

    images: tuple[LobeImage, ...]
    metadata: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        images = tuple(self.images)
        if not images or not all(isinstance(p, LobeImage) for p in images):
            raise InvalidInputError("images must be a non-empty sequence of LobeImage.")
        object.__setattr__(self, "images", images)
        if not isinstance(self.metadata, Mapping):
            raise InvalidInputError(
                f"metadata must be a dict (str keys, JSON-serialisable values); got {type(self.metadata).__name__}."
            )
        if not isinstance(self.metadata, dict):
            object.__setattr__(self, "metadata", dict(self.metadata))

    @property
    def scales(self) -> np.ndarray:
        """The distinct scales μ, ascending."""
        return np.unique([p.mu for p in self.images])
