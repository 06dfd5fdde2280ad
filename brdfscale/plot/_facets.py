"""Facet statistics of a surface against the facet size: Σ(μ), its errors, the facet counts and g_μ."""

import numpy as np

from .._errors import InvalidInputError
from .._show import display_unit
from ._common import colormap, figure, small_ticks


def _marginal(lobe, axis: int):
    """The marginal density of the tabulated lobe along u_x (axis 0) or u_y (axis 1):
    ``∫ g(u) du_y`` (resp. ``du_x``) by the trapezoid rule over the table's nodes — (u, values).

    A marginal holds every facet's count; a cut through ``u = 0`` holds one row's, which on a
    measured file with quantised heights is a comb of empty and full nodes on the log axis."""
    values, extent = np.asarray(lobe.values, dtype=float), np.asarray(lobe.extent, dtype=float)
    if axis == 1:
        values, extent = values.T, extent[::-1]
    n_other, n = values.shape
    step = 2.0 * extent[1] / (n_other - 1)
    return np.linspace(-extent[0], extent[0], n), (values.sum(axis=0) - 0.5 * (values[0] + values[-1])) * step


def facet_statistics(results, *, field=None):
    """Σ(μ) against the facet size with its standard errors and facet counts, beside the
    within-facet lobes ``g_μ`` — the figure of ``brdfscale topography``'s ``statistics.png``.

    Left: σ_x(μ) = √Σ_xx, σ_y(μ) = √Σ_yy log–log, error bars from
    :attr:`~brdfscale.synth.FacetStatistics.covariance_error` (δσ = δΣ/2σ), the number of facets
    at each point (a flat surface, Σ = 0 at every scale, is drawn on a linear axis and said so).
    Middle and right: the marginals of ``g_μ`` along u_x and u_y (``∫ g_μ du_y``, ``∫ g_μ du_x``:
    every facet's count, where a cut through ``u = 0`` holds one row's and shows a measured
    file's quantised heights as a comb) at up to four scales above one pixel (at one pixel
    ``g_μ`` is the micro lobe alone), over the central interval that holds :data:`CUT_MASS` of
    each marginal (widened by a quarter) — quantiles, so that the few outlier pixels of a
    measured file do not set the range. Every title names μ's unit.

    Args:
        results: the :class:`brdfscale.synth.FacetStatistics` of :func:`brdfscale.synth.facet_statistics`.
        field: the :class:`brdfscale.synth.HeightField` they were measured on (optional): its
            pixel pitch adds a pixel axis, its file name the title; lengths are shown in
            metric units when ``field.unit == "m"``.

    Returns a ``matplotlib.figure.Figure`` (made without pyplot). InvalidInputError for results
    that are not a non-empty sequence of FacetStatistics.
    """
    import numpy as np

    from ..synth import FacetStatistics, HeightField

    results = list(results) if isinstance(results, (list, tuple)) else [results]
    if not results or not all(isinstance(r, FacetStatistics) for r in results):
        raise InvalidInputError(
            "results must be brdfscale.synth.FacetStatistics (a sequence of them, from "
            "synth.facet_statistics); got " + ", ".join(sorted({type(r).__name__ for r in results}))
        )
    if field is not None and not isinstance(field, HeightField):
        raise InvalidInputError(f"field must be a brdfscale.synth.HeightField or None; got {type(field).__name__}.")
    results = sorted(results, key=lambda r: r.mu)
    mus = [r.mu for r in results]
    unit, size = display_unit(mus) if field is None or field.unit == "m" else (field.unit or "length units", 1.0)
    fig = figure(13.0, 4.2)
    ax, cx, cy = fig.subplots(1, 3)
    x = np.array(mus) / size
    flat = all(not np.any(np.diag(r.covariance) > 0) for r in results)
    for a, (marker, name) in enumerate((("o-", "σ_x"), ("s--", "σ_y"))):
        sd = np.sqrt(np.maximum([r.covariance[a, a] for r in results], 0.0))
        err = np.array([r.covariance_error[a, a] for r in results]) / np.where(sd > 0, 2 * sd, np.inf)
        ax.errorbar(
            x,
            sd if flat else np.where(sd > 0, sd, np.nan),  # on the log axis a zero has no place
            yerr=np.where(np.isfinite(err), err, np.nan),
            fmt=marker,
            ms=4,
            capsize=2,
            label=f"{name} = √Σ_{name[-1]}{name[-1]}",
        )
    top = np.sqrt(np.max([np.max(np.diag(r.covariance)) for r in results]))
    for xi, r in zip(x, results):
        peak = np.sqrt(max(np.max(np.diag(r.covariance)), 0.0))
        if peak > 0 or flat:
            ax.annotate(f"{r.count}", (xi, peak), textcoords="offset points", xytext=(3, 5), ha="left", fontsize=6)
    ax.set_xscale("log")
    if flat:  # a flat surface: Σ(μ) = 0 at every scale, on a linear axis
        ax.set_ylim(-1.0, 1.0)
        ax.text(0.5, 0.6, "flat surface: Σ(μ) = 0 at every scale", ha="center", transform=ax.transAxes, fontsize=8)
    else:
        ax.set_yscale("log")
        ax.set_ylim(None, top * 1.6)
    if field is not None:
        dx = field.spacing[0] / size
        pixels = ax.secondary_xaxis("top", functions=(lambda v: v / dx, lambda p: p * dx))
        pixels.set_xlabel("μ (pixels)", fontsize=8)
        pixels.tick_params(labelsize=7)
    ax.set_xlabel(f"facet size μ ({unit})", fontsize=8)
    ax.set_ylabel("facet-slope standard deviation", fontsize=8)
    ax.set_title(f"Σ(μ) ± standard error, μ in {unit} (numbers: facets)", fontsize=9)
    ax.legend(fontsize=7)
    small_ticks(ax)

    shown = [k for k, r in enumerate(results) if r.block != (1, 1)]  # at one pixel g_μ is the micro lobe alone
    if len(shown) > 4:
        shown = [shown[k] for k in np.unique(np.rint(np.linspace(0, len(shown) - 1, 4)).astype(int))]
    colours = colormap("viridis")(np.linspace(0.0, 0.85, max(len(shown), 1)))
    span = f"{results[shown[0]].mu / size:.3g}–{results[shown[-1]].mu / size:.3g} {unit}" if shown else ""
    for axis, panel, name, other in ((0, cx, "u_x", "u_y"), (1, cy, "u_y", "u_x")):
        reach, peak, edge, widest = 0.0, 0.0, 0.0, 1
        for colour, k in zip(colours, shown):
            u, g = _marginal(results[k].lobe, axis)
            if not g.max() > 0:
                continue
            g, width = _smoothed(g, _mass_reach(u, g, CORE_MASS), u)
            widest = max(widest, width)
            reach, peak = max(reach, _mass_reach(u, g, CUT_MASS)), max(peak, float(g.max()))
            edge = max(edge, float(u[-1]))
            panel.semilogy(
                u,
                np.where(g > 0, g, np.nan),
                color=colour,
                lw=1.2,
                label=f"μ = {results[k].mu / size:.3g} {unit}, {results[k].count} facets",
            )
        if flat and shown:  # every pixel facet parallel to its facet
            panel.cla()
            panel.text(0.5, 0.5, "flat surface: g_μ = δ(u) at every scale", ha="center", transform=panel.transAxes)
        elif peak > 0:
            reach = 1.25 * reach if reach > 0 else edge  # a lobe in one node: the whole grid
            panel.set_xlim(-reach, reach)
            panel.set_ylim(peak * 1e-4, peak * 2)
            panel.legend(fontsize=6)
        else:
            panel.text(
                0.5, 0.5, "no scale above one pixel", ha="center", va="center", transform=panel.transAxes, fontsize=8
            )
        panel.set_xlabel(f"slope offset {name}", fontsize=8)
        panel.set_ylabel(f"∫ g_μ d{other} (per unit slope)", fontsize=8)
        smoothed = f", moving average of ≤ {widest} nodes" if widest > 1 else ""
        panel.set_title(
            f"within-facet lobe g_μ along {name}" + (f", μ = {span}" if span else "") + f"\nmarginal{smoothed}",
            fontsize=9,
        )
        small_ticks(panel)
    name = None if field is None else field.description.get("file") or field.description.get("name")
    what = f"facet-slope statistics at μ = {mus[0] / size:.3g}–{mus[-1] / size:.3g} {unit}"
    fig.suptitle(f"{name}: {what}" if name else what, fontsize=10)
    return fig


CUT_MASS = 0.998
"""The share of each marginal's mass the lobe panels show: their range is the central interval
holding it (quantiles of the marginal, widened by a quarter), not the farthest non-zero node, so
one outlier pixel does not shrink the lobe to a spike."""


MAX_AVERAGE = 31
"""The widest moving average (nodes) the lobe panels apply to a marginal (:func:`_smoothed`)."""
CORE_MASS = 0.9
"""The share of a marginal's mass whose central interval :func:`_smoothed` examines for a comb
(the lobe's core: contiguous for a lobe; gaps farther out, e.g. between the core and a side
lobe of steps, are the surface's and are left as they are)."""
COMB_VARIATION = 1.5
"""The most total variation a shown marginal may have, relative to a single-peaked curve's."""


def _smoothed(g: np.ndarray, reach: float, u: np.ndarray) -> tuple[np.ndarray, int]:
    """``g`` averaged over the narrowest odd window of nodes (1, 3, …, :data:`MAX_AVERAGE`) after
    which, inside ``|u| ≤ reach``, it has no empty node and a total variation at most
    :data:`COMB_VARIATION` times a single-peaked curve's (``2 max − g(ends)``), and that window's
    width. A measured file's quantised heights put the facets' slope offsets on a comb of values
    whose spacing is several table nodes: full nodes between (nearly) empty ones, which a log
    axis draws as spikes; the average (a box of unit sum) keeps the mass and shows the lobe's
    shape. A smooth, well-sampled lobe is drawn as it is (width 1)."""
    inside = np.abs(u) <= reach
    smooth, width = g, 1
    for width in range(1, MAX_AVERAGE + 1, 2):
        smooth = np.convolve(g, np.full(width, 1.0 / width), mode="same") if width > 1 else g
        shown = smooth[inside]
        if shown.size < 3:
            return smooth, width
        single = 2.0 * shown.max() - shown[0] - shown[-1]
        if np.all(shown > 0) and np.abs(np.diff(shown)).sum() <= COMB_VARIATION * single:
            return smooth, width
    return smooth, width


def _mass_reach(u: np.ndarray, g: np.ndarray, mass: float) -> float:
    """The half-width of the central interval of ``u`` holding ``mass`` of the cut ``g`` (≥ 0)."""
    weight = np.maximum(g, 0.0)
    total = float(weight.sum())
    if not total > 0:
        return 0.0
    order = np.argsort(np.abs(u), kind="stable")
    inside = np.cumsum(weight[order]) / total
    k = min(int(np.searchsorted(inside, mass)), len(u) - 1)
    return float(np.abs(u[order[k]]))
