"""The style every figure of brdfscale shares — a ``matplotlib.figure.Figure`` made without
pyplot, labelled colour bars, readable ticks — used by :mod:`brdfscale.plot` (which re-exports
it: ``plot.figure``, ``plot.colorbar``, ``plot.colormap``, ``plot.small_ticks``,
``plot.SLOPE_DENSITY``) and by the fitting figures (:mod:`brdfscale.fitting`'s ``plot_fit`` and
siblings). It lives in the core so that the fitting layer draws in the same style without
importing the plot package, which sits above it (docs/architecture.md). matplotlib is imported
inside the functions only.

Tested in tests/test_show.py (axes, labels, pyplot's figure list unchanged).
"""

SLOPE_DENSITY = "per unit slope²"
"""The unit of a lobe ``A·g(u)`` and of a slope density ``s(m)``: slopes are dimensionless, the
densities are per unit area of the slope plane."""


def figure(width: float = 6.4, height: float = 4.8, **options):
    """A ``matplotlib.figure.Figure`` made without pyplot: no backend is chosen, pyplot's list
    of figures is untouched, and the figure is freed with its last reference. Jupyter shows it
    as a PNG when it is a cell's value, with or without pyplot's inline backend
    (:class:`~brdfscale._shown_figure.ShownFigure`); ``fig.savefig(path)`` writes it. Constrained
    layout (colour bars and labels fitted) unless ``layout=`` says otherwise; ``options`` go to
    ``Figure``."""
    from ._shown_figure import ShownFigure

    options.setdefault("layout", "constrained")
    return ShownFigure(figsize=(width, height), **options)


def colormap(name: str):
    """A registered matplotlib colormap by name (without pyplot)."""
    import matplotlib

    return matplotlib.colormaps[name]


def colorbar(fig, mappable, ax, label: str):
    """A colour bar beside ``ax`` for ``mappable`` (an image), labelled ``label`` (quantity and unit)."""
    bar = fig.colorbar(mappable, ax=ax, shrink=0.92)
    bar.set_label(label, fontsize=8)
    bar.ax.tick_params(labelsize=7)
    return bar


def small_ticks(ax, integer: bool = False) -> None:
    """Tick labels at a readable size for panels in a grid: at most six per linear axis
    (``integer``: whole numbers on the y axis, e.g. counts); on a log axis labels at 1, 2 and 5
    times powers of ten (at most eight) and none at the minor ticks."""
    from matplotlib.ticker import LogLocator, MaxNLocator, NullFormatter

    ax.tick_params(labelsize=7)
    for axis in (ax.xaxis, ax.yaxis):
        if axis.get_scale() == "linear":
            axis.set_major_locator(MaxNLocator(6, integer=integer and axis is ax.yaxis))
        elif axis.get_scale() == "log":
            axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0), numticks=8))
            axis.set_minor_formatter(NullFormatter())
