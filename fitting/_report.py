"""The main job's outputs: fit.json, figures (matplotlib) and evolved lobe tables.

The figures are those of :func:`fitting.plot_fit`, :func:`fitting.plot_recovered_statistics` and
:func:`fitting.plot_corner` (:mod:`fitting._plot`, the one place that draws them), on
:class:`matplotlib.figure.Figure` objects made without pyplot, so writing a report touches
neither pyplot's figure list nor the backend a notebook or script has chosen; matplotlib
itself is imported only when a figure is drawn.

``write_report`` is the only place in :mod:`fitting` that writes report files. Every file is
written through :func:`brdfscale.files.atomic_write` (a hidden temporary file in the output
directory, moved into place); before anything is written, every file the report would write
is checked, and none that exists is overwritten unless ``overwrite=True``.
"""

import math
import os
import platform
from typing import cast

import jax.numpy as jnp
import numpy as np

import brdfscale
from brdfscale import BrdfscaleError, InvalidInputError, MeasurementFileError, OutputWriteError
from brdfscale.checks import flag
from brdfscale.choices import ADEQUACY
from brdfscale.files import atomic_write, exclusive, json_text, jsonable, write_bytes, write_text

from ._adequacy import assess_against, with_adequacy_problem
from ._derived import compare_covariance_differences
from ._model import predict_images
from ._moments import moment_covariance_differences
from ._parametric import ParametricModel
from ._plot import (
    _quantities,
    _relative,
    check_samples,
    check_truth,
    CORNER_DRAWS,
    corner_figure,
    plot_fit,
    posterior_draws,
    statistics_figure,
    truth_theta,
)
from ._problem import check_fit, Problem
from ._result import FitResult
from ._sample import SampleResult


__all__ = ["summarise", "write_report", "record_problem", "truth_of", "report_files", "check_report_directory"]

_FIGURES = ("data_vs_fit.png", "statistics.png", "corner.png")
_TABLES = "evolved_lobes.exr"
_POSTERIOR = "posterior.nc"  # the samples as ArviZ InferenceData in NetCDF (with the extra brdfscale[mcmc])


def _atomic(path, write, overwrite: bool):
    """Write ``path`` atomically; without ``overwrite`` an existing file is never replaced
    (write_report has checked up front; this also holds against a file created meanwhile:
    InvalidInputError, as from the check)."""
    atomic_write(path, write, overwrite=overwrite, error=InvalidInputError)


def _arviz_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("arviz") is not None


def _write_posterior(out_dir, samples, overwrite: bool) -> str:
    """``posterior.nc``: :meth:`SampleResult.to_arviz` as NetCDF (``arviz.from_netcdf`` reads it)."""
    if not _arviz_available():
        return 'not written: ArviZ is not installed (pip install "brdfscale[mcmc]")'
    data = samples.to_arviz()
    path = os.path.join(out_dir, _POSTERIOR)
    # HDF5 that meets a full disk cannot recover (tracebacks from its destructors, then a segfault):
    # the file is made in memory and written through the checked write path (OutputWriteError)
    write_bytes(path, _netcdf_bytes(data), overwrite=overwrite, error=InvalidInputError)
    return path


def _netcdf_bytes(data) -> bytes:
    """``data.to_netcdf(path)``'s file (ArviZ's layout: attributes at the root, one group per
    InferenceData group, zlib on numeric variables) made in memory with h5netcdf."""
    import io

    import xarray as xr

    buffer, mode = io.BytesIO(), "w"
    if data.attrs:
        xr.Dataset(attrs=data.attrs).to_netcdf(buffer, mode=mode, engine="h5netcdf", group="/")
        mode = "a"
    for group in data.groups():
        ds = getattr(data, group)
        encoding = {name: {"zlib": True} for name, v in ds.variables.items() if v.dtype.kind in "biufc"}
        ds.to_netcdf(buffer, mode=mode, engine="h5netcdf", group=group, encoding=encoding)
        mode = "a"
    return buffer.getvalue()


def _exr_available() -> bool:
    try:
        from brdfscale import exr  # noqa: F401
    except ImportError:
        return False
    return True


def report_files(out_dir) -> list[str]:
    """The paths :func:`write_report` writes into ``out_dir`` (fit.json last: it is written
    when everything else is in place)."""
    names = (
        list(_FIGURES)
        + ([_TABLES] if _exr_available() else [])
        + ([_POSTERIOR] if _arviz_available() else [])
        + ["fit.json"]
    )
    return [os.path.join(os.fspath(out_dir), name) for name in names]


def check_report_directory(out_dir, overwrite: bool = False) -> list[str]:
    """Check that a report can be written into ``out_dir`` without clobbering anything, and
    create the directory; return :func:`report_files`.

    Raises:
        MeasurementFileError: ``out_dir`` exists but is not a directory, or cannot be created.
        InvalidInputError: without ``overwrite``, some report files already exist there
            (all of them are listed).
    """
    try:
        out_dir = os.fspath(out_dir)
    except TypeError:
        raise InvalidInputError(f"out_dir must be a path; got {type(out_dir).__name__} {out_dir!r}.") from None
    overwrite = flag(overwrite, "overwrite")
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise MeasurementFileError(
            f"report directory {out_dir} exists but is not a directory; give out_dir= a "
            "directory (existing or to be created)."
        )
    targets = report_files(out_dir)
    existing = [os.path.basename(t) for t in targets if os.path.lexists(t)]
    if existing and not overwrite:
        raise InvalidInputError(
            f"{out_dir} already holds {', '.join(existing)}, which the report would overwrite; choose another "
            "out_dir= or pass overwrite=True."
        )
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as err:
        raise MeasurementFileError(f"report directory {out_dir} cannot be created: {err}") from None
    return targets


def truth_of(model, metadata: dict) -> dict | None:
    """Ground-truth quantities from a measurement set's metadata, where they match the model.

    Recognised: ``{"truth": {"params": {name: value}}}`` (written by :func:`fitting.simulate`),
    and for ``law="gaussian_surface"`` the spectrum of a :mod:`brdfscale.synth` surface
    (``surface.spectrum`` of type GaussianCorrelation with an isotropic correlation length)
    plus its ``albedo`` as the amplitude, and for a Beckmann base lobe the width of the
    synthetic lobe at μ0 derived from the surface's recorded slope covariances
    (:func:`_synth_base_width`). Returns the known subset, or None.
    """
    if not isinstance(metadata, dict) or not isinstance(model, ParametricModel):
        return None
    params = metadata.get("truth", {}).get("params") if isinstance(metadata.get("truth"), dict) else None
    truth = {}
    if isinstance(params, dict):
        truth = {p: _truth_value(params[p], f"truth.params.{p}") for p in model.parameters if p in params}
    spectrum = metadata.get("surface", {}).get("spectrum") if isinstance(metadata.get("surface"), dict) else None
    if (
        model.law_kind == "gaussian_surface"
        and isinstance(spectrum, dict)
        and spectrum.get("type") == "GaussianCorrelation"
    ):
        raw = spectrum.get("correlation_length")
        ell = [
            _truth_value(v, "surface.spectrum.correlation_length") for v in (raw if isinstance(raw, list) else [raw])
        ]
        if np.allclose(ell, ell[0]):
            truth.update(
                rms_height=_truth_value(spectrum.get("rms_height"), "surface.spectrum.rms_height"),
                correlation_length=ell[0],
            )
        if metadata.get("albedo") is not None:
            truth["amplitude"] = _truth_value(metadata["albedo"], "albedo")
    if model.lobe == "beckmann" and "alpha_lobe" not in truth:
        width = _synth_base_width(metadata)
        if width is not None:
            truth["alpha_lobe"] = width
    return truth or None


def _synth_base_width(metadata: dict) -> float | None:
    """The Beckmann width with the second moment of a :func:`brdfscale.synth.gonioreflectometer`
    lobe at its finest scale μ0, from the measurement set's own record of its surface.

    The lobe at μ0 is the density of the pixel facets' slopes relative to their facet's mean
    slope, blurred by the micro lobe and the instrument's resolution, and binned onto the image
    nodes with bilinear (cloud-in-cell) weights, which convolves it with a tent of one node pitch
    h per axis (variance h²/6 per axis). By the law of total variance its covariance is
    ``Σ_micro + (C_pixel − C_μ0) + (resolution² + h²/6)·I``, where ``C_pixel`` and ``C_μ0`` are
    the recorded covariances of the pixel and μ0-facet slopes of this very surface (a facet's
    slope is the mean of its pixels' slopes); a Beckmann lobe of width α has ``tr Σ = α²``. So
    ``α_lobe`` is the square root of that trace — the width of a Beckmann lobe with the measured
    lobe's second moment, for this realisation (the spectrum's ``rms_height`` and ``correlation_length``
    are those of the ensemble). None when the record lacks any of these (e.g. a file from elsewhere) or the
    micro lobe is not Gaussian (Beckmann) or a mirror.
    """
    record, micro = metadata.get("truth"), metadata.get("micro")
    scales, resolution = metadata.get("scales"), metadata.get("resolution", 0.0)
    if (
        metadata.get("generator") != "brdfscale.synth.gonioreflectometer"
        or not isinstance(record, dict)
        or not isinstance(micro, dict)
    ):
        return None
    try:
        pixel = np.asarray(record["pixel_slope_covariance"], dtype=float)
        facets = np.asarray(record["facet_slope_covariance"], dtype=float)
        first = int(np.argmin(np.asarray(scales, dtype=float)))
        if micro.get("type") == "Delta":
            micro_trace = 0.0
        elif micro.get("type") == "Gaussian" and micro.get("mean") is None:
            micro_trace = float(np.trace(np.asarray(micro["cov"], dtype=float)))
        else:
            return None
        pitch = 2.0 * float(metadata["extent"]) / (int(metadata["pixels"]) - 1)
        second = micro_trace + float(np.trace(pixel - facets[first])) + 2.0 * float(resolution) ** 2 + pitch**2 / 3.0
    except (KeyError, TypeError, ValueError, IndexError, AttributeError):
        return None
    return math.sqrt(second) if math.isfinite(second) and second > 0 else None


def _truth_value(value, key: str) -> float:
    """A known-truth number from metadata: positive and finite (every parameter is), or
    InvalidInputError naming the metadata key."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise InvalidInputError(
            f"metadata {key} must be a positive finite number (a known true value); got "
            f"{value!r:.80}. Correct or remove it from the measurement set's metadata."
        )
    return float(value)


def summarise(problem: Problem, fit: FitResult, samples: SampleResult | None, truth: dict | None) -> dict:
    """Per-quantity table: estimate, std, 5/50/95 % quantiles (MCMC when sampled, else Laplace).

    A quantity the fit's identifiability analysis (:mod:`brdfscale.laplace`) finds undetermined
    gets no standard deviation and no quantiles — not even from the chain, whose spread along an
    undetermined direction is the prior's, not a measurement: its row carries ``prior_range``
    (the quantity at the prior box's lower and upper corner; for log-uniform parameters their
    bounds) and a note pointing at the determined combinations and ratios (:func:`summarise_ratios`).
    """
    model = problem.model
    table = {}
    if samples is not None:
        q = {k: np.asarray(v) for k, v in _quantities(model, jnp.asarray(samples.samples)).items()}
    corners = [
        {k: float(v) for k, v in model.quantities(jnp.asarray(b)).items()} for b in (problem.lower, problem.upper)
    ]
    for name, value in fit.estimates.items():
        determined = fit.std[name] is not None
        row = {"estimate_map": value, "determined": determined}
        if not determined:
            row.update(
                source="prior",
                std=None,
                quantiles_5_50_95=None,
                median=None,
                prior_range=sorted([corners[0][name], corners[1][name]]),
                note="not determined by the data (identifiability); no interval is reported — the data determine "
                "the combinations and ratios in identifiability.determined_combinations and ratios",
            )
        elif samples is not None:
            row.update(
                source="mcmc",
                median=float(np.median(q[name])),
                std=float(np.std(q[name])),
                quantiles_5_50_95=np.percentile(q[name], [5, 50, 95]).tolist(),
            )
        else:
            quantiles = fit.quantiles[name]
            row.update(
                source="laplace",
                std=fit.std[name],
                quantiles_5_50_95=quantiles,
                median=None if quantiles is None else quantiles[1],
            )
        if truth is not None and name in truth:
            row["truth"] = truth[name]
        table[name] = row
    return table


def summarise_ratios(problem: Problem, fit: FitResult, samples: SampleResult | None) -> dict:
    """The ratios ``S(W, μ0)/S(W, μ_k)`` the data determine (:attr:`FitResult.ratios`), with the
    chain's median, std and 5/50/95 % quantiles when sampled (else the fit's Laplace values).

    A ratio that is not a number where it is evaluated (``S(W, μ0)`` and ``S(W, μ_k)`` both 0 in
    float64: ``0/0``, e.g. a scale law at the edge of its prior box at the largest |W|) is
    undefined there: the fit holds None for it (fitting._analysis), and sampled, its median, std
    and quantiles are None (JSON null, "undetermined" everywhere in fitting) unless every draw
    has a finite value (tests/test_scale_invariance.py)."""
    if samples is None or not fit.ratios:
        return {name: {**r, "source": "laplace"} for name, r in fit.ratios.items()}
    W = jnp.asarray(sorted({r["W"] for r in fit.ratios.values()}))
    values = np.asarray(_relative(problem.model, jnp.asarray(samples.samples), W, problem.data))[:, 1:]
    values = values.reshape(values.shape[0], -1)
    out = {}
    for i, (name, r) in enumerate(fit.ratios.items()):
        v = values[:, i]
        defined = bool(np.all(np.isfinite(v)))
        out[name] = {
            **r,
            "source": "mcmc",
            "median": float(np.median(v)) if defined else None,
            "std": float(np.std(v)) if defined else None,
            "quantiles_5_50_95": np.percentile(v, [5, 50, 95]).tolist() if defined else None,
        }
    return out


def _save(path, fig, dpi: int, overwrite: bool):
    _atomic(path, lambda p: fig.savefig(p, dpi=dpi, format="png"), overwrite)


def _write_tables(out_dir, problem: Problem, fit: FitResult, overwrite: bool) -> list[str] | str:
    """Evolved lobes at every measured scale (at the estimate) as EXR, via brdfscale.exr."""
    try:
        from brdfscale import exr
    except ImportError:
        return "not written: brdfscale.exr is not available in this installation"
    data, model = problem.data, problem.model
    theta = jnp.clip(jnp.asarray(fit.theta), problem.lower, problem.upper)
    pred = np.asarray(predict_images(model, theta, data))
    images = []
    for k, mu in enumerate(np.asarray(data.scales)):
        i = data.scale_of_image.index(k)
        images.append(
            brdfscale.LobeImage(
                mu=float(mu),
                incident=np.array([0.0, 0.0, 1.0]),
                extent=data.extents[i],
                values=np.clip(data.image(i, pred[i]), 0, None),
            )
        )
    path = os.path.join(out_dir, "evolved_lobes.exr")
    exr.write_measurements(
        path, brdfscale.MeasurementSet(tuple(images), metadata={"source": "brdfscale fit"}), overwrite=overwrite
    )
    return [path]


def write_report(
    out_dir,
    problem: Problem,
    fit: FitResult,
    samples: SampleResult | None = None,
    *,
    truth: dict | None = None,
    model_info: dict | None = None,
    overwrite: bool = False,
    figures: bool = True,
    unit: str | None = None,
    covariance_truth: list | None = None,
    not_sampled: str | None = None,
) -> dict:
    """Write ``fit.json``, ``data_vs_fit.png``, ``statistics.png``, ``corner.png``, the
    evolved lobe tables (``evolved_lobes.exr``) and, for a sampled fit with ArviZ installed,
    the samples as ArviZ InferenceData in NetCDF (``posterior.nc``) into ``out_dir`` (created
    if missing); return the JSON document. Its ``mcmc`` section holds the sampler's record, its
    status and ArviZ's summary (ess_bulk, ess_tail, r_hat, MCSE) of every coordinate and quantity.

    ``figures=False`` leaves the three PNG figures out (matplotlib's drawing takes most of a
    report's time; :mod:`brdfscale.library` writes them only when asked). With ``overwrite``,
    the files of an earlier report in ``out_dir`` that this one does not write (figures,
    tables, ``posterior.nc``) are removed, so the directory never mixes two reports.

    ``outcome`` holds :func:`fitting.assess`'s verdict — lobes resolved, the model adequate
    (χ²/dof per scale, residual structure), optimiser and sampler converged — with its one-line
    reason and the per-scale figures (``brdfscale fit`` maps its status to the exit status).
    ``unit``: the length unit of the scales μ (the measurement set's ``metadata["unit"]``; None:
    pixels of the height field), in ``data.unit``, the figures' titles and the outcome's reason.
    ``moment_covariance_differences``: ΔΣ(μ0, μ_k) from the images' own second moments
    (:func:`fitting.moment_covariance_differences`: no model; ``truncated`` where an image's edge holds light).
    ``covariance_truth``: the true ΔΣ(μ0, μ_k) of the surface the set was made from
    (:func:`fitting.covariance_truth` of its metadata); each entry of ``covariance_differences`` and
    ``moment_covariance_differences`` then also holds its ``truth`` and ``pull``
    (:func:`fitting.compare_covariance_differences`), and the verdict tests the fit's ΔΣ against it
    (:func:`fitting.assess`'s ``covariance_truth``). ``not_sampled``: why a fit that was to be sampled was not
    (``brdfscale fit`` does not sample a fit whose Laplace-level verdict is "inadequate"); ``mcmc`` then reads
    ``{"status": "not sampled: …"}`` instead of null.

    Everything is checked before the first file is written: the arguments, and (without
    ``overwrite``) that none of those files exists. ``fit.json`` is written last.

    Raises:
        InvalidInputError: without ``overwrite``, any of the report's files exists in
            ``out_dir`` (the message lists them); ``fit`` or ``samples`` do not belong to
            ``problem``'s model; ``truth`` is not a dict of finite numbers (for a parametric
            model, positive ones); ``model_info`` is not a JSON-serialisable dict; ``unit`` is
            neither a string nor None.
        MeasurementFileError: ``out_dir`` exists but is not a directory, or it or a report
            file cannot be created or written.
    """
    check_fit(problem, fit, "write_report(out_dir, problem, fit)")
    check_samples(fit, samples, "write_report(out_dir, problem, fit, samples)")
    truth = check_truth(truth)
    if model_info is not None and not isinstance(model_info, dict):
        raise InvalidInputError(f"model_info must be a dict or None; got {type(model_info).__name__}.")
    if unit is not None and not isinstance(unit, str):
        raise InvalidInputError(f"unit must be a length unit's name (str) or None; got {type(unit).__name__}.")
    if not_sampled is not None and (samples is not None or not isinstance(not_sampled, str) or not not_sampled):
        raise InvalidInputError(
            "not_sampled must be None or, for a fit given without samples, a non-empty str saying why it was not "
            f"sampled; got {not_sampled!r}" + (" with samples." if samples is not None else ".")
        )
    overwrite = flag(overwrite, "overwrite")
    # everything that can fail on the arguments is computed before the first file is written
    model = problem.model
    true_theta = truth_theta(model, truth, fit)
    figures = flag(figures, "figures")
    # the draws of plot_recovered_statistics and plot_corner, drawn only for the figures
    draws = posterior_draws(problem, fit, samples) if figures else None
    corner_draws = posterior_draws(problem, fit, samples, n=CORNER_DRAWS) if figures else None
    observed_moments = moment_covariance_differences(problem.data)  # the verdict's and fit.json's
    fit_json = fit.to_json()
    doc = {
        "brdfscale_version": brdfscale.__version__,
        "python": platform.python_version(),
        "model": model_info or {"kind": type(model).__name__},
        "data": {
            "scales": np.asarray(problem.data.scales).tolist(),
            "images": len(problem.data.scale_of_image),
            "valid_pixels": problem.data.n_data,
            "unit": unit,
        },
        "outcome": assess_against(
            problem,
            fit,
            samples,
            unit=unit,
            thresholds=ADEQUACY,
            observed_moments=observed_moments,
            covariance_truth=covariance_truth,
        ).to_json(),
        "parameters": summarise(problem, fit, samples, truth),
        "ratios": summarise_ratios(problem, fit, samples),
        # ΔΣ(μ0, μk) ± Laplace std, with truth and pulls where the set records its surface (fitting._derived)
        "covariance_differences": compare_covariance_differences(fit.covariance_differences, covariance_truth),
        # their joint covariance (per coarser scale xx, xy, yy; null where an entry has no std): FitResult's
        "differences_covariance": fit_json["differences_covariance"],
        # the same from the images' own second moments, model-independent (fitting._moments)
        "moment_covariance_differences": compare_covariance_differences(observed_moments, covariance_truth),
        "identifiability": fit_json["identifiability"],
        "optimisation": {
            k: v
            for k, v in fit_json.items()
            if k not in ("identifiability", "ratios", "covariance_differences", "differences_covariance")
        },
        "mcmc": (
            samples.diagnostics()
            if samples is not None
            else None
            if not_sampled is None
            else {"status": f"not sampled: {not_sampled}"}
        ),
    }
    try:
        json_text(doc)
    except (TypeError, ValueError) as err:
        raise InvalidInputError(f"model_info must hold JSON values only (str, numbers, lists, dicts): {err}.") from None

    check_report_directory(out_dir, overwrite)
    out_dir = os.fspath(out_dir)
    with exclusive(out_dir, what="report directory"):  # re-entrant: `brdfscale fit` holds it for the whole run
        return _write_files(
            out_dir, problem, fit, model, (draws, corner_draws), true_theta, truth, doc, overwrite, samples, figures
        )


def record_problem(out_dir, doc: dict, problem: str) -> dict:
    """The report ``doc`` that :func:`write_report` wrote into ``out_dir``, amended by an adequacy problem found
    after it and written again: ``problem`` (one line, :func:`assess`'s form) joins the outcome's ``problems``, and
    the status is the one :func:`assess` would have given with it among its adequacy tests — ``"ok"``,
    ``"not_converged"`` and an identifiability ``"undetermined"`` become ``"inadequate"`` with it as the reason, a
    resolution ``"undetermined"`` or an ``"inadequate"`` stand (``fitting._adequacy.with_adequacy_problem``).
    ``brdfscale fit --predict`` records so the scale law its predictions rest on when the fit's ΔΣ estimates reject
    it (``LawFromDifferences.inadequate_because``): fit.json then says what the command's exit status says (5), not
    "ok". fit.json is replaced atomically under the directory's lock (the rest of the report stays as written);
    returns the amended document. tests/test_fit.py checks the file and the ranking, tests/test_measured_prediction.py
    the command's fit.json after a rejected law.

    Raises:
        InvalidInputError: ``doc`` has no outcome (not a report), ``problem`` is not a non-empty string, or
            ``out_dir`` is not a directory.
        OutputInUseError: another process holds the directory.
        OutputWriteError: fit.json cannot be written (e.g. a full disk).
    """
    outcome = doc.get("outcome") if isinstance(doc, dict) else None
    if not isinstance(outcome, dict) or "status" not in outcome or not isinstance(outcome.get("problems", []), list):
        raise InvalidInputError("record_problem(out_dir, doc, problem) needs the report write_report returned as doc.")
    if not isinstance(problem, str) or not problem.strip():
        raise InvalidInputError(f"record_problem: problem must be a non-empty line of text; got {problem!r}.")
    with exclusive(out_dir, what="report directory"):
        return _write_fit_json(out_dir, {**doc, "outcome": with_adequacy_problem(outcome, problem)}, overwrite=True)


def _write_fit_json(out_dir, doc: dict, overwrite: bool) -> dict:
    """Write ``doc`` as DIR/fit.json (atomic; replaced only with ``overwrite``); returns its JSON-ready copy."""
    doc = cast(dict, jsonable(doc))  # jsonable returns a dict's JSON-ready copy as a dict
    write_text(
        os.path.join(out_dir, "fit.json"), json_text(doc, indent=2), overwrite=overwrite, error=InvalidInputError
    )
    return doc


def _write_files(
    out_dir, problem, fit, model, draws, true_theta, truth, doc, overwrite, samples=None, with_figures=True
) -> dict:
    draws, corner_draws = draws
    check_report_directory(out_dir, overwrite)  # again, now that no other run can write here
    figures = {name: os.path.join(out_dir, name) for name in _FIGURES} if with_figures else {}
    target = os.path.join(out_dir, "fit.json")
    try:
        if with_figures:  # the figures of fitting.plot_fit, plot_recovered_statistics and plot_corner (fitting._plot)
            unit = doc["data"]["unit"]
            _save(figures["data_vs_fit.png"], plot_fit(problem, fit, unit=unit), 90, overwrite)
            _save(
                figures["statistics.png"], statistics_figure(problem, fit, draws, true_theta, unit=unit), 90, overwrite
            )
            _save(figures["corner.png"], corner_figure(model, corner_draws, truth, fit), 80, overwrite)
        try:
            tables = _write_tables(out_dir, problem, fit, overwrite)
        except OutputWriteError:
            raise  # a full disk is no reason to report a fit without its tables as written
        except BrdfscaleError as err:
            tables = f"not written: {err}"
        doc.update(figures=list(figures.values()), tables=tables)
        if samples is not None:
            doc["posterior"] = _write_posterior(out_dir, samples, overwrite)
        # overwriting: a file of an earlier report that this one does not write (figures left
        # out, no samples, tables not written) goes, so the directory holds one report
        written = {target, doc.get("posterior"), *figures.values(), *(tables if isinstance(tables, list) else [])}
        for stale in report_files(out_dir):
            if stale not in written and os.path.lexists(stale):
                os.remove(stale)
        doc = _write_fit_json(out_dir, doc, overwrite)
    except OSError as err:
        raise MeasurementFileError(f"the report cannot be written into {out_dir}: {err}") from None
    return doc
