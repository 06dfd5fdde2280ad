"""The figures of a fit — the same ones :func:`fitting.write_report` saves and a notebook shows.

* :func:`plot_fit` — data, fitted model and whitened residuals per measured scale
  (``data_vs_fit.png`` of the report);
* :func:`plot_recovered_statistics` — the recovered statistics with 5–95 % bands
  (``statistics.png``);
* :func:`plot_corner` — the posterior's one- and two-dimensional marginals (``corner.png``).

They live here, beside the fitting models they need, and :func:`brdfscale.plot.fit`,
:func:`brdfscale.plot.recovered_statistics` and :func:`brdfscale.plot.corner` call them: the
plot package sits above fitting (docs/architecture.md), so this module draws in its style
through the core's :mod:`brdfscale._figure_style` and never imports :mod:`brdfscale.plot`.
Every figure is a ``matplotlib.figure.Figure`` made without pyplot, so drawing one changes no
global matplotlib state; matplotlib is imported when a figure is drawn. Draws of the
posterior are reproducible: the first 400 of
a seeded generator (``seed``, default 0, as in the report), from the MCMC samples when given,
else from the Laplace approximation of the fit.
"""

import textwrap
from collections.abc import Mapping
from typing import cast

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from brdfscale import _figure_style as _figures, InvalidInputError
from brdfscale.checks import integer, real

from ._adequacy import lobe_moments
from ._derived import quantities_at
from ._model import predict_images
from ._nonparametric import NonParametricModel
from ._parametric import ParametricModel
from ._problem import check_fit, Problem
from ._result import FitResult
from ._sample import SampleResult


__all__ = ["plot_fit", "plot_recovered_statistics", "plot_corner"]

CORNER_MAX = 6
"""The most quantities a corner plot shows (the first ones)."""
DRAWS = 400
"""Posterior draws behind the bands of the statistics figure."""
CORNER_DRAWS = 4000
"""Posterior draws behind the corner plot (smooth histograms need more than the bands)."""
_LOBE_UNIT = f"A·g(u) ({_figures.SLOPE_DENSITY})"


def _quantities(model, thetas):
    """The model's quantities at every θ of ``thetas`` (:func:`fitting._derived.quantities_at`)."""
    return quantities_at(model, thetas)


@eqx.filter_jit
def _relative(model, thetas, W, data):
    return jax.vmap(lambda t: model.relative_statistics(t, W, data.scales))(thetas)


@eqx.filter_jit
def _relative_axes(model, thetas, W, data):
    """``R_k`` along the W_x and W_y axes for every draw: shape (draws, 2, k, w) (models with
    ``relative_statistics_plane``: the anisotropic ones)."""
    zero = jnp.zeros_like(W)
    along = (jnp.stack([W, zero], axis=-1), jnp.stack([zero, W], axis=-1))
    return jax.vmap(lambda t: jnp.stack([model.relative_statistics_plane(t, a, data.scales) for a in along]))(thetas)


@eqx.filter_jit
def _absolute(model, thetas, W, data):
    """``S(W, μ_k)`` for every draw and measured scale (parametric models)."""

    def one(t):
        return jnp.stack([model.statistics_at(t, data.scales[k]).cf_radial(W) for k in range(data.scales.shape[0])])

    return jax.vmap(one)(thetas)


def check_samples(fit: FitResult, samples, what: str) -> None:
    """InvalidInputError unless ``samples`` is None or the SampleResult of ``fit``'s coordinates."""
    if samples is not None and (not isinstance(samples, SampleResult) or tuple(samples.names) != tuple(fit.names)):
        got = (
            type(samples).__name__
            if not isinstance(samples, SampleResult)
            else f"a chain of {len(samples.names)} coordinates"
        )
        raise InvalidInputError(
            f"{what}: samples must be None or the SampleResult of fitting.sample for this problem's "
            f"{len(fit.names)} coordinates; got {got}."
        )


def check_truth(truth):
    """``truth`` (None or {name: value}) with float values; InvalidInputError otherwise."""
    if truth is None:
        return None
    if not isinstance(truth, Mapping):
        raise InvalidInputError(f"truth must be None or a dict of parameter values; got {type(truth).__name__}.")
    return {str(name): real(value, f"truth[{name!r}]") for name, value in truth.items()}


def truth_theta(model, truth, fit: FitResult):
    """θ of the truth for the statistics curves: parameters the truth lacks (e.g. the base
    lobe of a height-field simulation) are taken from the estimate; None without truth for
    every scale-law parameter (and for non-parametric models)."""
    if truth is None or not isinstance(model, ParametricModel):
        return None
    law_parameters = [p for p in model.free if p not in ("amplitude", "alpha_lobe")]
    if not all(p in truth for p in law_parameters):
        return None
    estimate = dict(fit.estimates)
    return jnp.asarray(model.theta_from({**estimate, **truth}))


def posterior_draws(problem: Problem, fit: FitResult, samples: SampleResult | None, seed: int = 0, n: int = DRAWS):
    """``n`` draws of θ: from the MCMC samples (without replacement) when given, else Laplace
    draws about θ̂ clipped to the prior box (the covariance is singular along undetermined
    directions: they stay at θ̂)."""
    rng = np.random.default_rng(seed)
    if samples is not None:
        flat = samples.samples
        return flat[rng.choice(flat.shape[0], size=min(n, flat.shape[0]), replace=False)]
    lam, V = np.linalg.eigh(fit.covariance)
    root = V * np.sqrt(np.clip(lam, 0, None))
    bounds = (np.asarray(problem.lower), np.asarray(problem.upper))
    return np.clip(fit.theta + rng.standard_normal((n, fit.theta.size)) @ root.T, *bounds)


def _mu_title(mu: float, unit: str | None) -> str:
    """``μ = 3.906e-08 m`` — μ with its length unit (None: pixels of the height field)."""
    return f"μ = {mu:.4g} {unit or 'px'}"


def _zoom(data, i: int) -> tuple[float, float, float, float]:
    """The part of image ``i``'s offset grid the figure shows: a square about the lobe's centre of
    half-width ``max(5·rms width along the wider axis, 8 pixel pitches)`` from the data's second
    moments (:func:`fitting._adequacy.lobe_moments`), within the image; the whole image when no
    pixel is significant."""
    e = data.extents[i]
    moments = lobe_moments(data, i)
    if moments is None:
        return (-e, e, -e, e)
    centre, cov = moments
    pitch = 2.0 * e / (data.image_sizes[i] - 1)
    half = min(max(5.0 * float(np.sqrt(max(np.linalg.eigvalsh(cov)[-1], 0.0))), 8.0 * pitch), e)
    cx, cy = (float(np.clip(c, -e + half, e - half)) for c in centre)
    return (cx - half, cx + half, cy - half, cy + half)


RESIDUAL_RANGE = 4.0
"""The least half-range of the residual panels' colour scale, in σ."""


def _residual_range(residual: np.ndarray, window, e: float) -> float:
    """The half-range of a residual panel: :data:`RESIDUAL_RANGE` σ, or the 99th percentile of
    ``|residual|`` inside the shown ``window`` where it is larger (rounded up to a whole σ), so
    the structure of a poor fit's residuals is not one saturated colour."""
    n = residual.shape[0]
    x = np.linspace(-e, e, n)
    inside = ((x >= window[0]) & (x <= window[1]))[None, :] & ((x >= window[2]) & (x <= window[3]))[:, None]
    shown = np.abs(residual[inside])
    return max(RESIDUAL_RANGE, float(np.ceil(np.quantile(shown, 0.99)))) if shown.size else RESIDUAL_RANGE


_WIDTH, _ROW = 10.5, 2.7
"""The width of :func:`plot_fit`'s figure and the height of one of its rows (one scale), in inches."""
_MARGINS = {"left": 0.7, "right": 0.65, "top": 0.25, "bottom": 0.45, "across": 1.2, "between": 0.62}
""":func:`plot_fit`'s fixed margins in inches: outside the grid, then ``across`` between the panels
of a row (a colour bar with its ticks and label, the next panel's y label and ticks) and
``between`` the rows (x ticks and label, the next row's titles)."""


def _fixed_grid(rows: int) -> dict:
    """:func:`plot_fit`'s panel grid (``gridspec_kw`` of ``rows`` × 3 panels) with the margins of
    :data:`_MARGINS`: every panel of the figure has the same title, labels and colour bar, so one
    fixed layout fits them all; constrained layout measured the 6·rows axes' text twice per save
    (~2.5 of ~3.5 s CPU of the figure on 8 scales)."""
    m, height = _MARGINS, _ROW * rows
    width = (_WIDTH - m["left"] - m["right"] - 2 * m["across"]) / 3
    tall = (height - m["top"] - m["bottom"] - (rows - 1) * m["between"]) / rows
    return {
        "left": m["left"] / _WIDTH,
        "right": 1 - m["right"] / _WIDTH,
        "top": 1 - m["top"] / height,
        "bottom": m["bottom"] / height,
        "wspace": m["across"] / width,
        "hspace": m["between"] / tall,
    }


def plot_fit(problem: Problem, fit: FitResult, *, unit: str | None = None):
    """Data, fit and whitened residuals at every measured scale (the report's ``data_vs_fit.png``).

    One row per scale (its first image): (1) the data ``A·g(u)`` over the slope offsets
    ``u`` (per unit slope²), (2) the model at the estimate on the same colour scale, (3) the
    whitened residual ``(fit − data)/σ`` (0 where masked) on [−r, r], ``r`` = 4 or, where
    larger, the 99th percentile of ``|residual|`` in the panel rounded up (a poor fit's
    residual structure is then not one saturated colour); each with its colour bar. Each row
    is zoomed to where its lobe is — a square about the lobe's centre, five rms widths (at
    least eight pixels) from it, from the data's second moments (:func:`fitting.lobe_widths`'
    pixels) — so that a narrow lobe on a wide image is not a dot; the title says when a row is
    zoomed (tests/test_plot_fit.py). ``unit``: the length unit of μ in the titles (None:
    pixels of the height field). Axes: 6 per scale.

    Returns a ``matplotlib.figure.Figure`` (made without pyplot).

    Raises:
        InvalidInputError: ``problem`` is not a :class:`fitting.Problem` or ``fit`` not its
            :class:`fitting.FitResult`.
    """
    check_fit(problem, fit, "plot_fit(problem, fit)")
    if unit is not None and not isinstance(unit, str):
        raise InvalidInputError(f"unit must be a length unit's name (str) or None; got {type(unit).__name__}.")
    data, model = problem.data, problem.model
    pred = np.asarray(predict_images(model, jnp.clip(jnp.asarray(fit.theta), problem.lower, problem.upper), data))
    first = [data.scale_of_image.index(k) for k in range(len(np.asarray(data.scales)))]
    fig = _figures.figure(_WIDTH, _ROW * len(first), layout=None)  # a fixed grid (_fixed_grid), not constrained layout
    axes = fig.subplots(len(first), 3, squeeze=False, gridspec_kw=_fixed_grid(len(first)))
    for row, i in enumerate(first):
        obs, fitted = data.image(i, data.values[i]), data.image(i, pred[i])
        w = data.image(i, data.weight[i])
        e = data.extents[i]
        window = _zoom(data, i)
        zoomed = window != (-e, e, -e, e)
        vmax = max(obs.max(), fitted.max())
        residual = (fitted - obs) * w
        r = _residual_range(residual, window, e)
        for col, (img, title, label, kw) in enumerate(
            (
                (obs, "data", _LOBE_UNIT, dict(vmin=0, vmax=vmax)),
                (fitted, "fit", _LOBE_UNIT, dict(vmin=0, vmax=vmax)),
                (residual, "(fit − data)/σ", "(fit − data)/σ", dict(vmin=-r, vmax=r, cmap="RdBu_r")),
            )
        ):
            ax = axes[row, col]
            im = ax.imshow(img, origin="lower", extent=(-e, e, -e, e), **kw)
            mu = _mu_title(float(data.scales[data.scale_of_image[i]]), unit)
            ax.set_title(f"{mu}: {title}" + (" (zoomed)" if zoomed else ""), fontsize=9)
            ax.set_xlim(*window[:2])
            ax.set_ylim(*window[2:])
            _figures.colorbar(fig, im, ax, label)
            ax.set_ylabel("u_y (slope)", fontsize=8)
            ax.set_xlabel("u_x (slope)", fontsize=8)
            _figures.small_ticks(ax)
    return fig


def _band(ax, W, curves, color, label, ls="-"):
    lo, mid, hi = np.percentile(curves, [5, 50, 95], axis=0)
    ax.fill_between(W, lo, hi, color=color, alpha=0.3, lw=0)
    ax.plot(W, mid, color=color, lw=1.2, ls=ls, label=label)


def statistics_figure(problem: Problem, fit: FitResult, draws, true_theta, *, unit: str | None = None):
    """The figure of :func:`plot_recovered_statistics` from given draws and true θ (or None);
    ``unit``: μ's length unit in the titles and legends (None: pixels of the height field)."""
    data, model = problem.data, problem.model
    scales = np.asarray(data.scales)
    absolute = isinstance(model, ParametricModel)
    # a parametric model's W range from its base lobe, the non-parametric one's knots, the anisotropic
    # one's from its base lobe's width α = √(tr C0) (α² = 2σ² per axis)
    q = model.quantities(jnp.asarray(fit.theta))
    w_max = (
        8.0 / float(q["alpha_lobe"])
        if absolute
        else cast(NonParametricModel, model).knots[-1]
        if isinstance(model, NonParametricModel)
        else 8.0 / float(np.sqrt(q["C0_xx"] + q["C0_yy"]))
    )
    W = jnp.linspace(0.0, w_max, 200)
    planar = hasattr(model, "relative_statistics_plane")  # an anisotropic model: R_k depends on W's direction
    w = np.asarray(W)  # matplotlib iterates over what it is given: a JAX array costs a dispatch per element
    wide = absolute or planar
    fig = _figures.figure(11 if wide else 6, 4)
    axes = fig.subplots(1, 2 if wide else 1, squeeze=False)[0]
    colors = _figures.colormap("viridis")(np.linspace(0, 0.9, len(scales)))
    mu0 = f"μ0 = {scales[0]:.4g} {unit or 'px'}"
    if planar:
        relative = np.asarray(_relative_axes(model, jnp.asarray(draws), W, data))
        for k in range(1, len(scales)):
            _band(axes[0], w, relative[:, 0, k], colors[k], _mu_title(scales[k], unit))
            _band(axes[0], w, relative[:, 1, k], colors[k], None, ls="--")
        axes[0].plot([], [], "k-", lw=1.2, label="along W_x")
        axes[0].plot([], [], "k--", lw=1.2, label="along W_y")
        axes[0].set_title(f"|S(W, μ0)/S(W, μ)| along W_x and W_y, {mu0} (5–95 % band)", fontsize=9)
        axes[0].set_xlabel("W_x or W_y (rad per unit slope)")
        _differences_panel(axes[1], fit, unit)
    else:
        relative = np.asarray(_relative(model, jnp.asarray(draws), W, data))
        for k in range(1, len(scales)):
            _band(axes[0], w, relative[:, k], colors[k], _mu_title(scales[k], unit))
            if true_theta is not None:
                axes[0].plot(w, np.asarray(model.relative_statistics(true_theta, W, data.scales))[k], "k--", lw=0.8)
        axes[0].set_title(f"S(W, μ0)/S(W, μ), {mu0}: determined by the data (5–95 % band)", fontsize=9)
        axes[0].set_xlabel("|W| (rad per unit slope)")
    axes[0].set_ylabel("S(W, μ0)/S(W, μ)")
    if absolute:
        curves = np.asarray(_absolute(model, jnp.asarray(draws), W, data))
        for k, mu in enumerate(scales):
            _band(axes[1], w, curves[:, k], colors[k], _mu_title(mu, unit))
            if true_theta is not None:
                axes[1].plot(w, np.asarray(model.statistics_at(true_theta, mu).cf_radial(W)), "k--", lw=0.8)
        axes[1].set_title("S(W, μ): absolute via the scale law's S(W, ∞) = 1", fontsize=9)
        axes[1].set_ylabel("S(W, μ)")
        axes[1].set_xlabel("|W| (rad per unit slope)")
    for ax in axes:
        if true_theta is not None:
            ax.plot([], [], "k--", lw=0.8, label="truth")
        ax.legend(fontsize=7)
        _figures.small_ticks(ax)
    return fig


def _differences_panel(ax, fit: FitResult, unit: str | None) -> None:
    """ΔΣ(μ0, μ) = Σ(μ0) − Σ(μ) against μ, its xx, yy and xy entries with their standard errors
    (``fit.covariance_differences``, what fit.json reports): the anisotropic models' statistics
    by direction, in slope² (a topography's Σ(μ0) − Σ(μ) is the same quantity). An entry without
    a standard error (undetermined) is drawn hollow, without a bar."""
    entries = [d for d in fit.covariance_differences if d.get("value") is not None]
    if not entries:
        ax.text(0.5, 0.5, "no ΔΣ in this fit result", ha="center", va="center", transform=ax.transAxes)
        ax.plot([], [], " ", label="ΔΣ: none")
    mus = np.array([float(d["mu"]) for d in entries])
    for (a, b, name), marker in zip(((0, 0, "xx"), (1, 1, "yy"), (0, 1, "xy")), ("o", "s", "^")):
        value = np.array([np.nan if d["value"][a][b] is None else float(d["value"][a][b]) for d in entries])
        std = np.array(
            [np.nan if d.get("std") is None or d["std"][a][b] is None else float(d["std"][a][b]) for d in entries]
        )
        known = np.isfinite(std)
        line = ax.errorbar(mus[known], value[known], yerr=std[known], fmt=marker, ms=4, capsize=2, label=f"ΔΣ_{name}")
        if np.any(~known):
            colour = line[0].get_color()
            ax.plot(mus[~known], value[~known], marker, ms=4, mfc="none", color=colour)
    if entries and np.any([d.get("std") is None or None in sum(d["std"], []) for d in entries]):
        ax.plot([], [], "ko", mfc="none", ms=4, label="no standard error (undetermined)")
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.set_xscale("log")
    if entries:  # ticks at the measured scales (a log axis over less than a decade labels 2.25×10⁰ …)
        ax.set_xticks(mus, [f"{m:.3g}" for m in mus])
        ax.minorticks_off()
    mu0 = f"{float(entries[0]['mu0']):.4g} {unit or 'px'}" if entries else "μ0"
    ax.set_title(f"ΔΣ(μ0, μ) = Σ(μ0) − Σ(μ) ± standard error, μ0 = {mu0}", fontsize=9)
    ax.set_xlabel(f"facet size μ ({unit or 'px'})")
    ax.set_ylabel("ΔΣ (slope²)")


def plot_recovered_statistics(
    problem: Problem,
    fit: FitResult,
    samples: SampleResult | None = None,
    *,
    truth: dict | None = None,
    seed: int = 0,
    unit: str | None = None,
):
    """The recovered facet-slope statistics with 5–95 % bands (the report's ``statistics.png``).

    Panels: (1) the ratios ``S(W, μ0)/S(W, μ)`` for every coarser measured scale — what
    multi-scale data determine — as median and 5–95 % band over 400 posterior draws (MCMC
    ``samples`` when given, else the fit's Laplace approximation) — for the anisotropic models
    (whose ratio ``exp(−½ Wᵀ ΔΣ W)`` depends on W's direction) along the W_x axis (solid) and
    the W_y axis (dashed), else against ``|W|``; (2, parametric models) the absolute
    ``S(W, μ)`` at every measured scale, which rests on the scale law's boundary condition
    ``S(W, ∞) = 1``; (2, anisotropic models) ``ΔΣ(μ0, μ)``'s xx, yy and xy entries against μ
    with their standard errors (``fit.covariance_differences``; hollow: no standard error).
    Known truth (``truth``: parameter values, e.g. from :func:`fitting.truth_of`) is drawn
    dashed (parametric models). W in radians per unit slope; ``unit``: the length unit of μ in
    the titles and legends (None: pixels of the height field). Axes: 2 for a parametric or an
    anisotropic model, 1 for the isotropic non-parametric one.

    Returns a ``matplotlib.figure.Figure`` (made without pyplot).

    Raises:
        InvalidInputError: ``fit``/``samples`` do not belong to ``problem``; ``truth`` is not a
            dict of finite numbers (positive for a parametric model); ``seed`` not an integer ≥ 0.
    """
    check_fit(problem, fit, "plot_recovered_statistics(problem, fit)")
    check_samples(fit, samples, "plot_recovered_statistics(problem, fit, samples)")
    truth = check_truth(truth)
    seed = integer(seed, "seed", 0)
    true_theta = truth_theta(problem.model, truth, fit)
    if unit is not None and not isinstance(unit, str):
        raise InvalidInputError(f"unit must be a length unit's name (str) or None; got {type(unit).__name__}.")
    return statistics_figure(problem, fit, posterior_draws(problem, fit, samples, seed), true_theta, unit=unit)


def corner_figure(model, draws, truth: dict | None, fit: FitResult | None = None):
    """The figure of :func:`plot_corner` from given draws of θ, drawn by the ``corner`` package."""
    import corner

    # in the model's order (quantities_at's keys: fitting._derived.quantity_names, no eager evaluation)
    q = {k: np.asarray(v) for k, v in _quantities(model, jnp.asarray(draws)).items()}
    order = list(q)
    left_out = [n for n in order if fit is not None and fit.std.get(n, 0.0) is None]
    names = [n for n in order if n not in left_out and np.ptp(q[n]) > 0][:CORNER_MAX]
    d = len(names)
    if d == 0:
        fig = _figures.figure(5, 2)
        fig.text(0.5, 0.5, "no determined quantity varies across the draws", ha="center", va="center")
        return fig
    side = max(2.2 * d + 0.8, 5.5)
    fig = _figures.figure(side, side, layout=None)  # corner places the panels itself (subplots_adjust)
    fig.subplots(d, d, squeeze=False)
    truths = [None if truth is None else truth.get(n) for n in names]
    corner.corner(
        np.stack([q[n] for n in names], axis=1),
        bins=30,
        labels=names,
        truths=truths,
        truth_color="C3",
        quantiles=[0.05, 0.5, 0.95],
        show_titles=True,
        title_fmt=".3g",
        title_kwargs={"fontsize": 9},
        label_kwargs={"fontsize": 10},
        smooth=1.0,
        smooth1d=1.0,
        max_n_ticks=3,
        fig=fig,
        plot_datapoints=False,
        fill_contours=True,
        levels=(0.393, 0.865),
    )
    for k, ax in enumerate(fig.axes):
        ax.tick_params(labelsize=8)
        if k % d > k // d:  # above the diagonal: empty (corner only hides the frame)
            ax.set_axis_off()
    title = f"posterior ({len(draws)} draws): 5/50/95 % dashed, 1σ and 2σ contours" + (", truth red" if truth else "")
    if left_out:
        title += "; not shown, undetermined by the data: " + ", ".join(left_out) + " (see the ratios in fit.json)"
    text = textwrap.fill(title, int(side * 14))
    fig.suptitle(text, fontsize=9, y=0.995, va="top")
    fig.subplots_adjust(top=1 - (0.17 * (text.count("\n") + 1) + 0.45) / side)  # room for it above the panels' titles
    return fig


def plot_corner(
    problem: Problem, fit: FitResult, samples: SampleResult | None = None, *, truth: dict | None = None, seed: int = 0
):
    """The posterior's marginals (the report's ``corner.png``).

    Drawn by the ``corner`` package for the first six quantities the data determine, in the
    model's order (physical parameters, e.g. ``amplitude``, ``alpha_lobe``; those the fit finds
    undetermined are left out and named in the title — their spread would be the prior's):
    smoothed histograms on the diagonal with the 5/50/95 % quantiles dashed and the median ± in
    the titles, 1σ and 2σ contours below it, over up to 4000 draws (MCMC ``samples`` when
    given, else the fit's Laplace approximation); known truth (``truth``) in red. Axes: d × d
    for d quantities (those above the diagonal switched off by ``corner``).

    Returns a ``matplotlib.figure.Figure`` (made without pyplot).

    Raises:
        InvalidInputError: as :func:`plot_recovered_statistics`.
    """
    check_fit(problem, fit, "plot_corner(problem, fit)")
    check_samples(fit, samples, "plot_corner(problem, fit, samples)")
    truth = check_truth(truth)
    seed = integer(seed, "seed", 0)
    return corner_figure(problem.model, posterior_draws(problem, fit, samples, seed, n=CORNER_DRAWS), truth, fit)
