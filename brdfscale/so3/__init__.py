"""Anisotropic evolution on the rotation group SO(3) (seed §5, docs/conventions.md §3).

When a facet's twist about its normal matters (brushed metal, grooves, oriented fibres),
BRDFs and facet statistics are functions of the facet orientation Γ ∈ SO(3) and evolve
block by block in the Wigner-D basis.

* Rotations and Wigner matrices: :func:`euler_to_matrix`, :func:`matrix_to_euler`,
  :func:`wigner_d`, :func:`wigner_D` (z-y-z active, ``D = e^{−iMα} d(β) e^{−iM'γ}``).
* Transforms on the Kostelec–Rockmore grid: :func:`grid`, :func:`quadrature_weights`,
  :func:`forward`, :func:`inverse`, :func:`synthesize` (arbitrary rotations),
  :func:`analyse_points` (point sets, e.g. facet frames).
* Convolution and normalisation: :func:`convolve`, :func:`to_operator`,
  :func:`from_operator`, :func:`reflect`.
* Generators: :func:`angular_momentum`, :func:`diffusion_generator`, :func:`diffusion_operator`.
* Evolution: :func:`evolve`, :func:`evolve_diffusion`, :class:`DiffusionLaw`.
* Models: :class:`Identity`, :class:`RotationalDiffusion`, :class:`TiltTwist` (sampling grid
  chosen up to :data:`MAX_AUTO_RESOLUTION`), :class:`EmpiricalOrientations`,
  :class:`AnisotropicMicrofacetLobe`.
* Band limits: :func:`band_limit`, :func:`truncation_error`, :func:`gaussian_spectrum`.
"""

from ._bandlimit import band_limit, gaussian_spectrum, truncation_error
from ._convolution import convolve, from_operator, reflect, to_operator
from ._evolution import DiffusionLaw, evolve, evolve_diffusion
from ._generators import angular_momentum, diffusion_generator, diffusion_operator
from ._grid import grid, MAX_BAND_LIMIT, quadrature_weights
from ._models import (
    AbstractOrientationDensity,
    AnisotropicMicrofacetLobe,
    EmpiricalOrientations,
    Identity,
    MAX_AUTO_RESOLUTION,
    RotationalDiffusion,
    TiltTwist,
)
from ._rotations import euler_to_matrix, matrix_to_euler
from ._transform import analyse_points, forward, inverse, synthesize
from ._wigner import MAX_DEGREE, wigner_D, wigner_d


__all__ = [
    "euler_to_matrix",
    "matrix_to_euler",
    "wigner_d",
    "wigner_D",
    "MAX_DEGREE",
    "grid",
    "quadrature_weights",
    "MAX_BAND_LIMIT",
    "forward",
    "inverse",
    "synthesize",
    "analyse_points",
    "convolve",
    "to_operator",
    "from_operator",
    "reflect",
    "angular_momentum",
    "diffusion_generator",
    "diffusion_operator",
    "evolve",
    "evolve_diffusion",
    "DiffusionLaw",
    "AbstractOrientationDensity",
    "Identity",
    "RotationalDiffusion",
    "TiltTwist",
    "MAX_AUTO_RESOLUTION",
    "EmpiricalOrientations",
    "AnisotropicMicrofacetLobe",
    "band_limit",
    "truncation_error",
    "gaussian_spectrum",
]
