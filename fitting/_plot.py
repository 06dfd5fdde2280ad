"""The figures of a fit — the same ones :func:`fitting.write_report` saves and a notebook shows.

* :func:`plot_fit` — data, fitted model and whitened residuals per measured scale
  (``data_vs_fit.png`` of the report);
* :func:`plot_recovered_statistics` — the recovered statistics with 5–95 % bands
  (``statistics.png``);
* :func:`plot_corner` — the posterior's one- and two-dimensional marginals (``corner.png``).

They live here, not in :mod:`brdfscale.plot`, because they need the fitting models (the
package ``fitting`` builds on brdfscale, not the other way round); :func:`brdfscale.plot.fit`,
:func:`brdfscale.plot.recovered_statistics` and :func:`brdfscale.plot.corner` call them, importing
:mod:`fitting` only then. Every figure is a ``matplotlib.figure.Figure`` made without pyplot
(:func:`brdfscale.plot.figure`), so drawing one changes no global matplotlib state; matplotlib
is imported when a figure is drawn. Draws of the posterior are reproducible: the first 400 of
a seeded generator (``seed``, default 0, as in the report), from the MCMC samples when given,
else from the Laplace approximation of the fit.
"""

from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from brdfscale import InvalidInputError
from brdfscale import plot as _figures
from brdfscale.checks import integer, real

from ._estimate import FitResult, Problem, check_fit
from ._model import predict_images
from ._parametric import ParametricModel
from ._sample import SampleResult

__all__ = ["plot_fit", "plot_recovered_statistics", "plot_corner"]

CORNER_MAX = 6
"""The most quantities a corner plot shows (the first ones)."""
DRAWS = 400
"""Posterior draws behind the bands and the corner plot."""
_LOBE_UNIT = f"A·g(u) ({_figures.SLOPE_DENSITY})"


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


def check_samples(fit: FitResult, samples, what: str) -> None:
    """InvalidInputError unless ``samples`` is None or the SampleResult of ``fit``'s coordinates."""
    if samples is not None and (not isinstance(samples, SampleResult) or tuple(samples.names) != tuple(fit.names)):
        got = type(samples).__name__ if not isinstance(samples, SampleResult) else f"a chain of {len(samples.names)} coordinates"
        raise InvalidInputError(f"{what}: samples must be None or the SampleResult of fitting.sample for this problem's "
                                f"{len(fit.names)} coordinates; got {got}.")


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


def plot_fit(problem: Problem, fit: FitResult):
    """Data, fit and whitened residuals at every measured scale (the report's ``data_vs_fit.png``).

    One row per scale (its first image): (1) the data ``A·g(u)`` over the slope offsets
    ``u`` (per unit slope²), (2) the model at the estimate on the same colour scale, (3) the
    whitened residual ``(fit − data)/σ`` on [−4, 4] (0 where masked); each with its colour
    bar. Axes: 6 per scale.

    Returns a ``matplotlib.figure.Figure`` (made without pyplot).

    Raises:
        InvalidInputError: ``problem`` is not a :class:`fitting.Problem` or ``fit`` not its
            :class:`fitting.FitResult`.
    """
    check_fit(problem, fit, "plot_fit(problem, fit)")
    data, model = problem.data, problem.model
    pred = np.asarray(predict_images(model, jnp.clip(jnp.asarray(fit.theta), problem.lower, problem.upper), data))
    first = [data.scale_of_image.index(k) for k in range(len(np.asarray(data.scales)))]
    fig = _figures.figure(10.5, 2.7 * len(first))
    axes = fig.subplots(len(first), 3, squeeze=False)
    for row, i in enumerate(first):
        obs, fitted = data.image(i, data.values[i]), data.image(i, pred[i])
        w = data.image(i, data.weight[i])
        e = data.extents[i]
        vmax = max(obs.max(), fitted.max())
        for col, (img, title, label, kw) in enumerate((
            (obs, "data", _LOBE_UNIT, dict(vmin=0, vmax=vmax)),
            (fitted, "fit", _LOBE_UNIT, dict(vmin=0, vmax=vmax)),
            ((fitted - obs) * w, "(fit − data)/σ", "(fit − data)/σ", dict(vmin=-4, vmax=4, cmap="RdBu_r")),
        )):
            ax = axes[row, col]
            im = ax.imshow(img, origin="lower", extent=(-e, e, -e, e), **kw)
            ax.set_title(f"μ = {float(data.scales[data.scale_of_image[i]]):.4g}: {title}", fontsize=9)
            _figures.colorbar(fig, im, ax, label)
            ax.set_ylabel("u_y (slope)", fontsize=8)
            ax.set_xlabel("u_x (slope)", fontsize=8)
            _figures.small_ticks(ax)
    return fig


def _band(ax, W, curves, color, label):
    lo, mid, hi = np.percentile(curves, [5, 50, 95], axis=0)
    ax.fill_between(W, lo, hi, color=color, alpha=0.3, lw=0)
    ax.plot(W, mid, color=color, lw=1.2, label=label)


def statistics_figure(problem: Problem, fit: FitResult, draws, true_theta):
    """The figure of :func:`plot_recovered_statistics` from given draws and true θ (or None)."""
    data, model = problem.data, problem.model
    scales = np.asarray(data.scales)
    absolute = isinstance(model, ParametricModel)
    w_max = 8.0 / float(model.quantities(jnp.asarray(fit.theta))["alpha_lobe"]) if absolute else model.knots[-1]
    W = jnp.linspace(0.0, w_max, 200)
    relative = np.asarray(_relative(model, jnp.asarray(draws), W, data))
    w = np.asarray(W)  # matplotlib iterates over what it is given: a JAX array costs a dispatch per element
    fig = _figures.figure(11 if absolute else 6, 4)
    axes = fig.subplots(1, 2 if absolute else 1, squeeze=False)[0]
    colors = _figures.colormap("viridis")(np.linspace(0, 0.9, len(scales)))
    for k in range(1, len(scales)):
        _band(axes[0], w, relative[:, k], colors[k], f"μ = {scales[k]:.3g}")
        if true_theta is not None:
            axes[0].plot(w, np.asarray(model.relative_statistics(true_theta, W, data))[k], "k--", lw=0.8)
    axes[0].set_title(f"S(W, μ0)/S(W, μ), μ0 = {scales[0]:.3g}: determined by the data (5–95 % band)", fontsize=9)
    axes[0].set_ylabel("S(W, μ0)/S(W, μ)")
    if absolute:
        curves = np.asarray(_absolute(model, jnp.asarray(draws), W, data))
        for k, mu in enumerate(scales):
            _band(axes[1], w, curves[:, k], colors[k], f"μ = {mu:.3g}")
            if true_theta is not None:
                axes[1].plot(w, np.asarray(model.statistics_at(true_theta, mu).cf_radial(W)), "k--", lw=0.8)
        axes[1].set_title("S(W, μ): absolute via the scale law's S(W, ∞) = 1", fontsize=9)
        axes[1].set_ylabel("S(W, μ)")
    for ax in axes:
        if true_theta is not None:
            ax.plot([], [], "k--", lw=0.8, label="truth")
        ax.set_xlabel("|W| (rad per unit slope)")
        ax.legend(fontsize=7)
        _figures.small_ticks(ax)
    return fig


def plot_recovered_statistics(problem: Problem, fit: FitResult, samples: SampleResult | None = None, *,
                              truth: dict | None = None, seed: int = 0):
    """The recovered facet-slope statistics with 5–95 % bands (the report's ``statistics.png``).

    Panels: (1) the ratios ``S(W, μ0)/S(W, μ)`` for every coarser measured scale — what
    multi-scale data determine — as median and 5–95 % band over 400 posterior draws (MCMC
    ``samples`` when given, else the fit's Laplace approximation); (2, parametric models) the
    absolute ``S(W, μ)`` at every measured scale, which rests on the scale law's boundary
    condition ``S(W, ∞) = 1``. Known truth (``truth``: parameter values, e.g. from
    :func:`fitting.truth_of`) is drawn dashed. W in radians per unit slope. Axes: 2 for a
    parametric model, 1 for the non-parametric one.

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
    return statistics_figure(problem, fit, posterior_draws(problem, fit, samples, seed), true_theta)


def corner_figure(model, draws, truth: dict | None):
    """The figure of :func:`plot_corner` from given draws of θ."""
    from matplotlib.ticker import MaxNLocator

    q = _quantities(model, jnp.asarray(draws))
    names = list(q)[:CORNER_MAX]
    x = np.stack([np.asarray(q[n]) for n in names], axis=1)
    d = len(names)
    fig = _figures.figure(1.8 * d + 1, 1.8 * d + 1)
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
                ax.set_yticks([])
            else:
                ax.hist2d(x[:, j], x[:, i], bins=40, cmap="Greys")
                if truth is not None and names[i] in truth:
                    ax.axhline(truth[names[i]], color="C3", lw=0.8)
            if truth is not None and names[j] in truth:
                ax.axvline(truth[names[j]], color="C3", lw=0.8)
            ax.tick_params(labelsize=6)
            ax.xaxis.set_major_locator(MaxNLocator(3))
            if i != j:
                ax.yaxis.set_major_locator(MaxNLocator(3))
            if i == d - 1:
                ax.set_xlabel(names[j], fontsize=8)
            if j == 0 and i > 0:
                ax.set_ylabel(names[i], fontsize=8)
    fig.suptitle("posterior draws: 5/50/95 % (dotted), truth (red)" if truth else "posterior draws: 5/50/95 % (dotted)",
                 fontsize=9)
    return fig


def plot_corner(problem: Problem, fit: FitResult, samples: SampleResult | None = None, *, truth: dict | None = None,
                seed: int = 0):
    """The posterior's marginals (the report's ``corner.png``).

    For the first six quantities (physical parameters, e.g. ``amplitude``, ``alpha_lobe``):
    histograms on the diagonal with the 5/50/95 % quantiles dotted, two-dimensional histograms
    below it, over 400 draws (MCMC ``samples`` when given, else the fit's Laplace
    approximation); known truth (``truth``) as red lines. Axes: d × d for d quantities (those
    above the diagonal switched off).

    Returns a ``matplotlib.figure.Figure`` (made without pyplot).

    Raises:
        InvalidInputError: as :func:`plot_recovered_statistics`.
    """
    check_fit(problem, fit, "plot_corner(problem, fit)")
    check_samples(fit, samples, "plot_corner(problem, fit, samples)")
    truth = check_truth(truth)
    seed = integer(seed, "seed", 0)
    return corner_figure(problem.model, posterior_draws(problem, fit, samples, seed), truth)
