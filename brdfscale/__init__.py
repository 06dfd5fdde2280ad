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
* :mod:`brdfscale.instrument` — a ray-traced multi-scale gonioreflectometer on Mitsuba 3 (extra ``[render]``);
* :mod:`brdfscale.render` — a scale-aware Mitsuba 3 BSDF and engine roughness export (extra ``[render]``);
* the exception classes, all derived from :class:`BrdfscaleError`.

Importing brdfscale changes no global state (JAX's configuration, matplotlib's backend) and
imports only the exception classes: every submodule and name below is loaded on first use
(PEP 562) from the one table ``_TABLE``, so ``brdfscale --help`` starts without JAX. Precision
is the user's choice: the library computes in the dtype of its inputs, and code that needs float64 (the fits) says so
with :class:`InvalidInputError` naming the line to add,
``jax.config.update("jax_enable_x64", True)``.
"""

import importlib
from typing import Any, TYPE_CHECKING

from ._errors import (
    BrdfscaleError as BrdfscaleError,
    InvalidInputError as InvalidInputError,
    LobeCutWarning as LobeCutWarning,
    MeasurementFileError as MeasurementFileError,
    MethodNotApplicableError as MethodNotApplicableError,
    MissingDependencyError as MissingDependencyError,
    NoBRDFAtScaleError as NoBRDFAtScaleError,
    OutputInUseError as OutputInUseError,
    OutputWriteError as OutputWriteError,
    SingularDensityError as SingularDensityError,
    ToleranceRelaxedWarning as ToleranceRelaxedWarning,
    UnprotectedHeaderWarning as UnprotectedHeaderWarning,
    UnresolvedMethodError as UnresolvedMethodError,
)


_TABLE = (  # the one list of the public names: (module relative to brdfscale, names); None: the submodules themselves
    ("._evolve", ("evolve", "select", "AbstractMethod", "Auto", "ClosedForm", "Radial", "Grid", "RadialTable")),
    ("._measurement", ("LobeImage", "MeasurementSet")),
    (
        None,
        (
            "geometry",
            "lobes",
            "stats",
            "synth",
            "topography",
            "plus",
            "so3",
            "scene",
            "exr",
            "files",
            "checks",
            "laplace",
            "special",
            "plot",
            "show",
            "fitting",
            "library",
            "instrument",
            "render",
        ),
    ),
    (
        "._errors",
        (
            "BrdfscaleError",
            "InvalidInputError",
            "LobeCutWarning",
            "MeasurementFileError",
            "MethodNotApplicableError",
            "MissingDependencyError",
            "NoBRDFAtScaleError",
            "SingularDensityError",
            "OutputInUseError",
            "OutputWriteError",
            "ToleranceRelaxedWarning",
            "UnprotectedHeaderWarning",
            "UnresolvedMethodError",
        ),
    ),
)
_LAZY = {name: where or f".{name}" for where, names in _TABLE for name in names}
"""Public name → the module (relative to brdfscale) it is loaded from; a submodule maps to itself."""

if TYPE_CHECKING:  # what the lazy loader below provides, for type checkers and IDEs (tests/test_imports.py: = _TABLE)
    from . import (
        checks as checks,
        exr as exr,
        files as files,
        fitting as fitting,
        geometry as geometry,
        instrument as instrument,
        laplace as laplace,
        library as library,
        lobes as lobes,
        plot as plot,
        plus as plus,
        render as render,
        scene as scene,
        show as show,
        so3 as so3,
        special as special,
        stats as stats,
        synth as synth,
        topography as topography,
    )
    from ._evolve import (
        AbstractMethod as AbstractMethod,
        Auto as Auto,
        ClosedForm as ClosedForm,
        evolve as evolve,
        Grid as Grid,
        Radial as Radial,
        RadialTable as RadialTable,
        select as select,
    )
    from ._measurement import LobeImage as LobeImage, MeasurementSet as MeasurementSet

    __version__: str


def __getattr__(name: str) -> Any:
    where = _LAZY.get(name)
    if where is not None:
        module = importlib.import_module(where, __name__)
        value = module if where == f".{name}" else getattr(module, name)
    elif name == "__version__":
        from importlib.metadata import PackageNotFoundError, version

        try:
            value = version("brdfscale")
        except PackageNotFoundError:  # running from a source tree that is not installed
            value = "0.0.0+unknown"
    else:
        from ._shadow import (
            hint,  # names the installed brdfscale when this copy shadows it
        )

        raise AttributeError(f"module {__name__!r} has no attribute {name!r}{hint(__file__)}")
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))


# built from _TABLE (tests/test_imports.py); type checkers read the TYPE_CHECKING imports above
__all__ = [*_LAZY, "__version__"]  # noqa: PLE0604  # pyright: ignore[reportUnsupportedDunderAll]
