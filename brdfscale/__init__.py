"""brdfscale: scale-dependent evolution of BRDFs (Pak 2016, "Scale-related evolution of BRDFs").

The public API:

* :mod:`brdfscale.stats` — facet-slope statistics ``s(m)``, their transforms, scale laws;
* :mod:`brdfscale.lobes` — BRDF lobes at one scale;
* :func:`brdfscale.evolve` — the evolution operator of seed Eq. 4.4, with its paths as objects
  (:class:`Auto`, :class:`ClosedForm`, :class:`Radial`, :class:`Grid`) and
  :func:`brdfscale.select`, which resolves their discretisation once from concrete values;
* :mod:`brdfscale.geometry` — directions, slopes, half vectors;
* :mod:`brdfscale.synth` — random height fields and a synthetic gonioreflectometer;
* :mod:`brdfscale.topography` — measured height maps: instrument files and arrays, detrended, masked;
* :mod:`brdfscale.exr` — measurement sets and lobe tables as OpenEXR files;
* :mod:`brdfscale.files` — atomic no-clobber writes and exclusive output locations;
* :mod:`brdfscale.plus` — plus-distributions and nearly-specular reflection (seed §6);
* :mod:`brdfscale.so3` — anisotropic evolution on SO(3) (seed §5);
* :mod:`brdfscale.scene` — a planner that evaluates only what a scene needs;
* :class:`MeasurementSet` / :class:`LobeImage` — multi-scale lobe measurements in memory;
* :mod:`brdfscale.checks` — argument checks for code built on brdfscale;
* :mod:`brdfscale.laplace` — the Laplace approximation of a fit and what its data determine (one policy for every fit);
* :mod:`brdfscale.special` — Bessel functions J0, J1, K0, x·K1 in pure JAX;
* :mod:`brdfscale.plot` — one-call matplotlib figures of lobes, statistics, measurements, plans, fits;
* :mod:`brdfscale.show` — the compact ``repr``/``_repr_html_`` of every object, and progress bars;
* :mod:`brdfscale.fitting` — inverse fitting of measurements (the repository's ``fitting/`` folder);
* the exception classes, all derived from :class:`BrdfscaleError`.

Importing brdfscale changes no global state (JAX's configuration, matplotlib's backend) and
imports only the exception classes: every submodule and name below is loaded on first use
(PEP 562) from the one table ``_TABLE``, so ``brdfscale --help`` starts without JAX. Precision
is the user's choice: the library computes in the dtype of its inputs, and code that needs float64 (the fits) says so
with :class:`InvalidInputError` naming the line to add,
``jax.config.update("jax_enable_x64", True)``.
"""

import importlib
from typing import TYPE_CHECKING

from ._errors import (
    BrdfscaleError,
    InvalidInputError,
    MeasurementFileError,
    MethodNotApplicableError,
    MissingDependencyError,
    NoBRDFAtScaleError,
    OutputInUseError,
    SingularDensityError,
    UnprotectedHeaderWarning,
    UnresolvedMethodError,
)

_TABLE = (  # the one list of the public names: (module relative to brdfscale, names); None: the submodules themselves
    ("._evolve", ("evolve", "select", "AbstractMethod", "Auto", "ClosedForm", "Radial", "Grid", "RadialTable")),
    ("._measurement", ("LobeImage", "MeasurementSet")),
    (None, ("geometry", "lobes", "stats", "synth", "topography", "plus", "so3", "scene", "exr", "files", "checks",
            "laplace", "special", "plot", "show", "fitting", "library")),
    ("._errors", ("BrdfscaleError", "InvalidInputError", "MeasurementFileError", "MethodNotApplicableError",
                  "MissingDependencyError", "NoBRDFAtScaleError", "SingularDensityError", "OutputInUseError",
                  "UnprotectedHeaderWarning", "UnresolvedMethodError")),
)
_LAZY = {name: where or f".{name}" for where, names in _TABLE for name in names}
"""Public name → the module (relative to brdfscale) it is loaded from; a submodule maps to itself."""

if TYPE_CHECKING:  # what the lazy loader below provides, for type checkers and IDEs (tests/test_layers.py: = _TABLE)
    from . import (checks, exr, files, fitting, geometry, laplace, library, lobes, plot, plus, scene, show, so3, special,
                   stats, synth, topography)
    from ._evolve import AbstractMethod, Auto, ClosedForm, Grid, Radial, RadialTable, evolve, select
    from ._measurement import LobeImage, MeasurementSet


def __getattr__(name: str):
    where = _LAZY.get(name)
    if where == f".{name}":
        value = importlib.import_module(where, __name__)
    elif where is not None:
        value = getattr(importlib.import_module(where, __name__), name)
    elif name == "__version__":
        from importlib.metadata import PackageNotFoundError, version

        try:
            value = version("brdfscale")
        except PackageNotFoundError:  # running from a source tree that is not installed
            value = "0.0.0+unknown"
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))


__all__ = [*_LAZY, "__version__"]
