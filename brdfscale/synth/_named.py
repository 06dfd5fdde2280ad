"""Built-in named surfaces (pixel pitch 1: lengths and scales in pixels)."""

from typing import Callable

from .. import stats
from .._errors import InvalidInputError
from .._surfaces import DESCRIPTIONS
from ._profiles import blazed, scratches
from ._random import as_generator
from ._spectral import _check_size, spectral_field
from ._surface import check_micro, HeightField


def _gaussian(size, seed):
    return spectral_field(stats.GaussianCorrelation(0.05, 8.0), size=size, seed=seed)


def _anisotropic(size, seed):
    return spectral_field(stats.GaussianCorrelation(0.05, (6.0, 24.0)), size=size, seed=seed)


def _fractal(size, seed):
    return spectral_field(stats.KCorrelation(A=30.0, B=32.0, C=3.5), size=size, seed=seed)


def _scratched(size, seed):
    rng = as_generator(seed)
    base = spectral_field(stats.GaussianCorrelation(0.02, 8.0), size=size, seed=rng)
    cuts = scratches(size=size, count=max(1, size // 32), depth=0.2, width=8.0, length=size / 4, seed=rng)
    return base + cuts


def _blazed(size, seed):
    if size % 16:
        raise InvalidInputError(f"the 'blazed' surface needs a size divisible by its 16-pixel period; got {size}.")
    return blazed(size=size, period=16, slopes=(0.03, -0.09))


_BUILDERS = {
    "gaussian": _gaussian,
    "anisotropic": _anisotropic,
    "fractal": _fractal,
    "scratched": _scratched,
    "blazed": _blazed,
}
SURFACES: dict[str, tuple[str, Callable[[int, object], HeightField]]] = {
    name: (DESCRIPTIONS[name], _BUILDERS[name]) for name in DESCRIPTIONS
}
"""name → (description, builder(size, seed))."""


def named_surface(
    name: str, *, size: int = 512, seed: object = 0, micro: stats.AbstractSlopeDensity | None = None
) -> HeightField:
    """A built-in surface by name (keys of :data:`SURFACES`), pixel pitch 1.

    ``micro`` replaces the pixel facets' lobe (default: mirror facets).

    Raises InvalidInputError for an unknown name, ``size`` not an integer ≥ 4 or above
    :data:`MAX_GRID_BYTES` (n × n float64 heights), a bad seed, or a ``micro`` that is not a
    probability density of facet slopes — all before the surface is synthesised.
    """
    if not isinstance(name, str) or name not in SURFACES:
        raise InvalidInputError(f"unknown surface {name!r}; built-in surfaces: {', '.join(SURFACES)}.")
    size = _check_size(size)
    as_generator(seed)  # checked here (the builder draws from it; "blazed" needs none)
    if micro is not None:
        check_micro(micro)
    field = SURFACES[name][1](size, seed)
    return HeightField(
        field.heights,
        field.spacing,
        micro=field.micro if micro is None else micro,
        spectrum=field.spectrum,
        description={**field.description, "name": name},
    )
