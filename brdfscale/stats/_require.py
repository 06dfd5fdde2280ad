"""The one check that a statistic is a probability density of facet slopes, not a
plus-distribution (:func:`require_density`): used wherever a lobe shape, a slope statistic, a
micro lobe, a mixture component, a smooth part or a tilt is taken."""

from .._errors import InvalidInputError
from ._base import AbstractGeneralisedDensity, AbstractSlopeDensity


__all__ = ["require_density"]


def require_density(value, name: str, *, use: str = "", other: str = "", each: bool = False):
    """``value`` if it is a probability density of facet slopes (mass 1): an
    :class:`AbstractSlopeDensity`. Otherwise :class:`brdfscale.InvalidInputError` naming the
    argument ``name``:

    * for an :class:`AbstractGeneralisedDensity` (a plus-distribution h_n: mass 0, no pointwise
      density — as a statistic it gives a negative lobe), saying so, followed by ``use`` (what
      to give instead, e.g. ``"Use brdfscale.plus.NearlySpecular(...)."``);
    * for anything else, ``"{name} must be a brdfscale.stats density{other}; got …"``.

    ``each``: ``value`` is a sequence, every item checked (``name`` the plural argument).
    """
    items = tuple(value) if each else (value,)
    generalised = [type(v).__name__ for v in items if isinstance(v, AbstractGeneralisedDensity)]
    if generalised:
        what = "probability densities" if each else "a probability density"
        raise InvalidInputError(
            f"{name} must be {what} of facet slopes (mass 1); got {', '.join(generalised)}, a generalised function "
            f"of mass 0 with no pointwise density (a plus-distribution h_n){'. ' + use if use else '.'}"
        )
    wrong = [type(v).__name__ for v in items if not isinstance(v, AbstractSlopeDensity)]
    if wrong or not items:
        raise InvalidInputError(
            f"{name} must be {'brdfscale.stats densities' if each else 'a brdfscale.stats density'}"
            f"{other}; got {', '.join(wrong) or 'none'}."
        )
    return value
