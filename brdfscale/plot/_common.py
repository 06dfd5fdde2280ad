"""What every figure of :mod:`brdfscale.plot` shares: the style (:mod:`brdfscale._figure_style`:
a Figure outside pyplot, labelled colour bars, tick sizes) and argument checks. matplotlib is
imported inside the functions only."""

import numpy as np

from .._errors import InvalidInputError
from .._figure_style import colorbar, colormap, figure, SLOPE_DENSITY, small_ticks
from .._show import concrete


__all__ = [
    "SLOPE_DENSITY",
    "colorbar",
    "colormap",
    "figure",
    "small_ticks",
    "require_concrete",
    "require_one",
    "positive_number",
    "grid_points",
    "luminance",
    "luminance_sigma",
]


def require_concrete(value, what: str) -> None:
    """InvalidInputError unless every array of ``value`` holds values (a figure needs numbers:
    not inside ``jax.jit``/``vmap``/``grad``, not ``jax.eval_shape`` output)."""
    if not concrete(value):
        raise InvalidInputError(
            f"{what} has traced or abstract values (inside jax.jit/vmap/grad or from "
            "jax.eval_shape); a figure needs concrete numbers: draw it outside the transformation."
        )


def require_one(shape: tuple, what: str) -> None:
    """InvalidInputError for a batch (e.g. a vmapped module): one object per figure."""
    if shape != ():
        raise InvalidInputError(
            f"{what} is a batch of shape {shape} (e.g. from jax.vmap); a figure draws one: "
            f"select one with jax.tree.map(lambda leaf: leaf[k], {what.split()[0]})."
        )


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
