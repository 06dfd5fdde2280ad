"""What every figure of :mod:`brdfscale.plot` shares: a Figure outside pyplot, labelled colour
bars, argument checks. matplotlib is imported inside the functions only."""

import numpy as np

from .._errors import InvalidInputError
from .._show import concrete

SLOPE_DENSITY = "per unit slope²"
"""The unit of a lobe ``A·g(u)`` and of a slope density ``s(m)``: slopes are dimensionless, the
densities are per unit area of the slope plane."""


def figure(width: float = 6.4, height: float = 4.8, **options):
    """A ``matplotlib.figure.Figure`` made without pyplot: no backend is chosen, pyplot's list
    of figures is untouched, and the figure is freed with its last reference. Jupyter shows it
    as a PNG when it is a cell's value, with or without pyplot's inline backend
    (:class:`~brdfscale.plot._figure.ShownFigure`); ``fig.savefig(path)`` writes it. Constrained
    layout (colour bars and labels fitted) unless ``layout=`` says otherwise; ``options`` go to
    ``Figure``."""
    from ._figure import ShownFigure

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


def require_concrete(value, what: str) -> None:
    """InvalidInputError unless every array of ``value`` holds values (a figure needs numbers:
    not inside ``jax.jit``/``vmap``/``grad``, not ``jax.eval_shape`` output)."""
    if not concrete(value):
        raise InvalidInputError(f"{what} has traced or abstract values (inside jax.jit/vmap/grad or from "
                                "jax.eval_shape); a figure needs concrete numbers: draw it outside the transformation.")


def require_one(shape: tuple, what: str) -> None:
    """InvalidInputError for a batch (e.g. a vmapped module): one object per figure."""
    if shape != ():
        raise InvalidInputError(f"{what} is a batch of shape {shape} (e.g. from jax.vmap); a figure draws one: "
                                f"select one with jax.tree.map(lambda leaf: leaf[k], {what.split()[0]}).")


def positive_number(value, name: str) -> float:
    from .._validation import real

    return real(value, name, minimum=0.0, strict=True)


def grid_points(size, name: str = "size", minimum: int = 9, maximum: int = 2049) -> int:
    """An odd number of grid points per axis (so the grid has a node at 0), in [minimum, maximum]."""
    from .._validation import integer

    n = integer(size, name, minimum)
    if n > maximum:
        raise InvalidInputError(f"{name} must be at most {maximum} points per axis; got {n}.")
    return n + 1 - n % 2


def luminance(values: np.ndarray) -> np.ndarray:
    """Rec. 709 luminance of an (n, n, 3) image; an (n, n) image as it is."""
    return values if values.ndim == 2 else values @ np.array([0.2126, 0.7152, 0.0722])


def luminance_sigma(sigma: np.ndarray) -> np.ndarray:
    """σ of the Rec. 709 luminance for independent channel noise; an (n, n) σ as it is."""
    return sigma if sigma.ndim == 2 else np.sqrt((sigma**2) @ (np.array([0.2126, 0.7152, 0.0722]) ** 2))
