"""One-call figures of lobes, statistics, measurements, plans and fits (docs/plotting.md).

Every function returns a ``matplotlib.figure.Figure`` made without pyplot: nothing global
changes (no backend is chosen, pyplot's list of figures stays as it was), Jupyter shows the
figure when it is a cell's value, and ``fig.savefig(path)`` writes it. matplotlib is imported
inside the functions only, so importing this module does not import it.

* :func:`lobe` — a lobe on the slope-offset plane, its slices, and (``incident=``) its BRDF;
* :func:`statistics` — facet-slope densities and their transforms S(W), of one statistic, a
  list, or a scale law at several facet sizes μ;
* :func:`facet_statistics` — Σ(μ) of a surface against the facet size with its standard errors
  and facet counts, beside the within-facet lobes g_μ (measured or synthesised fields);
* :func:`measurements` — every image of a :class:`brdfscale.MeasurementSet` with its σ;
* :func:`plan` — what a :func:`brdfscale.scene.plan` computes where;
* :func:`fit`, :func:`recovered_statistics`, :func:`corner` — a fit's data, model and
  residuals; the recovered S(W, μ) with 5–95 % bands; the posterior's marginals (the figures
  :func:`brdfscale.fitting.write_report` saves);
* :func:`chains` — the MCMC chains of :func:`fitting.sample`;
* :func:`figure`, :func:`colorbar`, :func:`colormap`, :func:`small_ticks` — the helpers
  behind them, for figures of one's own in the same style.

This package is the top of the library's layers but for the applications (docs/architecture.md):
it imports the objects it draws, and nothing in the library imports it. The objects have the
same figures as methods — ``lobe.plot()``, ``density.plot()``, ``law.plot(mu=…)``,
``mset.plot()``, ``plan.plot()``, ``samples.plot()`` — which reach this package through the one
seam :func:`brdfscale._figures.draw`, by name and only when called. The fitting figures are
drawn by :mod:`brdfscale.fitting` (``fitting.plot_fit`` and its siblings, beside the fitting
models they need, in the style of :mod:`brdfscale._figure_style`); :func:`fit`,
:func:`recovered_statistics` and :func:`corner` call them (``fit_result.plot(problem)`` too), and
import :mod:`brdfscale.fitting` when called, so importing this package stays light.

Tested in tests/test_show.py (axes, labels, pyplot's figure list unchanged).
"""

from ._common import colorbar, colormap, figure, SLOPE_DENSITY, small_ticks
from ._data import chains, measurements
from ._facets import facet_statistics
from ._lobes import lobe, statistics
from ._plan import plan


__all__ = [
    "lobe",
    "statistics",
    "facet_statistics",
    "measurements",
    "plan",
    "fit",
    "recovered_statistics",
    "corner",
    "chains",
    "figure",
    "colorbar",
    "colormap",
    "small_ticks",
    "SLOPE_DENSITY",
]


def fit(problem, fit, **options):
    """Data, fitted model and whitened residuals per measured scale: :func:`fitting.plot_fit`
    (the report's ``data_vs_fit.png``); returns a ``matplotlib.figure.Figure``."""
    from .. import fitting

    return fitting.plot_fit(problem, fit, **options)


def recovered_statistics(problem, fit, samples=None, **options):
    """The recovered S(W, μ0)/S(W, μ) and S(W, μ) with 5–95 % bands from ``samples`` or the
    Laplace draws, truth dashed when given (``truth=``): :func:`fitting.plot_recovered_statistics`
    (the report's ``statistics.png``); returns a ``matplotlib.figure.Figure``."""
    from .. import fitting

    return fitting.plot_recovered_statistics(problem, fit, samples, **options)


def corner(problem, fit, samples=None, **options):
    """The posterior's one- and two-dimensional marginals: :func:`fitting.plot_corner` (the
    report's ``corner.png``); returns a ``matplotlib.figure.Figure``."""
    from .. import fitting

    return fitting.plot_corner(problem, fit, samples, **options)
