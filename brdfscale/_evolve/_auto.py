"""The automatic choice: the first path that applies — closed form, else radial, else grid.

:class:`Auto` is a method like the paths (the pattern of lineax's ``AutoLinearSolver``): it
chooses one of them from the inputs' structure (families and isotropy, never values, so the
choice is the same under ``jax.jit``) and hands resolution and evaluation to it.
"""

from ..lobes import AbstractLobe
from ._closed_form import ClosedForm
from ._grid import Grid
from ._method import AbstractMethod
from ._radial import Radial


class Auto(AbstractMethod):
    """The first path that applies: closed form, else radial (everything radially symmetric),
    else grid (:meth:`select_method`)."""

    def select_method(self, lobe, s_from, s_to) -> AbstractMethod:
        """The path for these inputs, unresolved (structure only: the families and their
        isotropy, never parameter values, so it is the same under ``jax.jit``)."""
        for path in (ClosedForm(), Radial()):
            if path.applicable(lobe, s_from, s_to):
                return path
        return Grid()  # applies to everything

    def applicable(self, lobe, s_from, s_to) -> bool:
        return True

    def choose(self, lobe, s_from, s_to) -> AbstractMethod:
        return self.select_method(lobe, s_from, s_to)

    def resolve(self, lobe, s_from, s_to, **arguments) -> AbstractMethod:
        return self.choose(lobe, s_from, s_to).resolve(lobe, s_from, s_to, **arguments)

    def evaluate(self, lobe, s_from, s_to, **arguments) -> AbstractLobe:
        return self.choose(lobe, s_from, s_to).evaluate(lobe, s_from, s_to, **arguments)

    def explain(self) -> str:
        return "auto: closed form, else radial, else grid"
