"""Random height fields and synthetic multi-scale measurements (docs/conventions.md §2, §6).

* Surfaces: :func:`spectral_field` (Gaussian random fields with any
  :mod:`brdfscale.stats` power spectrum — Gaussian-correlated, anisotropic, K-correlation /
  ABC fractal), :func:`scratches` and :func:`blazed` (non-Gaussian micro-structure), the
  built-in named surfaces of :func:`named_surface`; all in a :class:`HeightField` — the one
  height-field type, which also holds measured surfaces (rectangular, per-axis pitch, a mask
  of unmeasured pixels, not periodic) from :mod:`brdfscale.topography`.
* Statistics: :func:`facet_slopes`, :func:`pixel_slopes`, :func:`facet_statistics` (``s(·, μ)`` and the
  within-facet lobe ``g_μ`` as :class:`brdfscale.stats.Tabulated`, with facet counts,
  effective independent facets and standard errors of ``Σ(μ)``), :func:`global_slopes`,
  :func:`steepest_slope`, :func:`offset_moments` (the moments of the lobe a measurement at μ holds).
* Measurements: :func:`gonioreflectometer` turns a surface into a
  :class:`brdfscale.MeasurementSet` with :class:`PoissonNoise` or :class:`GaussianNoise`
  and an optional angular resolution; :func:`robust_extent` sizes its images from robust slope quantiles.

Every random generator takes an explicit ``seed`` (int, NumPy Generator or JAX key).
Bad arguments raise :class:`brdfscale.InvalidInputError` before any work; every grid is
bounded by :data:`MAX_GRID_BYTES` (2**31 bytes of float64 nodes, 16384² — use tiles or
coarser grids beyond), Poisson counts by :data:`MAX_EXPECTED_COUNT` (1e18).
"""

from ._facets import (
    facet_slopes,
    facet_statistics,
    FacetStatistics,
    global_slopes,
    offset_moments,
    pixel_slopes,
    steepest_slope,
)
from ._gonio import GaussianNoise, gonioreflectometer, LIGHT_INSIDE, MAX_EXPECTED_COUNT, PoissonNoise, robust_extent
from ._named import named_surface, SURFACES
from ._profiles import blazed, scratches
from ._random import as_generator
from ._spectral import spectral_field
from ._surface import HeightField, MAX_GRID_BYTES


__all__ = [
    "HeightField",
    "spectral_field",
    "scratches",
    "blazed",
    "SURFACES",
    "named_surface",
    "FacetStatistics",
    "facet_slopes",
    "pixel_slopes",
    "facet_statistics",
    "global_slopes",
    "offset_moments",
    "steepest_slope",
    "GaussianNoise",
    "PoissonNoise",
    "gonioreflectometer",
    "robust_extent",
    "LIGHT_INSIDE",
    "as_generator",
    "MAX_GRID_BYTES",
    "MAX_EXPECTED_COUNT",
]
