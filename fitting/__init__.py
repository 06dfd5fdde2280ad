"""Inverse fitting: recover the facet-slope statistics S(W, μ) and the base lobe at μ0 from
multi-scale lobe measurements, with uncertainties (seed Eq. 4.4; docs/conventions.md §2).

The chain, each step in its own module:

* :class:`Dataset` — images of a :class:`brdfscale.MeasurementSet` with σ and masks;
* :class:`ParametricModel`, :class:`NonParametricModel`, :class:`AnisotropicModel` — forward maps
  θ ↦ images built on :func:`brdfscale.evolve` (the last, the command's default: a lobe of full
  covariance — Gaussian, GGX or Student-t — and ΔΣ(μ0, μk)), :class:`AnisotropicLawModel` (the same
  base lobe, ΔΣ from a continuous anisotropic scale law: any μ), :class:`AnisotropicNonParametricModel`
  (tabulated base lobe, ``R_k(W)`` over the W plane); :func:`compare` — which model the data prefer (AIC, BIC);
* :class:`TopographyData` — a topography's Σ(μ) as a joint data term (``Dataset.with_topography``);
* :func:`fit` — optimistix least squares (Levenberg–Marquardt by default), multi-start,
  Laplace covariance, identifiability (names the combinations the data cannot determine);
* :func:`fit_many` — many materials at once: padded, bucketed and divided over the devices,
  one compiled program per bucket (solves one at a time on CPUs, vmapped on accelerators),
  results equal to :func:`fit`'s (:func:`explain_plan`);
* :func:`sample` — emcee (:class:`Emcee`), BlackJAX NUTS (:class:`NUTS`) or HMC (:class:`HMC`), or independence
  Metropolis–Hastings from the Laplace approximation (:class:`IMH`), or by default :class:`Auto`: IMH where the
  Pareto k̂ of its proposal's importance weights (:func:`pareto_k`) says the approximation covers the posterior,
  NUTS elsewhere; on one posterior in smooth coordinates, ≥ 4 independent chains in one compiled program,
  chunked HDF5 checkpoints resumable bit for bit, ArviZ's R̂/ESS/MCSE and a status that
  names any failed criterion (:class:`SampleResult`, ``to_arviz()``);
* :func:`sample_many` — NUTS/HMC on many materials' posteriors at once: vmapped over the
  materials and sharded over the devices, one compiled program per bucket, each result
  :func:`sample`'s;
* :func:`moment_covariance_differences` — ΔΣ(μ0, μk) from the images' own second moments, no model;
* :func:`predict_from_measured` — unseen coarser scales from the lobe measured at the coarsest fitted scale,
  widened by a fitted scale law's increment (seed Eq. 4.4 started there); :func:`law_from_differences` — that law
  for the per-scale model, fitted to its ΔΣ estimates;
* :func:`assess` — can the outcome be trusted: the lobes resolved, the model adequate (χ²/dof
  per scale, residual structure: :func:`lag1_correlation`; where the misfit lies: :func:`away_from_lobe`), the
  optimiser and sampler converged (:class:`Outcome`, the ``brdfscale fit`` exit status);
* :func:`write_report` — fit.json, figures, evolved lobe tables; :func:`record_problem` — a problem found after it;
* :func:`plot_fit`, :func:`plot_recovered_statistics`, :func:`plot_corner` — the report's figures
  as ``matplotlib.figure.Figure`` objects made without pyplot (a notebook shows them; also
  ``brdfscale.plot.fit`` and its siblings, docs/plotting.md);
* :func:`simulate` — noisy measurement sets from a parametric model (tests, demo).

Importing this package changes no global state. The fits need float64 (optimistix's
Levenberg–Marquardt refuses mixed float32/float64 structures, and σ-whitened residuals of
well-measured lobes need the precision): start a script or notebook with
``jax.config.update("jax_enable_x64", True)``; without it :class:`Dataset` and
:class:`Problem` raise :class:`brdfscale.InvalidInputError` naming that line. The ``brdfscale``
command switches float64 on itself.

Import it as ``from brdfscale import fitting``: the repository's ``fitting/`` folder is
installed as ``brdfscale.fitting`` (pyproject's ``package-dir``), so no top-level package
named ``fitting`` is installed and a local ``fitting.py`` cannot take its place.
"""

from ._adequacy import assess, away_from_lobe, lag1_correlation, lobe_widths, Outcome, resolution
from ._anisotropic import AbstractCovarianceModel, AnisotropicModel
from ._anisotropic_law import AnisotropicLawModel
from ._batch import BatchPlan, COMPILE_ROWS, explain_plan, fit_many
from ._checkpoint import rewind_checkpoint
from ._compare import compare, Comparison
from ._data import Dataset, PointData
from ._derived import (
    compare_covariance_differences,
    covariance_truth,
    DIFFERENCE_ENTRIES,
    RATIO_FREQUENCIES,
    ratio_frequencies,
)
from ._diagnostics import pareto_k
from ._fit import fit, resolve_starts
from ._joint import TopographyData
from ._law_from_differences import law_from_differences, LawFromDifferences
from ._measured import MeasuredPrediction, predict_from_measured
from ._model import AbstractModel
from ._moments import moment_covariance_differences
from ._nonparametric import NonParametricModel, RelativeStatistics
from ._nonparametric_aniso import AnisotropicNonParametricModel
from ._parametric import ParametricModel
from ._plot import plot_corner, plot_fit, plot_recovered_statistics
from ._problem import Problem
from ._report import (
    check_report_directory,
    record_problem,
    report_files,
    summarise,
    summarise_ratios,
    truth_of,
    write_report,
)
from ._result import FitResult
from ._resume import report_problem, resume_report
from ._sample import Auto, Emcee, HMC, IMH, log_posterior, NUTS, sample, SampleResult, SAMPLERS
from ._sample_many import sample_many
from ._simulate import simulate
from ._solve import resolve_solver, SOLVERS


__all__ = [
    "COMPILE_ROWS",
    "DIFFERENCE_ENTRIES",
    "HMC",
    "IMH",
    "NUTS",
    "RATIO_FREQUENCIES",
    "SAMPLERS",
    "SOLVERS",
    "AbstractCovarianceModel",
    "AbstractModel",
    "Auto",
    "AnisotropicModel",
    "AnisotropicLawModel",
    "AnisotropicNonParametricModel",
    "BatchPlan",
    "Comparison",
    "Dataset",
    "Emcee",
    "FitResult",
    "LawFromDifferences",
    "MeasuredPrediction",
    "NonParametricModel",
    "Outcome",
    "ParametricModel",
    "PointData",
    "Problem",
    "RelativeStatistics",
    "SampleResult",
    "TopographyData",
    "assess",
    "away_from_lobe",
    "check_report_directory",
    "compare",
    "explain_plan",
    "fit",
    "fit_many",
    "lag1_correlation",
    "lobe_widths",
    "log_posterior",
    "plot_corner",
    "plot_fit",
    "plot_recovered_statistics",
    "law_from_differences",
    "predict_from_measured",
    "ratio_frequencies",
    "report_files",
    "resolve_solver",
    "resolve_starts",
    "report_problem",
    "resume_report",
    "rewind_checkpoint",
    "resolution",
    "sample",
    "sample_many",
    "simulate",
    "summarise",
    "summarise_ratios",
    "truth_of",
    "covariance_truth",
    "moment_covariance_differences",
    "pareto_k",
    "compare_covariance_differences",
    "write_report",
    "record_problem",
]
