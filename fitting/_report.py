"""The main job's outputs: fit.json, figures (matplotlib) and evolved lobe tables.

Figures are drawn on :class:`matplotlib.figure.Figure` objects made without pyplot, so writing a
report touches neither pyplot's figure list nor the backend a notebook or script has chosen;
matplotlib itself is imported only when a figure is drawn.

``write_report`` is the only place in :mod:`fitting` that writes report files. Every file is
written through :func:`brdfscale.files.atomic_write` (a hidden temporary file in the output
directory, moved into place); before anything is written, every file the report would write
is checked, and none that exists is overwritten unless ``overwrite=True``.
"""

import json
import math
import os
import platform
from collections.abc import Mapping
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import brdfscale
from brdfscale import BrdfscaleError, InvalidInputError, MeasurementFileError
from brdfscale.files import atomic_write, exclusive

from brdfscale.checks import flag, real
from ._estimate import FitResult, Problem, check_fit
from ._models import ParametricModel, predict_images
from ._sample import SampleResult

__all__ = ["summarise", "write_report", "truth_of", "report_files", "check_report_directory"]

_CORNER_MAX = 6
_FIGURES = ("data_vs_fit.png", "statistics.png", "corner.png")
_TABLES = "evolved_lobes.exr"


@eqx.filter_jit
def _quantities(model, thetas):
    return jax.vmap(model.quantities)(thetas)


@eqx.filter_jit
def _relative(model, thetas, W, data):
    return jax.vmap(lambda t: model.relative_statistics(t, W, data))(thetas)


@eqx.filter_jit
def _absolute(model, thetas, W, data):
    """``S(W, μ_k)`` for every draw and measured scale (parametric models)."""
    def one(t):
        return jnp.stack([model.statistics_at(t, data.scales[k]).cf_radial(W) for k in range(data.scales.shape[0])])
    return jax.vmap(one)(thetas)


def _figure(**kwargs):
    """A matplotlib Figure outside pyplot (no backend, no global figure list; freed with its last reference)."""
    from matplotlib.figure import Figure

    return Figure(**kwargs)


def _colormap(name: str):
    import matplotlib

    return matplotlib.colormaps[name]


def _atomic(path, write, overwrite: bool):
    """Write ``path`` atomically; without ``overwrite`` an existing file is never replaced
    (write_report has checked up front; this also holds against a file created meanwhile:
    InvalidInputError, as from the check)."""
    atomic_write(path, write, overwrite=overwrite, error=InvalidInputError)


def _exr_available() -> bool:
    try:
        from brdfscale import exr  # noqa: F401
    except ImportError:
        return False
    return True


def report_files(out_dir) -> list[str]:
    """The paths :func:`write_report` writes into ``out_dir`` (fit.json last: it is written
    when everything else is in place)."""
    names = list(_FIGURES) + ([_TABLES] if _exr_available() else []) + ["fit.json"]
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
        raise MeasurementFileError(f"report directory {out_dir} exists but is not a directory; give a directory "
                                   "(existing or to be created) as out_dir (CLI: --out).")
    targets = report_files(out_dir)
    existing = [os.path.basename(t) for t in targets if os.path.lexists(t)]
    if existing and not overwrite:
        raise InvalidInputError(
            f"{out_dir} already holds {', '.join(existing)}, which the report would overwrite; choose another "
            "--out directory or pass --force (overwrite=True)."
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
    plus its ``albedo`` as the amplitude. Returns the known subset, or None.
    """
    if not isinstance(metadata, dict) or not isinstance(model, ParametricModel):
        return None
    params = metadata.get("truth", {}).get("params") if isinstance(metadata.get("truth"), dict) else None
    truth = {}
    if isinstance(params, dict):
        truth = {p: _truth_value(params[p], f"truth.params.{p}") for p in model.parameters if p in params}
    spectrum = metadata.get("surface", {}).get("spectrum") if isinstance(metadata.get("surface"), dict) else None
    if model.law_kind == "gaussian_surface" and isinstance(spectrum, dict) and spectrum.get("type") == "GaussianCorrelation":
        raw = spectrum.get("correlation_length")
        ell = [_truth_value(v, "surface.spectrum.correlation_length") for v in (raw if isinstance(raw, list) else [raw])]
        if np.allclose(ell, ell[0]):
            truth.update(rms_height=_truth_value(spectrum.get("rms_height"), "surface.spectrum.rms_height"),
                         correlation_length=ell[0])
        if metadata.get("albedo") is not None:
            truth["amplitude"] = _truth_value(metadata["albedo"], "albedo")
    return truth or None


def _truth_value(value, key: str) -> float:
    """A known-truth number from metadata: positive and finite (every parameter is), or
    InvalidInputError naming the metadata key."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise InvalidInputError(f"metadata {key} must be a positive finite number (a known true value); got "
                                f"{value!r:.80}. Correct or remove it from the measurement set's metadata.")
    return float(value)


def _truth_theta(model, truth, fit: FitResult):
    """θ of the truth for the statistics curves: parameters the truth lacks (e.g. the base
    lobe of a height-field simulation) are taken from the estimate; None without truth for
    every scale-law parameter."""
    if truth is None:
        return None
    law_parameters = [p for p in model.free if p not in ("amplitude", "alpha_lobe")]
    if not all(p in truth for p in law_parameters):
        return None
    estimate = dict(fit.estimates)
    return jnp.asarray(model.theta_from({**estimate, **truth}))


def _draws(fit: FitResult, samples: SampleResult | None, bounds, rng, n=400):
    if samples is not None:
        flat = samples.samples
        return flat[rng.choice(flat.shape[0], size=min(n, flat.shape[0]), replace=False)]
    # Laplace draws; the covariance is singular along undetermined directions (they stay at θ̂)
    lam, V = np.linalg.eigh(fit.covariance)
    root = V * np.sqrt(np.clip(lam, 0, None))
    return np.clip(fit.theta + rng.standard_normal((n, fit.theta.size)) @ root.T, *bounds)


def summarise(problem: Problem, fit: FitResult, samples: SampleResult | None, truth: dict | None) -> dict:
    """Per-quantity table: estimate, std, 5/50/95 % quantiles (MCMC when sampled, else Laplace)."""
    model = problem.model
    table = {}
    if samples is not None:
        q = {k: np.asarray(v) for k, v in _quantities(model, jnp.asarray(samples.samples)).items()}
    for name, value in fit.estimates.items():
        row = {"estimate_map": value, "determined": fit.std[name] is not None}
        if samples is not None:
            row.update(source="mcmc", median=float(np.median(q[name])), std=float(np.std(q[name])),
                       quantiles_5_50_95=np.percentile(q[name], [5, 50, 95]).tolist())
        else:
            row.update(source="laplace", std=fit.std[name], quantiles_5_50_95=fit.quantiles[name],
                       median=None if fit.quantiles[name] is None else fit.quantiles[name][1])
        if not row["determined"]:
            row["note"] = "not determined by the data (see identifiability); the spread is the prior's"
        if truth is not None and name in truth:
            row["truth"] = truth[name]
        table[name] = row
    return table


def _figure_data_vs_fit(path, problem: Problem, fit: FitResult, overwrite: bool):
    data, model = problem.data, problem.model
    pred = np.asarray(predict_images(model, jnp.clip(jnp.asarray(fit.theta), problem.lower, problem.upper), data))
    first = [data.scale_of_image.index(k) for k in range(len(np.asarray(data.scales)))]
    fig = _figure(figsize=(9, 2.6 * len(first)))
    axes = fig.subplots(len(first), 3, squeeze=False)
    for row, i in enumerate(first):
        obs, fitted = data.image(i, data.values[i]), data.image(i, pred[i])
        w = data.image(i, data.weight[i])
        e = data.extents[i]
        vmax = max(obs.max(), fitted.max())
        for col, (img, title, kw) in enumerate((
            (obs, "data", dict(vmin=0, vmax=vmax)),
            (fitted, "fit", dict(vmin=0, vmax=vmax)),
            ((fitted - obs) * w, "(fit − data)/σ", dict(vmin=-4, vmax=4, cmap="RdBu_r")),
        )):
            im = axes[row, col].imshow(img, origin="lower", extent=(-e, e, -e, e), **kw)
            axes[row, col].set_title(f"μ = {float(data.scales[data.scale_of_image[i]]):.4g}: {title}", fontsize=9)
            fig.colorbar(im, ax=axes[row, col], fraction=0.046)
        axes[row, 0].set_ylabel("u_y")
    for ax in axes[-1]:
        ax.set_xlabel("u_x")
    fig.tight_layout()
    _atomic(path, lambda p: fig.savefig(p, dpi=90, format="png"), overwrite)


def _band(ax, W, curves, color, label):
    lo, mid, hi = np.percentile(curves, [5, 50, 95], axis=0)
    ax.fill_between(W, lo, hi, color=color, alpha=0.3, lw=0)
    ax.plot(W, mid, color=color, lw=1.2, label=label)


def _figure_statistics(path, problem: Problem, fit: FitResult, draws, true_theta, overwrite: bool):
    data, model = problem.data, problem.model
    scales = np.asarray(data.scales)
    absolute = isinstance(model, ParametricModel)
    w_max = 8.0 / float(model.quantities(jnp.asarray(fit.theta))["alpha_lobe"]) if absolute else model.knots[-1]
    W = jnp.linspace(0.0, w_max, 200)
    relative = np.asarray(_relative(model, jnp.asarray(draws), W, data))
    fig = _figure(figsize=(11 if absolute else 6, 4))
    axes = fig.subplots(1, 2 if absolute else 1, squeeze=False)
    colors = _colormap("viridis")(np.linspace(0, 0.9, len(scales)))
    for k in range(1, len(scales)):
        _band(axes[0, 0], W, relative[:, k], colors[k], f"μ = {scales[k]:.3g}")
        if true_theta is not None:
            axes[0, 0].plot(W, np.asarray(model.relative_statistics(true_theta, W, data))[k], "k--", lw=0.8)
    axes[0, 0].set_title("S(W, μ0)/S(W, μ) — determined by the data (5–95 % band)", fontsize=9)
    axes[0, 0].set_xlabel("|W|")
    axes[0, 0].legend(fontsize=7)
    if absolute:
        curves = np.asarray(_absolute(model, jnp.asarray(draws), W, data))
        for k, mu in enumerate(scales):
            _band(axes[0, 1], W, curves[:, k], colors[k], f"μ = {mu:.3g}")
            if true_theta is not None:
                axes[0, 1].plot(W, np.asarray(model.statistics_at(true_theta, mu).cf_radial(W)), "k--", lw=0.8)
        axes[0, 1].set_title("S(W, μ) — absolute via the scale law's S(W, ∞) = 1 (dashed: truth)", fontsize=9)
        axes[0, 1].set_xlabel("|W|")
    fig.tight_layout()
    _atomic(path, lambda p: fig.savefig(p, dpi=90, format="png"), overwrite)


def _figure_corner(path, model, draws, truth: dict | None, overwrite: bool):
    q = _quantities(model, jnp.asarray(draws))
    names = list(q)[:_CORNER_MAX]
    x = np.stack([np.asarray(q[n]) for n in names], axis=1)
    d = len(names)
    fig = _figure(figsize=(1.8 * d + 1, 1.8 * d + 1))
    axes = fig.subplots(d, d, squeeze=False)
    for i in range(d):
        for j in range(d):
            ax = axes[i, j]
            if j > i:
                ax.axis("off")
                continue
            if i == j:
                ax.hist(x[:, i], bins=40, color="0.4", histtype="step")
                for v in np.percentile(x[:, i], [5, 50, 95]):
                    ax.axvline(v, color="C0", lw=0.7, ls=":")
            else:
                ax.hist2d(x[:, j], x[:, i], bins=40, cmap="Greys")
                if truth is not None and names[i] in truth:
                    ax.axhline(truth[names[i]], color="C3", lw=0.8)
            if truth is not None and names[j] in truth:
                ax.axvline(truth[names[j]], color="C3", lw=0.8)
            ax.tick_params(labelsize=6)
            if i == d - 1:
                ax.set_xlabel(names[j], fontsize=8)
            if j == 0 and i > 0:
                ax.set_ylabel(names[i], fontsize=8)
    fig.tight_layout()
    _atomic(path, lambda p: fig.savefig(p, dpi=80, format="png"), overwrite)


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
        images.append(brdfscale.LobeImage(mu=float(mu), incident=np.array([0.0, 0.0, 1.0]), extent=data.extents[i],
                                          values=np.clip(data.image(i, pred[i]), 0, None)))
    path = os.path.join(out_dir, "evolved_lobes.exr")
    exr.write_measurements(path, brdfscale.MeasurementSet(tuple(images), metadata={"source": "brdfscale fit"}),
                           overwrite=overwrite)
    return [path]


def write_report(out_dir, problem: Problem, fit: FitResult, samples: SampleResult | None = None, *,
                 truth: dict | None = None, model_info: dict | None = None, overwrite: bool = False) -> dict:
    """Write ``fit.json``, ``data_vs_fit.png``, ``statistics.png``, ``corner.png`` and the
    evolved lobe tables (``evolved_lobes.exr``) into ``out_dir`` (created if missing); return
    the JSON document.

    Everything is checked before the first file is written: the arguments, and (without
    ``overwrite``) that none of those files exists. ``fit.json`` is written last.

    Raises:
        InvalidInputError: without ``overwrite``, any of the report's files exists in
            ``out_dir`` (the message lists them); ``fit`` or ``samples`` do not belong to
            ``problem``'s model; ``truth`` is not a dict of finite numbers (for a parametric
            model, positive ones); ``model_info`` is not a JSON-serialisable dict.
        MeasurementFileError: ``out_dir`` exists but is not a directory, or it or a report
            file cannot be created or written.
    """
    check_fit(problem, fit, "write_report(out_dir, problem, fit)")
    if samples is not None and (not isinstance(samples, SampleResult) or tuple(samples.names) != tuple(fit.names)):
        got = type(samples).__name__ if not isinstance(samples, SampleResult) else f"a chain of {len(samples.names)} coordinates"
        raise InvalidInputError(f"samples must be None or the SampleResult of fitting.sample for this problem's "
                                f"{len(fit.names)} coordinates; got {got}.")
    truth = _check_truth(truth)
    if model_info is not None and not isinstance(model_info, dict):
        raise InvalidInputError(f"model_info must be a dict or None; got {type(model_info).__name__}.")
    overwrite = flag(overwrite, "overwrite")
    # everything that can fail on the arguments is computed before the first file is written
    model = problem.model
    true_theta = _truth_theta(model, truth, fit) if isinstance(model, ParametricModel) else None
    rng = np.random.default_rng(0)
    draws = _draws(fit, samples, (np.asarray(problem.lower), np.asarray(problem.upper)), rng)
    doc = {
        "brdfscale_version": brdfscale.__version__,
        "python": platform.python_version(),
        "model": model_info or {"kind": type(model).__name__},
        "data": {"scales": np.asarray(problem.data.scales).tolist(), "images": len(problem.data.scale_of_image),
                 "valid_pixels": problem.data.n_data},
        "parameters": summarise(problem, fit, samples, truth),
        "identifiability": fit.to_json()["identifiability"],
        "optimisation": {k: v for k, v in fit.to_json().items() if k != "identifiability"},
        "mcmc": None if samples is None else samples.diagnostics(),
    }
    try:
        json.dumps(_finite(doc), allow_nan=False)
    except (TypeError, ValueError) as err:
        raise InvalidInputError(f"model_info must hold JSON values only (str, numbers, lists, dicts): {err}.") from None

    check_report_directory(out_dir, overwrite)
    out_dir = os.fspath(out_dir)
    with exclusive(out_dir, what="report directory"):  # re-entrant: `brdfscale fit` holds it for the whole run
        return _write_files(out_dir, problem, fit, model, draws, true_theta, truth, doc, overwrite)


def _write_files(out_dir, problem, fit, model, draws, true_theta, truth, doc, overwrite) -> dict:
    check_report_directory(out_dir, overwrite)  # again, now that no other run can write here
    figures = {name: os.path.join(out_dir, name) for name in _FIGURES}
    target = os.path.join(out_dir, "fit.json")
    try:
        _figure_data_vs_fit(figures["data_vs_fit.png"], problem, fit, overwrite)
        _figure_statistics(figures["statistics.png"], problem, fit, draws, true_theta, overwrite)
        _figure_corner(figures["corner.png"], model, draws, truth, overwrite)
        try:
            tables = _write_tables(out_dir, problem, fit, overwrite)
        except BrdfscaleError as err:
            tables = f"not written: {err}"
        doc.update(figures=list(figures.values()), tables=tables)
        doc = _finite(doc)
        text = json.dumps(doc, indent=2, allow_nan=False)
        _atomic(target, lambda p: Path(p).write_text(text), overwrite)
    except OSError as err:
        raise MeasurementFileError(f"the report cannot be written into {out_dir}: {err}") from None
    return doc


def _check_truth(truth):
    """``truth`` (None or {name: value}) with float values; InvalidInputError otherwise."""
    if truth is None:
        return None
    if not isinstance(truth, Mapping):
        raise InvalidInputError(f"truth must be None or a dict of parameter values; got {type(truth).__name__}.")
    return {str(name): real(value, f"truth[{name!r}]") for name, value in truth.items()}


def _finite(x):
    """JSON-safe copy: NumPy scalars to Python, non-finite floats to None."""
    if isinstance(x, dict):
        return {str(k): _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x
