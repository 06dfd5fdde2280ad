"""brdfscale: scale-dependent evolution of BRDFs (Pak 2016, "Scale-related evolution of BRDFs").

The public API:

* :mod:`brdfscale.stats` — facet-slope statistics ``s(m)``, their transforms, scale laws;
* :mod:`brdfscale.lobes` — BRDF lobes at one scale;
* :func:`brdfscale.evolve` — the evolution operator of seed Eq. 4.4, with its paths as objects
  (:class:`Auto`, :class:`ClosedForm`, :class:`Radial`, :class:`Grid`) and
  :func:`brdfscale.select`, which resolves their discretisation once from concrete values;
* :mod:`brdfscale.geometry` — directions, slopes, half vectors;
* :mod:`brdfscale.synth` — random height fields and a synthetic gonioreflectometer;
* :mod:`brdfscale.exr` — measurement sets and lobe tables as OpenEXR files;
* :mod:`brdfscale.files` — atomic no-clobber writes and exclusive output locations;
* :mod:`brdfscale.plus` — plus-distributions and nearly-specular reflection (seed §6);
* :mod:`brdfscale.so3` — anisotropic evolution on SO(3) (seed §5);
* :mod:`brdfscale.scene` — a planner that evaluates only what a scene needs;
* :class:`MeasurementSet` / :class:`LobeImage` — multi-scale lobe measurements in memory;
* the exception classes, all derived from :class:`BrdfscaleError`.
"""

from importlib.metadata import PackageNotFoundError, version as _version

from . import exr, files, geometry, lobes, plus, scene, so3, stats, synth
from ._errors import (
    BrdfscaleError,
    InvalidInputError,
    MeasurementFileError,
    MethodNotApplicableError,
    NoBRDFAtScaleError,
    OutputInUseError,
    SingularDensityError,
    UnprotectedHeaderWarning,
    UnresolvedMethodError,
)
from ._evolve import AbstractMethod, Auto, ClosedForm, Grid, Radial, RadialTable, evolve, select
from ._measurement import LobeImage, MeasurementSet

try:
    __version__ = _version("brdfscale")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"

__all__ = [
    "evolve",
    "select",
    "AbstractMethod",
    "Auto",
    "ClosedForm",
    "Radial",
    "Grid",
    "RadialTable",
    "UnresolvedMethodError",
    "LobeImage",
    "MeasurementSet",
    "geometry",
    "lobes",
    "stats",
    "synth",
    "plus",
    "so3",
    "scene",
    "exr",
    "files",
    "BrdfscaleError",
    "InvalidInputError",
    "MeasurementFileError",
    "MethodNotApplicableError",
    "NoBRDFAtScaleError",
    "SingularDensityError",
    "OutputInUseError",
    "UnprotectedHeaderWarning",
    "__version__",
]
