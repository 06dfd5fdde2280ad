"""Facet-slope statistics ``s(m)`` and their transforms ``S(W)`` (seed §4, DESIGN §1–2).

Every class represents the density of a facet's slope relative to the global orientation
(what a histogram of facet slopes shows). The seed's ``q`` in Eq. 4.2 is its reflection,
``q(x) = s(−x)``, hence ``Q(W) = S(−W)``; Eq. 4.4 in this library's terms reads
``G(W, μ) = G(W, μ0) S(W, μ0) / S(W, μ)`` for a lobe ``g`` around the specular slope.
"""

from ._base import AbstractSlopeDensity
from ._grid import FrequencyGrid
from ._families import GGX, Beckmann, Delta, Disk, Gaussian
from ._histogram import SlopeHistogram
from ._mixture import Mixture
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
from ._tabulated import Tabulated

__all__ = [
    "AbstractSlopeDensity",
    "FrequencyGrid",
    "Delta",
    "Gaussian",
    "Beckmann",
    "GGX",
    "Disk",
    "Mixture",
    "Tabulated",
    "SlopeHistogram",
    "AbstractPowerSpectrum",
    "GaussianCorrelation",
    "KCorrelation",
    "AbstractScaleLaw",
    "GaussianSurface",
    "WidthLaw",
    "ScaledFamily",
    "window_power",
]
