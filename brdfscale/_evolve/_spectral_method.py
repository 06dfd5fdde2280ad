"""What the two spectral paths share: the regularised quotient, resolution and evaluation.

:class:`AbstractSpectralMethod` is the abstract base of :class:`~brdfscale.Radial` and
:class:`~brdfscale.Grid`: both evaluate :class:`._spectral.EvolvedDensity` — the exact
transform ``G_from S_from / S_to`` with the Tikhonov λ of the division — and differ only in
how they invert it (``values``, ``discretise``: each path's own module). Here, once for both:

* ``resolve`` (what :func:`brdfscale.select` returns): the λ (a number as given, or a rule's
  choice from concrete values: :mod:`._regularise`), then the discretisation chosen and
  verified for the concrete values, carrying the λ;
* ``evaluate`` (what :func:`brdfscale.evolve` returns): the same density, resolved when the
  values are concrete and the method gives no tolerance of its own; refused
  (:class:`brdfscale.UnresolvedMethodError`) when traced and unresolved.
"""

import abc
import dataclasses
from typing import ClassVar

import jax.numpy as jnp

from .._errors import UnresolvedMethodError
from .._validation import integer, is_concrete
from ..lobes import Lobe
from ._method import AbstractMethod
from ._regularise import choose, needs_data, unresolved_regularisation
from ._spectral import EvolvedDensity


class AbstractSpectralMethod(AbstractMethod):
    """A path that inverts the evolved transform numerically (module docstring)."""

    size_argument: ClassVar[str]
    """The constructor argument that fixes the discretisation's size (``"nodes"``, ``"size"``)."""

    @property
    @abc.abstractmethod
    def resolution(self) -> int | None:
        """Gauss–Legendre nodes (radial) or grid side (grid); None: not yet chosen."""

    @property
    def resolved(self) -> bool:
        return self.resolution is not None

    @property
    def half_width(self):
        """The slope half-width the discretisation covers as given (None: from the support radius)."""
        return None

    def show_sizes(self) -> list[tuple[str, object]]:
        """The items an evolved lobe shows for its discretisation."""
        return [(self.size_argument, self.resolution)]

    def check_queries(self, density: EvolvedDensity, m) -> None:
        """Warn where concrete queries ``m`` lie beyond what the discretisation serves within tol."""

    @abc.abstractmethod
    def values(self, density: EvolvedDensity, m):
        """``density`` (whose discretisation this is) at the flat offsets ``m`` (q, 2)."""

    @abc.abstractmethod
    def discretise(self, density: EvolvedDensity) -> "AbstractSpectralMethod":
        """This method with every choice it leaves open made and verified for ``density``'s
        concrete values (each path's own module)."""

    @abc.abstractmethod
    def sized(self, size, extent) -> "AbstractSpectralMethod":
        """The method the string API's ``size=``/``extent=`` describe on this path."""

    # -- shared behaviour -----------------------------------------------------------------------
    def with_sizes(self, size, extent):
        if size is not None:
            integer(size, "size", 8)
        return self.sized(size, extent)

    def carried(self):
        """``(λ, rule)`` this method carries, ``(None, None)`` when none."""
        return self.regularisation, self.regularisation_rule

    def carrying(self, lam, rule: str | None, note: str | None):
        """This method carrying the Tikhonov λ chosen with it (None: none)."""
        return dataclasses.replace(self, regularisation=lam, regularisation_rule=rule, regularisation_note=note)

    def regularised(self, lobe, s_from, s_to, lam, rule, noise):
        """``(λ, method)``: the λ of the division — a number as given; a rule's choice
        (:mod:`._regularise`), reused from a method that carries one of that rule, else chosen
        here from concrete values (UnresolvedMethodError when traced) and carried by the
        returned method; None: the method's own λ, else 0."""
        own, own_rule = self.carried()
        if rule is None:
            if lam is not None:
                return lam, self
            return (jnp.asarray(0.0) if own is None else own), self
        if own is not None and own_rule == rule:
            return own, self
        if needs_data(lobe, s_to) and not is_concrete((lobe, s_from, s_to, noise)):
            raise unresolved_regularisation(rule)
        value, how = choose(lobe, s_from, s_to, rule, noise)
        value = jnp.asarray(value)
        return value, self.carrying(value, rule, how)

    def unresolved(self) -> UnresolvedMethodError:
        return UnresolvedMethodError(
            f"the {self.path} path's discretisation depends on parameter values, which are traced here (inside "
            "jax.jit, grad or vmap) and so unknown; brdfscale does not fall back to a default size. Resolve it "
            "outside the transformation from concrete values, `method = brdfscale.select(lobe, s_from, s_to, "
            "tol=...)`, and pass `method=method` inside (re-select when the parameters move far), or fix the "
            f"size yourself with {type(self).__name__}({self.size_argument}=...).")

    def _discretised(self, density: EvolvedDensity, given=None) -> "AbstractSpectralMethod":
        """:meth:`discretise`, carrying the λ this method carries — or ``given``, a nonzero λ
        passed as a number (recorded by :func:`brdfscale.select` as ``"given"``)."""
        chosen, how = self.carried()
        if chosen is None and given is not None and float(given) != 0:
            chosen, how = given, "given"
        resolved = self.discretise(density)
        return resolved if chosen is None else resolved.carrying(chosen, how, self.regularisation_note)

    def _density(self, lobe, s_from, s_to, tol, regularisation, rule, noise, check):
        lam, method = self.regularised(lobe, s_from, s_to, regularisation, rule, noise)
        return EvolvedDensity(lobe.shape, s_from, s_to, lam, method, tol, check), method

    def applicable(self, lobe, s_from, s_to) -> bool:
        return True

    def choose(self, lobe, s_from, s_to) -> AbstractMethod:
        return self

    def resolve(self, lobe, s_from, s_to, *, tol, regularisation, rule, noise, check):
        if not is_concrete((lobe, s_from, s_to)):
            raise self.unresolved()
        density, method = self._density(lobe, s_from, s_to, tol, regularisation, rule, noise, check)
        if not is_concrete(density):
            raise method.unresolved()
        return method._discretised(density, given=density.regularisation if rule is None else None)

    def evaluate(self, lobe, s_from, s_to, *, tol, regularisation, rule, noise, check):
        own = tol if self.tol is None else self.tol
        density, method = self._density(lobe, s_from, s_to, own, regularisation, rule, noise, check)
        if method.tol is None and is_concrete(density):
            resolved = method._discretised(density)
            density = density.with_discretisation(resolved, resolved.tol)
        elif not method.resolved:
            raise method.unresolved()
        return Lobe(density, lobe.amplitude)
