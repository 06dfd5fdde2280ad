"""Facet-slope statistics ``s(m)`` and their transforms ``S(W)`` (seed §4, docs/conventions.md §1–2).

Every density class here (Delta, Gaussian, …, Tabulated) is an :class:`AbstractSlopeDensity`:
the probability density (mass 1) of a facet's slope relative to the global orientation (what
a histogram of facet slopes shows). Its base :class:`AbstractDistribution`, the transform
interface, is shared with :class:`AbstractGeneralisedDensity`: generalised functions of mass 0
with no pointwise density (the plus-distributions of :mod:`brdfscale.plus`), which are terms
of a statistic, not statistics. The seed's ``q`` in Eq. 4.2 is the reflection of ``s``,
``q(x) = s(−x)``, hence ``Q(W) = S(−W)``; Eq. 4.4 in this library's terms reads
``G(W, μ) = G(W, μ0) S(W, μ0) / S(W, μ)`` for a lobe ``g`` around the specular slope.
"""

from ._base import AbstractDistribution, AbstractGeneralisedDensity, AbstractSlopeDensity
from ._families import Beckmann, Delta, Disk, Gaussian, GGX
from ._grid import FrequencyGrid
from ._histogram import SlopeHistogram
from ._learned_laws import MonotoneSplineLaw, StudentTLaw
from ._masking import mean_slope, smith_lambda
from ._measured import MeasuredScaleLaw
from ._mixture import Mixture
from ._pixels import PixelGaussians
from ._require import require_density
from ._scale_laws import (
    AbstractPowerSpectrum,
    AbstractScaleLaw,
    GaussianCorrelation,
    GaussianSurface,
    KCorrelation,
    ScaledFamily,
    WidthLaw,
    window_power,
)
from ._student import StudentT
from ._tabulated import Tabulated


__all__ = [
    "AbstractDistribution",
    "AbstractSlopeDensity",
    "AbstractGeneralisedDensity",
    "FrequencyGrid",
    "Delta",
    "Gaussian",
    "Beckmann",
    "GGX",
    "Disk",
    "StudentT",
    "Mixture",
    "PixelGaussians",
    "require_density",
    "Tabulated",
    "SlopeHistogram",
    "AbstractPowerSpectrum",
    "GaussianCorrelation",
    "KCorrelation",
    "AbstractScaleLaw",
    "GaussianSurface",
    "WidthLaw",
    "ScaledFamily",
    "MeasuredScaleLaw",
    "MonotoneSplineLaw",
    "StudentTLaw",
    "window_power",
    "smith_lambda",
    "mean_slope",
]
