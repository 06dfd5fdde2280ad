"""Inverse fitting: recover the facet-slope statistics S(W, μ) and the base lobe at μ0 from
multi-scale lobe measurements, with uncertainties (seed Eq. 4.4; DESIGN §2).

The chain, each step in its own module:

* :class:`Dataset` — images of a :class:`brdfscale.MeasurementSet` with σ and masks;
* :class:`ParametricModel`, :class:`NonParametricModel` — forward maps θ ↦ images built on
  :func:`brdfscale.evolve`;
* :func:`fit` — optimistix least squares (Levenberg–Marquardt by default), multi-start,
  Laplace covariance, identifiability (names the combinations the data cannot determine);
* :func:`sample` — emcee with chunked, resumable HDF5 checkpoints, τ and ESS;
* :func:`write_report` — fit.json, figures, evolved lobe tables;
* :func:`simulate` — noisy measurement sets from a parametric model (tests, demo).

Importing this package enables ``jax_enable_x64``: the fits run in float64 (optimistix's
Levenberg–Marquardt refuses mixed float32/float64 structures, and σ-whitened residuals of
well-measured lobes need the precision).
"""

import jax

jax.config.update("jax_enable_x64", True)

from ._data import Dataset, PointData  # noqa: E402
from ._estimate import SOLVERS, FitResult, Problem, fit  # noqa: E402
from ._models import AbstractModel, NonParametricModel, ParametricModel, RelativeStatistics  # noqa: E402
from ._report import summarise, truth_of, write_report  # noqa: E402
from ._sample import SampleResult, log_posterior, sample  # noqa: E402
from ._simulate import simulate  # noqa: E402

__all__ = [
    "Dataset",
    "PointData",
    "AbstractModel",
    "ParametricModel",
    "NonParametricModel",
    "RelativeStatistics",
    "Problem",
    "FitResult",
    "fit",
    "SOLVERS",
    "SampleResult",
    "sample",
    "log_posterior",
    "summarise",
    "write_report",
    "truth_of",
    "simulate",
]
